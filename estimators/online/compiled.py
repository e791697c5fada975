"""The EKF's and the MHE's updates as one compiled C call each (``csrc/ss_ekf.c``, ``csrc/ss_mhe.c``):
the workbench's estimators and the exported library run the same C.

:data:`EKF_CONFIG` declares the configuration once (:class:`models.cbuild.CStruct`);
:func:`ekf_config` takes its values from a built :class:`~estimators.online.ekf.EKF` (its estimation
model: parameters, noise, prior, the first sample's speed channels, the delayed encoders' zeros);
:class:`CompiledEKF` builds the library (cached), lays the filter out in numpy-owned memory and
calls ``sse_update``.  :data:`MHE_CONFIG`, :func:`mhe_config` and :class:`CompiledMHE` do the same for
the MHE (``ssm_update``: its EKF alongside, the window, the arrival prior, the Gauss-Newton step, the
fallback), whose generated window step is :attr:`estimators.online.mhe.MHE.gn_step`.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from models.cbuild import CSRC, CStruct, build_library, c_view, generate, lay_out, read_source
from models.errors import SolverFailure

__all__ = ["EKF_CONFIG", "ekf_config", "ekf_files", "CompiledEKF", "EKF_SOURCES", "MHE_CONFIG", "mhe_config",
           "mhe_files", "CompiledMHE"]

#: the C sources of the EKF's update
EKF_SOURCES = Path(__file__).resolve().parent / "csrc"

EKF_CONFIG = CStruct("sse_config", [
    ("nx", "int", None, "estimator states"), ("nc", "int", None, "DAQ channels read"),
    ("ny", "int", None, "internal measurements"), ("nu", "int", None, "rig inputs"),
    ("delay", "int", None, "samples of input history"), ("n_rig", "int", None, "the rig's states"),
    ("np", "int", None, "rig parameters"), ("nxx", "int", None, "nx * nx"), ("n_init", "int", None, "first-sample speed assignments"),
    ("n_zero", "int", None, "delayed encoders' zero states"),
    ("init_speeds", "int", None, "1: the first sample's speeds replace the prior's (no initial guess given)"),
    ("dt", "double", None, "DAQ period [s]"),
    ("p", "double", "np", "rig parameters"), ("q", "double", "nx", "process noise variances per sample"),
    ("r", "double", "ny", "measurement noise variances"), ("x0", "double", "nx", "prior mean"),
    ("P0", "double", "nxx", "prior covariance (nx x nx, column-major)"),
    ("init_ch", "int", "n_init", "channel of each first-sample speed"),
    ("init_state", "int", "n_init", "state it sets"),
    ("zero_state", "int", "n_zero", "zero: state"), ("zero_twist", "int", "n_zero", "the twist it follows"),
])


def ekf_config(ekf) -> dict:
    """The C configuration of a built EKF (every value its Python update uses)."""
    em = ekf.em
    m = em.model
    init_ch, init_state = [], []
    for j, c in enumerate(em.channels):
        body = m.channel_body(c)
        s = m.sensor_of(c)
        if body not in m.bodies or c != s.channels[-1] or s.offset is not None:
            continue
        name = f"omega_{body}"
        for n in [name] + [f"lag{d}:{name}" for d in range(1, em.delay + 1)]:
            init_ch.append(j)
            init_state.append(em.names.index(n))
    zero_state, zero_twist = [], []
    if em.delay:
        for j, n in enumerate(em.names):
            if n.startswith("zero:"):
                zero_state.append(j)
                zero_twist.append(m.states.index(n.partition(":")[2]))
    return dict(nx=em.nx, nc=len(em.channels), ny=em.ny, nu=em.nu, delay=em.delay, n_rig=em.n_rig, np=len(em.p),
                nxx=em.nx * em.nx, n_init=len(init_ch), n_zero=len(zero_state), init_speeds=int(ekf.context.x0 is None), dt=em.dt,
                p=em.p, q=em.q, r=em.r, x0=em.x0, P0=np.asarray(em.P0, float).ravel(order="F"),
                init_ch=init_ch, init_state=init_state, zero_state=zero_state, zero_twist=zero_twist)


def ekf_functions(ekf):
    """The generated Functions: the fused step and, with delayed encoders, the rig's ODE."""
    fns = [ekf.step_fn]
    if ekf_config(ekf)["n_zero"]:
        fns.append(ekf.em.model.ode(ekf.options.eps))
    return fns


