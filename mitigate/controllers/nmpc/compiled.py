"""The NMPC's step as one compiled C call: the workbench's default NMPC and the exported library are
the same C (``csrc/ss_nmpc.c``).

:data:`NMPC_CONFIG` declares, once, the configuration the C core reads (dimensions, index tables,
limits, the OCP's parameter template with the rig's parameters and the weights): it writes the C
header and fills the ctypes struct (:class:`models.cbuild.CStruct`).  :func:`nmpc_config` takes the
values from a built :class:`~mitigate.controllers.nmpc.controller.NMPC`, so the compiled step runs
exactly the settings the Python controller resolved from the rig.  :class:`CompiledStep` builds the
library (the core, the shared ``ss_common.c``, the CasADi-generated stage and forward functions,
linked to the hpipm and blasfeo of the casadi wheel; cached on disk), lays one controller out in
memory owned by numpy (no allocation inside a step) and calls ``ssn_step``.

Estimates reach the C core in a canonical layout: the rig's ``nx`` states, then one entry per
``load:<contact>`` the NMPC understands (NaN where the estimate has none), see :meth:`CompiledStep.canonical`.
"""

from __future__ import annotations

import ctypes
import math
from pathlib import Path

import numpy as np

from models.cbuild import (CSRC, CStruct, blasfeo_override, build_library, c_view, generate, hpipm_paths, lay_out,
                           load_library, read_channels, read_source)
from models.errors import SolverFailure
from mitigate.controllers.nmpc.start import LOAD_FACTOR_RANGE
from mitigate.controllers.nmpc.supervision import SLIDING_FRACTION, TRIM_DEADBAND, TRIM_LIMIT
from mitigate.controllers.nmpc.options import HPIPM_MODES, QP_CONDENSING, qp_blocks

__all__ = ["NMPC_CONFIG", "NMPC_INFO", "nmpc_config", "CompiledStep", "NMPC_SOURCES", "FAILURES", "REASONS"]

#: the C sources of the NMPC's step
NMPC_SOURCES = Path(__file__).resolve().parent / "csrc"

NMPC_CONFIG = CStruct("ssn_config", [
    ("nx", "int", None, "rig states"), ("nu", "int", None, "rig inputs"),
    ("nxa", "int", None, "augmented states"), ("nv", "int", None, "decisions = commanded inputs"),
    ("ns", "int", None, "commanded servos"), ("N", "int", None, "horizon"), ("nq", "int", None, "OCP parameters"),
    ("nfc", "int", None, "contact bodies (friction factors)"), ("n_load", "int", None, "load factors in an estimate"),
    ("n_ch", "int", None, "DAQ channels read"),
    ("drives", "int", None, "commands the drive"), ("torque_drive", "int", None, "the drive sets no speed"),
    ("reverses", "int", None, "the drive's set-point may reverse (else it keeps its sign)"),
    ("has_speed0", "int", None, "a fixed nominal speed (speed0)"),
    ("model_servo", "int", None, "predict the servos' lag"), ("prepare_ahead", "int", None, "RTI preparation"),
    ("use_load", "int", None, "take load factors from the estimate"),
    ("iterate", "int", None, "SQP to convergence (0: RTI)"), ("sqp_max_iter", "int", None, "SQP iterations"),
    ("qp_iter_max", "int", None, "QP iterations"), ("hpipm_mode", "int", None, "enum hpipm_mode"),
    ("qp_cond", "int", None, "0: Riccati on the OCP QP; 1: full condensing, hpipm's dense IPM; 2: partial condensing"),
    ("qp_cond_n", "int", None, "stages after partial condensing (qp_cond 2)"),
    ("u_drive", "int", None, "the drive's input index"), ("i_wprev", "int", None, "previous set-point in xa (-1)"),
    ("i_speed", "int", None, "objective body's speed in x"), ("window_n", "int", None, "supervision window"),
    ("force_n", "int", None, "the force band's moving window [DAQ samples] (0: every command in the band)"),
    ("q_hold", "int", None, "q: held inputs"), ("q_nom", "int", None, "q: nominal speed"),
    ("q_fc", "int", None, "q: friction factors"), ("q_lin", "int", None, "q: linear-cost flags"),
    ("q_ref", "int", None, "q: weight ref"), ("q_dref", "int", None, "q: weight d_ref"),
    ("q_force", "int", None, "q: weight force"),
    ("u_servo", "int", "ns", "servo input indices"), ("i_servo", "int", "ns", "servo forces in xa"),
    ("j_cmd", "int", "ns", "servo commands in v"),
    ("look_n", "int", "ns", "samples the force band looks ahead"), ("held", "int", "nu", "1: held over the horizon"),
    ("reader_ch", "int", "nu", "channel of each input's load cell (-1: none)"),
    ("load_contact", "int", "n_load", "contact body of each load factor"),
    ("contact_x", "int", "nfc", "contact body's speed in x"),
    ("dt_daq", "double", None, "DAQ period [s]"), ("dt", "double", None, "OCP interval [s]"),
    ("call_period", "double", None, "controller call period [s]"), ("period", "double", None, "stick-slip period [s]"),
    ("speed0", "double", None, "fixed nominal speed [rad/s]"),
    ("tau_force", "double", None, "held forces' low-pass [s]"),
    ("setpoint_band", "double", None, "set-point band [rad/s or N m]"),
    ("torque_max", "double", None, "torque drive's limit [N m]"),
    ("force_lo", "double", None, "a servo force with a positive programme: at least this x programme"),
    ("force_hi", "double", None, "a servo force with a positive programme: at most this x programme"),
    ("calm_lo", "double", None, "calm severity"), ("calm_hi", "double", None, "stick-slip severity"),
    ("hold_gain", "double", None, "calm weight factor"), ("trim_tau", "double", None, "speed trim [s] (0: none)"),
    ("trim_limit", "double", None, "largest trim / programme"), ("trim_deadband", "double", None, "trim deadband"),
    ("sliding_fraction", "double", None, "a body slides above this x nominal"),
    ("load_min", "double", None, "load factor clip"), ("load_max", "double", None, "load factor clip"),
    ("qp_tol", "double", None, "QP tolerance"), ("qp_mu0", "double", None, "hpipm's initial complementarity (0: the mode's)"), ("sqp_tol", "double", None, "SQP step tolerance"),
    ("reader_off", "double", "nu", "load cells' offsets"), ("reader_gain", "double", "nu", "load cells' gains"),
    ("servo_tau", "double", "ns", "servos' lag [s]"), ("servo_rate", "double", "ns", "servos' rate [N/s]"),
    ("servo_nmin", "double", "ns", "servos' range [N]"), ("servo_nmax", "double", "ns", "servos' range [N]"),
    ("servo_dg", "double", "ns", "servo rows' half-width [N]"),
    ("lo", "double", "nv", "command bounds"), ("hi", "double", "nv", "command bounds"),
    ("rate", "double", "nv", "command rate limits"),
    ("q0", "double", "nq", "OCP parameters: scales, weights, rig parameters"),
])


