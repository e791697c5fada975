"""The plant simulator: "the integrator" every closed loop runs against.

It steps a rig model at the DAQ rate with the input held over each sample (zero-order
hold).  The default method is the exact stick/slip stepping of :mod:`models.hybrid`
(no creep in stick).  ``method="smooth"`` steps the regularised model with RK4 and
``method="cvodes"`` with CasADi's CVODES, for cross-checks.  The R2 pin force passes
through the servo model; measurements pass through the sensor models; all randomness
comes from one seeded generator.

Example
-------
>>> from models import get_model
>>> from models.simulator import Plant, SimOptions
>>> m = get_model("rig3")
>>> plant = Plant(m, m.published(), SimOptions(seed=1))
>>> y = plant.step([3.14, 20.0, 0.0])      # omega_ref [rad/s], N1 [N], N2 command [N]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import casadi as ca
import numpy as np

from models.actuators import Servo, ServoOptions
from models.discretise import rk4
from models.errors import ConfigError
from models.hybrid import hybrid_step_function
from models.logs import Log
from models.params import ParameterSet
from models.sensors import SensorOptions, Sensors

__all__ = ["SimOptions", "Plant", "SimResult", "simulate", "step_function"]

_METHODS = ("hybrid", "smooth", "cvodes")


@dataclass(frozen=True, kw_only=True)
class SimOptions:
    """Plant simulator options.

    Parameters
    ----------
    dt : DAQ period [s] (thesis: 10 ms)
    nsub : substeps per sample (hybrid/smooth); stick/slip switching resolves to dt/nsub
    method : "hybrid" (exact stick/slip, default), "smooth" (regularised RK4) or "cvodes"
    eps : regularisation [rad/s] for "smooth"/"cvodes" (model default if None)
    seed : seed of the sensor-noise generator
    start : "rest" (all speeds zero, no twist) or "sliding" (steady sliding at the first input)
    """

    dt: float = 0.01
    nsub: int = 10
    method: str = "hybrid"
    eps: float | None = None
    seed: int = 0
    start: str = "rest"

    def __post_init__(self):
        if isinstance(self.dt, bool) or not isinstance(self.dt, (int, float)) or not (math.isfinite(self.dt) and self.dt > 0):
            raise ConfigError(f"sim.dt must be a finite number > 0 s, got {self.dt!r}")
        if isinstance(self.nsub, bool) or not isinstance(self.nsub, int) or self.nsub < 1:
            raise ConfigError(f"sim.nsub must be an integer >= 1, got {self.nsub!r}")
        if self.method not in _METHODS:
            raise ConfigError(f"sim.method must be one of {', '.join(_METHODS)}, got {self.method!r}")
        if self.eps is not None and not (isinstance(self.eps, (int, float)) and self.eps > 0):
            raise ConfigError(f"sim.eps must be > 0 rad/s, got {self.eps!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise ConfigError(f"sim.seed must be an integer, got {self.seed!r}")
        if self.start not in ("rest", "sliding"):
            raise ConfigError(f"sim.start must be 'rest' or 'sliding', got {self.start!r}")


_CACHE: dict = {}


def step_function(model, options: SimOptions) -> ca.Function:
    """``F(x, theta_ref, u, p) -> (x_next, theta_ref_next)`` for one sample (cached)."""
    key = (model.name, options.method, options.dt, options.nsub, options.eps)
    if key in _CACHE:
        return _CACHE[key]
    if options.method == "hybrid":
        F = hybrid_step_function(model, options.dt, options.nsub)
    else:
        f = model.ode(options.eps)
        x = ca.SX.sym("x", model.nx)
        th = ca.SX.sym("theta_ref")
        u = ca.SX.sym("u", model.nu)
        p = ca.SX.sym("p", model.n_p)
        P = model.unpack(p)
        xa = ca.vertcat(x, th)
        rhs = ca.vertcat(f(x, u, p), model.ref_rate(x, u, P))
        if options.method == "smooth":
            fa = ca.Function("fa", [xa, u, p], [rhs])
            xn = rk4(lambda a, b, c: fa(a, b, c), xa, u, p, options.dt, options.nsub)
            F = ca.Function(f"{model.name}_smooth_step", [x, th, u, p], [xn[:model.nx], xn[model.nx]],
                            ["x", "theta_ref", "u", "p"], ["x_next", "theta_ref_next"])
        else:
            up = ca.vertcat(u, p)
            integ = ca.integrator("plant", "cvodes", {"x": xa, "p": up, "ode": rhs}, 0.0, options.dt,
                                  {"abstol": 1e-10, "reltol": 1e-10})
            xs, ths = ca.MX.sym("x", model.nx), ca.MX.sym("th")
            us, ps = ca.MX.sym("u", model.nu), ca.MX.sym("p", model.n_p)
            xf = integ(x0=ca.vertcat(xs, ths), p=ca.vertcat(us, ps))["xf"]
            F = ca.Function(f"{model.name}_cvodes_step", [xs, ths, us, ps], [xf[:model.nx], xf[model.nx]],
                            ["x", "theta_ref", "u", "p"], ["x_next", "theta_ref_next"])
    _CACHE[key] = F
    return F


class Plant:
    """A simulated rig, stepped at the DAQ rate.

    Parameters
    ----------
    model : models.rigs.RigModel
    params : the plant's true parameter set
    options : SimOptions
    sensors : SensorOptions, or None for ideal (noise-free, unquantised) measurements
    servo : ServoOptions for the ``n2`` input (rig3), or None for an ideal actuator
    x0 : initial state (overrides ``options.start``)
    """

    def __init__(self, model, params: ParameterSet, options: SimOptions = SimOptions(), *,
                 sensors: SensorOptions | None = SensorOptions(), servo: ServoOptions | None = None,
                 x0=None, u0=None):
        if not isinstance(params, model.param_cls):
            raise ConfigError(f"plant params must be {model.param_cls.__name__} for model {model.name!r}, "
                              f"got {type(params).__name__}")
        self.model = model
        self.params = params
        self.options = options
        self._p = ca.DM(params.vector())
        self._F = step_function(model, options)
        self._h = model.meas()
        self.rng = np.random.default_rng(options.seed)
        self.sensor_options = sensors
        self.sensors = Sensors(sensors, options.dt, self.rng) if sensors is not None else None
        self.servo_options = servo
        self._servo_index = model.inputs.index("n2") if ("n2" in model.inputs and servo is not None) else None
        self.servo = Servo(servo, options.dt) if self._servo_index is not None else None
        if x0 is None:
            if options.start == "sliding":
                if u0 is None:
                    raise ConfigError("sim.start = 'sliding' needs the first input u0")
                x0 = model.steady_sliding(u0, params)
            else:
                x0 = np.zeros(model.nx)
        x0 = np.asarray(x0, dtype=float).ravel()
        if x0.shape != (model.nx,) or not np.all(np.isfinite(x0)):
            raise ConfigError(f"x0 must be {model.nx} finite numbers, got {x0}")
        self.x = x0
        self.theta_ref = 0.0
        self.t = 0.0
        self.u_applied = np.asarray(u0, dtype=float) if u0 is not None else np.zeros(model.nu)

    def truth(self) -> dict[str, float]:
        """Ideal outputs at the current state, plus the true states."""
        outs = self._h(x=self.x, u=self.u_applied, p=self._p, theta_ref=self.theta_ref)
        d = {k: float(v) for k, v in outs.items()}
        for name, v in zip(self.model.inputs, self.u_applied):
            d.setdefault(name, float(v))
        return d

    def measure(self) -> dict[str, float]:
        """What the DAQ records now (sensor models applied)."""
        truth = self.truth()
        if self.sensors is None:
            return truth
        meas = self.sensors.measure({k: v for k, v in truth.items() if k in self.model.measured})
        return meas

    def apply(self, u) -> np.ndarray:
        """Input actually applied over the next sample (servo on n2)."""
        u = np.asarray(u, dtype=float).ravel()
        if u.shape != (self.model.nu,):
            raise ConfigError(f"input must have {self.model.nu} entries {self.model.inputs}, got {u.shape}")
        u = u.copy()
        if self.servo is not None:
            u[self._servo_index] = self.servo.step(u[self._servo_index])
        return u

    def step(self, u) -> dict[str, float]:
        """Hold ``u`` over one sample, advance, and return the measurement at the new time."""
        ua = self.apply(u)
        self.u_applied = ua
        xn, thn = self._F(self.x, self.theta_ref, ua, self._p)
        self.x = np.array(xn).ravel()
        self.theta_ref = float(thn)
        self.t += self.options.dt
        return self.measure()


@dataclass(frozen=True)
class SimResult:
    """Result of :func:`simulate`; time on the first axis.

    Attributes
    ----------
    t : (n+1,) times [s]
    x : (n+1, nx) true states
    u : (n+1, nu) applied inputs (the last row repeats the previous one)
    y : measured channels, each (n+1,)
    truth : ideal outputs, each (n+1,)
    status : human-readable message; success : bool
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    y: dict = field(repr=False)
    truth: dict = field(repr=False)
    model: str = ""
    status: str = "ok"
    success: bool = True

    def to_log(self, *, measured: bool = True, include_truth_twist: bool = False) -> Log:
        """The run as a :class:`models.logs.Log` (measured channels, or ideal ones)."""
        from models.logs import CANONICAL_UNITS

        src = self.y if measured else self.truth
        chans = {k: v for k, v in src.items() if k in CANONICAL_UNITS and k != "t" and not k.startswith("twist")}
        if include_truth_twist:
            chans.update({k: v for k, v in self.truth.items() if k.startswith("twist")})
        return Log(self.t, chans, f"simulation:{self.model}")


