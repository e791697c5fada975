"""The laws' steps as compiled C calls: SoftSpeed, Z-Torque, D-OSKIL and the brake run the same C
(``csrc/ss_laws.c``) in the workbench and in an exported library.

Why hand-written C and not CasADi Functions: the laws have no model to differentiate (their one
nonlinearity, a DC motor's friction ``tanh``, is a libm call); what they have is branches --
"not started yet" (the Python ``None``), an integral held while the set-point sits at its band's
edge or the torque at its limit, a filter over a variable interval, a missing reading answered by
the fallback.  In C each branch is one line beside its Python twin, the operations run in the same
order, and the two agree bit for bit; an SX graph would evaluate both sides of every ``if_else``
and reorder nothing we could check line by line.  And the configuration is numbers only, so ONE
library (built once from fixed sources, cached) serves every law on every rig: nothing is
generated per rig.

:data:`LAW_CONFIG` declares the configuration once (:class:`models.cbuild.CStruct`: the C header
and the ctypes struct); each law fills it from the values it resolved from the rig
(``law.c_config()``: :func:`law_config` with the law's fields, the rest zero).  :class:`CompiledLaw`
lays one law out in numpy-owned memory and calls ``ssl_step``; a missing reading comes back as the
index of its channel, and the workbench's law raises the same ``SolverFailure`` its Python step
raises (:func:`mitigate.controllers.base.reading`), so the counts and the messages are the same.
"""

from __future__ import annotations

import ctypes
import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from mitigate.controllers.base import Action, Controller, estimated, reading
from models.cbuild import CSRC, CStruct, build_library, c_view, lay_out, read_channels, read_source
from models.checks import check_options, option
from models.errors import SolverFailure

__all__ = ["LAW_CONFIG", "LAW_IDS", "LAW_SOURCES", "IMPLEMENTATIONS", "law_config", "law_files", "law_library",
           "CompiledLaw", "compiled_law", "compiled_action", "LawOptions", "CompiledStepLaw"]

#: the C sources of the laws' steps
LAW_SOURCES = Path(__file__).resolve().parent / "csrc"
#: implementations of a law's step: the compiled C core (default), the Python reference
IMPLEMENTATIONS = ("c", "python")
#: ``ssl_config.law`` of each kind (enum in csrc/ss_laws.h)
LAW_IDS = {"softspeed": 1, "ztorque": 2, "doskil": 3, "brake": 4}

LAW_CONFIG = CStruct("ssl_config", [
    ("law", "int", None, "1 SoftSpeed, 2 Z-Torque, 3 D-OSKIL, 4 brake"),
    ("n_ch", "int", None, "DAQ channels read (y)"),
    ("ch_drive", "int", None, "y: the drive's speed (D-OSKIL's top, the brake's drive body; -1 none)"),
    ("ch_torque", "int", None, "y: the torque at the drive (-1 none)"),
    ("torque_flip", "int", None, "the torque channel reads minus the string's torque (a flange in a shaft toward the drive)"),
    ("ch_body", "int", None, "y: the servo's body's speed (-1 none)"),
    ("torque_drive", "int", None, "the drive sets a torque: the law is its speed loop"),
    ("motor_friction", "int", None, "the torque channel reads the motor's electromagnetic torque"),
    ("use_estimate", "int", None, "brake: speeds from the estimate when it has them"),
    ("est_body", "int", None, "the servo's body's speed from the estimate e[0] (the rig does not measure it)"),
    ("period", "double", None, "call period [s]"),
    ("pipe_J", "double", None, "inertia the torque channel reads beyond the pipe [kg m^2]"),
    ("tau_pipe", "double", None, "pipe torque's low-pass [s]"),
    ("tau_acc", "double", None, "drive acceleration's (and torque's) low-pass [s]"),
    ("eta", "double", None, "gear ratio [-] (motor friction)"), ("Tf", "double", None, "motor Coulomb friction [N m]"),
    ("Cm", "double", None, "motor viscous friction [N m s/rad]"),
    ("eps_motor", "double", None, "motor friction's regularisation [rad/s]"),
    ("Kp", "double", None, "SoftSpeed / a torque drive's loop: proportional gain [N m s/rad]"),
    ("Ki", "double", None, "SoftSpeed / a torque drive's loop: integral gain [N m/rad]"),
    ("torque_max", "double", None, "a torque drive's limit [N m]"),
    ("J_v", "double", None, "SoftSpeed: virtual drive inertia [kg m^2]"),
    ("band", "double", None, "the set-point within the programme +- band [rad/s] (0: the programme's speed)"),
    ("gain", "double", None, "Z-Torque z/Z [rad/(N m s)]; D-OSKIL k_n, brake overspeed gain [N s/rad]"),
    ("gain_relative", "double", None, "brake: relative-speed gain [N s/rad]"),
    ("deadband", "double", None, "brake: speed error ignored [rad/s]"),
    ("tau_hp", "double", None, "Z-Torque: high-pass time constant [s]"),
    ("tau", "double", None, "D-OSKIL, brake: speed filter [s] (brake 0: none)"),
    ("n_min", "double", None, "force range [N]"), ("n_max", "double", None, "force range [N]"),
])