class NMPC_INFO(ctypes.Structure):
    """``ssn_info`` (csrc/ss_nmpc.h)."""

    _fields_ = [(n, ctypes.c_int) for n in ("status", "reason", "held_status", "n_u", "planned", "prepared",
                                            "failure", "fail_detail", "shifted_index", "iterations",
                                            "qp_iterations", "converged")] + \
               [(n, ctypes.c_double) for n in ("violation", "last_step", "cost", "solve_time", "step_time", "weight_factor",
                                               "severity", "nominal", "trim", "target")]


#: enum ssn_reason
REASONS = ("plan", "stall", "shifted", "programme")
#: enum ssn_failure -> the message of the SolverFailure it stands for
FAILURES = {1: "no state estimate", 2: "non-finite or short state estimate", 3: "non-finite held input",
            4: "QP (hpipm) failed", 5: "non-finite plan", 6: "plan violates its bounds", 7: "compiled function returned an error",
            8: "injected failure", 9: "the estimate is of another rig"}


def channels_read(nmpc) -> tuple[str, ...]:
    """The DAQ channels the NMPC reads (the load cells of its non-drive inputs), in input order."""
    out = []
    for j in sorted(nmpc.start.readers):
        ch = nmpc.start.readers[j][0]
        if ch not in out:
            out.append(ch)
    return tuple(out)


