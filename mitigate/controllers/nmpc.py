"""Nonlinear MPC of the 3-disc rig: R2 pin force N2 and speed set-point omega_ref.

The controller plans over ``horizon`` intervals of ``dt`` [s] (the OCP step, default
0.05 s, longer than the 10 ms DAQ period) with the OCP of
:mod:`mitigate.controllers.ocp`.  **Timing, explicitly:** it re-plans when at least
``dt`` has passed since its last plan (so with the loop calling every DAQ sample and
``dt = 0.05 s`` it solves every 5th call) and holds the first planned input in between
(zero-order hold over one OCP interval, which is what the rate limits assume).  If the
loop calls less often than ``dt`` it re-plans at every call and shifts the warm start by
the elapsed number of intervals.

Inputs to the prediction: the rig3 state ``estimate.x[:7]``; the measured N1
``measurement["n1"]`` held over the horizon; the servo's pin force from a replica of the
servo model driven by the controller's own commands (started from ``measurement["n2"]``).

Failures: a failed or bound-violating solve -> the previous plan shifted to now
(``fallback="shift"``); no plan left -> baseline (a): nominal set-point and no pin force
(``fallback="baseline"``).  Every failure is counted in ``counts.failures``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Mapping

import numpy as np

from mitigate.controllers.base import Action, Controller
from mitigate.controllers.ocp import NXA, OCPSolver, OCPSpec, rk4_substeps_needed
from models.actuators import Servo, ServoOptions
from models.errors import ConfigError, SolverFailure
from models.checks import finite_number as _num
from models.params import Rig3Params
from models.rigs import get_model

__all__ = ["NMPCOptions", "NMPCWeights", "NMPCController", "make_nmpc"]

_SOLVERS = ("rti", "sqp", "ipopt")
# The OCP, its build and each QP grow with the horizon.  N = 500 plans 25 s ahead at dt = 0.05 s
# (a stick-slip cycle is about 2 s) and builds in about 3 s (N = 20: 0.2 s; without compile);
# N = 100000 would take about 9 minutes to build before the first sample.
MAX_HORIZON = 500
_QP = ("hpipm", "qrqp", "osqp")


@dataclass(frozen=True, kw_only=True)
class NMPCWeights:
    """Dimensionless weights of the NMPC cost (residuals scaled by the nominal speed and n2_max).

    speed : omega1 - omega_nominal (stick-slip of R1 and mean speed)
    rel : omega1 - omega2 and omega2 - omega3 (relative speeds across the shaft)
    ref : omega_ref - omega_nominal (stay near the programme's set-point)
    n2 : quadratic pin force; n2_linear : linear pin force (friction work / wear at pin 2)
    d_ref : set-point change per OCP interval; d_n2 : servo activity, (N2 command - servo force)
        = tau x the servo's rate; terminal : factor on the terminal speeds
    """

    speed: float = 1.0
    rel: float = 0.3
    ref: float = 0.2
    n2: float = 0.2
    n2_linear: float = 0.01
    d_ref: float = 0.3
    d_n2: float = 0.3
    terminal: float = 3.0
    where: str = "nmpc.weights"

    def __post_init__(self):
        for f in fields(self):
            if f.name != "where":
                _num(getattr(self, f.name), f"{self.where}.{f.name}", nonneg=True)
        if self.d_ref <= 0 or self.d_n2 <= 0:
            raise ConfigError(f"{self.where}.d_ref and d_n2 must be > 0 (they make the QP positive definite), "
                              f"got {self.d_ref}, {self.d_n2}")


@dataclass(frozen=True, kw_only=True)
class NMPCOptions:
    """NMPC options (scenario ``[[controllers]]`` keys with ``kind = "nmpc"``).

    horizon : OCP intervals N; dt : OCP interval [s] (>= the DAQ period)
    substeps : RK4 substeps per interval (0: the smallest stable number, |h lambda| <= 2.5)
    eps : friction regularisation [rad/s]
    weights : NMPCWeights (or a table of them)
    n2_max : pin-force upper bound [N] (None: servo.n_max); n2_rate : the servo's rate limit [N/s]
        (None: servo.rate_max), imposed as ``|N2 command - servo force| <= n2_rate tau``
    omega_band : omega_ref stays within omega_nominal +- omega_band [rad/s] (and >= 0)
    omega_rate : rate limit of omega_ref [rad/s^2]
    solver : "rti" (one Gauss-Newton QP per plan), "sqp" (Gauss-Newton to convergence), "ipopt" (reference)
    compile : compile the stage function with gcc (cached on disk) for rti/sqp
    qp_solver : "hpipm", "qrqp" or "osqp"; qp_tol : QP tolerance (see :class:`OCPSolver`)
    model_servo : predict the servo's first-order lag (tau from ServoOptions)
    prepare_ahead : RTI preparation/feedback split (rti/sqp): linearise at the shifted plan in the
        first call after a plan (a held sample), so a planning call only solves the QP
    use_load_estimate : scale the measured N1 by the estimator's ``load1`` state (the EKF/MHE
        random-walk factor on R1's friction load) when the estimate has one: a disturbance
        model that absorbs friction mismatch and "formation" drift
    """

    horizon: int = 20
    dt: float = 0.05
    substeps: int = 0
    eps: float = 0.05
    weights: NMPCWeights = NMPCWeights()
    n2_max: float | None = None
    n2_rate: float | None = None
    omega_band: float = 3.0
    omega_rate: float = 20.0
    solver: str = "rti"
    compile: bool = True
    qp_solver: str = "hpipm"
    qp_tol: float = 1e-5
    sqp_max_iter: int = 20
    model_servo: bool = True
    prepare_ahead: bool = True
    use_load_estimate: bool = True
    where: str = "nmpc"

    def __post_init__(self):
        w = self.where
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, int) or self.horizon < 2:
            raise ConfigError(f"{w}.horizon must be an integer >= 2, got {self.horizon!r}")
        if self.horizon > MAX_HORIZON:
            raise ConfigError(f"{w}.horizon must be <= {MAX_HORIZON} (OCP intervals; the OCP and each QP grow "
                              f"with it), got {self.horizon}")
        _num(self.dt, f"{w}.dt [s]", positive=True)
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 0:
            raise ConfigError(f"{w}.substeps must be an integer >= 0 (0 = automatic), got {self.substeps!r}")
        _num(self.eps, f"{w}.eps [rad/s]", positive=True)
        if not isinstance(self.weights, NMPCWeights):
            raise ConfigError(f"{w}.weights must be a table of weights, got {type(self.weights).__name__}")
        if self.n2_max is not None:
            _num(self.n2_max, f"{w}.n2_max [N]", positive=True)
        if self.n2_rate is not None:
            _num(self.n2_rate, f"{w}.n2_rate [N/s]", positive=True)
        _num(self.omega_band, f"{w}.omega_band [rad/s]", nonneg=True)
        _num(self.omega_rate, f"{w}.omega_rate [rad/s^2]", positive=True)
        if self.solver not in _SOLVERS:
            raise ConfigError(f"{w}.solver must be one of {', '.join(_SOLVERS)}, got {self.solver!r}")
        if not isinstance(self.compile, bool):
            raise ConfigError(f"{w}.compile must be true or false, got {self.compile!r}")
        if self.qp_solver not in _QP:
            raise ConfigError(f"{w}.qp_solver must be one of {', '.join(_QP)}, got {self.qp_solver!r}")
        _num(self.qp_tol, f"{w}.qp_tol", positive=True)
        if isinstance(self.sqp_max_iter, bool) or not isinstance(self.sqp_max_iter, int) or self.sqp_max_iter < 1:
            raise ConfigError(f"{w}.sqp_max_iter must be an integer >= 1, got {self.sqp_max_iter!r}")
        for name in ("model_servo", "prepare_ahead", "use_load_estimate"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{w}.{name} must be true or false, got {getattr(self, name)!r}")

    @classmethod
    def from_mapping(cls, options: Mapping, where: str = "nmpc") -> "NMPCOptions":
        """Validate raw scenario options (unknown keys are errors)."""
        if not isinstance(options, Mapping):
            raise ConfigError(f"{where} must be a table, got {type(options).__name__}")
        known = {f.name for f in fields(cls)} - {"where"}
        opts = dict(options)
        unknown = sorted(set(opts) - known)
        if unknown:
            raise ConfigError(f"{where}: unknown NMPC option(s) {unknown}; expected some of {sorted(known)}")
        if "weights" in opts:
            wt = opts["weights"]
            if not isinstance(wt, Mapping):
                raise ConfigError(f"{where}.weights must be a table, got {type(wt).__name__}")
            wknown = {f.name for f in fields(NMPCWeights)} - {"where"}
            bad = sorted(set(wt) - wknown)
            if bad:
                raise ConfigError(f"{where}.weights: unknown weight(s) {bad}; expected some of {sorted(wknown)}")
            opts["weights"] = NMPCWeights(**dict(wt), where=f"{where}.weights")
        return cls(**opts, where=where)


class NMPCController(Controller):
    """NMPC acting on N2 and omega_ref (see module docstring).

    Parameters
    ----------
    options : NMPCOptions
    params : Rig3Params the controller believes (nominal model)
    dt_daq : DAQ period [s]
    omega_nominal : nominal speed [rad/s]
    servo : ServoOptions of the R2 pin servo
    """

    name = "nmpc"

    def __init__(self, options: NMPCOptions, params: Rig3Params, dt_daq: float, omega_nominal: float,
                 servo: ServoOptions = ServoOptions()):
        super().__init__(omega_nominal)
        self.options = o = options
        self.params = params
        self.dt_daq = float(dt_daq)
        self.servo_options = servo
        self.model = get_model("rig3")
        if o.dt < self.dt_daq - 1e-12:
            raise ConfigError(f"{o.where}.dt must be >= the DAQ period {self.dt_daq} s, got {o.dt}")
        self.n2_max = float(servo.n_max if o.n2_max is None else min(o.n2_max, servo.n_max))
        self.n2_min = float(servo.n_min)
        self.n2_rate = float(servo.rate_max if o.n2_rate is None else o.n2_rate)
        tau = servo.tau if o.model_servo else 0.0
        nsub = o.substeps or rk4_substeps_needed(self.model, params, o.dt, o.eps, 40.0, self.n2_max,
                                                 max(abs(omega_nominal) + o.omega_band, 1.0))
        self.nsub = nsub
        self.spec = OCPSpec(horizon=o.horizon, dt=o.dt, nsub=nsub, eps=o.eps, tau_servo=float(tau),
                            n2_max=self.n2_max, omega_scale=max(abs(omega_nominal), 1.0),
                            w_speed=o.weights.speed, w_rel=o.weights.rel, w_ref=o.weights.ref, w_n2=o.weights.n2,
                            c_n2=o.weights.n2_linear, w_dref=o.weights.d_ref, w_dn2=o.weights.d_n2,
                            w_terminal=o.weights.terminal)
        self.ocp = OCPSolver(self.model, self.spec, solver=o.solver, compile=o.compile, qp_solver=o.qp_solver,
                             qp_tol=o.qp_tol, sqp_max_iter=o.sqp_max_iter)
        self._p = np.asarray(params.vector(), float)
        #: test hook: a callable(t) -> bool; True makes the next solve fail (fallback tests)
        self.inject_failure = None
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        self.ocp.shift(0)           # drops prepared QP data
        self.ocp.w = None
        self.ocp.lam_g = None
        self._servo = None
        self._t_call = None         # time of the last call
        self._t_plan = None         # time of the last successful plan
        self._plan_u = None         # (N, 2) inputs of that plan
        self._t_solve = None        # time of the last solve attempt
        self._action = None         # action held between plans
        self._u_prev = None         # last command [omega_ref, n2]
        self.last_result = None
        self.solve_times: list[float] = []
        self._q_prep = None         # parameters for the pending preparation phase

    def _bounds(self):
        o = self.options
        lo = np.array([max(0.0, self.omega_nominal - o.omega_band), self.n2_min])
        hi = np.array([self.omega_nominal + o.omega_band, self.n2_max])
        return lo, hi

    def _advance_servo(self, t, measurement):
        if self._servo is None:
            n2m = measurement.get("n2", 0.0) if hasattr(measurement, "get") else 0.0
            n2m = float(n2m) if n2m is not None and np.isfinite(n2m) else 0.0
            self._servo = Servo(self.servo_options, self.dt_daq, n0=n2m)
        elif self._t_call is not None:
            k = int(round((t - self._t_call) / self.dt_daq))
            for _ in range(max(0, k)):
                self._servo.step(self._u_prev[1])
        return self._servo.force

    # ------------------------------------------------------------------ step
    def _step_impl(self, t: float, estimate, measurement: Mapping[str, float]) -> Action:
        o = self.options
        n2a = self._advance_servo(t, measurement)
        self._t_call = t
        if self._u_prev is None:
            wr = measurement.get("omega_ref", self.omega_nominal) if hasattr(measurement, "get") else self.omega_nominal
            wr = float(wr) if wr is not None and np.isfinite(wr) else self.omega_nominal
            self._u_prev = np.array([wr, n2a])
        due = self._t_solve is None or t - self._t_solve >= o.dt - 0.5 * self.dt_daq
        if not due and self._action is not None:
            if self._q_prep is not None:
                q_prep, self._q_prep = self._q_prep, None
                try:
                    self.ocp.prepare(q_prep)
                except Exception:  # noqa: BLE001 - the next plan linearises itself
                    self.ocp.shift(0)
            a = self._action  # between plans: zero-order hold (fallbacks are counted once, when made)
            return Action(a.n2, a.omega_ref, f"hold: {a.status}", a.success, "")
        steps = 1 if self._t_solve is None else max(1, int(round((t - self._t_solve) / o.dt)))
        self._t_solve = t
        try:
            if self.inject_failure is not None and self.inject_failure(t):
                raise SolverFailure("injected failure")
            if estimate is None or getattr(estimate, "x", None) is None:
                raise SolverFailure("no state estimate")
            x = np.asarray(estimate.x, float).ravel()[:7]
            n1 = float(measurement["n1"])
            names = getattr(estimate, "names", ())
            if o.use_load_estimate and "load1" in names:
                n1 *= float(np.clip(estimate.x[names.index("load1")], 0.2, 5.0))
            if x.shape != (7,) or not (np.all(np.isfinite(x)) and np.isfinite(n1)):
                raise SolverFailure("non-finite estimate or n1")
            # servo force (or, without a servo model, the previous command) and the previous set-point
            n2s = n2a if o.model_servo else self._u_prev[1]
            xa0 = np.concatenate([x, [n2s, self._u_prev[0]]])
            q = self.spec.q(max(n1, 0.0), self.omega_nominal, self._p)
            if self.ocp.w is not None and not (self.ocp.prepared and steps == 1):
                # prepare() already shifted by one interval
                self.ocp.shift(steps - 1 if self.ocp.prepared else steps)
            lo, hi = self._bounds()
            rate = np.array([o.omega_rate, self.n2_rate])
            res = self.ocp.solve(xa0, q, lo, hi, rate)
        except Exception as exc:  # noqa: BLE001 - any solver failure goes to the fallback chain
            self.counts.failures += 1
            self.ocp.w = None  # do not warm-start from a failed iterate
            return self._hold(self._shift_or_baseline(t, f"{type(exc).__name__}: {exc}"))
        self.last_result = res
        self.solve_times.append(res.solve_time)
        self._plan_u, self._t_plan = res.u, t
        if o.prepare_ahead and o.solver != "ipopt":
            self._q_prep = q
        # remove QP-tolerance excursions only; the ranges may have been widened for reachability
        # (nominal speed jumped by more than a rate-limited move), so clip to the widened ones
        u0 = np.clip(res.u[0], *self.ocp.input_range(xa0, lo, hi, rate))
        return self._hold(Action(float(u0[1]), float(u0[0]), res.status, True, ""))

    def _shift_or_baseline(self, t, why) -> Action:
        if self._plan_u is not None:
            j = int(round((t - self._t_plan) / self.options.dt))
            if 0 <= j < len(self._plan_u):
                u = self._plan_u[j]
                lo, hi = self._bounds()
                u = np.clip(u, lo, hi)
                return Action(float(u[1]), float(u[0]), f"solver failed ({why}); shifted plan [{j}]", False, "shift")
            self._plan_u = None
        return Action(0.0, self.omega_nominal, f"solver failed ({why}); no plan left: baseline (a)", False,
                      "baseline")

    def _hold(self, a: Action) -> Action:
        self._action = a
        self._u_prev = np.array([a.omega_ref, a.n2])
        return a


def make_nmpc(options: Mapping, model_params: Rig3Params, dt: float, omega_nominal: float,
              servo: ServoOptions, where: str = "nmpc") -> NMPCController:
    """Validate raw scenario options and build the NMPC controller.

    Parameters
    ----------
    options : raw ``[[controllers]]`` options (without name/kind)
    model_params : the nominal rig3 parameters the controller uses
    dt : DAQ period [s]
    omega_nominal : nominal speed [rad/s]
    servo : ServoOptions of the R2 pin servo
    where : prefix of error messages, e.g. ``"scenario.toml: controllers[2]"``

    Raises
    ------
    ConfigError : one line naming ``<where>.<field>``
    """
    if not isinstance(model_params, Rig3Params):
        raise ConfigError(f"{where}: the NMPC needs Rig3Params, got {type(model_params).__name__}")
    opts = NMPCOptions.from_mapping(options, where)
    return NMPCController(opts, model_params, dt, omega_nominal, servo)