def law_config(kind: str, **fields) -> dict:
    """The C configuration of a law of ``kind``: the fields it gives, every other field zero
    (channels: -1)."""
    if kind not in LAW_IDS:
        raise ValueError(f"law kind must be one of {', '.join(LAW_IDS)}, got {kind!r}")
    out = {f.name: (-1 if f.name.startswith("ch_") else 0) for f in LAW_CONFIG.fields}
    unknown = sorted(set(fields) - set(out))
    if unknown:
        raise ValueError(f"ssl_config has no field(s) {unknown}")
    out.update(fields)
    out["law"] = LAW_IDS[kind]
    return out


def law_files() -> dict[str, str]:
    """Every C file of the laws' steps (no generated code: the same for every rig)."""
    files = read_source("ss_common.h", "ss_common.c", folder=CSRC)
    files.update(read_source("ss_laws.h", "ss_laws.c", folder=LAW_SOURCES))
    files["ss_laws_config.h"] = LAW_CONFIG.header()
    return files


@functools.lru_cache(maxsize=1)
def law_library() -> ctypes.CDLL:
    """The laws' shared library (built once, cached on disk), its functions typed.

    Raises
    ------
    RuntimeError : no C compiler, or the build failed.
    """
    so = build_library("ss_laws", law_files(), ["ss_common.c", "ss_laws.c"])
    lib = ctypes.CDLL(str(so))
    lib.ssl_reset.argtypes = [ctypes.c_void_p]
    lib.ssl_step.restype = ctypes.c_int
    lib.ssl_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int,
                             ctypes.c_double, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p]
    lib.ssl_virtual_drive.restype = ctypes.c_void_p
    lib.ssl_virtual_drive.argtypes = [ctypes.c_void_p, ctypes.c_int]
    lib.path = so
    return lib


class SSL_INFO(ctypes.Structure):
    """``ssl_info`` (csrc/ss_laws.h)."""

    _fields_ = [("status", ctypes.c_int), ("n_u", ctypes.c_int), ("missing", ctypes.c_int)]