def ekf_files(ekf, stem: str) -> dict[str, str]:
    """Every C file of the EKF's update: the core, the generated functions, the config header."""
    src, hdr = generate(ekf_functions(ekf), stem)
    files = read_source("ss_common.h", "ss_common.c", folder=CSRC)
    files.update(read_source("ss_ekf.h", "ss_ekf.c", folder=EKF_SOURCES))
    files["ss_ekf_config.h"] = EKF_CONFIG.header()
    files[f"{stem}.c"], files[f"{stem}_funs.h"] = src, hdr
    return files


class SSE_INFO(ctypes.Structure):
    """``sse_info`` (csrc/ss_ekf.h)."""

    _fields_ = [(n, ctypes.c_int) for n in ("status", "corrected", "missing", "failed", "held")]


class CompiledEKF:
    """One EKF's update in compiled C (module docstring).

    Raises
    ------
    SolverFailure : the library could not be built or the configuration was refused.
    """

    def __init__(self, ekf):
        fns = ekf_functions(ekf)
        stem = f"{fns[0].name()}_c"
        try:
            so = build_library(stem, ekf_files(ekf, stem), ["ss_common.c", "ss_ekf.c", f"{stem}.c"])
        except RuntimeError as exc:
            raise SolverFailure(f"building the EKF's compiled update failed: {exc}") from None
        self.library = so
        lib = self._lib = ctypes.CDLL(str(so))
        self._step = ctypes.c_void_p.in_dll(lib, f"{stem}_{fns[0].name()}")
        self._ode = ctypes.c_void_p.in_dll(lib, f"{stem}_{fns[1].name()}") if len(fns) > 1 else None
        lib.sse_reset.argtypes = [ctypes.c_void_p]
        lib.sse_set.argtypes = [ctypes.c_void_p] * 3
        lib.sse_update.restype = ctypes.c_int
        lib.sse_update.argtypes = [ctypes.c_void_p] * 4
        for f in ("sse_x", "sse_P", "sse_x0_used"):
            getattr(lib, f).restype = ctypes.c_void_p
            getattr(lib, f).argtypes = [ctypes.c_void_p]
        self.config = ekf_config(ekf)
        self.nx, self.nc, self.nu = self.config["nx"], self.config["nc"], self.config["nu"]
        self._cfg, self._keep = EKF_CONFIG.fill(self.config)
        od = ctypes.addressof(self._ode) if self._ode is not None else None
        self._mem, self._m = lay_out(lib, "sse", self._cfg, ctypes.addressof(self._step), od,
                                     what="EKF's compiled update")
        self.y = np.zeros(max(self.nc, 1))
        self.u = np.zeros(self.nu)
        self.info = SSE_INFO()
        self._x = c_view(lib.sse_x(self._m), self.nx)
        self._P = c_view(lib.sse_P(self._m), self.nx * self.nx)
        self._x0u = c_view(lib.sse_x0_used(self._m), self.nx)
        self._args = (self._m, self.y.ctypes.data, self.u.ctypes.data, ctypes.addressof(self.info))

    def update(self, y, u) -> SSE_INFO:
        """One sample: ``y`` the channels (NaN: missing), ``u`` the inputs over the sample."""
        self.y[:self.nc] = y
        self.u[:] = u
        self._lib.sse_update(*self._args)
        return self.info

    @property
    def x(self) -> np.ndarray:
        return self._x.copy()

    @property
    def x0_used(self) -> np.ndarray:
        return self._x0u.copy()

    @property
    def P(self) -> np.ndarray:
        return self._P.reshape(self.nx, self.nx, order="F").copy()

    def set(self, x, P=None) -> None:
        x = np.ascontiguousarray(x, float)
        Pf = None if P is None else np.asfortranarray(np.asarray(P, float)).ravel(order="F")
        self._lib.sse_set(self._m, x.ctypes.data, None if Pf is None else Pf.ctypes.data)

    def reset(self) -> None:
        self._lib.sse_reset(self._m)


