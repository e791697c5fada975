"""Extended Kalman filter for the 3-disc rig, one fused and compiled CasADi step per sample.

The filter runs on the regularised model (``models.rigs.Rig3Model.ode``) discretised by
RK4 with substeps (``models.discretise.rk4``); its Jacobian is exact (CasADi AD of the
discretisation, not of the ODE).  Predict and correct are ONE CasADi Function
``ekf_step(x, P, u, y, m, p, q, r) -> (x_next, P_next)``:

- predict: ``x- = F(x, u, p)``, ``P- = A P A' + diag(q)`` with ``A = dF/dx``;
- correct: sequential scalar updates, one per internal measurement, each weighted by its
  mask entry ``m_j`` (0 skips the channel exactly: its gain is zero).  The measurement
  functions are linear in the state, so the sequential update equals the batch update.

State (``EKF.names``): the rig3 states ``phi12, phi23, omega1, omega2, omega3, i, z``,
then optional augmented states:

- ``o12``, ``o23`` [rad]: encoder power-on offsets (only with ``angles = "zeroed"``);
- ``load1``, ``load2`` [-]: random-walk factors on the friction load of R1/R2 (they
  multiply ``n1``/``n2`` inside the friction law, i.e. the product ``N mu`` drifts as
  the contact "formation" changes).

Encoder angles.  Absolute angles would need a tracked reference angle; the filter uses
angle DIFFERENCES instead (``theta1 - theta2`` -> twist12, ``theta2 - theta3`` ->
twist23, or ``theta1 - theta3`` if theta2 is absent).  Incremental encoders read zero
at power-on, so a difference measures the twist only up to the twist at power-on:

- ``angles = "zeroed"`` (default, realistic): ``d12 = phi12 - o12`` with ``o12`` a
  constant state whose prior is the initial-twist prior and fully correlated with it
  (``o12`` IS the twist at power-on).  With an uncertain initial twist the level of the
  twist comes from the dynamics (speeds, motor torque), the differences add resolution.
- ``angles = "absolute"``: ``d12 = phi12`` (encoders referenced to the untwisted
  shaft, as the simulator's encoders are).
- leave the theta channels out of ``channels`` to use speeds and torque only.

Noise covariances follow :mod:`estimators.noise` (from ``SensorOptions``).

Speed.  ``compile=True`` generates C for the fused step, builds it with gcc into a
shared library cached under ``$XDG_CACHE_HOME/stickslip`` (or ``~/.cache/stickslip``),
keyed by a hash of the generated code, and calls it through ctypes with preallocated
numpy buffers (no CasADi call overhead).  ``compile=False`` (or a failed build) calls
the CasADi Function directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

import casadi as ca

from models.codegen import CtypesFunction, cache_dir, compile_cached  # noqa: F401  (re-exported)
import numpy as np

from estimators.base import Estimate, StateEstimator
from estimators.noise import measurement_variance, process_variances
from models.discretise import rk4
from models.errors import ConfigError
from models.params import Rig3Params
from models.rigs import get_model
from models.sensors import SensorOptions

__all__ = ["EKFOptions", "EKF", "EstimationModel", "build_estimation_model", "make_ekf", "compile_cached",
           "cache_dir", "ALL_CHANNELS", "AUGMENTS"]

ALL_CHANNELS = ("theta1", "theta2", "theta3", "omega1", "omega2", "omega3", "motor_torque")
AUGMENTS = ("load1", "load2")
RIG3_STATES = ("phi12", "phi23", "omega1", "omega2", "omega3", "i", "z")


def _check_pos(where, name, v, *, allow_zero=False):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 \
            or (v == 0 and not allow_zero):
        rel = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{where}.{name} must be a finite number {rel}, got {v!r}")


def _check_common(o, where: str) -> None:
    """Validate the options the EKF and the MHE share (ConfigError naming the field)."""
    if isinstance(o.channels, str) or not isinstance(o.channels, (tuple, list)) or not o.channels:
        raise ConfigError(f"{where}.channels must be a non-empty list of {', '.join(ALL_CHANNELS)}, "
                          f"got {o.channels!r}")
    bad = [c for c in o.channels if c not in ALL_CHANNELS]
    if bad:
        raise ConfigError(f"{where}.channels: unknown channel {bad[0]!r}; expected some of {', '.join(ALL_CHANNELS)}")
    if len(set(o.channels)) != len(o.channels):
        raise ConfigError(f"{where}.channels has duplicates: {list(o.channels)!r}")
    thetas = [c for c in o.channels if c.startswith("theta")]
    if len(thetas) == 1:
        raise ConfigError(f"{where}.channels: one encoder angle ({thetas[0]}) alone is not used (the filter "
                          f"measures angle differences); give at least two of theta1, theta2, theta3 or none")
    if o.angles not in ("zeroed", "absolute"):
        raise ConfigError(f"{where}.angles must be 'zeroed' or 'absolute', got {o.angles!r}")
    if isinstance(o.augment, str) or not isinstance(o.augment, (tuple, list)):
        raise ConfigError(f"{where}.augment must be a list of {', '.join(AUGMENTS)}, got {o.augment!r}")
    bad = [a for a in o.augment if a not in AUGMENTS]
    if bad or len(set(o.augment)) != len(o.augment):
        raise ConfigError(f"{where}.augment: expected distinct entries of {', '.join(AUGMENTS)}, got {list(o.augment)!r}")
    _check_pos(where, "eps", o.eps)
    if isinstance(o.nsub, bool) or not isinstance(o.nsub, int) or o.nsub < 1:
        raise ConfigError(f"{where}.nsub must be an integer >= 1, got {o.nsub!r}")
    for name in ("q_torque", "q_current", "q_load", "q_twist", "p0_twist", "p0_speed", "p0_current", "p0_z",
                 "p0_load"):
        _check_pos(where, name, getattr(o, name), allow_zero=True)
    if not isinstance(o.compile, bool):
        raise ConfigError(f"{where}.compile must be true or false, got {o.compile!r}")


@dataclass(frozen=True, kw_only=True)
class EKFOptions:
    """Options of the EKF (a scenario's ``[estimator]`` table with ``kind = "ekf"``).

    Parameters
    ----------
    channels : log channels used (subset of theta1, theta2, theta3, omega1, omega2, omega3, motor_torque)
    angles : "zeroed" (encoders read 0 at power-on; offsets estimated) or "absolute"
    augment : augmented random-walk states, subset of ("load1", "load2"); default ("load1",)
    eps : friction regularisation of the filter's model [rad/s]
    nsub : RK4 substeps per DAQ sample (the friction/electrical rates are ~400 1/s)
    q_torque : unmodelled torque per disc, std [N m]
    q_current : unmodelled current per sample, std [A]
    q_load : random-walk intensity of the load factors [1/sqrt(s)]
    q_twist : unmodelled twist per sample, std [rad]
    p0_twist, p0_speed, p0_current, p0_z, p0_load : initial standard deviations
        [rad], [rad/s], [A], [rad], [-]
    compile : build the fused step in C (cached on disk) and call it via ctypes
    """

    channels: tuple = ALL_CHANNELS
    angles: str = "zeroed"
    augment: tuple = ("load1",)
    eps: float = 0.05
    nsub: int = 4
    q_torque: float = 0.02
    q_current: float = 0.05
    q_load: float = 0.05
    q_twist: float = 1e-4
    p0_twist: float = 0.5
    p0_speed: float = 1.0
    p0_current: float = 2.0
    p0_z: float = 1.0
    p0_load: float = 0.3
    compile: bool = True

    def __post_init__(self):
        if isinstance(self.channels, list):
            object.__setattr__(self, "channels", tuple(self.channels))
        if isinstance(self.augment, list):
            object.__setattr__(self, "augment", tuple(self.augment))
        _check_common(self, "estimator")


def options_from_mapping(cls, opts: Mapping[str, Any], where: str):
    """Build an options dataclass from a TOML table; unknown keys / bad values -> one-line ConfigError."""
    allowed = {f.name for f in fields(cls)}
    unknown = [k for k in opts if k not in allowed]
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} for kind {cls.kind_name!r}; "
                          f"expected some of {', '.join(sorted(allowed))}")
    try:
        o = cls(**dict(opts))
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("estimator.", f"{where}.", 1)) from None
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return o


EKFOptions.kind_name = "ekf"


# --------------------------------------------------------------------------------------------
# the estimation model shared by the EKF and the MHE
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class EstimationModel:
    """The augmented discrete-time model both filters use.

    Attributes
    ----------
    names : estimator state names
    channels : raw log channels read from a measurement dict (in order)
    meas_names : internal measurement names (angle differences, speeds, torque)
    F : Function (x, u, p) -> x_next, augmented state, one DAQ sample
    h : Function (x, p) -> y, internal measurements (linear in x)
    to_internal : Function (y_raw, m_raw) -> (y, m): angle differences and their masks
    q : (nx,) process-noise variances per sample
    r : (ny,) measurement-noise variances
    lb, ub : (nx,) state bounds (for the MHE)
    """

    names: tuple
    channels: tuple
    meas_names: tuple
    F: ca.Function
    h: ca.Function
    to_internal: ca.Function
    q: np.ndarray
    r: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    x0: np.ndarray
    P0: np.ndarray

    @property
    def nx(self) -> int:
        return len(self.names)

    @property
    def ny(self) -> int:
        return len(self.meas_names)


def build_estimation_model(o, params: Rig3Params, sensors: SensorOptions, dt: float,
                           x0=None) -> EstimationModel:
    """Build the augmented model, noise covariances and prior from EKF/MHE options ``o``."""
    if not isinstance(params, Rig3Params):
        raise ConfigError(f"estimator model params must be Rig3Params, got {type(params).__name__}")
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not (math.isfinite(dt) and dt > 0):
        raise ConfigError(f"estimator dt must be a finite number > 0 s, got {dt!r}")
    model = get_model("rig3")
    chans = tuple(c for c in ALL_CHANNELS if c in o.channels)  # canonical order
    th = [c for c in chans if c.startswith("theta")]
    diffs = []
    if "theta1" in th and "theta2" in th:
        diffs.append("d12")
    if "theta2" in th and "theta3" in th:
        diffs.append("d23")
    if "theta1" in th and "theta3" in th and "theta2" not in th:
        diffs.append("d13")
    offsets = []
    if o.angles == "zeroed":
        if "d12" in diffs or "d13" in diffs:
            offsets.append("o12")
        if "d23" in diffs or "d13" in diffs:
            offsets.append("o23")
    names = RIG3_STATES + tuple(offsets) + tuple(a for a in AUGMENTS if a in o.augment)
    nx = len(names)
    idx = {n: i for i, n in enumerate(names)}

    # dynamics
    f = model.ode(o.eps)
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_p)
    ueff = ca.vertcat(u[0], u[1] * (x[idx["load1"]] if "load1" in idx else 1),
                      u[2] * (x[idx["load2"]] if "load2" in idx else 1))
    xr = rk4(lambda a, b, c: f(a, b, c), x[:7], ueff, p, dt, int(o.nsub))
    F = ca.Function("est_F", [x, u, p], [ca.vertcat(xr, x[7:])], ["x", "u", "p"], ["x_next"])

    # measurements
    other = [c for c in chans if not c.startswith("theta")]
    hv = model.meas_vector(other) if other else None
    ys = []
    meas = []
    for d in diffs:
        if d == "d12":
            e = x[0] - (x[idx["o12"]] if "o12" in idx else 0)
        elif d == "d23":
            e = x[1] - (x[idx["o23"]] if "o23" in idx else 0)
        else:
            e = x[0] + x[1] - (x[idx["o12"]] + x[idx["o23"]] if "o12" in idx else 0)
        ys.append(e)
        meas.append(d)
    if hv is not None:
        ys.append(hv(x[:7], ca.DM.zeros(model.nu), p))
        meas.extend(other)
    h = ca.Function("est_h", [x, p], [ca.vertcat(*ys)], ["x", "p"], ["y"])

    yr = ca.SX.sym("y_raw", len(chans))
    mr = ca.SX.sym("m_raw", len(chans))
    ci = {c: i for i, c in enumerate(chans)}
    yi, mi = [], []
    pairs = {"d12": ("theta1", "theta2"), "d23": ("theta2", "theta3"), "d13": ("theta1", "theta3")}
    for d in diffs:
        a, b = pairs[d]
        yi.append(yr[ci[a]] - yr[ci[b]])
        mi.append(mr[ci[a]] * mr[ci[b]])
    for c in other:
        yi.append(yr[ci[c]])
        mi.append(mr[ci[c]])
    to_internal = ca.Function("est_to_internal", [yr, mr], [ca.vertcat(*yi), ca.vertcat(*mi)],
                              ["y_raw", "m_raw"], ["y", "m"])

    q = process_variances(names, params, dt, q_torque=o.q_torque, q_current=o.q_current, q_load=o.q_load,
                          q_twist=o.q_twist)
    r = np.array([measurement_variance(sensors, dt, n) for n in meas])

    # prior
    xx = np.zeros(nx)
    if x0 is not None:
        x0 = np.asarray(x0, dtype=float).ravel()
        if x0.shape not in ((7,), (nx,)) or not np.all(np.isfinite(x0)):
            raise ConfigError(f"estimator x0 must be 7 (rig3) or {nx} finite numbers, got shape {x0.shape}")
        xx[:x0.size] = x0
    for a in ("load1", "load2"):
        if a in idx and (x0 is None or x0.size == 7):
            xx[idx[a]] = 1.0
    std = {"phi12": o.p0_twist, "phi23": o.p0_twist, "omega1": o.p0_speed, "omega2": o.p0_speed,
           "omega3": o.p0_speed, "i": o.p0_current, "z": o.p0_z, "load1": o.p0_load, "load2": o.p0_load}
    P0 = np.diag([std.get(n, 0.0) ** 2 for n in names])
    for off, tw in (("o12", 0), ("o23", 1)):
        if off in idx:
            # the power-on offset IS the initial twist: same prior, fully correlated
            j = idx[off]
            if x0 is None or x0.size == 7:
                xx[j] = xx[tw]
            P0[j, j] = P0[tw, tw]
            P0[j, tw] = P0[tw, j] = P0[tw, tw]
    P0 += 1e-12 * np.eye(nx)

    big = 1e3
    lb = np.full(nx, -big)
    ub = np.full(nx, big)
    for n, (lo, hi) in {"phi12": (-3.0, 3.0), "phi23": (-3.0, 3.0), "o12": (-3.0, 3.0), "o23": (-3.0, 3.0),
                        "omega1": (-200.0, 200.0), "omega2": (-200.0, 200.0), "omega3": (-200.0, 200.0),
                        "i": (-50.0, 50.0), "load1": (0.0, 5.0), "load2": (0.0, 5.0)}.items():
        if n in idx:
            lb[idx[n]], ub[idx[n]] = lo, hi
    return EstimationModel(names, chans, tuple(meas), F, h, to_internal, q, r, lb, ub, xx, P0)


def ekf_step_function(em: EstimationModel, model_np: int) -> ca.Function:
    """The fused predict + correct step ``(x, P, u, y, m, p, q, r) -> (x_next, P_next)`` (SX)."""
    nx, ny = em.nx, em.ny
    x = ca.SX.sym("x", nx)
    Pv = ca.SX.sym("P", nx * nx)
    u = ca.SX.sym("u", 3)
    y = ca.SX.sym("y", len(em.channels))
    m = ca.SX.sym("m", len(em.channels))
    p = ca.SX.sym("p", model_np)
    q = ca.SX.sym("q", nx)
    r = ca.SX.sym("r", ny)
    P = ca.reshape(Pv, nx, nx)
    xp = em.F(x, u, p)
    A = ca.jacobian(xp, x)
    P = ca.mtimes([A, P, A.T]) + ca.diag(q)
    yi, mi = em.to_internal(y, m)
    C = ca.jacobian(em.h(x, p), x)   # the measurements are linear in x
    C = ca.substitute(C, x, ca.DM.zeros(nx)) if ca.depends_on(C, x) else C
    hx = em.h(xp, p)
    xc = xp
    # sequential scalar updates; a masked channel gets zero gain (exact skip)
    for j in range(ny):
        cj = C[j, :]
        innov = yi[j] - (hx[j] + ca.mtimes(cj, xc - xp))
        Ph = ca.mtimes(P, cj.T)
        s = ca.mtimes(cj, Ph) + r[j]
        k = mi[j] * Ph / s
        xc = xc + k * innov
        P = P - ca.mtimes(k, Ph.T)
    P = 0.5 * (P + P.T)
    return ca.Function("ekf_step", [x, Pv, u, y, m, p, q, r], [xc, ca.reshape(P, nx * nx, 1)],
                       ["x", "P", "u", "y", "m", "p", "q", "r"], ["x_next", "P_next"])


# --------------------------------------------------------------------------------------------
# compiled functions, cached on disk
# --------------------------------------------------------------------------------------------

# (cache_dir, compile_cached and CtypesFunction live in models.codegen)


# --------------------------------------------------------------------------------------------
# the filter
# --------------------------------------------------------------------------------------------

class EKF(StateEstimator):
    """Extended Kalman filter for rig3 (see module docstring).

    Parameters
    ----------
    params : Rig3Params the filter believes
    sensors : SensorOptions (measurement noise)
    dt : DAQ period [s]
    options : EKFOptions
    x0 : initial state (7 rig3 states or the full augmented state); zeros if None
    """

    def __init__(self, params: Rig3Params, sensors: SensorOptions = SensorOptions(), dt: float = 0.01,
                 options: EKFOptions = EKFOptions(), x0=None):
        super().__init__()
        self.options = options
        self.em = build_estimation_model(options, params, sensors, dt, x0)
        self.names = self.em.names
        self.channels = self.em.channels
        self.dt = float(dt)
        self._p = np.asarray(params.vector(), dtype=float)
        self.step_fn = ekf_step_function(self.em, len(self._p))
        nx = self.em.nx
        self.x = self.em.x0.copy()
        self.P = self.em.P0.copy()
        self._nx = nx
        self.compiled = False
        self.compile_status = "not requested"
        self._c = None
        if options.compile:
            try:
                so = compile_cached(self.step_fn)
                self._c = CtypesFunction(so, self.step_fn)
                c = self._c
                c.inputs[5][:] = self._p
                c.inputs[6][:] = self.em.q
                c.inputs[7][:] = self.em.r
                self.compiled = True
                self.compile_status = f"compiled ({so.name})"
            except Exception as exc:  # fall back to the CasADi call, never fail here
                self._c = None
                self.compile_status = f"compile failed, using CasADi: {exc}"
        self._miss_names = np.array(self.channels)

    def _status(self, mask):
        if mask.all():
            return "ok"
        return "partial/prediction only: missing " + ",".join(self._miss_names[~mask])

    def _update_impl(self, y, mask, u, t):
        nx = self._nx
        if self._c is not None:
            c = self._c
            c.inputs[0][:] = self.x
            c.inputs[1][:] = self.P.ravel(order="F")
            c.inputs[2][:] = u
            np.copyto(c.inputs[3], y)
            c.inputs[3][~mask] = 0.0
            c.inputs[4][:] = mask
            c()
            x = c.outputs[0].copy()
            P = c.outputs[1].reshape(nx, nx, order="F").copy()
        else:
            yy = np.where(mask, y, 0.0)
            xo, Po = self.step_fn(self.x, self.P.ravel(order="F"), u, yy, mask.astype(float), self._p,
                                  self.em.q, self.em.r)
            x = np.array(xo).ravel()
            P = np.array(Po).reshape(nx, nx, order="F")
        self.x, self.P = x, P
        corrected = bool(mask.any())
        return Estimate(t, x, P, self.names, self._status(mask), True, corrected)

    def reset(self, x, P=None):
        """Restart from state ``x`` (full augmented) and covariance ``P`` (prior if None)."""
        self.x = np.asarray(x, dtype=float).ravel().copy()
        self.P = self.em.P0.copy() if P is None else np.asarray(P, dtype=float).copy()

    def _fallback(self, y, mask, u, t, status):
        """Prediction with the CasADi Function (no correction); keeps the filter alive."""
        try:
            xo, Po = self.step_fn(self.x, self.P.ravel(order="F"), u, np.zeros(len(y)), np.zeros(len(y)),
                                  self._p, self.em.q, self.em.r)
            x = np.array(xo).ravel()
            P = np.array(Po).reshape(self._nx, self._nx, order="F")
            if np.all(np.isfinite(x)) and np.all(np.isfinite(P)):
                self.x, self.P = x, P
                return Estimate(t, x, P, self.names, status, False, False)
        except Exception:
            pass
        return super()._fallback(y, mask, u, t, status)


def make_ekf(opts: Mapping[str, Any], model_params: Rig3Params, sensors: SensorOptions, dt: float,
             x0=None, where: str = "estimator") -> EKF:
    """Factory hook: validate ``opts`` (an ``[estimator]`` table without ``kind``) and build an EKF."""
    o = options_from_mapping(EKFOptions, opts, where)
    return EKF(model_params, sensors, dt, o, x0)