class CompiledLaw:
    """One law's step in compiled C (module docstring).

    Parameters
    ----------
    config : the law's :data:`LAW_CONFIG` values (:func:`law_config`)
    channels : the DAQ channels the configuration's ``ch_*`` indices point into, in order
    estimates : the estimate names e[] holds (the brake: its body's and the drive body's speed state;
        D-OSKIL: its body's speed state when the rig does not measure it), or ()

    Raises
    ------
    SolverFailure : the library could not be built, or the configuration was refused.
    """

    def __init__(self, config: Mapping[str, float], channels: tuple[str, ...], estimates: tuple[str, ...] = ()):
        try:
            lib = self._lib = law_library()
        except RuntimeError as exc:
            raise SolverFailure(f"building the laws' compiled steps failed: {exc}") from None
        self.library = lib.path
        self.config = dict(config)
        self.channels = tuple(channels)
        self.estimates = tuple(estimates)
        self._cfg, self._keep = LAW_CONFIG.fill(self.config)
        self._mem, self._m = lay_out(lib, "ssl", self._cfg, what="law's compiled step")
        self.y = np.full(max(len(self.channels), 1), np.nan)
        self.e = np.full(2, np.nan)
        self.u = np.zeros(1)
        self.info = SSL_INFO()
        self._p = (self.y.ctypes.data, self.e.ctypes.data, self.u.ctypes.data, ctypes.addressof(self.info))

    def reset(self) -> None:
        self._lib.ssl_reset(self._m)

    def step(self, t: float, measurement: Mapping[str, float] | None, estimate, w_nom: float,
             u_prog: float = 0.0) -> float | None:
        """One call of ``ssl_step``: the command, or None when a reading was missing (the index of
        its channel in ``info.missing``; ``-2 - i``: the estimate ``estimates[i]``)."""
        read_channels(measurement, self.channels, self.y)
        mask = 0
        if self.estimates and estimate is not None:
            names = estimate.names
            for i, n in enumerate(self.estimates):
                if n in names:
                    self.e[i] = estimate.get(n)
                    mask |= 1 << i
        p = self._p
        self._lib.ssl_step(self._m, float(t), p[0], p[1], mask, float(w_nom), float(u_prog), p[2], p[3])
        return float(self.u[0]) if self.info.n_u else None

    def missing_channel(self) -> str:
        """The channel whose reading the last call missed (None: an estimate was missing, :meth:`missing_estimate`)."""
        return self.channels[self.info.missing] if self.info.missing >= 0 else None

    def missing_estimate(self) -> str | None:
        """The estimate the last call missed, or None."""
        return self.estimates[-2 - self.info.missing] if self.info.missing <= -2 else None

    def virtual_drive(self) -> tuple[np.ndarray, np.ndarray]:
        """SoftSpeed's ``(Ad, Bd)`` as the C core computed them (2 x 2 each)."""
        out = []
        for which in (0, 1):
            a = self._lib.ssl_virtual_drive(self._m, which)
            out.append(c_view(a, 4).reshape(2, 2).copy())
        return out[0], out[1]


def compiled_law(law) -> tuple[CompiledLaw | None, str]:
    """``(CompiledLaw, status)`` for a built law whose options ask for ``implementation = "c"``;
    ``(None, why)`` for the Python reference, or when no C compiler builds the library (the Python
    step is the same law)."""
    if law.options.implementation != "c":
        return None, "python (implementation = 'python')"
    config, channels, estimates = law.c_config()
    try:
        c = CompiledLaw(config, channels, estimates)
    except SolverFailure as exc:
        return None, f"python ({exc})"
    return c, f"c ({c.library.name})"


def compiled_action(law, t: float, measurement, estimate, name: str, w_nom: float, u_prog: float = 0.0) -> Action:
    """A law's action from its compiled step: ``{name: command}``; a missing reading raises the
    :class:`SolverFailure` the Python step raises (its fallback answers it)."""
    u = law.compiled.step(t, measurement, estimate, w_nom, u_prog)
    if u is None:
        name = law.compiled.missing_estimate()
        if name is not None:
            estimated(estimate, name)
            raise SolverFailure(f"no finite estimate of {name!r} in this call")
        ch = law.compiled.missing_channel()
        reading(measurement, ch)
        raise SolverFailure(f"channel {ch!r} has no finite reading in this sample")
    return Action({name: u})


@dataclass(frozen=True, kw_only=True)
class LawOptions:
    """The option every law with a compiled step takes; a law's options class extends it.

    Parameters
    ----------
    implementation : "c": the step as one compiled C call (csrc/ss_laws.c, the one ``mitigate
        export`` writes out); "python": the law's reference step in Python
    """

    implementation: str = option("c", choices=IMPLEMENTATIONS)

    def __post_init__(self):
        check_options(self)


class CompiledStepLaw(Controller):
    """Base of a law whose step runs as one compiled C call or as its Python reference.

    A subclass resolves what its ``c_config()`` reads, then calls :meth:`compile_step`; it keeps
    its Python step's state in :meth:`reset_reference`, and its ``_step_impl`` answers with
    :func:`compiled_action` while ``self.compiled`` is set.
    """

    #: the compiled step (csrc/ss_laws.c); None: the Python reference
    compiled: CompiledLaw | None = None
    #: which step runs, and why (:func:`compiled_law`)
    compile_status: str = ""

    def compile_step(self) -> None:
        """Build the step the options ask for (:func:`compiled_law`), then reset."""
        self.compiled, self.compile_status = compiled_law(self)
        self.reset()

    def reset(self) -> None:
        if self.compiled is not None:
            self.compiled.reset()
        self.reset_reference()

    def reset_reference(self) -> None:
        """Forget the Python reference step's state."""
