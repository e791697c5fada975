"""The plant simulator: the "rig" every closed loop, log and benchmark runs against.

It steps a rig model at the DAQ rate with the input held over each sample (zero-order
hold).  The default method is the exact stick/slip stepping of :mod:`models.plant.hybrid`
(no creep in stick); ``method="smooth"`` steps the regularised model with RK4 and
``method="cvodes"`` with CasADi's CVODES, for cross-checks.  Inputs that a servo sets pass
through the rig's actuator models; readings pass through its sensor models
(:mod:`models.sensors`); all randomness comes from one seeded generator.

Example
-------
>>> from models.plant import Plant
>>> plant = Plant("rig3", seed=1)
>>> y = plant.step([3.14, 20.0, 0.0])      # omega_ref [rad/s], N1 [N], N2 command [N]
>>> y["omega1"], y["motor_torque"]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import casadi as ca
import numpy as np

from models.actuators import Servo
from models.checks import check_options, finite_number, option, prefix
from models.codegen import FastFunction
from models.discretise import Integration, integration
from models.errors import ConfigError
from models.logs import TRUTH_PREFIX, Log
from models.params import ParameterSet
from models.plant.hybrid import hybrid_step_function
from models.rig import get_model
from models.rig.spec import SI_UNITS
from models.sensors import SensorOptions, Sensors
from models.status import Outcome, Status

__all__ = ["SimOptions", "Plant", "Trajectory", "SimResult", "simulate", "step_function", "plant_integration", "MAX_SAMPLES"]

_METHODS = ("hybrid", "smooth", "cvodes")
#: the largest run (DAQ samples) the simulator accepts; a state history of 10 states takes 0.8 GB at this size
MAX_SAMPLES = 10_000_000


@dataclass(frozen=True, kw_only=True)
class SimOptions:
    """Plant simulator options.

    Parameters
    ----------
    dt : DAQ period [s] (thesis: 10 ms)
    nsub : substeps per sample at least (hybrid/smooth); stick/slip switching resolves to dt/nsub.
        The integration rule (:func:`models.discretise.integration`) raises it for a stiff rig, and
        treats a DC motor's current quasi-statically when its L/R is far below the substep
        (:func:`plant_integration`; the plant's ``integration`` says what it did)
    method : "hybrid" (exact stick/slip, default; a rig whose laws all have states is integrated
        smoothly, by the rule's method), "smooth" (the regularised model, by the rule's method: RK4 or
        the implicit step) or "cvodes"
    eps : regularisation [rad/s] for "smooth"/"cvodes" (model default if None)
    seed : seed of the sensor-noise generator
    start : "rest" (all speeds zero, no twist) or "sliding" (steady sliding at the first input)
    """

    dt: float = option(0.01, lo=0.0, lo_open=True, unit="s")
    nsub: int = option(10, lo=1)
    method: str = option("hybrid", choices=_METHODS)
    eps: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s", none=True)
    seed: int = option(0)
    start: str = option("rest", choices=("rest", "sliding"))

    def __post_init__(self):
        check_options(self, prefix("sim"))


def plant_integration(model, params: ParameterSet | None, options: SimOptions, u0=None) -> Integration:
    """How the plant advances one sample: :func:`models.discretise.integration` for the exact
    stick/slip plant (``eps=None``; "smooth"/"cvodes": the regularised model), at least
    ``options.nsub`` substeps, at the first input ``u0`` (default: the rig's operating point).

    A rig whose contacts all have laws with states (LuGre, rate-and-state: smooth models of stick
    themselves, :mod:`models.plant.hybrid`) needs no event logic: where they are stiff, the rule
    gives the implicit step and the plant integrates the model with it (``integration.note`` says so)."""
    model = get_model(model)
    params = model.published() if params is None else params
    eps = None if options.method == "hybrid" else (model.eps_default if options.eps is None else options.eps)
    return integration(model, params, options.dt, u=u0, eps=eps, min_nsub=options.nsub, where="plant")


def step_function(model, options: SimOptions, integ: Integration | None = None) -> ca.Function:
    """``F(x, theta_ref, u, p) -> (x_next, theta_ref_next)`` for one sample.

    ``integ`` (default: :func:`plant_integration` with the rig's published parameters) sets the
    substeps and the quasi-static current.  Cached on the model object (its lifetime, never a
    key that another model could reuse: two rigs of one name, e.g. a plant with ``[structure]``
    changes and its nominal model, differ).
    """
    model = get_model(model)
    if integ is None:
        integ = plant_integration(model, None, options)
    key = ("plant_step", options.method, options.dt, integ.key, options.eps)
    cache = model._fcache
    if key in cache:
        return cache[key]
    if options.method == "hybrid" and not integ.implicit:
        F = hybrid_step_function(model, options.dt, integ.nsub, quasi_static=integ.quasi_static)
    else:
        f = model.ode(options.eps)
        x = ca.SX.sym("x", model.nx)
        th = ca.SX.sym("theta_ref")
        u = ca.SX.sym("u", model.nu)
        p = ca.SX.sym("p", model.n_p)
        P = model.unpack(p)
        xa = ca.vertcat(x, th)
        rhs = ca.vertcat(f(x, u, p), model.ref_rate(x, u, P))
        if options.method != "cvodes":          # "smooth", or a hybrid plant whose laws all have states
            fa = ca.Function("fa", [xa, u, p], [rhs])
            xn = integ.advance(lambda a, b, c: fa(a, b, c), xa, u, p,
                               lambda a, b, c: model.quasi_static_current(a, b, model.unpack(c)))
            F = ca.Function(f"{model.cname}_smooth_step", [x, th, u, p], [xn[:model.nx], xn[model.nx]],
                            ["x", "theta_ref", "u", "p"], ["x_next", "theta_ref_next"])
        else:
            up = ca.vertcat(u, p)
            integ = ca.integrator("plant", "cvodes", {"x": xa, "p": up, "ode": rhs}, 0.0, options.dt,
                                  {"abstol": 1e-10, "reltol": 1e-10})
            xs, ths = ca.MX.sym("x", model.nx), ca.MX.sym("th")
            us, ps = ca.MX.sym("u", model.nu), ca.MX.sym("p", model.n_p)
            xf = integ(x0=ca.vertcat(xs, ths), p=ca.vertcat(us, ps))["xf"]
            F = ca.Function(f"{model.cname}_cvodes_step", [xs, ths, us, ps], [xf[:model.nx], xf[model.nx]],
                            ["x", "theta_ref", "u", "p"], ["x_next", "theta_ref_next"])
    cache[key] = F
    return F


class Plant:
    """A simulated rig, stepped at the DAQ rate.

    Parameters
    ----------
    model : a rig (name, rig-file path or :class:`models.rig.RigModel`)
    params : its true parameter set (default: the rig file's)
    options : SimOptions
    sensors : SensorOptions, or None for ideal readings (no noise, quantisation or delay)
    actuators : pass the inputs that a servo sets through the rig's servo models
    x0 : initial state (overrides ``options.start``); u0 : the first input (needed for
        ``start = "sliding"``)
    drift : ``{parameter: relative rate [1/s]}``: the plant's parameter drifts as
        ``p(t) = p(0) (1 + rate t)`` (e.g. wear of a friction coefficient)
    """

    def __init__(self, model, params: ParameterSet | None = None, options: SimOptions = SimOptions(), *,
                 sensors: SensorOptions | None = SensorOptions(), actuators: bool = True, x0=None, u0=None,
                 drift: Mapping[str, float] | None = None):
        model = get_model(model)
        params = model.published() if params is None else model.check_params(params, "plant params")
        self.model = model
        self.params = params
        self.options = options
        self._p0 = np.asarray(params.vector(), float)
        self._p = self._p0.copy()
        self._drift = np.zeros(model.n_p)
        for name, rate in dict(drift or {}).items():
            if name not in model.param_names:
                raise ConfigError(f"drift.{name}: not a parameter of rig {model.name!r}")
            self._drift[model.param_names.index(name)] = finite_number(rate, f"drift.{name}", unit="1/s")
        #: how a sample is integrated (substeps, quasi-static current): :func:`plant_integration`
        self.integration = plant_integration(model, params, options, u0)
        # compiled (cached on disk) and called through ctypes: the CasADi call's overhead was half a
        # closed loop's time
        F = step_function(model, options, self.integration)
        self._F = FastFunction(F, compile=options.method != "cvodes")
        h = model.meas()
        self._h_names = tuple(h.name_out())
        xs, us, ps, ths = (ca.SX.sym(n, h.size1_in(i)) for i, n in enumerate(("x", "u", "p", "th")))
        self._h = FastFunction(ca.Function(f"{model.cname}_h_vec", [xs, us, ps, ths],
                                           [ca.vertcat(*h(xs, us, ps, ths))]))
        self._ideal = None
        self.rng = np.random.default_rng(options.seed)
        self.sensor_options = sensors
        self.sensors = Sensors(model, sensors, options.dt, self.rng) if sensors is not None else None
        self.servos: dict[int, Servo] = {}
        #: (input index, limit [N m]) of a torque drive with ``[drive] torque_max``: its input is clipped
        tmax = model.drive.torque_limit() if not model.drive.sets_speed else math.inf
        self._torque_max = (model.inputs.index(model.drive_input), tmax) if math.isfinite(tmax) else None
        if actuators:
            for a in model.actuators:
                j = model.inputs.index(a.input)
                self.servos[j] = Servo(a, options.dt, 0.0 if u0 is None else float(np.asarray(u0, float)[j]))
        if x0 is None:
            if options.start == "sliding":
                if u0 is None:
                    raise ConfigError("sim.start = 'sliding' needs the first input u0")
                x0 = model.steady_sliding(u0, params)
            else:
                x0 = np.zeros(model.nx)
        x0 = np.asarray(x0, dtype=float).ravel()
        if x0.shape != (model.nx,) or not np.all(np.isfinite(x0)):
            raise ConfigError(f"x0 must be {model.nx} finite numbers {model.states}, got {x0}")
        self.x = x0
        self.theta_ref = 0.0
        self.t = 0.0
        self.u_applied = np.asarray(u0, dtype=float) if u0 is not None else np.zeros(model.nu)

    @property
    def p(self) -> np.ndarray:
        """The plant's current parameter vector (it drifts with ``drift``)."""
        return self._p

    def ideal(self) -> dict[str, float]:
        """Noise-free readings and physical quantities at the current state."""
        key = (self.x.tobytes(), np.asarray(self.u_applied, float).tobytes(), self.theta_ref, self._p.tobytes())
        if self._ideal is None or self._ideal[0] != key:
            y = self._h(self.x, self.u_applied, self._p, self.theta_ref)[0]
            self._ideal = (key, dict(zip(self._h_names, y.tolist())))
        return dict(self._ideal[1])

    truth = ideal

    def measure(self) -> dict[str, float]:
        """What the DAQ records now (sensor models applied)."""
        ideal = self.ideal()
        if self.sensors is None:
            return {k: ideal[k] for k in self.model.measured if k in ideal}
        return self.sensors.measure(ideal)

    def apply(self, u) -> np.ndarray:
        """Input actually applied over the next sample (servos on the inputs they set)."""
        u = np.asarray(u, dtype=float).ravel()
        if u.shape != (self.model.nu,):
            raise ConfigError(f"input must have {self.model.nu} entries {self.model.inputs}, got {u.shape}")
        u = u.copy()
        for j, servo in self.servos.items():
            u[j] = servo.step(u[j])
        if self._torque_max is not None:
            j, lim = self._torque_max
            u[j] = min(max(u[j], -lim), lim)
        return u

    def step(self, u) -> dict[str, float]:
        """Hold ``u`` over one sample, advance, and return the measurement at the new time."""
        ua = self.apply(u)
        self.u_applied = ua
        if self._drift.any():
            self._p = self._p0 * (1.0 + self._drift * self.t)
        xn, thn = self._F(self.x, self.theta_ref, ua, self._p)
        self.x = xn
        self.theta_ref = float(thn[0])
        self.t += self.options.dt
        return self.measure()


class Trajectory(Outcome):
    """Base of a run's result with true states ``x`` (names in ``states``) and applied inputs ``u``
    (names in ``inputs``), time on axis 0: their trajectories by name."""

    __slots__ = ()

    def state(self, name: str) -> np.ndarray:
        """A true state's trajectory by name (e.g. ``"twist_shaft1"``, ``"omega_R1"``)."""
        try:
            return self.x[:, self.states.index(name)]
        except ValueError:
            raise ConfigError(f"no state {name!r}; states: {', '.join(self.states)}") from None

    def input(self, name: str) -> np.ndarray:
        """An applied input's trajectory by name."""
        try:
            return self.u[:, self.inputs.index(name)]
        except ValueError:
            raise ConfigError(f"no input {name!r}; inputs: {', '.join(self.inputs)}") from None


@dataclass(frozen=True)
class SimResult(Trajectory):
    """Result of :func:`simulate`; time on the first axis.

    Attributes
    ----------
    t : (n+1,) times [s]
    x : (n+1, nx) true states (names in ``states``)
    u : (n+1, nu) applied inputs (names in ``inputs``; the last row repeats the previous one)
    y : measured channels, each (n+1,)
    truth : noise-free readings and physical quantities, each (n+1,)
    units : SI unit of every channel and state (:meth:`models.rig.RigModel.output_units`)
    status : :class:`models.status.Status`; message : detail; success : bool
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    y: dict = field(repr=False)
    truth: dict = field(repr=False)
    model: str = ""
    states: tuple = ()
    inputs: tuple = ()
    status: Status = Status.OK
    message: str = "ok"
    units: dict = field(default_factory=dict, repr=False)

    def to_log(self, *, measured: bool = True, include_truth: bool = False) -> Log:
        """The run as a :class:`models.logs.Log`: the measured channels (or their noise-free
        values) in their SI units, plus the true twists and speeds of the states if
        ``include_truth``, as ``true_twist_<connection>`` / ``true_omega_<body>`` columns (the
        prefix keeps them apart from a sensor channel of the same name, such as an encoder's
        default speed channel ``omega_<body>``)."""
        src = self.y if measured else self.truth
        chans = {k: v for k, v in src.items() if k in self.y}
        units = {k: self.units[k] for k in chans if k in self.units}
        if include_truth:
            for j, n in enumerate(self.states):
                if n.startswith(("twist_", "omega_")):
                    chans[TRUTH_PREFIX + n] = self.x[:, j]
                    units[TRUTH_PREFIX + n] = self.units.get(n) or ("rad" if n.startswith("twist_") else "rad/s")
        return Log(self.t, chans, f"simulation:{self.model}", (), units)


def simulate(model, params: ParameterSet | None = None,
             inputs: Callable[[float], np.ndarray] | np.ndarray | None = None, duration: float = 10.0,
             options: SimOptions = SimOptions(), *, sensors: SensorOptions | None = SensorOptions(),
             actuators: bool = True, x0=None, drift=None, progress: bool = False) -> SimResult:
    """Open-loop simulation of a rig with inputs ``u(t)`` (callable) or an (n, nu) array.

    Parameters
    ----------
    model : a rig name (``"rig3"``), rig-file path or model
    params : true parameters (default: the rig file's)
    inputs : callable ``t -> (nu,)``, a constant (nu,) vector, or an (n, nu) array with
        ``n = round(duration/dt)``; order ``model.inputs``
    duration : [s]

    Returns
    -------
    SimResult with ``n = round(duration/dt)`` steps.
    """
    model = get_model(model)
    if inputs is None:
        raise ConfigError(f"simulate needs inputs for {', '.join(model.inputs)}")
    finite_number(duration, "duration", positive=True, unit="s")
    n = int(round(duration / options.dt))
    if n < 1:
        raise ConfigError(f"duration must be at least one sample ({options.dt} s), got {duration}")
    if n > MAX_SAMPLES:
        raise ConfigError(f"duration / dt = {n} samples; the limit is {MAX_SAMPLES}")
    if callable(inputs):
        U = np.array([np.asarray(inputs(k * options.dt), dtype=float).ravel() for k in range(n)])
    else:
        U = np.asarray(inputs, dtype=float)
        if U.ndim == 1:
            U = np.tile(U, (n, 1))
    if U.shape != (n, model.nu):
        raise ConfigError(f"inputs must have shape ({n}, {model.nu}) for {model.inputs}, got {U.shape}")
    plant = Plant(model, params, options, sensors=sensors, actuators=actuators, x0=x0, u0=U[0], drift=drift)
    X = np.empty((n + 1, model.nx))
    UA = np.empty((n + 1, model.nu))
    X[0] = plant.x
    UA[0] = U[0]
    plant.u_applied = U[0]
    ys, truths = [plant.measure()], [plant.ideal()]
    it = range(n)
    if progress:
        from tqdm import tqdm
        it = tqdm(it, desc=f"simulate {model.name}", unit="step")
    status, msg, last = Status.OK, "ok", n
    for k in it:
        ys.append(plant.step(U[k]))
        truths.append(plant.ideal())
        X[k + 1] = plant.x
        UA[k] = plant.u_applied
        if not np.all(np.isfinite(plant.x)):
            status, msg, last = Status.DIVERGED, f"non-finite state at t = {(k + 1) * options.dt:.3f} s", k + 1
            break
    UA[last] = UA[last - 1]
    m = last + 1
    t = np.arange(m) * options.dt
    keys = ys[-1].keys()
    y = {k: np.array([d.get(k, np.nan) for d in ys]) for k in keys}
    truth = {k: np.array([d[k] for d in truths]) for k in truths[-1].keys()}
    return SimResult(t, X[:m], UA[:m], y, truth, model.name, model.states, model.inputs, status, msg,
                     units=model.output_units())
