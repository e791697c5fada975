"""Offline parameter identification by multiple shooting and Gauss-Newton.

Problem, function, result: :class:`IdentifyOptions` says what to fit, :func:`identify`
fits one or several logs (shared parameters, separate state nodes) and returns a frozen
:class:`FitResult`.

Method
------
- The regularised model (:meth:`models.rigs.RigModel.ode`, tanh friction of width
  ``eps`` [rad/s]) is discretised with RK4 and ``nsub`` substeps per DAQ sample, input
  held over each sample (zero-order hold).
- Every ``shoot_every`` samples the state is a decision variable (a shooting node);
  continuity between consecutive intervals of one log is an equality constraint.  The
  unmeasured states (twists, current, PI integral) are thus free node variables.
- Inputs of the model come from the log channels of the same names (rig3: omega_ref, n1,
  n2; rig2: motor_torque; leadscrew: omega_drive, axial_force; disc: omega3, n1).  The
  sample convention is the simulator's (:meth:`models.plant.SimResult.to_log`): row
  ``k+1`` holds the input applied over ``[t_k, t_{k+1})`` (``input_row="end"``).
- Outputs compared: the measured channels the model has (speeds, motor torque), each
  divided by its noise level.  A DAQ speed is a backward difference of encoder angles,
  i.e. the *mean* speed over the preceding sample; the model's speeds are therefore
  averaged over the sample by quadrature (``speed_average=True``).
- Gauss-Newton (default ``solver="gn"``, :mod:`estimators.identify_gn`): SQP with the
  Hessian ``J^T J`` of the weighted residuals, each step from the sparse KKT system of the
  continuity-constrained problem, parameter bounds by a small active set, backtracking on an
  l1 merit function.  The residuals, gaps and Jacobians come from ONE per-sample function
  (RK4 substeps + quadrature + forward sensitivities) mapped over all intervals on 2 threads
  and chained over the samples of an interval; it is compiled with gcc and cached on disk
  (``$XDG_CACHE_HOME/stickslip``) when gcc is available.  ``solver="ipopt"`` keeps the
  earlier path: IPOPT with the ``J^T J`` Hessian (``hess_lag``) on the uncompiled, mapped
  interval function (same optimum, 10-20x slower).  All decision variables are scaled.
- Uncertainty: the parameter covariance is ``s^2 [(J^T J, A^T), (A, 0)]^-1`` restricted to
  the parameters (``A`` the continuity Jacobian, ``s^2`` the residual variance per degree
  of freedom), from which standard errors and the correlation matrix follow.

Biases.  The regularised model cannot stick exactly: it creeps where the plant sticks
(default ``eps`` 0.005 rad/s, far below the 0.05 of the controllers' models).  The logged
inputs are taken as exact, so load-cell noise on a normal force is an error in the
variables; at 3x the nominal noise it is the dominant bias of damping and friction on the
benchmark's disc logs (``input_cutoff`` low-passes such inputs).  Measured
(benchmarks/results/identify.md, 60 s logs): stiffness within 0.7 %, friction levels within
1-11 % (0.4-3.8 % with the force low-passed), damping off by 6-101 % raw (12-22 % with the
force low-passed, disc); 2-11 s per fit on 2 cores.  The standard errors are statistical
(white noise, inflated by the residuals' autocorrelation time) and do not include these
biases.  ``IdentifyOptions(systematic=True)`` adds the regularisation sensitivity
``syserr = |theta(eps) - theta(eps/2)|`` (one refit, warm-started from the estimate) and the total
``sqrt(SE^2 + syserr^2)``; it captures the eps bias only, not the input-noise (errors-in-variables)
bias nor a jump of the refit to another local minimum (benchmarks/results/identify.md, section
"Error bars").
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from models.errors import ConfigError, DataError, SolverFailure
from models.logs import Log
from models.params import ParameterSet
from models.rigs import RigModel, get_model
from models.sensors import SensorOptions
from estimators.identify_gn import ShootingProblem, compiled_or_none, sample_function, solve_gn

__all__ = ["IdentifyOptions", "FitResult", "Validation", "identify", "default_noise", "output_channels",
           "validate_fit", "IdentifiabilityWarning"]

_SPEED_ANGLE = {"omega1": "theta1", "omega2": "theta2", "omega3": "theta3", "omega_drive": "theta_drive"}


class IdentifiabilityWarning(UserWarning):
    """Some parameters are poorly identifiable from the data (high correlation or large SE)."""


@dataclass(frozen=True, kw_only=True)
class IdentifyOptions:
    """What to fit and how.

    Parameters
    ----------
    free : names of the parameters to fit (the others stay at the initial set's values)
    bounds : optional ``{name: (lo, hi)}``; default ``params.bounds(name)`` (TOML ``[bounds]``
        or the physical bounds)
    outputs : compared channels; default all measured outputs of the model found in the log
    noise : ``{channel: standard deviation}`` in SI units; default :func:`default_noise`
    eps : friction regularisation [rad/s].  The regularised model creeps where the plant
        sticks; the bias this puts on the friction and damping estimates shrinks with
        ``eps`` (disc, 36 % stuck: d off by 47 / 31 / 21 % at eps = 0.01 / 0.005 / 0.002),
        at the price of more substeps.
    nsub : RK4 substeps per sample; None: chosen from the stiffest rate of the model at
        zero contact speed and the largest logged input, ``ceil(dt |lambda|max / 3.5)`` (RK4 is stable to 2.8 on the real axis, but the stiff rate holds only for |v| < eps; fits were unchanged up to 3.5)
    shoot_every : samples per shooting interval
    speed_average : compare speeds as means over the sample (backward-difference DAQ speeds)
    use_twist : also compare twists measured as encoder-angle differences (e.g. ``theta1-theta3``)
        with the twist states; this needs encoders zeroed at zero twist (the simulator's logs
        starting at rest).  Without it a constant friction offset and a twist offset are
        indistinguishable from speeds alone (``k phi + T_f`` enters only as a sum).
    input_row : "end" (row k+1 holds the input over [t_k, t_k+1), the simulator's logs) or "start"
    max_iter, tol : iteration limit and tolerance (GN: converged when the scaled step is below
        ``sqrt(tol)`` and the scaled gaps below ``100 tol``; IPOPT: its ``tol``)
    solver : "gn" (hand-written constrained Gauss-Newton on the sparse KKT system,
        :mod:`estimators.identify_gn`) or "ipopt" (IPOPT with the GN Hessian, uncompiled)
    compile : GN only: build the per-sample sensitivity function with gcc (cached on disk
        under ``$XDG_CACHE_HOME/stickslip``); None: if gcc is available; False: CasADi's
        virtual machine (same numbers, about 2x slower)
    input_cutoff : ``{input channel: cutoff [Hz]}``: zero-phase 2nd-order Butterworth low-pass
        applied to those logged inputs before the fit.  The model takes the logged inputs as
        exact; load-cell noise on a normal force is then an error in the variables that biases
        damping and friction (disc, noise x3: d off by 62-100 % raw, 19-29 % with the true force).
        Choose the cutoff below the noise band but above the force's real bandwidth
    corr_warn, rse_warn : identifiability thresholds (|correlation|, relative standard error)
    progress : print a one-line status per iteration to stderr
    systematic : also estimate a regularisation-sensitivity (systematic) error: refit, warm-started
        from the estimate, with the friction regularisation halved (``eps/2``; lead screw: its
        zero-speed rate ``r1`` doubled) and twice the substeps (``nsub`` given) or the automatic
        substeps for the new ``eps``; ``syserr = |theta(eps) - theta(eps/2)|`` per parameter and
        the total error ``sqrt(stderr^2 + syserr^2)`` (:attr:`FitResult.error`).  Off by default
        (costs one more, warm-started fit)
    systematic_iter : iteration limit of that refit
    input_noise : errors in the variables: ``{input channel: noise std [SI]}``, ``"auto"``
        (default: the force/torque inputs that :func:`detect_input_noise` finds white noise on,
        with the estimated std, except channels in ``input_cutoff``; GN solver only, nothing
        for IPOPT) or ``"off"``.  Those logged inputs are taken as noisy: every shooting
        interval gets a constant correction per channel, a decision variable with the prior
        N(0, std^2 / shoot_every) (:class:`estimators.identify_gn.ShootingProblem`).  Unlike
        ``input_cutoff`` it does not assume the input is slow.  Disc, noise x1/x3: damping
        +19..+28 % instead of -58..+101 %; rig2 with the torque's 0.01 N m given: c +10 %
        instead of +39 % (BENCHMARKS.md)
    """

    free: tuple[str, ...]
    bounds: Mapping[str, tuple[float, float]] | None = None
    outputs: tuple[str, ...] | None = None
    noise: Mapping[str, float] | None = None
    eps: float = 0.005
    nsub: int | None = None
    shoot_every: int = 10
    speed_average: bool = True
    use_twist: bool = True
    input_row: str = "end"
    max_iter: int = 100
    tol: float = 1e-8
    corr_warn: float = 0.95
    rse_warn: float = 0.5
    progress: bool = False
    solver: str = "gn"
    compile: bool | None = None
    input_cutoff: Mapping[str, float] | None = None
    systematic: bool = False
    systematic_iter: int = 20
    input_noise: Mapping[str, float] | str | None = "auto"

    def __post_init__(self):
        if isinstance(self.free, str):
            object.__setattr__(self, "free", tuple(s.strip() for s in self.free.split(",") if s.strip()))
        object.__setattr__(self, "free", tuple(self.free))
        if not self.free:
            raise ConfigError("identify.free must name at least one parameter, got none")
        if len(set(self.free)) != len(self.free):
            raise ConfigError(f"identify.free must not repeat names, got {list(self.free)}")
        if self.eps is not None and not (isinstance(self.eps, (int, float)) and math.isfinite(self.eps) and self.eps > 0):
            raise ConfigError(f"identify.eps must be a finite number > 0 rad/s, got {self.eps!r}")
        if self.systematic not in (True, False):
            raise ConfigError(f"identify.systematic must be true or false, got {self.systematic!r}")
        for name in ("nsub", "shoot_every", "max_iter", "systematic_iter"):
            v = getattr(self, name)
            if name == "nsub" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"identify.{name} must be an integer >= 1, got {v!r}")
        if self.input_row not in ("end", "start"):
            raise ConfigError(f"identify.input_row must be 'end' or 'start', got {self.input_row!r}")
        if not (isinstance(self.tol, (int, float)) and self.tol > 0):
            raise ConfigError(f"identify.tol must be > 0, got {self.tol!r}")
        if not 0 < self.corr_warn <= 1:
            raise ConfigError(f"identify.corr_warn must be in (0, 1], got {self.corr_warn!r}")
        if not self.rse_warn > 0:
            raise ConfigError(f"identify.rse_warn must be > 0, got {self.rse_warn!r}")
        if self.solver not in ("gn", "ipopt"):
            raise ConfigError(f"identify.solver must be 'gn' or 'ipopt', got {self.solver!r}")
        if self.compile not in (None, True, False):
            raise ConfigError(f"identify.compile must be true, false or unset, got {self.compile!r}")
        for k, v in (self.input_cutoff or {}).items():
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"identify.input_cutoff.{k} must be a frequency > 0 Hz, got {v!r}")
        if isinstance(self.input_noise, str):
            if self.input_noise not in ("auto", "off"):
                raise ConfigError(f"identify.input_noise must be 'auto', 'off' or a table of standard deviations, "
                                  f"got {self.input_noise!r}")
        else:
            for k, v in (self.input_noise or {}).items():
                if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                    raise ConfigError(f"identify.input_noise.{k} must be a standard deviation > 0, got {v!r}")
            if self.input_noise and self.solver != "gn":
                raise ConfigError(f"identify.input_noise needs solver 'gn', got {self.solver!r}")
        if self.noise is not None:
            for k, v in self.noise.items():
                if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                    raise ConfigError(f"identify.noise.{k} must be a finite number > 0, got {v!r}")


@dataclass(frozen=True)
class Validation:
    """Free-run prediction of a held-back log segment with the fitted parameters.

    The simulation uses the EXACT stick/slip plant (:mod:`models.hybrid`, 10 substeps per
    sample) from the fitted state at the end of the training segment, driven by the logged
    inputs; speeds are compared as sample means (like the DAQ's backward differences).
    """

    t: np.ndarray
    measured: dict = field(repr=False)
    simulated: dict = field(repr=False)
    nrmse: dict = field(default_factory=dict)
    period_measured: float = float("nan")
    period_simulated: float = float("nan")
    period_error: float = float("nan")       # relative
    amplitude_measured: float = float("nan")
    amplitude_simulated: float = float("nan")
    amplitude_error: float = float("nan")    # relative
    method: str = "hybrid"


@dataclass(frozen=True)
class FitResult:
    """Result of :func:`identify`.

    Attributes
    ----------
    model : model name
    names : fitted parameter names
    estimate, stderr : (n_free,) values and standard errors (SI units)
    initial : (n_free,) initial guess
    corr : (n_free, n_free) correlation matrix
    params : the full fitted :class:`ParameterSet` (with ``[stderr]``)
    t, measured, simulated : per log: times (n,), and dicts channel -> (n,) (the fitted trajectory)
    residuals : per log: dict channel -> (n,) weighted residuals (measured - simulated)/noise
    nrmse : per channel NRMSE over all logs (RMS error / range of the measured signal)
    sigma2 : residual variance per degree of freedom (1 if the noise levels are right)
    tau : integrated autocorrelation time of the residuals that inflated the covariance
    nsub : RK4 substeps used
    noise : noise level used per channel
    states : per log: (n_nodes, nx) fitted node states
    status, success, iterations, wall_time [s], warnings, validation (or None)
    syserr : (n_free,) regularisation-sensitivity error ``|theta(eps) - theta(eps/2)|`` (SI units),
        or None when not requested (``IdentifyOptions.systematic``); NaN where the refit failed
    input_noise : ``{input channel: std}`` treated as errors in the variables (resolved from ``"auto"``)
    """

    model: str
    names: tuple
    estimate: np.ndarray
    stderr: np.ndarray
    initial: np.ndarray
    corr: np.ndarray
    params: ParameterSet
    t: tuple = field(repr=False)
    measured: tuple = field(repr=False)
    simulated: tuple = field(repr=False)
    residuals: tuple = field(repr=False)
    nrmse: dict = field(default_factory=dict)
    sigma2: float = float("nan")
    tau: float = 1.0
    nsub: int = 0
    noise: dict = field(default_factory=dict)
    states: tuple = field(default=(), repr=False)
    status: str = ""
    success: bool = False
    iterations: int = 0
    wall_time: float = 0.0
    warnings: tuple = ()
    at_bound: tuple = ()
    validation: Validation | None = None
    syserr: np.ndarray | None = None
    input_noise: dict = field(default_factory=dict)

    @property
    def error(self) -> np.ndarray:
        """Total error ``sqrt(stderr^2 + syserr^2)`` (just ``stderr`` when no systematic error was estimated)."""
        if self.syserr is None:
            return self.stderr
        return np.sqrt(self.stderr ** 2 + self.syserr ** 2)

    def as_dict(self) -> dict:
        """A JSON-friendly summary."""
        params = {n: {"estimate": float(e), "stderr": float(s), "initial": float(i), "unit": self.params.spec(n).unit}
                  for n, e, s, i in zip(self.names, self.estimate, self.stderr, self.initial)}
        if self.syserr is not None:
            for n, y, t in zip(self.names, self.syserr, self.error):
                params[n].update({"syserr": float(y), "error": float(t)})
        return {
            "model": self.model,
            "parameters": params,
            "corr": self.corr.tolist(),
            "nrmse": dict(self.nrmse),
            "sigma2": self.sigma2,
            "tau": self.tau,
            "nsub": self.nsub,
            "status": self.status,
            "success": self.success,
            "iterations": self.iterations,
            "wall_time": self.wall_time,
            "warnings": list(self.warnings),
            "at_bound": list(self.at_bound),
            "input_noise": dict(self.input_noise),
            "validation": None if self.validation is None else {
                "nrmse": dict(self.validation.nrmse),
                "period_measured": self.validation.period_measured,
                "period_simulated": self.validation.period_simulated,
                "period_error": self.validation.period_error,
                "amplitude_measured": self.validation.amplitude_measured,
                "amplitude_simulated": self.validation.amplitude_simulated,
                "amplitude_error": self.validation.amplitude_error,
                "method": self.validation.method,
            },
        }


# --------------------------------------------------------------------------- helpers
def output_channels(model: RigModel, log: Log) -> tuple[str, ...]:
    """The measured outputs of ``model`` present in ``log`` that are not model inputs."""
    names = model.output_names()
    return tuple(n for n in names if n in log.channels and n not in model.inputs
                 and not n.startswith("theta") and not n.startswith("twist"))


def default_noise(name: str, dt: float, sensors: SensorOptions = SensorOptions()) -> float:
    """Noise standard deviation of a channel with the default sensors (thesis rig, 1000-tick encoders).

    Speeds: backward difference of quantised angles, ``sqrt(2 q^2/12)/dt``; the R3/motor-side
    speed uses the motor encoder (``eta`` times finer).  Forces and torques: the load-cell noise.
    """
    if name in ("omega1", "omega2"):
        return math.sqrt(sensors.speed_variance(dt))
    if name == "omega3":
        return math.sqrt(sensors.speed_variance(dt, motor=True))
    if name == "motor_torque":
        return sensors.torque_noise * sensors.noise_scale
    if name in ("n1", "n2", "axial_force"):
        return sensors.force_noise * sensors.noise_scale
    if name.startswith("omega"):
        return math.sqrt(sensors.speed_variance(dt))
    if "-" in name:  # twist from two encoders
        a, b = name.split("-")
        return math.sqrt(sum(sensors.angle_variance(motor=(c == "theta3")) for c in (a, b)) or 1e-8) \
            if all(c in ("theta1", "theta2", "theta3") for c in (a, b)) else math.sqrt(2 * sensors.angle_variance())
    raise ConfigError(f"no default noise level for channel {name!r}; give identify.noise.{name}")


def _interval_function(model: RigModel, dt: float, M: int, nsub: int, eps, outputs, speed_average: bool):
    """G(x0, U (nu x M), p) -> (x_end, Y (ny x M)): M samples of RK4 with quadrature of speeds."""
    f = model.ode(eps)
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_p)
    h_all = _output_function(model, outputs)
    avg = [speed_average and n.startswith("omega") for n in outputs]
    # augmented ODE: state + running integral of the averaged outputs
    idx_avg = [i for i, a in enumerate(avg) if a]
    yexpr = h_all(x, u, p)
    q_rhs = ca.vertcat(*[yexpr[i] for i in idx_avg]) if idx_avg else ca.SX(0, 1)
    fa = ca.Function("fa", [x, u, p], [ca.vertcat(f(x, u, p), q_rhs)])
    nq = len(idx_avg)
    hs = dt / nsub

    def step(xk, uk, pk):
        xa = ca.vertcat(xk, ca.SX.zeros(nq))
        for _ in range(nsub):
            k1 = fa(xa[:model.nx], uk, pk)
            k2 = fa(xa[:model.nx] + hs / 2 * k1[:model.nx], uk, pk)
            k3 = fa(xa[:model.nx] + hs / 2 * k2[:model.nx], uk, pk)
            k4 = fa(xa[:model.nx] + hs * k3[:model.nx], uk, pk)
            xa = xa + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xn = xa[:model.nx]
        yend = h_all(xn, uk, pk)
        ys, jq = [], 0
        for i in range(len(outputs)):
            if avg[i]:
                ys.append(xa[model.nx + jq] / dt)
                jq += 1
            else:
                ys.append(yend[i])
        return xn, ca.vertcat(*ys)

    xs, us, ps = ca.SX.sym("xs", model.nx), ca.SX.sym("us", model.nu), ca.SX.sym("ps", model.n_p)
    xn, yk = step(xs, us, ps)
    S = ca.Function(f"{model.name}_id_sample", [xs, us, ps], [xn, yk], ["x", "u", "p"], ["x_next", "y"])
    x0 = ca.SX.sym("x0", model.nx)
    U = ca.SX.sym("U", model.nu, M)
    xk, Ys = x0, []
    for k in range(M):
        xk, yk = S(xk, U[:, k], p)
        Ys.append(yk)
    return ca.Function(f"{model.name}_id_interval", [x0, U, p], [xk, ca.horzcat(*Ys)],
                       ["x0", "U", "p"], ["x_end", "Y"])


def auto_nsub(model: RigModel, params: ParameterSet, u, dt: float, eps: float, rho_h: float = 3.5) -> int:
    """RK4 substeps so that ``h |lambda|max <= rho_h`` at zero contact speed (stiffest point)."""
    f = model.ode(eps)
    x = ca.SX.sym("x", model.nx)
    Jf = ca.Function("jf", [x], [ca.jacobian(f(x, ca.DM(u), ca.DM(params.vector())), x)])
    try:
        x0 = np.asarray(model.sliding_guess(u, params), dtype=float)
    except Exception:  # noqa: BLE001 - any finite point will do
        x0 = np.zeros(model.nx)
    x0 = np.where(np.isfinite(x0), x0, 0.0)
    for idx in model.contacts:
        x0[idx] = 0.0
    lam = np.linalg.eigvals(np.array(Jf(x0)))
    rho = float(np.max(np.abs(lam))) if lam.size else 0.0
    return max(1, int(math.ceil(dt * rho / rho_h)))


def _output_function(model: RigModel, outputs) -> ca.Function:
    """h(x, u, p) stacking model outputs and twist pseudo-outputs ``"thetaA-thetaB"``."""
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_p)
    P = model.unpack(p)
    th = ca.SX(0)
    out = model.outputs(x, u, P, th)
    ys = []
    for n in outputs:
        if "-" in n:
            a, b = n.split("-")
            ys.append(out[a] - out[b])
        elif n in out:
            ys.append(out[n])
        else:
            raise ConfigError(f"{model.name}: unknown output {n!r}; expected some of {list(out)}")
    return ca.Function(f"{model.name}_id_h", [x, u, p], [ca.vertcat(*ys)], ["x", "u", "p"], ["y"])


def twist_channels(model: RigModel, log: Log, params: ParameterSet) -> tuple[str, ...]:
    """Angle differences ``"thetaA-thetaB"`` in ``log`` that equal a state of ``model``."""
    return tuple(f"{a}-{b}" for j, (a, b) in sorted(_angle_pairs(model, log, params).items()))


def _angle_pairs(model, log, params):
    h = model.meas()
    rng = np.random.default_rng(0)
    x0 = rng.standard_normal(model.nx)
    u0 = rng.standard_normal(model.nu)
    p = params.vector()

    def ev(x, th):
        return {k: float(v) for k, v in h(x=x, u=u0, p=p, theta_ref=th).items()}

    base = ev(x0, 0.3)
    grads = {k: np.zeros(model.nx + 1) for k in base}
    for j in range(model.nx):
        xe = x0.copy()
        xe[j] += 1.0
        d = ev(xe, 0.3)
        for k in base:
            grads[k][j] = d[k] - base[k]
    d = ev(x0, 1.3)
    for k in base:
        grads[k][model.nx] = d[k] - base[k]
    angles = [k for k in grads if k.startswith("theta") and k in log.channels]
    pairs = {}
    for j in range(model.nx):
        e = np.zeros(model.nx + 1)
        e[j] = 1.0
        for a in angles:
            for b in angles:
                if a != b and j not in pairs and np.allclose(grads[a] - grads[b], e, atol=1e-9):
                    pairs[j] = (a, b)
    return pairs


def _state_from_log(model: RigModel, log: Log, params: ParameterSet):
    """Which states are measured directly (speeds) or as angle differences (twists).

    Returns ``{state index: array (n,)}`` built by matching the (linear) output map
    numerically, so it works for every model.
    """
    h = model.meas()
    rng = np.random.default_rng(0)
    x0 = rng.standard_normal(model.nx)
    u0 = rng.standard_normal(model.nu)
    p = params.vector()
    base = {k: float(v) for k, v in h(x=x0, u=u0, p=p, theta_ref=0.3).items()}
    grads = {}
    for j in range(model.nx):
        xe = x0.copy()
        xe[j] += 1.0
        d = {k: float(v) for k, v in h(x=xe, u=u0, p=p, theta_ref=0.3).items()}
        for k in base:
            grads.setdefault(k, np.zeros(model.nx + 1))[j] = d[k] - base[k]
    d = {k: float(v) for k, v in h(x=x0, u=u0, p=p, theta_ref=1.3).items()}
    for k in base:
        grads[k][model.nx] = d[k] - base[k]
    out = {}
    for j in range(model.nx):
        e = np.zeros(model.nx + 1)
        e[j] = 1.0
        for k, g in grads.items():
            if k in log.channels and np.allclose(g, e, atol=1e-9) and k.startswith("omega"):
                out[j] = log[k]
        if j in out:
            continue
        angles = [k for k in grads if k.startswith("theta") and k in log.channels]
        for a in angles:
            for b in angles:
                if a != b and np.allclose(grads[a] - grads[b], e, atol=1e-9):
                    out[j] = log[a] - log[b]
    return out


def _autocorr_time(r: np.ndarray) -> float:
    """Integrated autocorrelation time ``1 + 2 sum rho_k`` with Sokal's window (k >= 5 tau)."""
    r = np.asarray(r, dtype=float) - np.mean(r)
    n = r.size
    if n < 4 or not np.any(r):
        return 1.0
    f = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac = ac / ac[0]
    tau = 1.0
    for k in range(1, n // 2):
        tau += 2 * ac[k]
        if k >= 5 * tau:
            break
    return max(1.0, float(tau))


def _channel(log: Log, name: str) -> np.ndarray:
    if "-" in name:
        a, b = name.split("-")
        return log[a] - log[b]
    return log[name]


def _moving_average(x, n):
    if n <= 1:
        return x
    k = np.ones(n) / n
    return np.convolve(np.pad(x, (n // 2, n - 1 - n // 2), mode="edge"), k, mode="valid")


def _lowpass_inputs(log: Log, model: RigModel, cutoff: Mapping[str, float]) -> Log:
    """``log`` with the named input channels passed through a zero-phase Butterworth low-pass."""
    from scipy.signal import butter, filtfilt

    ch = dict(log.channels)
    nyq = 0.5 / log.dt
    for name, fc in cutoff.items():
        if name not in model.inputs:
            raise ConfigError(f"identify.input_cutoff.{name}: not an input of model {model.name!r} "
                              f"(inputs: {', '.join(model.inputs)})")
        if not fc < nyq:
            raise ConfigError(f"identify.input_cutoff.{name} must be below the Nyquist frequency {nyq:g} Hz, got {fc:g}")
        b, a = butter(2, fc / nyq)
        x = np.asarray(ch[name], dtype=float)
        if x.size > 3 * (max(len(a), len(b)) + 1):
            ch[name] = filtfilt(b, a, x)
    return Log(log.t, ch, log.source, log.derived)


def detect_input_noise(logs: Sequence[Log], model: RigModel) -> dict[str, float]:
    """Force and torque inputs (unit N or N m) that carry white measurement noise:
    ``{channel: noise std}``.

    The part of the logged signal above 0.5 Hz (zero-phase Butterworth) counts as noise when it
    is uncorrelated from sample to sample (|lag-1 autocorrelation| < 0.2) and larger than 0.1 %
    of the signal; its std is then the noise estimate (for white noise at 100 Hz, 99 % of the
    variance lies above 0.5 Hz).  A torque that follows a speed loop has correlated fast content
    (rig2's PI torque: lag-1 autocorrelation 0.82) and is not flagged: give its load cell's noise
    explicitly.
    """
    from scipy.signal import butter, filtfilt

    found: dict[str, float] = {}
    for name, unit in zip(model.inputs, model.input_units):
        if unit not in ("N", "N m"):
            continue
        fast_parts, level = [], 0.0
        for lg in logs:
            if name not in lg.channels:
                continue  # identify() reports the missing input
            x = np.asarray(lg[name], dtype=float)
            if x.size < 200:
                continue
            b, a = butter(2, 0.5 / (0.5 / lg.dt))
            fast_parts.append(x - filtfilt(b, a, x))
            level = max(level, float(np.mean(np.abs(x))))
        if not fast_parts:
            continue
        fast = np.concatenate(fast_parts)
        sd = float(np.std(fast))
        if sd <= 1e-3 * max(level, 1e-9):
            continue
        if abs(float(np.corrcoef(fast[:-1], fast[1:])[0, 1])) < 0.2:
            found[name] = sd
    return found


def input_noise_hints(logs: Sequence[Log], model: RigModel, cutoff: Mapping[str, float] | None,
                      input_noise: Mapping[str, float] | None = None) -> list[str]:
    """Hints for inputs with white noise (:func:`detect_input_noise`) that the fit takes as exact:
    that noise is an error in the variables that biases damping and friction (BENCHMARKS.md:
    disc damping +51 % taking the force as exact, +28 % with ``input_noise``)."""
    hints = []
    for name, sd in detect_input_noise(logs, model).items():
        if name in (cutoff or {}) or name in (input_noise or {}):
            continue
        unit = dict(zip(model.inputs, model.input_units))[name]
        hints.append(f"input {name} carries white noise ({sd:.3g} {unit} std above 0.5 Hz) that the model takes as "
                     f"exact: this biases damping and friction; treat it as noisy: input_noise {name}={sd:.2g} "
                     f"(CLI --input-noise {name}={sd:.2g})")
    return hints


# --------------------------------------------------------------------------- the fit
def identify(logs: Log | Sequence[Log], model: str | RigModel, initial: ParameterSet,
             options: IdentifyOptions, *, holdout: float = 0.0, _validate: bool = True,
             _nodes=None) -> FitResult:
    """Fit the free parameters of ``model`` to one or several logs.

    Parameters
    ----------
    logs : a :class:`models.logs.Log` or a sequence of them (same sample period)
    model : model name or :class:`models.rigs.RigModel`
    initial : initial guess and values of the fixed parameters (e.g. ``published(model)``)
    options : :class:`IdentifyOptions`
    holdout : fraction in [0, 0.9) of the END of each log kept out of the fit and
        predicted afterwards with the fitted parameters (:class:`Validation`, first log)

    Returns
    -------
    FitResult

    Raises
    ------
    ConfigError : unknown parameter, bad bounds, initial guess outside the bounds
    DataError : a log lacks an input channel, has no output channel, or is too short
    SolverFailure : the solver returned non-finite values
    """
    t_start = time.perf_counter()
    m = get_model(model) if isinstance(model, str) else model
    if not isinstance(initial, m.param_cls):
        raise ConfigError(f"initial parameters must be {m.param_cls.__name__} for model {m.name!r}, "
                          f"got {type(initial).__name__}")
    logs = [logs] if isinstance(logs, Log) else list(logs)
    logs = [lg.with_speeds() for lg in logs]  # e.g. omega_drive from theta_drive
    if not logs:
        raise DataError("identify needs at least one log")
    if not (isinstance(holdout, (int, float)) and 0 <= holdout < 0.9):
        raise ConfigError(f"holdout must be a fraction in [0, 0.9), got {holdout!r}")
    all_names = m.param_cls.names()
    for n in options.free:
        if n not in all_names:
            raise ConfigError(f"free parameter {n!r} is not a parameter of model {m.name!r}; "
                              f"expected some of {', '.join(all_names)}")
    free_idx = [all_names.index(n) for n in options.free]
    nf = len(free_idx)
    theta0 = initial.vector(options.free)
    lo, hi = np.empty(nf), np.empty(nf)
    for i, n in enumerate(options.free):
        b = (options.bounds or {}).get(n) or initial.bounds(n)
        lo[i], hi[i] = float(b[0]), float(b[1])
        if not lo[i] < hi[i]:
            raise ConfigError(f"bounds.{n} must have lower < upper, got [{lo[i]:g}, {hi[i]:g}]")
        if not lo[i] <= theta0[i] <= hi[i]:
            raise ConfigError(f"initial {n} = {theta0[i]:g} lies outside its bounds [{lo[i]:g}, {hi[i]:g}]")

    # --- data
    dt = logs[0].dt
    for lg in logs:
        if abs(lg.dt - dt) > 1e-9 * max(1.0, dt):
            raise DataError(f"{lg.source}: sample period {lg.dt:g} s differs from {dt:g} s of {logs[0].source}; "
                            f"resample the logs to one period")
        for name in m.inputs:
            if name not in lg.channels:
                raise DataError(f"{lg.source}: missing input column {name!r} needed by model {m.name!r} "
                                f"(inputs: {', '.join(m.inputs)})")
    logs_in = logs  # before the input low-pass (the systematic refit filters again)
    if options.input_cutoff:
        logs = [_lowpass_inputs(lg, m, options.input_cutoff) for lg in logs]
    outputs = options.outputs or output_channels(m, logs[0])
    if not outputs:
        raise DataError(f"{logs[0].source}: no output channel of model {m.name!r} found "
                        f"(expected some of {', '.join(o for o in m.output_names() if o.startswith('omega') or o == 'motor_torque')})")
    for lg in logs:
        for o in outputs:
            for part in o.split("-"):
                if part not in lg.channels:
                    raise DataError(f"{lg.source}: missing output column {part!r}")
    if options.use_twist and options.outputs is None:
        tw = twist_channels(m, logs[0], initial)
        outputs = tuple(outputs) + tuple(c for c in tw if all(x in lg.channels for lg in logs for x in c.split("-")))
    noise = {o: float((options.noise or {}).get(o) or default_noise(o, dt)) for o in outputs}
    M = options.shoot_every
    train, held = [], None
    for i, lg in enumerate(logs):
        n = len(lg.t)
        ntr = n if holdout == 0 else int(round(n * (1 - holdout)))
        if i == 0 and holdout > 0:
            held = (lg, ntr)
        nint = (ntr - 1) // M
        if nint < 1:
            raise DataError(f"{lg.source}: needs at least {M + 1} samples for shoot_every = {M}, got {ntr}")
        train.append((lg, nint))

    # --- the NLP
    nsub = options.nsub or auto_nsub(m, initial, np.max(np.abs(np.concatenate(
        [np.column_stack([lg[name] for name in m.inputs]) for lg in logs])), axis=0), dt, options.eps)
    h_all = _output_function(m, outputs)
    avg = [options.speed_average and o.startswith("omega") for o in outputs]
    if options.input_noise == "auto":
        eiv = {k: v for k, v in detect_input_noise(logs_in, m).items() if k not in (options.input_cutoff or {})} \
            if options.solver == "gn" else {}
    elif options.input_noise == "off" or options.input_noise is None:
        eiv = {}
    else:
        eiv = dict(options.input_noise)
    for name in eiv:
        if name not in m.inputs:
            raise ConfigError(f"identify.input_noise.{name}: not an input of model {m.name!r} "
                              f"(inputs: {', '.join(m.inputs)})")
    S = sample_function(m, nsub, h_all, avg, input_jac=bool(eiv))
    S_val = sample_function(m, nsub, h_all, avg, values_only=True)
    S_run = S
    use_c = options.compile if options.compile is not None else (options.solver == "gn")
    if use_c:
        S_run = compiled_or_none(S) or S
        if S_run is not S:
            S_val = compiled_or_none(S_val) or S_val
    compiled = S_run is not S
    G = _interval_function(m, dt, M, nsub, options.eps, outputs, options.speed_average) \
        if options.solver == "ipopt" else None
    ny = len(outputs)
    Ublocks, Yblocks, node_init, log_ranges = [], [], [], []
    sig = np.array([noise[o] for o in outputs])
    for lg, nint in train:
        n_used = nint * M + 1
        U = np.column_stack([lg[name][:n_used] for name in m.inputs])  # (n_used, nu)
        # input over interval k (samples k -> k+1)
        Uint = U[1:] if options.input_row == "end" else U[:-1]
        Y = np.column_stack([_channel(lg, o)[:n_used] for o in outputs])[1:]
        Ublocks.append(Uint.reshape(nint, M, m.nu))
        Yblocks.append(Y.reshape(nint, M, ny))
        log_ranges.append(nint)
    Uall = np.concatenate(Ublocks)          # (Nint, M, nu)
    Yall = np.concatenate(Yblocks)          # (Nint, M, ny)
    Nint = Uall.shape[0]

    # initial node states: smooth simulation with the initial parameters, measured states overwritten
    p_init = initial.vector()
    x_abs = np.zeros(m.nx)
    if _nodes is not None:  # warm start (systematic refit): node states of a previous fit of the same logs
        if [len(n) for n in _nodes] != [nint + 1 for _lg, nint in train]:
            raise ConfigError("warm-start node states do not match the logs' shooting intervals")
        train_loop = []
        node_init = [np.asarray(n, dtype=float).copy() for n in _nodes]
        for nodes in node_init:
            x_abs = np.maximum(x_abs, np.max(np.abs(nodes), axis=0))
    else:
        train_loop = train
    for (lg, nint) in train_loop:
        known = _state_from_log(m, lg, initial)
        u_first = np.array([lg[name][1 if options.input_row == "end" else 0] for name in m.inputs])
        try:
            x = np.asarray(m.sliding_guess(u_first, initial), dtype=float) if abs(u_first[0]) > 0 \
                else np.zeros(m.nx)
            if not np.all(np.isfinite(x)):
                raise ValueError
        except Exception:  # noqa: BLE001 - a failed Newton solve only worsens the initial guess
            x = np.zeros(m.nx)
        nodes = np.empty((nint + 1, m.nx))
        lg_u = np.column_stack([lg[name] for name in m.inputs])
        smooth = {j: _moving_average(v, 5) for j, v in known.items()}
        for k in range(nint + 1):
            for j, v in smooth.items():
                x[j] = v[k * M]
            nodes[k] = x
            if k < nint:
                Ub = lg_u[(k * M + 1 if options.input_row == "end" else k * M):][:M]
                xn = x.copy()
                for Uk in Ub:
                    xn = np.array(S_val(xn, Uk, p_init, dt, options.eps)[0]).ravel()
                x = xn if np.all(np.isfinite(xn)) and np.max(np.abs(xn)) < 1e6 else nodes[k].copy()
        node_init.append(nodes)
        x_abs = np.maximum(x_abs, np.max(np.abs(nodes), axis=0))
    x_scale = np.where(x_abs > 1e-6, x_abs, 1.0)
    x_scale = np.maximum(x_scale, 1e-3 * np.max(x_scale))
    th_scale = np.where(np.abs(theta0) > 0, np.abs(theta0), np.maximum(hi - lo, 1e-6) * 0.1)
    th_scale = np.where(np.isfinite(th_scale), th_scale, 1.0)

    # decision variables (scaled): [theta; nodes of log 1; nodes of log 2; ...]
    n_nodes = [nint + 1 for nint in log_ranges]
    nw = nf + m.nx * sum(n_nodes) + Nint * len(eiv)
    w0 = np.concatenate([theta0 / th_scale] + [(nodes / x_scale).T.ravel(order="F") for nodes in node_init]
                        + [np.zeros(Nint * len(eiv))])
    lbx = np.full(nw, -np.inf)
    ubx = np.full(nw, np.inf)
    lbx[:nf] = lo / th_scale
    ubx[:nf] = hi / th_scale
    Ymeas = Yall.reshape(Nint * M, ny).T                                    # (ny, Nint*M)
    if options.solver == "gn":
        wgt_arr = np.broadcast_to(1.0 / sig, Yall.shape)  # per residual
        starts_idx = np.concatenate([off_n + np.arange(nint) for off_n, nint in
                                     zip(np.cumsum([0] + n_nodes[:-1]), log_ranges)])
        prob = ShootingProblem(S_run, m.nx, m.n_p, p_init, free_idx, th_scale, x_scale, Uall, Yall, wgt_arr,
                               starts_idx, dt, options.eps, S_val=S_val,
                               eiv_idx=[m.inputs.index(n) for n in eiv],
                               eiv_scale=[eiv[n] / math.sqrt(M) for n in eiv])

        def _progress(it, f, gmax, step):
            if options.progress:
                import sys
                sys.stderr.write(f"\ridentify {m.name}: iteration {it:3d}, cost {f:.6g}, gap {gmax:.2e}, "
                                 f"step {step:.2e}   ")
                sys.stderr.flush()

        res = solve_gn(prob, w0, lbx[:nf], ubx[:nf], max_iter=options.max_iter, tol=options.tol, callback=_progress)
        if options.progress:
            import sys
            sys.stderr.write("\n")
        w_opt = res.w
        if not np.all(np.isfinite(w_opt)):
            raise SolverFailure(f"identify {m.name}: the solver returned non-finite values ({res.status})")
        status, success, iterations = res.status, res.success, res.iterations
        r_v, _g, Jr, A, Yp3 = prob.evaluate(w_opt)
        Yp_all = Yp3.reshape(Nint * M, ny).T
        theta = w_opt[:nf] * th_scale
    else:
        w = ca.MX.sym("w", nw)
        th = w[:nf] * th_scale
        p_full = ca.MX(ca.DM(p_init))
        p_parts = [p_full[i] for i in range(m.n_p)]
        for i, j in enumerate(free_idx):
            p_parts[j] = th[i]
        p_sym = ca.vertcat(*p_parts)
        Snodes = []
        off = nf
        xs_dm = ca.DM(x_scale)
        for nn in n_nodes:
            blk = ca.reshape(w[off:off + m.nx * nn], m.nx, nn)
            Snodes.append(blk * ca.repmat(xs_dm, 1, nn))
            off += m.nx * nn
        starts = ca.horzcat(*[s[:, :-1] for s in Snodes])        # (nx, Nint)
        ends_target = ca.horzcat(*[s[:, 1:] for s in Snodes])
        Gm = G.map(Nint, "thread", 2)
        Ustack = ca.DM(np.concatenate([Uall[i].T for i in range(Nint)], axis=1))  # (nu, Nint*M)
        Xend, Ypred = Gm(starts, Ustack, ca.repmat(p_sym, 1, Nint))
        wgt = ca.DM(1.0 / sig)
        r = (Ypred - ca.DM(Ymeas)) * ca.repmat(wgt, 1, Nint * M)
        r = ca.vec(r)
        gap = ca.vec((Xend - ends_target) / ca.repmat(xs_dm, 1, Nint))
        f_obj = 0.5 * ca.dot(r, r)
        J_r = ca.jacobian(r, w)
        lam_f = ca.MX.sym("lam_f")
        lam_g = ca.MX.sym("lam_g", gap.numel())
        pp = ca.MX.sym("pp", 0)
        H = lam_f * ca.mtimes(J_r.T, J_r)
        hess = ca.Function("gn_hess", [w, pp, lam_f, lam_g], [ca.triu(H)], ["x", "p", "lam_f", "lam_g"],
                           ["triu_hess_gamma_x_x"])
        nlp = {"x": w, "f": f_obj, "g": gap}
        its = {"n": 0}

        class _Cb(ca.Callback):
            def __init__(self):
                ca.Callback.__init__(self)
                self.construct("id_progress", {})

            def get_n_in(self):
                return ca.nlpsol_n_out()

            def get_n_out(self):
                return 1

            def get_name_in(self, i):
                return ca.nlpsol_out(i)

            def get_name_out(self, i):
                return "ret"

            def get_sparsity_in(self, i):
                n = ca.nlpsol_out(i)
                if n in ("f",):
                    return ca.Sparsity.scalar()
                if n in ("x", "lam_x"):
                    return ca.Sparsity.dense(nw)
                if n in ("g", "lam_g"):
                    return ca.Sparsity.dense(gap.numel())
                return ca.Sparsity(0, 0)

            def eval(self, arg):
                its["n"] += 1
                if options.progress:
                    import sys
                    sys.stderr.write(f"\ridentify {m.name}: iteration {its['n']:3d}, cost {float(arg[1]):.6g}   ")
                    sys.stderr.flush()
                return [0]

        cb = _Cb()
        opts = {"hess_lag": hess, "print_time": False, "iteration_callback": cb,
                "ipopt": {"print_level": 0, "sb": "yes", "max_iter": options.max_iter, "tol": options.tol,
                          "acceptable_tol": 1e-5, "linear_solver": "mumps", "mu_strategy": "adaptive"}}
        solver = ca.nlpsol("identify", "ipopt", nlp, opts)
        sol = solver(x0=w0, lbx=lbx, ubx=ubx, lbg=0, ubg=0)
        if options.progress:
            import sys
            sys.stderr.write("\n")
        stats = solver.stats()
        w_opt = np.array(sol["x"]).ravel()
        if not np.all(np.isfinite(w_opt)):
            raise SolverFailure(f"identify {m.name}: the solver returned non-finite values ({stats.get('return_status')})")
        status = str(stats.get("return_status", "unknown"))
        success = bool(stats.get("success", False)) or status == "Solved_To_Acceptable_Level"
        theta = w_opt[:nf] * th_scale

        iterations = int(stats.get("iter_count", its["n"]))
        Yp_all = np.array(ca.Function("yp", [w], [Ypred])(w_opt))
        # --- covariance from the GN information matrix of the constrained problem
        fJ = ca.Function("fJ", [w], [r, J_r, gap, ca.jacobian(gap, w)])
        r_v, Jr_v, g_v, A_v = fJ(w_opt)
        r_v = np.array(r_v).ravel()
        Jr = sp.csc_matrix(Jr_v.sparse()) if hasattr(Jr_v, "sparse") else sp.csc_matrix(np.array(Jr_v))
        A = sp.csc_matrix(A_v.sparse()) if hasattr(A_v, "sparse") else sp.csc_matrix(np.array(A_v))
    n_res = r_v.size
    dof = n_res - (nf + m.nx * len(train))
    sigma2 = float(r_v @ r_v / max(dof, 1))
    at_bound = tuple(n for i, n in enumerate(options.free)
                     if (theta[i] - lo[i]) <= 1e-6 * th_scale[i] or (hi[i] - theta[i]) <= 1e-6 * th_scale[i])
    ng = A.shape[0]
    K = sp.bmat([[Jr.T @ Jr, A.T], [A, None]], format="csc")
    reg = sp.diags(np.r_[np.full(nw, 1e-12), np.full(ng, -1e-12)])
    cov_s = np.full((nf, nf), np.nan)
    try:
        lu = spla.splu((K + reg).tocsc())
        E = np.zeros((nw + ng, nf))
        E[np.arange(nf), np.arange(nf)] = 1.0
        Z = lu.solve(E)
        cov_s = sigma2 * Z[:nf, :nf]
    except RuntimeError:
        pass
    # residuals of quantised, slowly varying signals (and of model error) are correlated in
    # time; inflate by the largest integrated autocorrelation time over the channels
    tau = 1.0
    for j in range(ny):
        rr = np.concatenate([(Ymeas[j] - np.array(Yp_all[j]).ravel()) / sig[j]])
        tau = max(tau, _autocorr_time(rr))
    cov = tau * cov_s * np.outer(th_scale, th_scale)
    var = np.diag(cov)
    se = np.sqrt(np.where(var > 0, var, np.nan))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)

    # --- trajectories, residuals, NRMSE
    Yp = Yp_all
    t_list, meas_list, sim_list, res_list, states = [], [], [], [], []
    col = 0
    off = nf
    for (lg, nint), nn in zip(train, n_nodes):
        ncol = nint * M
        t_list.append(lg.t[1:ncol + 1])
        meas_list.append({o: Ymeas[j, col:col + ncol] for j, o in enumerate(outputs)})
        sim_list.append({o: Yp[j, col:col + ncol] for j, o in enumerate(outputs)})
        res_list.append({o: (Ymeas[j, col:col + ncol] - Yp[j, col:col + ncol]) / sig[j] for j, o in enumerate(outputs)})
        states.append((w_opt[off:off + m.nx * nn].reshape(nn, m.nx)) * x_scale)
        off += m.nx * nn
        col += ncol
    nrmse = {}
    for j, o in enumerate(outputs):
        ym = np.concatenate([d[o] for d in meas_list])
        ys = np.concatenate([d[o] for d in sim_list])
        span = float(np.max(ym) - np.min(ym))
        nrmse[o] = float(np.sqrt(np.mean((ym - ys) ** 2)) / span) if span > 0 else float("nan")

    # --- identifiability warnings
    warns = input_noise_hints(logs_in, m, options.input_cutoff, eiv)
    for i, n in enumerate(options.free):
        if not np.isfinite(se[i]):
            warns.append(f"{n}: standard error not available (singular information matrix): not identifiable")
        elif abs(theta[i]) > 0 and se[i] / abs(theta[i]) > options.rse_warn:
            warns.append(f"{n}: relative standard error {100 * se[i] / abs(theta[i]):.0f} % > "
                         f"{100 * options.rse_warn:.0f} %: poorly identifiable")
    for i in range(nf):
        for j in range(i + 1, nf):
            if np.isfinite(corr[i, j]) and abs(corr[i, j]) > options.corr_warn:
                warns.append(f"{options.free[i]} and {options.free[j]} are correlated "
                             f"(corr = {corr[i, j]:+.3f}): poorly identifiable separately")
    for n in at_bound:
        warns.append(f"{n}: estimate at its bound; the standard error is not meaningful")
    for msg in warns:
        warnings.warn(msg, IdentifiabilityWarning, stacklevel=2)

    clipped = np.clip(theta, lo, hi)
    fitted = initial.with_vector(options.free, clipped)
    fitted = type(fitted).from_mapping({
        "model": m.name, "params": fitted.as_dict(),
        "bounds": {n: [float(a), float(b)] for n, a, b in fitted.fit_bounds},
        "stderr": {n: float(s) for n, s in zip(options.free, se) if np.isfinite(s)}})

    syserr = None
    if options.systematic:
        syserr, msg = _regularisation_sensitivity(logs_in, m, fitted, options, holdout, states)
        if msg:
            warns.append(msg)
            warnings.warn(msg, IdentifiabilityWarning, stacklevel=2)
        total = np.sqrt(se ** 2 + syserr ** 2)
        fitted = type(fitted).from_mapping({
            "model": m.name, "params": fitted.as_dict(),
            "bounds": {n: [float(a), float(b)] for n, a, b in fitted.fit_bounds},
            "stderr": {n: float(s) for n, s in zip(options.free, total) if np.isfinite(s)}})

    validation = None
    if held is not None and _validate:
        lg, ntr = held
        n_used = log_ranges[0] * M
        validation = validate_fit(m, fitted, lg, n_used, states[0][-1], outputs, options)

    return FitResult(
        model=m.name, names=tuple(options.free), estimate=clipped, stderr=se, initial=theta0, corr=corr,
        params=fitted, t=tuple(t_list), measured=tuple(meas_list), simulated=tuple(sim_list),
        residuals=tuple(res_list), nrmse=nrmse, sigma2=sigma2, tau=tau, nsub=nsub, noise=noise, states=tuple(states),
        status=status, success=success, iterations=iterations,
        wall_time=time.perf_counter() - t_start, warnings=tuple(warns), at_bound=at_bound,
        validation=validation, syserr=syserr, input_noise=eiv)


def _regularisation_sensitivity(logs, m: RigModel, fitted: ParameterSet, options: IdentifyOptions,
                                holdout: float, states) -> tuple[np.ndarray, str]:
    """``|theta(eps) - theta(eps/2)|``: refit warm-started from ``fitted`` and its node ``states``
    with the regularisation halved.

    The smooth friction of most models has the width ``eps`` [rad/s]; the lead screw's has
    the zero-speed rate ``r1`` [s/rad] instead (its ``ode`` ignores ``eps``), which is doubled.
    The substeps are doubled when given, else chosen anew for the stiffer model.  Returns the
    per-parameter difference (NaN if the refit failed) and a warning message ("" if none).
    """
    from dataclasses import replace

    start, eps2 = fitted, options.eps / 2
    if m.name == "leadscrew":  # r1 of rig3 is a pin radius, not a regularisation
        if "r1" in options.free:
            nan = np.full(len(options.free), np.nan)
            return nan, "systematic error not estimated: the regularisation rate r1 is itself a free parameter"
        start, eps2 = fitted.replace(r1=2 * fitted.r1), options.eps
    opt2 = replace(options, eps=eps2, nsub=None if options.nsub is None else 2 * options.nsub, systematic=False,
                   max_iter=options.systematic_iter, progress=False)
    theta = fitted.vector(options.free)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit2 = identify(logs, m, start, opt2, holdout=holdout, _validate=False, _nodes=states)
    except SolverFailure as exc:
        return np.full(theta.size, np.nan), f"systematic error not estimated: the refit failed ({exc})"
    msg = "" if fit2.success else f"systematic error from an unconverged refit ({fit2.status})"
    return np.abs(fit2.estimate - theta), msg


# --------------------------------------------------------------------------- validation
def _period(w: np.ndarray, dt: float) -> float:
    """Stick-slip period [s] from the dominant frequency of the speed."""
    from mitigate.metrics import dominant_frequency
    f = dominant_frequency(w, dt)
    return 1.0 / f if f > 0 else float("nan")


def validate_fit(model: RigModel, params: ParameterSet, log: Log, k0: int, x0, outputs, options: IdentifyOptions,
                 nsub: int = 10) -> Validation:
    """Free-run the EXACT stick/slip plant from sample ``k0`` of ``log`` and compare.

    ``x0`` is the (fitted) state at sample ``k0``; inputs come from the log.  Speeds
    are sample means (differences of the plant's absolute angles, like the DAQ's).
    """
    from models.plant.hybrid import hybrid_step_function

    dt = log.dt
    F = hybrid_step_function(model, dt, nsub)
    h = model.meas()
    n = len(log.t)
    if n - k0 < 3:
        raise DataError(f"{log.source}: hold-out segment too short ({n - k0} samples)")
    U = np.column_stack([log[name] for name in model.inputs])
    p = params.vector()
    x = np.asarray(x0, dtype=float)
    # a speed that is numerically tiny is treated as stuck by the exact plant
    for idx in model.contacts:
        if abs(x[idx]) < 1e-3:
            x[idx] = 0.0
    th = 0.0
    sims = {o: [] for o in outputs}
    ang_prev = {k: float(v) for k, v in h(x=x, u=U[min(k0 + 1, n - 1)], p=p, theta_ref=th).items()}
    for k in range(k0, n - 1):
        uk = U[k + 1] if options.input_row == "end" else U[k]
        xn, thn = F(x, th, uk, p)
        x = np.array(xn).ravel()
        th = float(thn)
        out = {kk: float(v) for kk, v in h(x=x, u=uk, p=p, theta_ref=th).items()}
        for o in outputs:
            ang = _SPEED_ANGLE.get(o)
            if options.speed_average and ang in out:
                sims[o].append((out[ang] - ang_prev[ang]) / dt)
            elif "-" in o:
                a, b = o.split("-")
                sims[o].append(out[a] - out[b])
            else:
                sims[o].append(out[o])
        ang_prev = out
    t = log.t[k0 + 1:]
    meas = {o: _channel(log, o)[k0 + 1:] for o in outputs}
    sims = {o: np.array(v) for o, v in sims.items()}
    nrmse = {}
    for o in outputs:
        span = float(np.ptp(meas[o]))
        nrmse[o] = float(np.sqrt(np.mean((meas[o] - sims[o]) ** 2)) / span) if span > 0 else float("nan")
    key = outputs[0]
    Pm, Ps = _period(meas[key], dt), _period(sims[key], dt)
    Am, As = 0.5 * float(np.ptp(_moving_average(meas[key], 3))), 0.5 * float(np.ptp(sims[key]))
    return Validation(t=t, measured=meas, simulated=sims, nrmse=nrmse, period_measured=Pm, period_simulated=Ps,
                      period_error=(Ps - Pm) / Pm if Pm > 0 else float("nan"), amplitude_measured=Am,
                      amplitude_simulated=As, amplitude_error=(As - Am) / Am if Am > 0 else float("nan"))