def nmpc_config(nmpc) -> dict:
    """The configuration of the C core for a built NMPC (every value the Python controller resolved)."""
    m, L, cfg, o, st = nmpc.model, nmpc.layout, nmpc.cfg, nmpc.options, nmpc.start
    chans = channels_read(nmpc)
    ns = L.ns
    reader = np.full(m.nu, -1, int)
    off, gain = np.zeros(m.nu), np.ones(m.nu)
    for j, (ch, o_, g) in st.readers.items():
        reader[j], off[j], gain[j] = chans.index(ch), o_, g
    acts = st.acts
    return dict(
        nx=m.nx, nu=m.nu, nxa=L.nxa, nv=L.nv, ns=ns, N=nmpc.spec.horizon, nq=L.nq, nfc=L.n_fc,
        n_load=len(st.load_keys), n_ch=len(chans),
        drives=int(nmpc.drives), torque_drive=int(nmpc._torque_drive), reverses=int(m.drive.reverses),
        has_speed0=int(nmpc._speed0 is not None),
        model_servo=int(o.model_servo), prepare_ahead=int(o.prepare_ahead), use_load=int(o.use_load_estimate),
        iterate=int(o.solver == "sqp"), sqp_max_iter=o.sqp_max_iter, qp_iter_max=100, hpipm_mode=HPIPM_MODES[o.qp_mode],
        qp_cond=QP_CONDENSING.index(o.qp_condensing), qp_cond_n=qp_blocks(o.qp_blocks, nmpc.spec.horizon),
        u_drive=L.u_drive, i_wprev=-1 if L.i_wprev is None else L.i_wprev, i_speed=nmpc._i_speed,
        window_n=nmpc.supervisor.state.window.n, force_n=nmpc.start.window_n, look_n=list(nmpc._look_n),
        q_hold=L.q_hold, q_nom=L.q_nom, q_fc=L.q_fc, q_lin=L.q_lin,
        q_ref=nmpc.q_index["ref"], q_dref=nmpc.q_index["d_ref"], q_force=nmpc.q_index["force"],
        u_servo=list(L.u_servo), i_servo=list(L.i_servo), j_cmd=list(L.j_cmd),
        held=[int(j in st.held) for j in range(m.nu)], reader_ch=reader,
        load_contact=list(st.load_keys.values()), contact_x=list(m.contacts),
        dt_daq=nmpc.dt_daq, dt=cfg.dt, call_period=nmpc.call_period, period=cfg.period,
        speed0=nmpc._speed0 if nmpc._speed0 is not None else 0.0, tau_force=cfg.force_filter,
        setpoint_band=cfg.setpoint_band, force_lo=nmpc.force_band[0], force_hi=nmpc.force_band[1],
        torque_max=float(nmpc.context.torque_max) if m.drive.reverses else math.inf,
        calm_lo=o.calm_band[0], calm_hi=o.calm_band[1], hold_gain=cfg.hold_gain,
        trim_tau=nmpc.supervisor.trim_tau, trim_limit=TRIM_LIMIT, trim_deadband=TRIM_DEADBAND,
        sliding_fraction=SLIDING_FRACTION, load_min=LOAD_FACTOR_RANGE[0], load_max=LOAD_FACTOR_RANGE[1],
        qp_tol=nmpc.ocp.qp_tol, qp_mu0=0.0 if o.qp_mu0 is None else float(o.qp_mu0), sqp_tol=nmpc.ocp.sqp_tol,
        reader_off=off, reader_gain=gain,
        servo_tau=[float(a.tau) for a in acts], servo_rate=[float(a.rate_max) for a in acts],
        servo_nmin=[float(a.n_min) for a in acts], servo_nmax=[float(a.n_max) for a in acts],
        servo_dg=[nmpc.spec.step_limit(k, nmpc._rate[L.j_cmd[k]]) for k in range(ns)],
        lo=nmpc._lo, hi=nmpc._hi, rate=nmpc._rate, q0=nmpc._q,
    )


def nmpc_files(nmpc, stem: str) -> dict[str, str]:
    """Every C file of the NMPC's step for ``nmpc``: the cores, the generated functions (stages and
    the forward step, named ``<stem>_stages`` / ``<stem>_forward`` tables) and the config header."""
    ev = nmpc.ocp.evaluator
    fns = [ev.fn, nmpc.ocp.F]
    src, hdr = generate(fns, stem)
    files = read_source("ss_common.h", "ss_common.c", folder=CSRC)
    files.update(read_source("ss_nmpc.h", "ss_nmpc.c", folder=NMPC_SOURCES))
    files["ss_nmpc_config.h"] = NMPC_CONFIG.header()
    files[f"{stem}.c"], files[f"{stem}_funs.h"] = src, hdr
    return files


