"""The NMPC controller: plans with the OCP of :mod:`mitigate.controllers.nmpc.ocp` on any rig.

One call (:meth:`NMPC._step_impl`) reads as its phases::

    estimate   the plan's start: servo forces, held inputs, the rig's state, friction factors (:mod:`.start`)
    supervise  the speed window, the calm schedule's weight factor, the speed trim (:mod:`.supervision`)
    solve      one RTI step (or SQP / IPOPT) of the OCP from that start (:mod:`.ocp`, :mod:`.rti`)
    guard      the first move clipped to its reachable range; the stall guard; the fallback chain

What is optimised: the objective body's speed error and the springs' relative speeds over the
horizon (half a stick-slip period by default), against staying near the programme and moving
gently, within the set-point's band and rate and the servos' ranges and rates (:mod:`.stage`).

**Timing.**  The NMPC re-plans when at least ``dt`` (the OCP interval) has passed since its last
plan, so with the loop calling every DAQ sample it solves every few calls and holds the first
planned input in between (``Status.HOLD``; a zero-order hold over one OCP interval, which is
what the rate limits assume).  With ``prepare_ahead`` the first held call after a plan shifts the
plan and linearises it (RTI preparation), so a planning call only embeds the new state and solves
one QP (feedback).  If the loop calls less often than ``dt`` it re-plans at every call and shifts
the warm start by the elapsed intervals.  The supervision's window is fed at every call and sized
with the call period (``ControlContext.period``: the DAQ period times ``[control] every``).

**Failures.**  A failed or bound-violating solve: the previous plan shifted to now
(``Status.FALLBACK``); no plan left: an empty action, i.e. the programme (``Status.FALLBACK``).
The stall guard replaces a stalling plan by the programme (``Status.FALLBACK``).  Every failure is
counted in ``counts.failures``.  A failure is a :class:`SolverFailure` (the OCP solver's
numerical errors are turned into one, :func:`.ocp.solver_failures`); any other exception is a bug
and fails the run.
"""

from __future__ import annotations

import math
import time
from typing import Mapping

import numpy as np

from mitigate.controllers.base import Action, ControlContext, Controller
from mitigate.controllers.nmpc.band import window_bounds
from mitigate.controllers.nmpc.defaults import resolve as resolve_defaults
from mitigate.controllers.nmpc.layout import OCPSpec
from mitigate.controllers.nmpc.compiled import FAILURES, CompiledStep
from mitigate.controllers.nmpc.ocp import OCPResult, solver_failures
from mitigate.controllers.nmpc.options import MAX_SUBSTEPS, WEIGHT_NAMES, NMPCOptions
from mitigate.controllers.nmpc.solvers import make_ocp_solver
from mitigate.controllers.nmpc.start import PlanStart
from mitigate.controllers.nmpc.supervision import Decision, Supervisor
from mitigate.metrics.quantities import FORCE_BAND
from mitigate.tunables import Tunable
from models.discretise import integration
from models.errors import ConfigError, PluginError, SolverFailure
from models.plugins import describe
from models.status import Status

__all__ = ["NMPC", "resolve_inputs"]


def resolve_inputs(inputs, model, where: str) -> tuple[str, ...]:
    """The inputs an ``inputs`` option asks for, the drive's first (one-line ConfigError naming
    ``<where>.inputs`` if the rig cannot set one)."""
    drive, servos = model.drive_input, model.servo_inputs
    if inputs == "both":
        return (drive,) + servos
    if inputs == "motor":
        return (drive,)
    if inputs == "pin":
        if not servos:
            raise ConfigError(f"{where}.inputs = 'pin' needs a servo input, and rig {model.name!r} has none "
                              f"(it can set: {', '.join(model.commands)})")
        return servos
    bad = [n for n in inputs if n not in model.commands]
    if bad:
        raise ConfigError(f"{where}.inputs: rig {model.name!r} cannot set {', '.join(map(repr, bad))} "
                          f"(it can set: {', '.join(model.commands)})")
    return tuple(n for n in model.commands if n in inputs)