# ----------------------------------------------------------------------------- the MHE (csrc/ss_mhe.c)
MHE_CONFIG = CStruct("ssm_config", [
    ("nx", "int", None, "estimator states"), ("ny", "int", None, "internal measurements"),
    ("nc", "int", None, "DAQ channels read"), ("nuh", "int", None, "input history length (nu * (delay + 1))"),
    ("np", "int", None, "rig parameters"), ("N", "int", None, "window: samples (nodes N + 1)"),
    ("max_iter", "int", None, "Gauss-Newton iterations per sample"), ("nw", "int", None, "nx * (N + 1)"),
    ("nxx", "int", None, "nx * nx"), ("nyc", "int", None, "ny * nc"),
    ("p", "double", "np", "rig parameters"), ("q", "double", "nx", "process noise variances per sample"),
    ("sr", "double", "ny", "measurement noise standard deviations"),
    ("lb", "double", "nw", "lower bounds of the window's node states"),
    ("ub", "double", "nw", "upper bounds of the window's node states"),
    ("T", "double", "nyc", "channels -> internal measurements (ny x nc, column-major)"),
    ("dep", "int", "nyc", "1: the internal measurement needs the channel (ny x nc, column-major)"),
    ("P0", "double", "nxx", "prior covariance (nx x nx, column-major)"),
])


def mhe_config(mhe) -> dict:
    """The C configuration of a built MHE (every value its Python update uses)."""
    em = mhe.em
    N, nx, ny, nc = mhe.N, em.nx, em.ny, len(mhe.channels)
    dep = np.zeros((ny, nc), dtype=int)
    for j, ix in enumerate(mhe._mask_idx):
        dep[j, ix] = 1
    return dict(nx=nx, ny=ny, nc=nc, nuh=em.nuh, np=len(em.p), N=N, max_iter=mhe.options.max_iter, nw=nx * (N + 1),
                nxx=nx * nx, nyc=ny * nc, p=em.p, q=em.q, sr=mhe._sr, lb=mhe._lbw, ub=mhe._ubw,
                T=np.asarray(mhe._T, float).reshape(ny, nc).ravel(order="F"), dep=dep.ravel(order="F"),
                P0=np.asarray(em.P0, float).ravel(order="F"))


def mhe_functions(mhe) -> list:
    """The generated Functions: the window's Gauss-Newton step, the arrival prior's propagation,
    then the EKF alongside's (:func:`ekf_functions`)."""
    return [mhe.gn_step, mhe.arrival] + ekf_functions(mhe.ekf)


def mhe_files(mhe, stem: str) -> dict[str, str]:
    """Every C file of the MHE's update: the MHE and EKF cores, the generated functions, both configs."""
    src, hdr = generate(mhe_functions(mhe), stem)
    files = read_source("ss_common.h", "ss_common.c", folder=CSRC)
    files.update(read_source("ss_ekf.h", "ss_ekf.c", "ss_mhe.h", "ss_mhe.c", folder=EKF_SOURCES))
    files["ss_ekf_config.h"] = EKF_CONFIG.header()
    files["ss_mhe_config.h"] = MHE_CONFIG.header()
    files[f"{stem}.c"], files[f"{stem}_funs.h"] = src, hdr
    return files