class CompiledStep:
    """One NMPC's step in compiled C (module docstring).

    Parameters
    ----------
    nmpc : a built :class:`~mitigate.controllers.nmpc.controller.NMPC` (solver "rti" or "sqp", hpipm)

    Raises
    ------
    SolverFailure : the library could not be built (no compiler, no hpipm) or the configuration
        was refused.
    """

    def __init__(self, nmpc):
        m = nmpc.model
        self.nx, self.nu, self.nv = m.nx, m.nu, nmpc.layout.nv
        self.states = m.states
        self.channels = channels_read(nmpc)
        self.load_keys = tuple(nmpc.start.load_keys)
        self.i_speed = nmpc._i_speed
        ev = nmpc.ocp.evaluator
        stem = f"{ev.fn.name()}_step"
        files = nmpc_files(nmpc, stem)
        try:
            #: STICKSLIP_BLASFEO: the step links that blasfeo (models.cbuild.stage_optimised)
            self.blasfeo = blasfeo_override()
            inc, lib = hpipm_paths()
            so = build_library(stem, files, ["ss_common.c", "ss_nmpc.c", f"{stem}.c"], include=[inc],
                               libs=["hpipm", "blasfeo"], libdirs=[lib])
        except RuntimeError as exc:
            raise SolverFailure(f"building the NMPC's compiled step failed: {exc}") from None
        self.library = so
        self._lib = lib_ = load_library(so, own_first=self.blasfeo is not None)
        fn_t = ctypes.c_void_p
        self._stages = fn_t.in_dll(lib_, f"{stem}_{ev.fn.name()}")
        self._forward = fn_t.in_dll(lib_, f"{stem}_{nmpc.ocp.F.name()}")
        lib_.ssn_reset.argtypes = [ctypes.c_void_p]
        lib_.ssn_step.restype = ctypes.c_int
        lib_.ssn_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int,
                                  ctypes.c_void_p, ctypes.c_double, ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p]
        lib_.ssn_plan.restype = ctypes.c_void_p
        lib_.ssn_plan.argtypes = [ctypes.c_void_p]
        lib_.ssn_last_q.restype = ctypes.c_void_p
        lib_.ssn_last_q.argtypes = [ctypes.c_void_p]
        self.config = nmpc_config(nmpc)
        self._cfg, self._keep = NMPC_CONFIG.fill(self.config)
        self._mem, self._m = lay_out(lib_, "ssn", self._cfg, ctypes.addressof(self._stages),
                                     ctypes.addressof(self._forward), what="NMPC's compiled step")
        self.nq = self.config["nq"]
        self.N = self.config["N"]
        # call buffers: bound once
        self.y = np.full(max(len(self.channels), 1), np.nan)
        self.xe = np.full(self.nx + len(self.load_keys), np.nan)
        self.u_prog = np.zeros(self.nu)
        self.u = np.zeros(self.nv)
        self.info = NMPC_INFO()
        self._p = (self.y.ctypes.data, self.xe.ctypes.data, self.u_prog.ctypes.data, self.u.ctypes.data,
                   ctypes.addressof(self.info))
        self._names_seen, self._size_seen = None, -1

    def reset(self) -> None:
        self._lib.ssn_reset(self._m)

    def canonical(self, estimate) -> tuple[bool, bool, int]:
        """Write an estimate into the canonical buffer; ``(present, observe, flags)``."""
        x = getattr(estimate, "x", None) if estimate is not None else None
        if x is None:
            return False, False, 0
        names = getattr(estimate, "names", None) or ()
        xe = x if isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == 1 else np.asarray(x, float).ravel()
        if names is not self._names_seen or xe.size != self._size_seen:
            names = tuple(names)
            self._names_seen, self._size_seen = getattr(estimate, "names", None), xe.size
            self._bad = bool(names) and names[:self.nx] != self.states
            # where each canonical entry comes from (-1: NaN): the rig's states, then the load factors
            src = [i if i < xe.size else -1 for i in range(self.nx)]
            src += [names.index(k) if k in names and names.index(k) < xe.size else -1 for k in self.load_keys]
            self._src = np.array([i if i >= 0 else 0 for i in src], dtype=np.intp)
            self._missing = np.array([i < 0 for i in src], dtype=bool)
            # the missing entries are NaN from here on (only this method writes the buffer); the usual
            # estimate (the rig's states first, in order) is then one slice copy
            self.xe[self._missing] = np.nan
            have = np.flatnonzero(~self._missing)
            self._have, self._from = have, self._src[have]
            k = have.size
            self._prefix = k if np.array_equal(have, np.arange(k)) and np.array_equal(self._from, np.arange(k)) else -1
        k = self._prefix
        if k >= 0:
            self.xe[:k] = xe[:k]
        else:
            self.xe[self._have] = xe[self._from]
        return True, xe.size > self.i_speed, 2 if self._bad else 0

    def step(self, t: float, measurement, estimate, u_prog, target: float, inject: bool = False) -> NMPC_INFO:
        """One call of ``ssn_step``; the action is in :attr:`u` (``nv``), what happened in the info."""
        read_channels(measurement, self.channels, self.y)
        present, observe, flags = self.canonical(estimate)
        self.u_prog[:] = u_prog
        p = self._p
        self._lib.ssn_step(self._m, float(t), p[0], p[1] if present else None, int(observe), p[2], float(target),
                           flags | (1 if inject else 0), p[3], p[4])
        return self.info

    def plan(self) -> np.ndarray | None:
        """The last plan's commanded inputs (N, nv), or None."""
        a = self._lib.ssn_plan(self._m)
        return None if not a else c_view(a, self.N * self.nv).reshape(self.N, self.nv).copy()

    def last_q(self) -> np.ndarray | None:
        """The OCP parameters of the last plan attempt (nq), or None."""
        a = self._lib.ssn_last_q(self._m)
        return None if not a else c_view(a, self.nq).copy()