class NMPC(Controller):
    """Nonlinear MPC of any rig (module docstring).

    Parameters
    ----------
    options : NMPCOptions (or a raw options table, validated with ``context.where``)
    context : ControlContext: the rig the NMPC believes, its nominal parameters, the DAQ period,
        the call period, the programme

    Attributes
    ----------
    inputs : the inputs it sets (the drive's first); body : the objective body
    cfg : the unit-carrying settings (:class:`mitigate.controllers.nmpc.defaults.Resolved`: given
        options, or the rig's defaults); stick_slip_period : the rig's stick-slip period [s]
    spec : the OCPSpec; ocp : its solver (an OCPSolver); nsub : RK4 substeps per interval
    start : the plan's start (:class:`.start.PlanStart`); supervisor : :class:`.supervision.Supervisor`
    last_result : the last OCPResult; last_decision : the supervision's last :class:`.supervision.Decision`;
    last_q : the OCP parameters of the last plan; inject_failure : test hook, ``callable(t) -> bool``
        (True makes the next solve fail)
    """

    kind = "nmpc"
    options_class = NMPCOptions
    #: a plan on the model needs the string's state: a rig read only at its speed drive gives the
    #: estimator nothing of it (the rig zoo: a 1-body lead screw, PI 1.00, the blind NMPC 3.84)
    needs = ("string_sensor",)
    #: the cost weights (dimensionless), a decade or so around the defaults (``mitigate tune``)
    tunables = {
        "weights.speed": Tunable(low=0.1, high=10.0), "weights.rel": Tunable(low=0.03, high=3.0),
        "weights.ref": Tunable(low=0.02, high=2.0, needs="drive"),
        "weights.d_ref": Tunable(low=0.03, high=3.0, needs="drive"),
        "weights.force": Tunable(low=0.02, high=2.0, needs="force"),
        "weights.force_linear": Tunable(low=0.001, high=0.1, needs="force"),
        "weights.d_force": Tunable(low=0.03, high=3.0, needs="force"),
        "weights.terminal": Tunable(low=0.3, high=30.0),
    }

    def __init__(self, options: NMPCOptions, context: ControlContext):
        if isinstance(options, Mapping):
            options = NMPCOptions.from_mapping(options, context.where)
        if not isinstance(options, NMPCOptions):
            raise ConfigError(f"{context.where}: NMPC options must be NMPCOptions or a table, got "
                              f"{type(options).__name__}")
        super().__init__(options, context)
        o, m, where = options, context.model, options.where
        self.model = m
        self.params = m.check_params(context.params, f"{where}: params")
        self.dt_daq = float(context.dt)
        self.call_period = float(context.period)
        self.inputs = resolve_inputs(o.inputs, m, where)
        self.body = o.body or m.objective_body
        if self.body not in m.bodies:
            raise ConfigError(f"{where}.body must be a body of rig {m.name!r} ({', '.join(m.bodies)}), "
                              f"got {self.body!r}")
        drive = m.drive_input
        self.drives = drive in self.inputs
        self.servos = tuple(n for n in self.inputs if n != drive)
        self._torque_drive = not m.drive.sets_speed
        if o.speed is None and self._torque_drive:
            # the scenario's [control] speed (ControlContext.target_speed, as SoftSpeed and Z-Torque);
            # without one the rig's operating_point.speed
            op = m.spec.extra.get("operating_point", {})
            if context.speed is None and "speed" not in op:
                raise ConfigError(f"{where}.speed: rig {m.name!r} has a torque drive and no operating_point.speed; "
                                  f"give the nominal speed of {self.body!r} [rad/s] (or the scenario's control.speed)")
            self._speed0 = None
        else:
            self._speed0 = None if o.speed is None else float(o.speed)
        acts = [m.actuator(n) for n in self.servos]
        self._n_min = np.array([a.n_min for a in acts], float)
        # structure of the OCP; the unit-carrying settings from the options or the rig
        u0 = np.asarray(context.programme(0.0), float)
        nom0 = self._nominal(0.0, u0)
        self.cfg = cfg = resolve_defaults(o, m, self.params, self.dt_daq, nom0, float(u0[m.inputs.index(drive)]), where,
                                          u=u0)
        w_s = abs(nom0) if nom0 != 0 else 1.0
        taus = tuple(float(a.tau) if o.model_servo else 0.0 for a in acts)
        self.weights = weights = o.weights
        #: how the prediction integrates the rig over an interval (:func:`models.discretise.integration`)
        self.integration = self._integration(u0, nom0, taus)
        self.nsub = self.integration.nsub
        if self.nsub > MAX_SUBSTEPS:
            how = "implicit (SDIRK2)" if self.integration.implicit else "RK4"
            raise ConfigError(f"{where}.substeps: rig {m.name!r} needs {self.nsub} {how} substeps per {cfg.dt} s "
                              f"interval to be stable (stiff friction or springs); the limit is {MAX_SUBSTEPS}: shorten "
                              f"dt, or widen eps where the friction law uses it")
        self.spec = OCPSpec(horizon=o.horizon, dt=cfg.dt, nsub=self.nsub, eps=cfg.eps, body=self.body,
                            quasi_static=self.integration.quasi_static, method=self.integration.method,
                            inputs=self.inputs, taus=taus, speed_scale=w_s,
                            setpoint_scale=(cfg.setpoint_band if self._torque_drive else w_s) or 1.0,
                            force_scales=tuple(float(a.n_max) for a in acts), weights=weights.as_tuple())
        use_c = o.implementation == "c" and o.compile and o.solver in ("rti", "sqp") and o.qp_solver == "hpipm"
        if o.qp_condensing != "none" and not use_c:
            raise ConfigError(f"{where}.qp_condensing: \"{o.qp_condensing}\" needs the compiled C step "
                              f"(implementation \"c\", compile true, solver rti or sqp, qp_solver hpipm); got "
                              f"implementation {o.implementation!r}, compile {str(o.compile).lower()}, solver {o.solver!r}, "
                              f"qp_solver {o.qp_solver!r}")
        if (o.qp_mode != "speed_abs" or o.qp_mu0 is not None) and (o.qp_solver != "hpipm" or o.solver == "ipopt"):
            what = "qp_mode" if o.qp_mode != "speed_abs" else "qp_mu0"
            raise ConfigError(f"{where}.{what}: hpipm's setting needs qp_solver \"hpipm\" and solver rti or sqp; got "
                              f"qp_solver {o.qp_solver!r}, solver {o.solver!r}")
        # the compiled step has the stages in its own library: the Python solver's own build is not needed then
        self.ocp = make_ocp_solver(m, self.spec, solver=o.solver, compile=o.compile and not use_c, qp_solver=o.qp_solver,
                                   qp_tol=o.qp_tol, sqp_max_iter=o.sqp_max_iter, qp_mode=o.qp_mode, qp_mu0=o.qp_mu0)
        L = self.ocp.layout
        self.layout = L
        self._q = L.q_template(self.spec, self.params.vector())
        self._rate = np.array(([cfg.setpoint_rate] if self.drives else []) + [a.rate_max for a in acts], float)
        self._lo = np.array(([0.0] if self.drives else []) + [a.n_min for a in acts], float)
        self._hi = np.array(([0.0] if self.drives else []) + [a.n_max for a in acts], float)
        #: the programme's band of a commanded servo force, ratios (``NMPCOptions.force_band``)
        self.force_band = tuple(float(v) for v in (o.force_band if o.force_band is not None else FORCE_BAND))
        self.stick_slip_period = cfg.period
        #: the moving window of the force band [s] and its DAQ samples (0: every command in the band)
        self.force_window = float(o.force_window)
        self.force_window_n = max(1, int(round(self.force_window / self.dt_daq))) if self.force_window > 0 else 0
        #: the servos' arithmetic (:func:`.band.window_bounds`) and the samples it looks ahead: one OCP
        #: interval, the servo's time across its range and three lags
        self._servo_steps = [(float(a.n_min), float(a.n_max), 1.0 - math.exp(-self.dt_daq / a.tau) if a.tau > 0 else 1.0,
                              float(a.rate_max) * self.dt_daq) for a in acts]
        self._look_n = [max(1, int(round(cfg.dt / self.dt_daq)))
                        + (int(math.ceil((a.n_max - a.n_min) / (a.rate_max * self.dt_daq))) if math.isfinite(a.rate_max)
                           and a.rate_max > 0 else 0)
                        + int(math.ceil(3.0 * a.tau / self.dt_daq)) for a in acts]
        self.start = PlanStart(m, self.params, self.inputs, self.dt_daq, cfg.force_filter, o.use_load_estimate,
                               self.force_window_n if self.servos else 0)
        # the trim moves the speed the drive's set-point aims at: without the drive, nothing to trim
        self.supervisor = Supervisor(cfg.period, self.call_period, o.calm_band, cfg.hold_gain,
                                     cfg.speed_trim if self.drives else 0.0, self.drives)
        #: where the weights the schedule scales sit in the OCP's parameter vector q
        self.q_index = {k: L.q_w + WEIGHT_NAMES.index(k) for k in ("ref", "force", "d_ref")}
        self._i_speed = m.speed_index(self.body)
        self.inject_failure = None
        #: the compiled step (csrc/ss_nmpc.c) for RTI/SQP with hpipm, compiled; None: the Python reference
        self.compiled = CompiledStep(self) if use_c else None
        self.reset()

    # ------------------------------------------------------------------ set-up helpers
    def _integration(self, u0, nom0: float, taus):
        """The integration rule at the largest inputs the plan may use (``substeps`` fixes the count)."""
        m, cfg = self.model, self.cfg
        umax = np.abs(u0).astype(float)
        for j, n in enumerate(m.inputs):
            a = m.actuator(n)
            if n == m.drive_input:
                umax[j] = abs(u0[j]) + cfg.setpoint_band
            elif a is not None:
                umax[j] = a.n_max
            elif m.input_kinds[j] == "force":
                umax[j] = 2.0 * abs(u0[j])  # a held normal force may double (load factor, ramps)
        speed = abs(nom0) + (0.0 if self._torque_drive else cfg.setpoint_band)
        # beyond MAX_SUBSTEPS RK4 substeps the rule takes the implicit step (its stages' Jacobians by the
        # implicit function theorem keep the stage's code small); substeps asked in the options stay RK4
        return integration(m, self.params, cfg.dt, u=umax, eps=cfg.eps, speed=speed if speed > 0 else 1.0,
                           nsub=self.options.substeps or None, rates=[1.0 / t for t in taus if t > 0],
                           max_nsub=MAX_SUBSTEPS)

    def tuning_values(self) -> dict[str, float]:
        """The settings the NMPC runs with (given, or derived from the rig: :mod:`.defaults`), for
        the report: dt [s], horizon [-], eps [rad/s], setpoint_band and setpoint_rate [rad/s, rad/s^2
        or N m, N m/s], force_filter [s], hold_gain [-], speed_trim [s]; force_window [s] when set."""
        c = self.cfg
        out = {"dt": c.dt, "horizon": float(self.spec.horizon), "eps": c.eps,
               "setpoint_band": c.setpoint_band, "setpoint_rate": c.setpoint_rate,
               "force_filter": c.force_filter, "hold_gain": c.hold_gain, "speed_trim": c.speed_trim}
        if self.force_window_n:          # the force band on a moving mean (not the default): say so
            out["force_window"] = self.force_window
        return out

    @property
    def derived_units(self) -> dict[str, str]:
        """The unit of each :meth:`tuning_values` entry (a torque drive's set-point is a torque)."""
        sp, rate = self.model.drive.unit, self.model.drive.rate_unit
        out = {"dt": "s", "horizon": "-", "eps": "rad/s", "setpoint_band": sp, "setpoint_rate": rate,
               "force_filter": "s", "hold_gain": "-", "speed_trim": "s"}
        if self.force_window_n:
            out["force_window"] = "s"
        return out

    def _nominal(self, t: float, u_prog) -> float:
        """Nominal speed of the objective body [rad/s]."""
        if self._speed0 is not None:
            return self._speed0
        if self._torque_drive:
            return self.context.target_speed(t)
        return float(u_prog[self.model.inputs.index(self.model.drive_input)])

    def actuated_inputs(self) -> tuple[str, ...]:
        return tuple(self.inputs)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        if getattr(self, "compiled", None) is not None:
            self.compiled.reset()
            self._message = ""
            self._plan_info = None
        self.ocp.reset()
        self.start.reset()
        self.supervisor.reset()
        self._t_call = None       # time of the last call
        self._t_plan = None       # time of the last successful plan
        self._plan_u = None       # (N, m) commanded inputs of that plan
        self._t_solve = None      # time of the last solve attempt
        self._action = None       # action held between plans
        self._u_prev = None       # last commands (self.inputs order)
        self._prep_q = None       # parameters for the pending preparation phase
        self.last_result = None
        self.last_decision = None
        self._last_q = None

    @property
    def last_q(self) -> np.ndarray | None:
        """The OCP parameters of the last plan attempt (held inputs, target, friction factors,
        weights after the schedule, rig parameters: :meth:`.layout.OCPLayout.set_q`)."""
        return self.compiled.last_q() if self.compiled is not None else self._last_q

    def _bounds(self, u_prog):
        """Bounds of the commanded inputs: the set-point within the programme's band (a speed
        set-point does not reverse the rotation; a torque drive within its limit), the servos'
        ranges, each servo with a positive programme within ``force_band`` of it: its mean over every
        ``force_window`` (:func:`.band.window_bounds`), or each command (no window)."""
        lo, hi = self._lo.copy(), self._hi.copy()
        b_lo, b_hi = self.force_band
        hist = self.start.history
        for i, (j, k) in enumerate(zip(self.layout.j_cmd, self.layout.u_servo)):
            p = float(u_prog[k])
            if not p > 0:
                continue
            if hist is not None and hist.filled:
                f, pp = hist.newest_first(i)
                lo[j], hi[j] = window_bounds(f, pp, float(f[0]), p, self._servo_steps[i], self._look_n[i],
                                             self.force_band, float(lo[j]), float(hi[j]))
                continue
            a, b = max(lo[j], b_lo * p), min(hi[j], b_hi * p)
            if a > b:               # the band lies outside the servo's range: the range's nearest force
                a = b = min(max(p, lo[j]), hi[j])
            lo[j], hi[j] = a, b
        if self.drives:
            c = float(u_prog[self.layout.u_drive])
            band = self.cfg.setpoint_band
            lo[0], hi[0] = c - band, c + band
            if not self.model.drive.reverses:   # a speed set-point does not reverse the rotation
                if c >= 0:
                    lo[0] = max(lo[0], 0.0)
                else:
                    hi[0] = min(hi[0], 0.0)
            else:                        # [drive] torque_max; inf: none
                tmax = self.context.torque_max
                lo[0], hi[0] = max(lo[0], -tmax), min(hi[0], tmax)
        return lo, hi

    # ------------------------------------------------------------------ step
    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        if self.compiled is not None:
            return self._step_compiled(t, measurement, estimate)
        u_prog = self.context.programme(t)
        nominal = self._nominal(t, u_prog)
        forces, hold = self._estimate(t, measurement, u_prog)                  # estimate
        xe = getattr(estimate, "x", None)
        if xe is not None and len(xe) > self._i_speed:
            self.supervisor.observe(t, float(xe[self._i_speed]), nominal)      # supervise
        if not self._due(t):
            return self._between_plans()
        steps = 1 if self._t_solve is None else max(1, int(round((t - self._t_solve) / self.cfg.dt)))
        self._t_solve = t
        try:
            decision = self.last_decision = self.supervisor.decide(nominal)
            res, q = self._solve(estimate, forces, hold, decision, u_prog, steps)  # solve
        except SolverFailure as exc:   # the fallback chain; anything else is a bug and fails the run
            self.counts.failures += 1
            self.ocp.reset()   # never warm-start from a failed iterate
            return self._hold(self._shift_or_programme(t, u_prog, f"{type(exc).__name__}: {exc}"))
        return self._hold(self._guard(t, res, q, u_prog))                       # guard

    def _estimate(self, t: float, measurement, u_prog):
        """The plan's start from the measurements: the servo forces now and the held inputs."""
        first = self._u_prev is None
        if first:   # the set-point starts where the programme has held it until now
            self._u_prev = self.start.first_commands(measurement, u_prog)
        elapsed = self.dt_daq if self._t_call is None else max(t - self._t_call, 0.0)
        steps = 0 if self._t_call is None else int(round((t - self._t_call) / self.dt_daq))
        forces = self.start.servo_forces(steps, measurement, u_prog, self._u_prev)
        hold = self.start.held_inputs(elapsed, measurement, u_prog)
        self._t_call = t
        return forces, hold

    def _due(self, t: float) -> bool:
        """A plan is due when an OCP interval has passed since the last (or nothing is held)."""
        return (self._t_solve is None or self._action is None
                or t - self._t_solve >= self.cfg.dt - 0.5 * self.dt_daq)

    def _between_plans(self) -> Action:
        """Hold the last action; the first held call after a plan runs the RTI preparation."""
        if self._prep_q is not None:
            q, self._prep_q = self._prep_q, None
            try:
                with solver_failures("preparation"):
                    self.ocp.prepare(q)
            except SolverFailure:   # the next plan starts afresh
                self.ocp.reset()
        a = self._action
        return Action(a.u, Status.HOLD, f"hold: {a.status.value}: {a.message}" if a.message else "hold")

    def _solve(self, estimate, forces, hold, decision: Decision, u_prog, steps: int):
        """One solve of the OCP from the estimate, with the supervision's decision."""
        o, L = self.options, self.layout
        if self.inject_failure is not None and self.inject_failure(self._t_call):
            raise SolverFailure("injected failure")
        x, fc = self.start.state(estimate, decision.nominal)
        if not math.isfinite(hold.sum()):
            raise SolverFailure("non-finite held input")
        xa0 = np.empty(L.nxa)
        xa0[:L.nx] = x
        xa0[L.i_servo] = forces if o.model_servo else self._u_prev[L.j_cmd]
        if self.drives:
            xa0[L.i_wprev] = self._u_prev[0]
        at_min = [float(hold[j] <= lo + 1e-9 * max(abs(lo), 1.0)) for j, lo in zip(L.u_servo, self._n_min)]
        q = L.set_q(self._q.copy(), hold, decision.target, fc, at_min)
        f, i = decision.weight_factor, self.q_index
        q[i["ref"]] *= f
        q[i["d_ref"]] *= f
        q[i["force"]] *= f * f if self.drives else f   # pin only: the servo is all it has
        if self.ocp.X is not None and not (self.ocp.prepared and steps == 1):
            # prepare() already shifted by one interval
            self.ocp.shift(steps - 1 if self.ocp.prepared else steps)
        lo, hi = self._bounds(u_prog)
        self._last_q = q
        res = self.ocp.solve(xa0, q, lo, hi, self._rate)
        self._xa0, self._lohi = xa0, (lo, hi)
        return res, q

    def _guard(self, t: float, res, q, u_prog) -> Action:
        """The plan's first move within its reachable range (QP-tolerance excursions only: the
        ranges may have been widened for reachability); the stall guard."""
        self.last_result = res
        self._plan_u, self._t_plan = res.u, t
        if self.options.prepare_ahead and self.options.solver != "ipopt":
            self._prep_q = q
        xa0, (lo, hi) = self._xa0, self._lohi
        u0 = np.clip(res.u[0], *self.ocp.first_range(xa0, lo, hi, self._rate, self.ocp.last_bounds))
        j = self.model.inputs.index(self.model.drive_input)
        if self.drives and self.supervisor.stalled(t, float(u0[0]), float(u_prog[j])):
            return Action({}, Status.FALLBACK,
                          f"stall guard: {self.body!r} has not slid for a stick-slip period "
                          f"({self.stick_slip_period:.3g} s) and the plan slowed the drive below half its "
                          f"programme: the programme")
        return Action(dict(zip(self.inputs, map(float, u0))), Status.OK, res.message)

    def _shift_or_programme(self, t: float, u_prog, why: str) -> Action:
        if self._plan_u is not None:
            j = int(round((t - self._t_plan) / self.cfg.dt))
            if 0 <= j < len(self._plan_u):
                lo, hi = self._bounds(u_prog)
                u = np.clip(self._plan_u[j], lo, hi)
                return Action(dict(zip(self.inputs, map(float, u))), Status.FALLBACK,
                              f"solver failed ({why}); shifted plan [{j}]")
            self._plan_u = None
        return Action({}, Status.FALLBACK, f"solver failed ({why}); no plan left: the programme")

    def _hold(self, a: Action) -> Action:
        self._action = a
        if a.u:
            self._u_prev = np.array([a.u[n] for n in self.inputs], float)
        else:
            u_prog = self.context.programme(self._t_call)
            self._u_prev = np.array([u_prog[self.model.inputs.index(n)] for n in self.inputs], float)
        return a

    # ------------------------------------------------------------------ the compiled step
    def _guarded_step(self, t: float, measurement, estimate) -> Action:
        """The compiled step without the plug-in wrapper: it is this project's C, which checks its
        plan itself (finite, within its bounds: ``Status.FALLBACK`` otherwise) and which the plug-in
        timer could not interrupt anyway.  The rule's outcome is kept: an error of its Python glue,
        or a call longer than the scenario's ``timeout``, is a PluginError (the run FAILED)."""
        if self.compiled is None:
            return super()._guarded_step(t, measurement, estimate)
        t0 = time.perf_counter()
        try:
            a = self._step_compiled(t, measurement, estimate)
        except (SolverFailure, KeyboardInterrupt, PluginError):   # as models.plugins.call
            raise
        except BaseException as exc:  # noqa: BLE001 - the plug-in rule: anything else fails the run
            raise PluginError(describe(exc)) from exc
        timeout = self.context.timeout
        if timeout is not None:
            took = time.perf_counter() - t0
            if took > timeout:
                raise PluginError(f"TimeoutError: step did not return within {timeout:g} s (it took {took:.3g} s)")
        return a

    def _step_compiled(self, t: float, measurement, estimate) -> Action:
        """The same phases in one compiled call (csrc/ss_nmpc.c); the messages are written here."""
        u_prog = self.context.programme(t)
        target = self.context.target_speed(t) if self._torque_drive and self._speed0 is None else 0.0
        inject = self.inject_failure is not None and bool(self.inject_failure(t))
        info = self.compiled.step(t, measurement, estimate, u_prog, target, inject)
        if info.planned:   # the Decision is made when asked for (last_decision)
            self._decided = (info.weight_factor, info.severity, info.nominal, info.trim, info.target)
        if info.failure:
            self.counts.failures += 1
        status = Status.HOLD if info.status == 1 else Status.FALLBACK if info.status == 2 else Status.OK
        u = dict(zip(self.inputs, self.compiled.u.tolist())) if info.n_u else {}
        if status is Status.HOLD:
            held = Status.FALLBACK if info.held_status == 2 else Status.OK
            return Action(u, Status.HOLD, f"hold: {held.value}: {self._message}" if self._message else "hold")
        if info.failure:
            why = self._failure_text(info, estimate)
            self._message = (f"solver failed (SolverFailure: {why}); shifted plan [{info.shifted_index}]" if info.reason == 2
                             else f"solver failed (SolverFailure: {why}); no plan left: the programme")
        elif info.reason == 1:
            self._message = (f"stall guard: {self.body!r} has not slid for a stick-slip period "
                             f"({self.stick_slip_period:.3g} s) and the plan slowed the drive below half its programme: "
                             f"the programme")
        else:
            self._message = self._solve_text(info)
            self._plan_info = (info.cost, info.iterations, info.qp_iterations, bool(info.converged), info.solve_time)
        return Action(u, status, self._message)

    @property
    def last_decision(self):
        """The supervision's decision for the last plan (:class:`.supervision.Decision`), or None."""
        d = self._decided
        return d if d is None or isinstance(d, Decision) else Decision(*d)

    @last_decision.setter
    def last_decision(self, value) -> None:
        self._decided = value

    @property
    def last_result(self):
        """The last OCPResult (the compiled step's plan; its ``xa`` is not kept there), or None."""
        if self.compiled is None:
            return self._last_result
        if getattr(self, "_plan_info", None) is None:
            return None
        cost, it, qp_it, conv, st = self._plan_info
        return OCPResult(self.compiled.plan(), np.empty((0, self.layout.nxa)), self.spec.inputs, self.layout.states,
                         cost, it, qp_it, Status.OK if conv else Status.NOT_CONVERGED, self._solve_text_of(conv, it), st)

    @last_result.setter
    def last_result(self, value) -> None:
        self._last_result = value

    def _solve_text(self, info) -> str:
        if self.options.solver == "rti":
            return "rti step"
        if info.converged:
            return f"converged in {info.iterations} Gauss-Newton iterations"
        return f"sqp: {self.options.sqp_max_iter} iterations, last step {info.last_step:.2g}"

    def _solve_text_of(self, converged: bool, iterations: int) -> str:
        if self.options.solver == "rti":
            return "rti step"
        return f"converged in {iterations} Gauss-Newton iterations" if converged else \
            f"sqp: {self.options.sqp_max_iter} iterations"

    def _failure_text(self, info, estimate) -> str:
        f, solver = info.failure, self.options.solver
        if f == 4:
            from mitigate.controllers.nmpc.qp import HPIPM_STATUS
            st = info.fail_detail
            what = HPIPM_STATUS[st] if 0 <= st < len(HPIPM_STATUS) else f"status {st}"
            return f"QP (hpipm) failed: {what} after {info.qp_iterations} iterations"
        if f == 5:
            return f"{solver}: non-finite plan"
        if f == 6:
            return f"{solver}: plan violates its bounds by {info.violation:.3g}"
        if f == 7:
            return f"{solver}: RuntimeError: compiled function returned an error"
        if f == 9:
            names = tuple(getattr(estimate, "names", ()) or ())
            return f"the estimate's states {names[:self.model.nx]} are not the rig's {self.model.states}"
        return FAILURES.get(f, f"failure {f}")
