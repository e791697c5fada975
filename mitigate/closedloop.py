"""The closed loop: plant, sensors, estimator and controller at the DAQ rate, on any rig.

One sample ``k`` (time ``t_k = k dt``)::

    y_k    = DAQ measurement at t_k (the plant's sensors: counted encoders, noisy load cells, delays)
    xhat_k = estimator.update(t_k, y_k, u over [t_{k-1}, t_k])
    a_k    = controller.step(t_k, y_k, xhat_k)   from control.start, every control.every samples,
             held in between; before control.start the programme alone
    u_k    = the programme at t_k, with the inputs the newest due action sets replaced   held over [t_k, t_{k+1}]
    plant  <- one exact stick/slip step (servos on the inputs they set, the true parameters,
              the plant's own structure)

Controllers and estimators see only measurements, estimates and the NOMINAL model and
parameters (``scenario.model``, ``scenario.model_params``); the true state, the true parameters
and the plant's structure stay in the plant.  The estimator's input is the commanded drive
input with the MEASURED normal forces where a load cell measures them (a servo's output is not
known exactly).

Computation latency (``[control] latency``): 0 (default) applies an action at the sample it was
computed for; a fixed time ``L``, or ``"measured"`` (each call's own wall time, capped at the
deadline), applies it from the first DAQ sample at or after ``t_k + L`` (outputs are written at
sample instants; a newer action that is due replaces every older one).

How a run ends (``ClosedLoopResult.status``):

- ``Status.OK``; ``Status.WARNING`` when the controller's or the estimator's fallbacks (solver
  failures they answered themselves, deadline misses) exceed :data:`FALLBACK_WARN_FRACTION` of
  their calls, or the controller's set-point chatters (:func:`setpoint_chatter`); the message
  gives the counts, the first reason and the controller's derived tuning values;
- ``Status.FAILED`` when the controller or the estimator breaks its contract (raises -- also in
  ``reset`` or with ``SystemExit`` --, returns NaN or the wrong type, or does not return within
  ``[control] timeout``; :mod:`models.plugins`): the run ends at that sample, the message names
  who failed, when, and the exception's type and first line (``controller failed at t = 15.000 s
  in step: KeyError: 'motor_torque'``);
- ``Status.DIVERGED`` when the plant leaves its physical bounds (a non-finite state, or a body
  faster than ``scenario.max_speed``), ``Status.FAILED`` when the plant's step raises.
The samples so far are returned in every case.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from models import plugins
from models.errors import ConfigError, PluginError
from models.logs import TRUTH_PREFIX, Log
from models.plant import Plant, Trajectory
from models.status import Status
from mitigate.controllers.base import Action

#: the column of a command whose input has a measured channel of the same name (:meth:`ClosedLoopResult.to_log`)
COMMAND_PREFIX = "command_"

__all__ = ["COMMAND_PREFIX", "ClosedLoopResult", "run_closed_loop", "model_twists", "setpoint_chatter", "FALLBACK_WARN_FRACTION"]

#: fallbacks on more than this fraction of a controller's (or estimator's) calls make the run a WARNING
FALLBACK_WARN_FRACTION = 0.01
#: set-point chatter: at least this fraction of the increments change sign ...
CHATTER_SIGN_FRACTION = 0.5
#: ... and the median increment is at least this fraction of the input's scale (module docstring)
CHATTER_STEP_FRACTION = 0.1


@dataclass(frozen=True)
class ClosedLoopResult(Trajectory):
    """One closed-loop run; time on axis 0 (``n + 1`` samples unless the run ended early).

    Attributes
    ----------
    t : (m,) times [s]
    x : (m, nx_plant) TRUE plant states (names in ``states``)
    twists : ``{twist_<spring>: (m,)}`` the true twists of the MODEL's springs (angle
        differences, also when the plant splits a shaft into elements) [rad]
    y : measured channels, each (m,) (what the DAQ recorded)
    xhat : (m, nxe) state estimates; ``xhat_names`` their names
    u : (m, nu) inputs applied to the plant (servo outputs; names in ``inputs``); servo_inputs: the
        inputs a servo sets
    commands : ``{input: (m,)}`` what the loop sent for each input (programme or controller)
    controller_active : (m,) bool, the controller was in charge
    controller_ok : (m,) bool, the held action did not come from a fallback
    solve_times : (c,) wall time of each controller call [s]; plan_calls : (c,) bool, the call
        planned (not a hold between the plans of a multi-rate controller)
    estimator_times : (m,) wall time of each estimator update [s]
    controller_counts, estimator_counts : counts from the base classes
    observability : the estimator's observability report (or None)
    drive : ``{name: (m,)}`` the plant drive's electrical and torque quantities (a DC motor's
        ``current`` [A] and ``voltage`` [V], a torque drive's ``drive_torque`` [N m]:
        :meth:`models.rig.drives.Drive.signals`), TRUE values of the plant
    units : SI unit of every measured channel, input and drive quantity (the rig's names, free or not)
    status : Status.OK, or Status.DIVERGED / FAILED; message : the reason
    """

    t: np.ndarray
    x: np.ndarray
    twists: dict = field(repr=False)
    y: dict = field(repr=False)
    xhat: np.ndarray = field(repr=False)
    xhat_names: tuple = ()
    u: np.ndarray = field(default=None, repr=False)
    commands: dict = field(default_factory=dict, repr=False)
    controller_active: np.ndarray = field(default=None, repr=False)
    controller_ok: np.ndarray = field(default=None, repr=False)
    solve_times: np.ndarray = field(default=None, repr=False)
    plan_calls: np.ndarray = field(default=None, repr=False)
    estimator_times: np.ndarray = field(default=None, repr=False)
    controller_counts: dict = field(default_factory=dict)
    estimator_counts: dict = field(default_factory=dict)
    controller: str = ""
    model: str = ""
    objective_body: str = ""
    states: tuple = ()
    inputs: tuple = ()
    servo_inputs: tuple = ()
    control_start: float = 0.0
    observability: object = None
    status: Status = Status.OK
    message: str = "ok"
    units: dict = field(default_factory=dict, repr=False)
    drive: dict = field(default_factory=dict, repr=False)

    def estimate(self, name: str) -> np.ndarray:
        """Estimated state trajectory by name."""
        return self.xhat[:, self.xhat_names.index(name)]

    @property
    def objective_speed(self) -> np.ndarray:
        """True speed of the body whose stick-slip is suppressed [rad/s]."""
        return self.state(f"omega_{self.objective_body}")

    def to_log(self) -> Log:
        """Measured channels, the commands sent, plus the TRUE twists, speeds, servo forces and drive
        quantities as ``true_twist_<spring>`` / ``true_omega_<body>`` / ``true_<servo input>`` /
        ``true_<drive quantity>`` columns (:data:`models.logs.TRUTH_PREFIX`; the force a servo applied,
        its lagged output, beside its command; a DC motor's ``true_current [A]`` and ``true_voltage [V]``,
        a torque drive's ``true_drive_torque [N m]``), as a log.  A command whose input has a measured
        channel of the same name (a load cell named after the force it reads) is ``command_<input>``:
        the channel keeps its name, as in an open-loop log and a real DAQ's."""
        chans = dict(self.y)
        units = {}
        for n, v in self.commands.items():
            key = COMMAND_PREFIX + n if n in self.y else n
            chans[key] = v
            if n in self.units:
                units[key] = self.units[n]
        if self.u is not None:
            for n in self.servo_inputs:
                if n in self.inputs:
                    chans[TRUTH_PREFIX + n] = self.u[:, self.inputs.index(n)]
                    if n in self.units:
                        units[TRUTH_PREFIX + n] = self.units[n]
        for n, v in self.twists.items():
            chans[TRUTH_PREFIX + n] = v
        for j, n in enumerate(self.states):
            if n.startswith("omega_"):
                chans[TRUTH_PREFIX + n] = self.x[:, j]
        units.update({k: self.units[k] for k in chans if k in self.units and k not in units})
        for n, v in self.drive.items():
            chans[TRUTH_PREFIX + n] = v
            units[TRUTH_PREFIX + n] = self.units[n]
        return Log(self.t, chans, f"closed loop: {self.controller}", (), units)


def model_twists(model, plant_model) -> np.ndarray:
    """``(n_plant_states, n_model_springs)`` matrix ``S`` with ``twists = x_plant @ S``: the true
    twist of each MODEL spring.  A plant that splits a shaft section ``c`` into elements
    (``[structure] shaft_elements``) names them ``c``, ``c_1``, ...: their twists add up."""
    springs = [c.name for c in model.spec.connections if c.stiffness is not None]
    S = np.zeros((plant_model.nx, len(springs)))
    for j, c in enumerate(springs):
        for i, st in enumerate(plant_model.states):
            if st == f"twist_{c}" or (st.startswith(f"twist_{c}_") and st[len(f"twist_{c}_"):].isdigit()):
                S[i, j] = 1.0
    return S


def setpoint_chatter(cmd: np.ndarray, scale: float, min_steps: int = 20) -> str | None:
    """Why a command sequence chatters, or None.

    Chatter: the sign of the increments ``diff(cmd)`` changes on more than
    :data:`CHATTER_SIGN_FRACTION` of the steps AND the median non-zero increment is at least
    :data:`CHATTER_STEP_FRACTION` of ``scale`` (the larger of the programme's mean and the largest
    command, in the input's unit): a set-point jumping between two values every sample (hardware
    damage), not a law that follows sensor noise with small steps."""
    d = np.diff(np.asarray(cmd, float))
    d = d[np.isfinite(d) & (d != 0.0)]
    if d.size < min_steps or not scale > 0:
        return None
    flips = float(np.mean(np.sign(d[1:]) != np.sign(d[:-1])))
    step = float(np.median(np.abs(d)))
    if flips > CHATTER_SIGN_FRACTION and step >= CHATTER_STEP_FRACTION * scale:
        return f"its increments change sign on {100 * flips:.0f} % of the steps, median step {step:.3g}"
    return None


def _latency_samples(latency, action, deadline, dt) -> int:
    L = action.solve_time if latency == "measured" else float(latency)
    if latency == "measured" and deadline is not None:
        L = min(L, deadline)
    return int(math.ceil(L / dt - 1e-9)) if L > 0 else 0


def run_closed_loop(scenario, controller, *, estimator=None, progress=None, plant=None) -> ClosedLoopResult:
    """Run ``controller`` against the scenario's plant.

    Parameters
    ----------
    scenario : mitigate.scenario.Scenario
    controller : a :class:`mitigate.controllers.base.Controller`
    estimator : a :class:`estimators.base.StateEstimator`, or None to build ``scenario.estimator``
        with the NOMINAL model and parameters
    progress : optional callable ``progress(k_done)`` called every 100 samples
    plant : optional pre-built plant; default: ``models.plant.Plant`` of ``scenario.plant_model``
        with ``scenario.plant_params``, its sensors, servos, options and drift

    Returns
    -------
    ClosedLoopResult : ``status`` OK, WARNING, FAILED or DIVERGED with the reason in ``message``
        (module docstring); a controller or estimator that fails ends its run as FAILED, it never raises.

    Raises
    ------
    ConfigError : a scenario too short for one sample; PluginError : building the default
        estimator failed (a broken estimator plug-in).
    """
    model, pm = scenario.model, scenario.plant_model
    dt = scenario.dt
    n = scenario.samples
    if n < 1:
        raise ConfigError(f"{scenario.where}: scenario.duration must be at least one sample ({dt} s), "
                          f"got {scenario.duration}")
    u0 = scenario.programme(0.0)
    if plant is None:
        plant = Plant(pm, scenario.plant_params, scenario.sim, sensors=scenario.sensors, u0=u0,
                      drift=scenario.drift)
    timeout = scenario.control.timeout
    deadline = scenario.control.deadline
    latency = scenario.control.latency
    if estimator is None:
        from estimators.base import EstimatorContext
        from estimators.online.factory import make_estimator
        # the estimator's initial guess comes from the NOMINAL model, never from the plant
        x0 = model.steady_sliding(u0, scenario.model_params) if scenario.sim.start == "sliding" else np.zeros(model.nx)
        estimator = make_estimator(scenario.estimator, EstimatorContext(
            model, scenario.model_params, dt, scenario.sensors, x0, f"{scenario.where}: estimator", timeout))
    k_start = int(math.ceil(scenario.control.start / dt - 1e-9))
    every = scenario.control.every
    twist_map = model_twists(model, pm)
    twist_names = tuple(f"twist_{c.name}" for c in model.spec.connections if c.stiffness is not None)
    speed_idx = np.array([pm.speed_index(b) for b in pm.bodies])
    measured_inputs = [j for j, name in enumerate(model.inputs) if name in model.measured
                       and model.sensor_of(name) is not None and model.sensor_of(name).kind != "encoder"]

    T = np.arange(n + 1) * dt
    X = np.full((n + 1, pm.nx), np.nan)
    TW = np.full((n + 1, len(twist_names)), np.nan)
    U = np.full((n + 1, pm.nu), np.nan)
    CMD = np.full((n + 1, model.nu), np.nan)
    active = np.zeros(n + 1, bool)
    ok = np.ones(n + 1, bool)
    est_times = np.full(n + 1, np.nan)
    solve_times: list[float] = []
    plan_calls: list[bool] = []
    ys: list[dict] = []
    xh: list[np.ndarray] = []
    names: tuple = ()
    pending: list[tuple[int, int, object]] = []     # (due sample, call number, action) under a latency
    first_fallback = {"controller": "", "estimator": ""}

    y = plant.measure()
    u_prev = u0.copy()
    if scenario.sim.start != "sliding":
        # the estimator's first update predicts over the sample before t = 0, when the rig rested
        # and nothing drove it; the programme's set-point there threw the EKF's first correction off
        # (rig3 from rest: 0.44 rad of twist, -3 rad of PI integral) and an NMPC on that estimate
        # overshot R1 by 80 %
        u_prev[model.inputs.index(model.drive_input)] = 0.0
    held = None
    sampler = bool(getattr(controller, "own_estimator", False))
    status, message = Status.OK, "ok"
    last = n
    X[0] = plant.x
    TW[0] = plant.x @ twist_map
    with plugins.watchdog(timeout):       # one periodic alarm for every guarded call of the run
        try:
            plugins.call(controller.reset, timeout=timeout, what="reset")
        except PluginError as exc:
            status, message, last = Status.FAILED, f"controller failed at t = 0.000 s in reset: {exc}", -1
        for k in range(n + 1) if last == n else ():
            t = T[k]
            ys.append(y)
            u_est = u_prev.copy()
            for j in measured_inputs:
                v = y.get(model.inputs[j], np.nan)
                if np.isfinite(v):
                    u_est[j] = v
            u = scenario.programme(t)
            try:
                est = estimator.update(t, y, u_est)
            except PluginError as exc:
                status, message, last = Status.FAILED, f"estimator failed at t = {t:.3f} s in update: {exc}", k
                xh.append(np.full(len(xh[-1]) if xh else 0, np.nan))
                CMD[k], U[k] = u, (U[k - 1] if k > 0 else u)
                break
            if est.status is Status.FALLBACK and not first_fallback["estimator"]:
                first_fallback["estimator"] = f"t = {t:.3f} s: {est.message}"
            names = est.names
            xh.append(np.asarray(est.x, dtype=float))
            est_times[k] = est.solve_time
            if sampler:
                try:
                    plugins.call(controller.sample, t, dict(y), k >= k_start, timeout=timeout, what="sample")
                except PluginError as exc:
                    status, message, last = Status.FAILED, f"controller failed at t = {t:.3f} s in sample: {exc}", k
                    CMD[k], U[k] = u, (U[k - 1] if k > 0 else u)
                    break
            if k >= k_start:
                if (k - k_start) % every == 0:
                    try:
                        a = plugins.call(controller.step, t, dict(y), est, timeout=timeout, what="step")   # its own copy
                        if not isinstance(a, Action):
                            raise PluginError(f"TypeError: step must return an Action, got {type(a).__name__}")
                    except PluginError as exc:
                        status, message, last = Status.FAILED, f"controller failed at t = {t:.3f} s in step: {exc}", k
                        CMD[k], U[k] = u, (U[k - 1] if k > 0 else u)
                        break
                    if a.status is Status.FALLBACK and not first_fallback["controller"]:
                        first_fallback["controller"] = f"t = {t:.3f} s: {a.message}"
                    solve_times.append(a.solve_time)
                    plan_calls.append(a.status is not Status.HOLD)
                    pending.append((k + _latency_samples(latency, a, deadline, dt), len(solve_times), a))
                due = [p for p in pending if p[0] <= k]
                if due:
                    newest = max(due, key=lambda p: p[1])
                    held = newest[2]
                    pending = [p for p in pending if p[1] > newest[1]]
                active[k] = True
                if held is not None:
                    ok[k] = held.success
                    for name, v in held.u.items():
                        u[model.inputs.index(name)] = v
            CMD[k] = u
            if k == n:
                U[k] = U[k - 1] if k > 0 else u
                break
            try:
                y = plant.step(u)
                xk = np.asarray(plant.x, dtype=float)
            except Exception as exc:  # noqa: BLE001 - the plant is the one thing that may end a run
                status, message, last = Status.FAILED, f"plant step failed at t = {T[k + 1]:.3f} s: " \
                                                       f"{type(exc).__name__}: {exc}", k
                U[k] = u
                break
            U[k] = plant.u_applied
            X[k + 1] = xk
            TW[k + 1] = xk @ twist_map
            u_prev = u
            if not np.all(np.isfinite(xk)):
                status, message, last = Status.DIVERGED, f"diverged at t = {T[k + 1]:.3f} s: non-finite plant state", k + 1
                break
            fast = np.abs(xk[speed_idx])
            if np.any(fast > scenario.max_speed):
                b = pm.bodies[int(np.argmax(fast))]
                status, message, last = Status.DIVERGED, (
                    f"diverged at t = {T[k + 1]:.3f} s: |omega_{b}| = {float(np.max(fast)):.3g} rad/s exceeds "
                    f"plant.max_speed = {scenario.max_speed:g} rad/s"), k + 1
                break
            if progress is not None and (k + 1) % 100 == 0:
                progress(k + 1)
    if last < 0:          # reset failed: the first sample only, the programme, no estimate
        last = 0
        ys.append(y)
        xh.append(np.zeros(0))
        CMD[0] = U[0] = u0
    m = last + 1
    if status is Status.DIVERGED:
        # the diverged sample is kept: what the DAQ read there, the inputs held over the step that led
        # to it, no estimate (every array has the same m rows)
        ys.append(y)
        xh.append(np.full(len(xh[-1]), np.nan))
        U[last], CMD[last] = U[last - 1], CMD[last - 1]
    keys = list(dict.fromkeys(k for d in ys[:m] for k in d))
    Y = {c: np.array([d.get(c, np.nan) for d in ys[:m]]) for c in keys}
    commands = {name: CMD[:m, j] for j, name in enumerate(model.inputs) if name in model.commands}
    if status is Status.OK:
        status, message = _warnings(scenario, controller, estimator, commands, active[:m], first_fallback)
    width = max((len(r) for r in xh[:m]), default=0)
    xhat = np.array([r if len(r) == width else np.full(width, np.nan) for r in xh[:m]]) if xh else np.zeros((0, 0))
    return ClosedLoopResult(
        t=T[:m], x=X[:m], twists={nm: TW[:m, j] for j, nm in enumerate(twist_names)}, y=Y, xhat=xhat,
        xhat_names=tuple(names), u=U[:m], commands=commands, controller_active=active[:m], controller_ok=ok[:m],
        solve_times=np.array(solve_times), plan_calls=np.array(plan_calls, dtype=bool),
        estimator_times=est_times[:m], controller_counts=controller.counts.as_dict(),
        estimator_counts=estimator.counts.as_dict(), controller=getattr(controller, "name", type(controller).__name__),
        model=model.name, objective_body=model.objective_body, states=pm.states, inputs=pm.inputs,
        servo_inputs=tuple(pm.servo_inputs), control_start=float(k_start * dt), observability=getattr(estimator, "observability", None),
        status=status, message=message, units={**pm.output_units(), **model.output_units(), **pm.drive.signal_units()},
        drive=pm.drive.signals(pm, scenario.plant_params, X[:m], U[:m]))


def _warnings(scenario, controller, estimator, commands, active, first_fallback) -> tuple[Status, str]:
    """Status.WARNING with the reasons (fallbacks over the threshold, set-point chatter), or OK."""
    notes, warn = [], False
    for who, counts in (("controller", controller.counts), ("estimator", estimator.counts)):
        calls, fb = counts.steps, counts.fallbacks
        if not fb:
            continue
        misses = getattr(counts, "deadline_misses", 0)
        detail = f"{fb} {who} fallback(s) in {calls} call(s) ({100 * fb / max(calls, 1):.2g} %" + \
                 (f", {misses} deadline miss(es)" if misses else "") + f"), the first at {first_fallback[who]}"
        warn = warn or fb > FALLBACK_WARN_FRACTION * calls
        notes.append(detail)
    chatter = []
    prog = np.array([scenario.programme(t) for t in (scenario.control.start, scenario.duration)])
    for name, cmd in commands.items():
        c = np.asarray(cmd)[active]
        j = scenario.model.inputs.index(name)
        why = setpoint_chatter(c, max(float(np.max(np.abs(prog[:, j]))), float(np.max(np.abs(c))) if c.size else 0.0))
        if why:
            chatter.append(f"set-point chatter on {name}: {why}")
    if chatter:
        warn = True
        try:
            tv = plugins.call(controller.tuning_values, timeout=scenario.control.timeout) \
                if hasattr(controller, "tuning_values") else {}
        except PluginError:
            tv = {}
        tune = f" (derived tuning: {', '.join(f'{k} = {v:.4g}' for k, v in tv.items())})" if tv else ""
        notes += [c + tune for c in chatter]
    if not notes:
        return Status.OK, "ok"
    return (Status.WARNING, "; ".join(notes)) if warn else (Status.OK, "ok (" + "; ".join(notes) + ")")