def simulate(model, params: ParameterSet, inputs: Callable[[float], np.ndarray] | np.ndarray, duration: float,
             options: SimOptions = SimOptions(), *, sensors: SensorOptions | None = SensorOptions(),
             servo: ServoOptions | None = None, x0=None, progress: bool = False) -> SimResult:
    """Open-loop simulation with inputs ``u(t)`` (callable) or an (n, nu) array.

    Returns a :class:`SimResult` with ``n = round(duration/dt)`` steps.
    """
    n = int(round(duration / options.dt))
    if n < 1:
        raise ConfigError(f"duration must be at least one sample ({options.dt} s), got {duration}")
    if callable(inputs):
        U = np.array([np.asarray(inputs(k * options.dt), dtype=float).ravel() for k in range(n)])
    else:
        U = np.asarray(inputs, dtype=float)
        if U.ndim == 1:
            U = np.tile(U, (n, 1))
        if U.shape != (n, model.nu):
            raise ConfigError(f"inputs must have shape ({n}, {model.nu}), got {U.shape}")
    plant = Plant(model, params, options, sensors=sensors, servo=servo, x0=x0, u0=U[0])
    X = np.empty((n + 1, model.nx))
    UA = np.empty((n + 1, model.nu))
    X[0] = plant.x
    UA[0] = U[0]
    plant.u_applied = U[0]
    ys, truths = [plant.measure()], [plant.truth()]
    it = range(n)
    if progress:
        from tqdm import tqdm
        it = tqdm(it, desc=f"simulate {model.name}", unit="step")
    for k in it:
        ys.append(plant.step(U[k]))
        truths.append(plant.truth())
        X[k + 1] = plant.x
        UA[k] = plant.u_applied
    UA[n] = UA[n - 1]
    t = np.arange(n + 1) * options.dt
    keys = ys[-1].keys()
    y = {k: np.array([d.get(k, np.nan) for d in ys]) for k in keys}
    # the first sample has no speed from differences: it uses the true speed (documented)
    truth = {k: np.array([d[k] for d in truths]) for k in truths[-1].keys()}
    ok = bool(np.all(np.isfinite(X)))
    return SimResult(t, X, UA, y, truth, model.name, "ok" if ok else "non-finite state", ok)
