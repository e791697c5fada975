"""The NMPC controller: plans with the OCP of :mod:`mitigate.controllers.nmpc.ocp` on any rig.

**Timing.**  The NMPC re-plans when at least ``dt`` (the OCP interval, default 0.05 s) has passed
since its last plan, so with the loop calling every 10 ms DAQ sample it solves every 5th call
and holds the first planned input in between (``Status.HOLD``; a zero-order hold over one OCP
interval, which is what the rate limits assume).  With ``prepare_ahead`` the first held call
after a plan shifts the plan and linearises it (RTI preparation), so a planning call only
embeds the new state and solves one QP (feedback).  If the loop calls less often than ``dt`` it
re-plans at every call and shifts the warm start by the elapsed intervals.

**Disturbance model.**  With ``use_load_estimate``, an estimate state ``load:<contact>`` (the EKF's
random-walk factor on a contact's friction) scales that contact body's friction in the
prediction: the offset-free part of the design (without it, a wrong estimated twist at steady
sliding left R1 15-19 % slow from rest).  The factor is taken while the contact body slides
(``|w| > SLIDING_FRACTION`` of the nominal speed) and held while it sticks.

**Inputs to the prediction.**  The rig's state is the first ``model.nx`` entries of
``estimate.x`` (whose ``names`` must start with ``model.states``).  A servo's force comes from a
replica of the rig's servo model driven by the controller's own commands, started from the
servo's load-cell reading.  Inputs the NMPC does not set are held over the horizon: the drive at
the programme's value; a normal force at the programme's value plus the low-passed difference
between its load cell's reading (corrected for the cell's gain and offset) and the programme
(time constant ``force_filter``; a missing or non-finite reading leaves the difference as it
was).  The raw reading would pass the cell's noise to the plan: on rig3 its 0.2 N moved the
set-point by 0.056 rad/s (std) at steady sliding with the TRUE state, and the programme's own
steps reach the prediction at once.

**Failures.**  A failed or bound-violating solve: the previous plan shifted to now
(``Status.FALLBACK``); no plan left: an empty action, i.e. the programme (``Status.FALLBACK``).
The stall guard (:meth:`NMPC._stalled`): a plan that holds the drive below half its programme while
the objective body has stuck for a whole stick-slip period is replaced by the programme
(``Status.FALLBACK``, counted as a fallback).
Every failure is counted in ``counts.failures``.  A failure is a :class:`SolverFailure` (the OCP
solver's numerical errors are turned into one, :func:`.ocp.solver_failures`); any other exception
is a bug and fails the run.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from mitigate.controllers.base import Action, ControlContext, Controller
from mitigate.controllers.nmpc.defaults import resolve as resolve_defaults
from mitigate.controllers.nmpc.layout import OCPSpec
from mitigate.controllers.nmpc.ocp import solver_failures
from mitigate.controllers.nmpc.solvers import make_ocp_solver
from mitigate.controllers.nmpc.options import MAX_SUBSTEPS, WEIGHT_NAMES, NMPCOptions
from mitigate.controllers.nmpc.schedule import CalmSchedule
from mitigate.controllers.nmpc.trim import SpeedTrim
from mitigate.tunables import Tunable
from models.discretise import integration
from models.actuators import Servo
from models.errors import ConfigError, SolverFailure
from models.status import Status

__all__ = ["NMPC", "resolve_inputs"]

#: clip of the load factor taken from an estimate (a diverging estimator must not wreck the plan)
LOAD_FACTOR_RANGE = (0.2, 5.0)
#: a contact body slides (its load factor is taken from the estimate) above this fraction of the
#: objective body's nominal speed
SLIDING_FRACTION = 0.5


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
        the programme

    Attributes
    ----------
    inputs : the inputs it sets (the drive's first); body : the objective body
    cfg : the unit-carrying settings (:class:`mitigate.controllers.nmpc.defaults.Resolved`: given
        options, or the rig's defaults); period : the rig's stick-slip period [s]
    spec : the OCPSpec; ocp : its solver (an OCPSolver); nsub : RK4 substeps per interval
    last_result : the last OCPResult; inject_failure : test hook, ``callable(t) -> bool`` (True
        makes the next solve fail)
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
        self.inputs = resolve_inputs(o.inputs, m, where)
        self.body = o.body or m.objective_body
        if self.body not in m.bodies:
            raise ConfigError(f"{where}.body must be a body of rig {m.name!r} ({', '.join(m.bodies)}), "
                              f"got {self.body!r}")
        drive = m.drive_input
        self.drives = drive in self.inputs
        self.servos = tuple(n for n in self.inputs if n != drive)
        self._torque_drive = m.drive_kind == "torque"
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
        self._acts = acts
        self._held = [j for j, n in enumerate(m.inputs) if n not in self.inputs]
        self._n_min = np.array([a.n_min for a in acts], float)
        self._readers = {j: self._reader(n) for j, n in enumerate(m.inputs) if n != drive}
        # structure of the OCP; the unit-carrying settings from the options or the rig
        u0 = np.asarray(context.programme(0.0), float)
        nom0 = self._nominal(0.0, u0)
        self.cfg = cfg = resolve_defaults(o, m, self.params, self.dt_daq, nom0, float(u0[m.inputs.index(drive)]), where,
                                          u=u0)
        self._tau_force = cfg.force_filter
        w_s = abs(nom0) if nom0 != 0 else 1.0
        taus = tuple(float(a.tau) if o.model_servo else 0.0 for a in acts)
        self.weights = weights = o.weights
        #: how the prediction integrates the rig over an interval (:func:`models.discretise.integration`)
        self.integration = self._integration(u0, nom0, taus)
        self.nsub = self.integration.nsub
        if self.nsub > MAX_SUBSTEPS:
            raise ConfigError(f"{where}.substeps: rig {m.name!r} needs {self.nsub} RK4 substeps per {cfg.dt} s "
                              f"interval to be stable (stiff friction or springs); the limit is {MAX_SUBSTEPS}: shorten "
                              f"dt, or widen eps where the friction law uses it")
        self.spec = OCPSpec(horizon=o.horizon, dt=cfg.dt, nsub=self.nsub, eps=cfg.eps, body=self.body,
                            quasi_static=self.integration.quasi_static, method=self.integration.method,
                            inputs=self.inputs, taus=taus, speed_scale=w_s,
                            setpoint_scale=(cfg.setpoint_band if self._torque_drive else w_s) or 1.0,
                            force_scales=tuple(float(a.n_max) for a in acts), weights=weights.as_tuple())
        self.ocp = make_ocp_solver(m, self.spec, solver=o.solver, compile=o.compile, qp_solver=o.qp_solver,
                             qp_tol=o.qp_tol, sqp_max_iter=o.sqp_max_iter)
        L = self.ocp.layout
        self.layout = L
        self._q = L.q_template(self.spec, self.params.vector())
        self._rate = np.array(([cfg.setpoint_rate] if self.drives else []) + [a.rate_max for a in acts], float)
        self._lo = np.array(([0.0] if self.drives else []) + [a.n_min for a in acts], float)
        self._hi = np.array(([0.0] if self.drives else []) + [a.n_max for a in acts], float)
        self._load_keys = {f"load:{c}": i for i, names in enumerate(m.contact_names) for c in names}
        self.period = cfg.period
        self.schedule = CalmSchedule(self.period, self.dt_daq, o.calm_band, cfg.hold_gain)
        # the trim moves the speed the drive's set-point aims at: without the drive, nothing to trim
        self.trim = SpeedTrim(cfg.speed_trim if self.drives else 0.0, self.period, self.dt_daq, o.calm_band[0])
        self._i_ref, self._i_force, self._i_dref = (L.q_w + WEIGHT_NAMES.index(k) for k in ("ref", "force", "d_ref"))
        self._i_speed = m.speed_index(self.body)
        self._names_seen = None
        self.inject_failure = None
        self.reset()

    # ------------------------------------------------------------------ set-up helpers
    def _reader(self, name: str):
        """``(channel, offset, gain)`` of the load cell that measures input ``name``, or
        ``(name, 0, 1)`` when the rig logs the input itself."""
        m = self.model
        contact = m.contact_of_input(name)
        for s in m.sensors:
            if s.kind == "load_cell" and contact is not None and s.target == contact.name:
                off = float(s.offset.value(self.params)) if s.offset is not None else 0.0
                gain = float(s.gain.value(self.params)) if s.gain is not None else None
                return s.channels[0], off, 1.0 if gain is None else gain
        return name, 0.0, 1.0

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
        return integration(m, self.params, cfg.dt, u=umax, eps=cfg.eps, speed=speed if speed > 0 else 1.0,
                           nsub=self.options.substeps or None, rates=[1.0 / t for t in taus if t > 0], max_nsub=None)

    def tuning_values(self) -> dict[str, float]:
        """The settings the NMPC runs with (given, or derived from the rig: :mod:`.defaults`), for
        the report: dt [s], horizon [-], eps [rad/s], setpoint_band and setpoint_rate [rad/s, rad/s^2
        or N m, N m/s], force_filter [s], hold_gain [-], speed_trim [s]."""
        c = self.cfg
        return {"dt": c.dt, "horizon": float(self.spec.horizon), "eps": c.eps,
                "setpoint_band": c.setpoint_band, "setpoint_rate": c.setpoint_rate,
                "force_filter": c.force_filter, "hold_gain": c.hold_gain, "speed_trim": c.speed_trim}

    @property
    def derived_units(self) -> dict[str, str]:
        """The unit of each :meth:`tuning_values` entry (a torque drive's set-point is a torque)."""
        sp, rate = ("N m", "N m/s") if self._torque_drive else ("rad/s", "rad/s^2")
        return {"dt": "s", "horizon": "-", "eps": "rad/s", "setpoint_band": sp, "setpoint_rate": rate,
                "force_filter": "s", "hold_gain": "-", "speed_trim": "s"}

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
        self.ocp.reset()
        self._servos = None       # replicas of the commanded servos
        self._t_call = None       # time of the last call
        self._t_plan = None       # time of the last successful plan
        self._plan_u = None       # (N, m) commanded inputs of that plan
        self._t_solve = None      # time of the last solve attempt
        self._action = None       # action held between plans
        self._u_prev = None       # last commands (self.inputs order)
        self._prep_q = None       # parameters for the pending preparation phase
        self._dev = {}            # low-passed (reading - programme) of each held measured input
        self._fc = np.ones(len(self.model.contacts))   # friction factors of the plan
        self.schedule.reset()
        self.trim.reset()
        self._t_moving = None     # last time the objective body slid (the stall guard)
        self.last_result = None

    def _measured(self, j: int, measurement, fallback: float) -> float:
        ch, off, gain = self._readers[j]
        v = measurement.get(ch) if measurement is not None else None
        if v is None or not math.isfinite(v):
            return fallback
        return (float(v) - off) / gain

    def _held_inputs(self, t: float, measurement, u_prog) -> np.ndarray:
        """The programme with every held measured input moved by its low-passed deviation."""
        hold = np.asarray(u_prog, float).copy()
        dt = self.dt_daq if self._t_call is None else max(t - self._t_call, 0.0)
        a = 1.0 - math.exp(-dt / self._tau_force) if self._tau_force > 0 else 1.0
        for j in self._held:
            if j in self._readers:
                v = self._measured(j, measurement, math.nan)
                if math.isfinite(v):
                    d = self._dev.get(j)
                    self._dev[j] = v - hold[j] if d is None else d + a * (v - hold[j] - d)
                hold[j] += self._dev.get(j, 0.0)
        return hold

    def _advance_servos(self, t: float, measurement, u_prog) -> np.ndarray:
        """Forces of the commanded servos now (replicas driven by the last commands)."""
        m = self.model
        if self._servos is None:
            self._servos = [Servo(a, self.dt_daq, self._measured(m.inputs.index(n), measurement,
                                                                 u_prog[m.inputs.index(n)]))
                            for a, n in zip(self._acts, self.servos)]
        elif self._t_call is not None:
            k = int(round((t - self._t_call) / self.dt_daq))
            j0 = 1 if self.drives else 0
            for _ in range(max(0, k)):
                for i, s in enumerate(self._servos):
                    s.step(self._u_prev[j0 + i])
        return np.array([s.force for s in self._servos])

    def _bounds(self, u_prog):
        lo, hi = self._lo.copy(), self._hi.copy()
        if self.drives:
            c = float(u_prog[self.layout.u_drive])
            band = self.cfg.setpoint_band
            lo[0], hi[0] = c - band, c + band
            if not self._torque_drive:   # a speed set-point does not reverse the rotation
                if c >= 0:
                    lo[0] = max(lo[0], 0.0)
                else:
                    hi[0] = min(hi[0], 0.0)
            else:                        # a torque drive's limit ([drive] torque_max; inf: none)
                tmax = self.context.torque_max
                lo[0], hi[0] = max(lo[0], -tmax), min(hi[0], tmax)
        return lo, hi

    def _state(self, estimate):
        """The rig's state and the friction factors from an estimate."""
        if estimate is None or getattr(estimate, "x", None) is None:
            raise SolverFailure("no state estimate")
        m = self.model
        names = tuple(getattr(estimate, "names", ()) or ())
        if names is not self._names_seen:
            if names and names[:m.nx] != m.states:
                raise SolverFailure(f"the estimate's states {names[:m.nx]} are not the rig's {m.states}")
            self._load_idx = [(names.index(k), i) for k, i in self._load_keys.items() if k in names]
            self._names_seen = names
        xe = np.asarray(estimate.x, float).ravel()
        x = xe[:m.nx]
        if x.shape != (m.nx,) or not math.isfinite(x.sum()):   # a sum is finite iff every entry is
            raise SolverFailure("non-finite or short state estimate")
        fc = None
        if self.options.use_load_estimate and self._load_idx:
            # in stick the friction is a constraint force and its level unobservable: the filter's
            # factor drifts there (rig3 from rest: 1.0 -> 2.1 in 0.5 s), so the plan keeps the
            # factor last seen while the contact body slid (1 before it ever slid)
            fc = self._fc
            slide = SLIDING_FRACTION * abs(self._nominal(self._t_call, self.context.programme(self._t_call)))
            for k, i in self._load_idx:
                if math.isfinite(xe[k]) and abs(x[m.contacts[i]]) > slide:
                    fc[i] = min(max(float(xe[k]), LOAD_FACTOR_RANGE[0]), LOAD_FACTOR_RANGE[1])
        return x, fc

    # ------------------------------------------------------------------ step
    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        o, L = self.options, self.layout
        u_prog = self.context.programme(t)
        if self._u_prev is None:
            m = self.model
            # the set-point starts where the programme has held it until now
            first = [float(u_prog[L.u_drive])] if self.drives else []
            self._u_prev = np.array(first + [self._measured(m.inputs.index(n), measurement, u_prog[m.inputs.index(n)])
                                             for n in self.servos], float)
        forces = self._advance_servos(t, measurement, u_prog)
        hold = self._held_inputs(t, measurement, u_prog)
        self._t_call = t
        xe = getattr(estimate, "x", None)
        if xe is not None and len(xe) > self._i_speed:
            self.schedule.update(float(xe[self._i_speed]), self._nominal(t, u_prog))
            self.trim.update(float(xe[self._i_speed]), self._nominal(t, u_prog))
            if self._t_moving is None or abs(float(xe[self._i_speed])) > SLIDING_FRACTION * abs(self._nominal(t, u_prog)):
                self._t_moving = t
        dt = self.cfg.dt
        due = self._t_solve is None or t - self._t_solve >= dt - 0.5 * self.dt_daq
        if not due and self._action is not None:
            if self._prep_q is not None:
                q, self._prep_q = self._prep_q, None
                try:
                    with solver_failures("preparation"):
                        self.ocp.prepare(q)
                except SolverFailure:   # the next plan starts afresh
                    self.ocp.reset()
            a = self._action
            return Action(a.u, Status.HOLD, f"hold: {a.status.value}: {a.message}" if a.message else "hold")
        steps = 1 if self._t_solve is None else max(1, int(round((t - self._t_solve) / dt)))
        self._t_solve = t
        try:
            if self.inject_failure is not None and self.inject_failure(t):
                raise SolverFailure("injected failure")
            x, fc = self._state(estimate)
            if not math.isfinite(hold.sum()):
                raise SolverFailure("non-finite held input")
            xa0 = np.empty(L.nxa)
            xa0[:L.nx] = x
            xa0[L.i_servo] = forces if o.model_servo else self._u_prev[L.j_cmd]
            if self.drives:
                xa0[L.i_wprev] = self._u_prev[0]
            at_min = [float(hold[j] <= lo + 1e-9 * max(abs(lo), 1.0)) for j, lo in zip(L.u_servo, self._n_min)]
            q = L.set_q(self._q.copy(), hold, self._nominal(t, u_prog) + self.trim.value, fc, at_min)
            f = self.schedule.current()
            q[self._i_ref] *= f
            q[self._i_dref] *= f
            q[self._i_force] *= f * f if self.drives else f   # pin only: the servo is all it has
            if self.ocp.X is not None and not (self.ocp.prepared and steps == 1):
                # prepare() already shifted by one interval
                self.ocp.shift(steps - 1 if self.ocp.prepared else steps)
            lo, hi = self._bounds(u_prog)
            res = self.ocp.solve(xa0, q, lo, hi, self._rate)
        except SolverFailure as exc:   # the fallback chain; anything else is a bug and fails the run
            self.counts.failures += 1
            self.ocp.reset()   # never warm-start from a failed iterate
            return self._hold(self._shift_or_programme(t, u_prog, f"{type(exc).__name__}: {exc}"))
        self.last_result = res
        self._plan_u, self._t_plan = res.u, t
        if o.prepare_ahead and o.solver != "ipopt":
            self._prep_q = q
        # remove QP-tolerance excursions only; the ranges may have been widened for reachability
        u0 = np.clip(res.u[0], *self.ocp.first_range(xa0, lo, hi, self._rate, self.ocp.last_bounds))
        if self._stalled(t, u0, u_prog):
            return self._hold(Action({}, Status.FALLBACK,
                                     f"stall guard: {self.body!r} has not slid for a stick-slip period "
                                     f"({self.period:.3g} s) and the plan slowed the drive below half its programme: "
                                     f"the programme"))
        return self._hold(Action(dict(zip(self.inputs, map(float, u0))), Status.OK, res.message))

    def _stalled(self, t: float, u0, u_prog) -> bool:
        """The stall guard: the objective body has stuck for a whole stick-slip period while the plan
        holds the drive below half its programme.  Within its horizon (half a period) the plan cannot
        see the wind-up that breaks a stuck string free, and every term of its cost then favours a
        still drive: on the suite's ``mismatch_m40`` (plant 40 % softer, heavier, smoother) the NMPC
        set the drive to 0 and left the disc stuck to the end in 3 of 18 runs (the two-input NMPC at
        13-19 % of its speed).  The programme winds the string up again; the plan takes over once it
        slides."""
        if not self.drives or self._t_moving is None:
            return False
        j = self.model.inputs.index(self.model.drive_input)
        return (t - self._t_moving >= self.period
                and abs(float(u0[0])) < SLIDING_FRACTION * abs(float(u_prog[j])))

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