class SSM_INFO(ctypes.Structure):
    """``ssm_info`` (csrc/ss_mhe.h)."""

    _fields_ = [("status", ctypes.c_int), ("filling", ctypes.c_int), ("failed", ctypes.c_int), ("ekf", SSE_INFO)]


#: what ``ssm_info.failed`` means (csrc/ss_mhe.h), as the Python MHE's messages say it
MHE_FAILURES = {1: "EKF alongside failed", 2: "RuntimeError: a generated function of the window's step failed",
                3: "non-finite Gauss-Newton step", 4: "Gauss-Newton Hessian not positive definite"}


class CompiledMHE:
    """One MHE's update in compiled C, with its EKF alongside (the MHE's ``gn_step`` and
    ``arrival`` Functions must be SX-built, not externals).

    Raises
    ------
    SolverFailure : the library could not be built or the configuration was refused.
    """

    def __init__(self, mhe):
        fns = mhe_functions(mhe)
        stem = f"{fns[0].name()}_c"
        try:
            so = build_library(stem, mhe_files(mhe, stem), ["ss_common.c", "ss_ekf.c", "ss_mhe.c", f"{stem}.c"])
        except RuntimeError as exc:
            raise SolverFailure(f"building the MHE's compiled update failed: {exc}") from None
        self.library = so
        lib = self._lib = ctypes.CDLL(str(so))
        tables = [ctypes.c_void_p.in_dll(lib, f"{stem}_{f.name()}") for f in fns]
        self._tables = tables
        lib.ssm_reset.argtypes = [ctypes.c_void_p]
        lib.ssm_update.restype = ctypes.c_int
        lib.ssm_update.argtypes = [ctypes.c_void_p] * 4
        lib.ssm_ekf.restype = ctypes.c_void_p
        lib.ssm_ekf.argtypes = [ctypes.c_void_p]
        for f in ("ssm_x", "ssm_P"):
            getattr(lib, f).restype = ctypes.c_void_p
            getattr(lib, f).argtypes = [ctypes.c_void_p]
        for f in ("sse_x", "sse_P", "sse_x0_used"):
            getattr(lib, f).restype = ctypes.c_void_p
            getattr(lib, f).argtypes = [ctypes.c_void_p]
        self.config = mhe_config(mhe)
        self.ekf_config = ekf_config(mhe.ekf)
        self.nx, self.nc, self.nu = self.config["nx"], self.config["nc"], self.ekf_config["nu"]
        self._cfg, self._keep = MHE_CONFIG.fill(self.config)
        self._ecfg, self._ekeep = EKF_CONFIG.fill(self.ekf_config)
        addr = [ctypes.addressof(t) for t in tables] + [None] * (4 - len(tables))
        self._mem, self._m = lay_out(lib, "ssm", self._cfg, ctypes.addressof(self._ecfg), *addr,
                                     what="MHE's compiled update")
        self.y = np.zeros(max(self.nc, 1))
        self.u = np.zeros(self.nu)
        self.info = SSM_INFO()
        nx = self.nx
        self._x = c_view(lib.ssm_x(self._m), nx)
        self._P = c_view(lib.ssm_P(self._m), nx * nx)
        e = lib.ssm_ekf(self._m)
        self._x0u = c_view(lib.sse_x0_used(e), nx)
        self._args = (self._m, self.y.ctypes.data, self.u.ctypes.data, ctypes.addressof(self.info))

    def update(self, y, u) -> SSM_INFO:
        """One sample: ``y`` the channels (NaN: missing), ``u`` the inputs over the sample."""
        self.y[:self.nc] = y
        self.u[:] = u
        self._lib.ssm_update(*self._args)
        return self.info

    @property
    def x(self) -> np.ndarray:
        return self._x.copy()

    @property
    def P(self) -> np.ndarray:
        return self._P.reshape(self.nx, self.nx, order="F").copy()

    @property
    def x0_used(self) -> np.ndarray:
        return self._x0u.copy()

    def reset(self) -> None:
        self._lib.ssm_reset(self._m)
