"""The run window every metric is a function of, and the settings and helpers that make it.

A metric (:mod:`mitigate.metrics.registry`) sees one run through a window:

- :class:`ClosedLoopWindow`: a closed-loop run after its control start, from the TRUE plant trajectory
  (the objective body's speed; the programme; the true states and applied inputs; the controller's
  commands, counts and call times; the measured channels), with the windows the stick-slip period sets
  (the residual window, non-overlapping and moving severity windows) and the stuck threshold;
- :class:`SweepWindow`: one point of a parameter sweep after its settling time (the speed and the
  amplitude state, the limit-cycle threshold).

Every default that carries a unit comes from the scenario (:class:`MetricOptions`): windows from the
rig's stick-slip period, stuck thresholds from the programmed speed and the encoder's resolution.
All arrays are sampled at a constant period ``dt`` [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cached_property
from typing import Any, Mapping

import numpy as np

from mitigate.severity import amplitude, moving_severity, windowed_severity
from models.checks import finite_number
from models.errors import ConfigError

__all__ = ["RunWindow", "ClosedLoopWindow", "SweepWindow", "MetricOptions", "contact_work", "solve_time_stats",
           "programmed_speed", "measured_stuck_speed", "rig_period", "force_roles", "windows", "result_voltage"]


def contact_work(model, params, x: np.ndarray, u: np.ndarray, contact: str, dt: float, *,
                 caused_by_normal: bool = False) -> float:
    """Energy dissipated at a friction contact, ``sum |T(|w|)| |w| dt`` [J], from the true states
    ``x`` (n, nx) and applied inputs ``u`` (n, nu) of ``model`` (rectangle rule).

    ``caused_by_normal``: count only the part of the torque that the contact's normal force causes,
    ``|T(|w|, N) - T(|w|, 0)|`` (a law's viscous term, such as the bit-rock law's ``c_b |w|``, acts
    at zero normal force: it is not wear caused by pressing); only for a contact whose normal force
    is an input.
    """
    import casadi as ca
    from models.friction import get_law
    c = next((c for c in model.spec.contacts if c.name == contact), None)
    if c is None:
        raise ConfigError(f"rig {model.name!r} has no contact {contact!r}")
    idx = model.speed_index(c.body)
    xs, us, v = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("v")
    P = model.unpack(ca.DM(params.vector()))
    law = get_law(c.law)

    def torque(u_sym):
        un = {n: u_sym[k] for k, n in enumerate(model.inputs)}
        N, r, LP = model.contact_args(c, P, un)
        return law.torque(v, 1.0, N, r, LP)

    T = torque(us)
    if caused_by_normal:
        if c.normal is None or c.normal.kind != "input":
            raise ConfigError(f"contact {contact!r}: caused_by_normal needs a normal force that is an input")
        j = model.inputs.index(c.normal.name)
        u0 = ca.vertcat(*[0.0 if k == j else us[k] for k in range(model.nu)])
        T = T - torque(u0)
    f = ca.Function("work", [v, xs, us], [ca.fabs(T) * v])
    w = np.abs(np.asarray(x[:, idx], float))
    vals = np.array(f.map(len(w))(w[None, :], np.asarray(x, float).T, np.asarray(u, float).T)).ravel()
    return float(np.sum(vals) * dt)


def solve_time_stats(times: np.ndarray) -> dict[str, float]:
    """Median, 95th percentile and maximum of solve times [s] (NaN if there are none)."""
    t = np.asarray(times, dtype=float)
    t = t[np.isfinite(t)]
    if t.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"median": float(np.median(t)), "p95": float(np.percentile(t, 95)), "max": float(np.max(t))}


@dataclass(frozen=True, kw_only=True)
class MetricOptions:
    """Settings of :func:`closed_loop_metrics`; None means "from the scenario" (every default with a
    unit comes from it: windows from the rig's stick-slip period, thresholds from the programmed speed).

    Parameters
    ----------
    period : the stick-slip period [s] that sets the windows (None: the rig's lowest torsional mode
        with the drive held, :func:`rig_period`; the benchmark passes the period it measured on the
        uncontrolled run)
    residual_periods : length of the residual window in periods [-] (3; whole periods, see below)
    residual_fraction : the residual window is at most this fraction of the controlled part [-]
        (0.5: the first half holds the switch-on transient); it is a whole number of periods (at
        least one) that fits in both limits
    window_periods : non-overlapping severity windows (``sss_window_*``, ``sss_final``) in periods (2)
    moving_periods : the drilling convention's moving window in periods (1.5)
    suppress_threshold : moving severity below which stick-slip counts as suppressed [-] (0.1)
    stuck_speed : |speed| at or below which the TRUE body is stuck [rad/s] (None: 1e-3 of the
        programmed speed, :func:`programmed_speed`; with none -- a torque drive without a target --
        1e-3 of the run's mean |speed|; it is exactly 0 in stick in the hybrid plant)
    stuck_speed_measured : the same for the measured speed [rad/s] (None: half an encoder tick per
        DAQ period on an encoder channel, else 5 % of that speed scale: :func:`measured_stuck_speed`)
    force_band : ``(low, high)`` band of the mean applied normal force over its programme [-] outside
        which a run violates the programme (the driller's weight on bit; (0.8, 1.25))
    speed_band : ``(low, high)`` band of the objective body's mean speed over the residual window over
        its programme [-] outside which a run violates the programme (the bit's speed; (0.95, 1.05))
    """

    period: float | None = None
    residual_periods: float = 3.0
    residual_fraction: float = 0.5
    window_periods: float = 2.0
    moving_periods: float = 1.5
    suppress_threshold: float = 0.1
    stuck_speed: float | None = None
    stuck_speed_measured: float | None = None
    force_band: tuple = (0.8, 1.25)
    speed_band: tuple = (0.95, 1.05)
    where: str = "metrics"

    def __post_init__(self):
        w = self.where
        for name in ("period", "stuck_speed", "stuck_speed_measured"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, finite_number(v, f"{w}.{name}", positive=True,
                                                             unit="s" if name == "period" else "rad/s"))
        for name in ("residual_periods", "window_periods", "moving_periods", "suppress_threshold"):
            object.__setattr__(self, name, finite_number(getattr(self, name), f"{w}.{name}", positive=True))
        f = finite_number(self.residual_fraction, f"{w}.residual_fraction", positive=True)
        if f > 1:
            raise ConfigError(f"{w}.residual_fraction must be in (0, 1], got {f!r}")
        object.__setattr__(self, "residual_fraction", f)
        for name in ("force_band", "speed_band"):
            b = getattr(self, name)
            if not isinstance(b, (list, tuple)) or len(b) != 2:
                raise ConfigError(f"{w}.{name} must be [low, high] (ratios to the programme), got {b!r}")
            lo = finite_number(b[0], f"{w}.{name}[0]", nonneg=True)
            hi = finite_number(b[1], f"{w}.{name}[1]", positive=True)
            if not lo < 1 <= hi:
                raise ConfigError(f"{w}.{name} must have low < 1 <= high, got [{lo:g}, {hi:g}]")
            object.__setattr__(self, name, (lo, hi))

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], where: str = "metrics") -> "MetricOptions":
        """Validate a raw TOML table (a suite's ``[metrics]``); unknown keys are errors naming ``where``."""
        if not isinstance(table, Mapping):
            raise ConfigError(f"{where} must be a table, got {type(table).__name__}")
        known = [f.name for f in fields(cls) if f.name != "where"]
        bad = sorted(set(table) - set(known))
        if bad:
            raise ConfigError(f"{where}.{bad[0]}: unknown key; expected one of {', '.join(known)}")
        return cls(**dict(table), where=where)


def rig_period(model, params) -> float:
    """The rig's stick-slip period estimate [s]: its lowest torsional mode with the drive held
    (:func:`mitigate.controllers.tuning.stick_slip_frequency`)."""
    from mitigate.controllers.tuning import stick_slip_frequency
    return 1.0 / stick_slip_frequency(model, params)


def programmed_speed(scenario, t: np.ndarray) -> np.ndarray:
    """The objective body's programmed speed at the times ``t`` [rad/s]: the drive's set-point (or
    prescribed speed), or for a torque drive the scenario's ``[control] speed`` (the target its laws aim
    at), else the rig file's ``operating_point.speed`` (NaN if it has none)."""
    m = scenario.model
    t = np.asarray(t, float)
    if m.drive_kind == "torque":
        if getattr(scenario, "control_speed", None) is not None:
            return np.array([scenario.control_speed(tk) for tk in t], float)
        v = m.spec.extra.get("operating_point", {}).get("speed")      # SI, resolved by the rig parser
        return np.full(t.shape, float(v) if v is not None else np.nan)
    prof = scenario.inputs[m.drive_input]
    return np.array([prof(tk) for tk in t], float)


def force_roles(model, programme: np.ndarray) -> dict[str, str]:
    """``{input: "process" | "brake"}`` for every input that sets a contact's normal force: the
    process load (a positive programme: the weight on bit, the rock the bit cuts) or a brake (a zero
    programme: a pin that only ever brakes).  ``programme`` is (n, nu) in ``model.inputs`` order."""
    out = {}
    for j, name in enumerate(model.inputs):
        if model.contact_of_input(name) is None:
            continue
        out[name] = "process" if float(np.mean(programme[:, j])) > 0 else "brake"
    return out


def windows(o: MetricOptions, period: float, span: float, dt: float) -> tuple[float, float, float]:
    """(residual, non-overlapping, moving) window lengths [s] for ``span`` seconds after the start.
    The residual window is a whole number of periods (a cycle that stays is averaged over whole
    cycles: its mean speed is the programme's), at least one, at most ``residual_periods`` and
    ``residual_fraction`` of the span (a span shorter than one period: that fraction of it)."""
    room = min(o.residual_periods * period, o.residual_fraction * span)
    whole = math.floor(room / period + 1e-9)
    res = max(dt, whole * period if whole >= 1 else min(period, o.residual_fraction * span))
    return res, max(dt, o.window_periods * period), max(dt, min(o.moving_periods * period, span))


def measured_stuck_speed(scenario, w_scale: float, given: float | None = None) -> tuple[str | None, float]:
    """(the objective body's speed channel, the |measured speed| at or below which it counts as stuck
    [rad/s]): ``given``, else half an encoder tick per DAQ period on an encoder channel, else 5 % of
    ``w_scale`` (the programmed speed) [rad/s]."""
    from models.sensors import stuck_speed
    m = scenario.model
    ch = m.speed_channel(m.objective_body)
    return ch, (given if given is not None else stuck_speed(m, ch, scenario.dt, w_scale))


def result_voltage(model, params, X: np.ndarray, U: np.ndarray) -> np.ndarray:
    """The DC motor's armature voltage along a trajectory (its drive's limits applied) [V]."""
    f = model.meas_vector(["voltage"])
    return np.array(f.map(X.shape[0])(X.T, U.T, np.asarray(params.vector(), float))).ravel()


class RunWindow:
    """What every window has.

    Attributes
    ----------
    kind : the kind of run (:data:`mitigate.metrics.registry.RUN_KINDS`)
    has : what the run has (:data:`mitigate.metrics.registry.NEEDS`)
    dt : sample period [s]
    speed : (n,) the measured body's TRUE speed over the window [rad/s]
    stuck_speed : |speed| at or below which the body is stuck [rad/s]
    """

    kind: str = ""
    has: frozenset = frozenset()
    dt: float
    speed: np.ndarray
    stuck_speed: float


class ClosedLoopWindow(RunWindow):
    """A closed-loop run after its control start (the whole run if fewer than two samples follow it).

    Parameters
    ----------
    result : mitigate.closedloop.ClosedLoopResult
    scenario : its scenario (the plant's model and true parameters, the programme)
    options : :class:`MetricOptions` (default: every window and threshold from the scenario)

    Attributes
    ----------
    speed, t : the objective body's true speed [rad/s] and the times [s] after the start, (n,)
    span : seconds the window covers (n samples of dt) [s]
    period : the stick-slip period that sets the windows [s] (the options', else the rig's lowest
        mode with the drive held, else a quarter of the span)
    severity_window, moving_window : the non-overlapping and the moving severity windows [s];
        n_res, n_win : samples of the residual and of a non-overlapping window
    tail : (n_res,) the speed over the residual window (the last part: :func:`windows`)
    speed_programme : (n,) the programmed speed [rad/s]; ref : its mean, None when it is not finite
        or zero; speed_scale : abs(ref), else the run's mean |speed| [rad/s]
    programme, x, u : (n, nu), (n, nx), (n, nu) the programmed inputs, true states, applied inputs
    model, plant, params : the scenario's nominal model, the plant's model and true parameters
    roles : :func:`force_roles` of the plant's normal-force inputs
    """

    kind = "closed_loop"

    def __init__(self, result, scenario, options: MetricOptions | None = None):
        o = options or MetricOptions()
        self.result, self.scenario, self.options = result, scenario, o
        self.dt = dt = scenario.dt
        m = result.t >= result.control_start - 1e-12
        if m.sum() < 2:
            m = np.ones_like(result.t, dtype=bool)
        self.mask = m
        self.t = result.t[m]
        self.speed = w = result.state(f"omega_{result.objective_body}")[m]
        self.span = float(self.t[-1] - self.t[0]) + dt
        self.model, self.plant, self.params = scenario.model, scenario.plant_model, scenario.plant_params
        period = o.period
        if period is None:
            try:
                period = rig_period(scenario.model, scenario.model_params)
            except ConfigError:          # no torsional mode with the drive held: a quarter of the controlled part
                period = self.span / 4
        self.period = float(period)
        res_win, self.severity_window, self.moving_window = windows(o, period, self.span, dt)
        self.n_res = max(2, min(len(w), int(round(res_win / dt))))
        self.n_win = max(1, int(round(self.severity_window / dt)))
        self.tail = w[-self.n_res:]
        self.speed_programme = programmed_speed(scenario, self.t)
        w_ref = float(np.mean(self.speed_programme))
        self.ref = w_ref if math.isfinite(w_ref) and w_ref != 0 else None
        # the speed scale of a run without a programmed speed (a torque drive, no target): its own mean |speed|
        self.speed_scale = abs(w_ref) if self.ref else float(np.mean(np.abs(w))) if len(w) else 0.0
        self.stuck_speed = o.stuck_speed if o.stuck_speed is not None else 1e-3 * self.speed_scale
        self.programme = np.array([scenario.programme(tk) for tk in self.t]).reshape(len(self.t), -1)
        self.x, self.u = result.x[m], result.u[m]
        self.roles = force_roles(self.plant, self.programme)
        self.torque_channel = next((s.channels[0] for s in scenario.model.sensors if s.kind == "torque"), None)
        self.has = frozenset(
            {"controlled"}
            | ({"programmed_speed"} if self.ref is not None else set())
            | ({"servo"} if self.plant.servo_inputs else set())
            | ({"process_force"} if "process" in self.roles.values() else set())
            | ({"measured_speed"} if self.measured[0] in result.y else set())
            | ({"twist"} if result.twists else set())
            | ({"torque_sensor"} if self.torque_channel and self.torque_channel in result.y else set()))

    @cached_property
    def measured(self) -> tuple[str | None, float]:
        """(the objective body's measured speed channel, its stuck threshold [rad/s]): :func:`measured_stuck_speed`."""
        return measured_stuck_speed(self.scenario, self.speed_scale, self.options.stuck_speed_measured)

    @cached_property
    def windowed_severity(self) -> np.ndarray:
        """Severity over consecutive non-overlapping windows (:func:`mitigate.severity.windowed_severity`)."""
        return windowed_severity(self.speed, self.dt, self.severity_window, self.stuck_speed)

    @cached_property
    def moving_severity(self) -> np.ndarray:
        """Severity over the moving window (:func:`mitigate.severity.moving_severity`)."""
        return moving_severity(self.speed, self.dt, self.moving_window, stuck=self.stuck_speed)

    @cached_property
    def normal_forces(self) -> dict[str, tuple[float, float]]:
        """``{servo input: (mean applied force [N], its ratio to the mean programme [-] or NaN
        for a zero programme)}``."""
        out = {}
        for name in self.plant.servo_inputs:
            j = self.plant.inputs.index(name)
            mean_n, mean_p = float(np.mean(self.u[:, j])), float(np.mean(self.programme[:, j]))
            out[name] = (mean_n, mean_n / mean_p if mean_p > 0 else float("nan"))
        return out

    @cached_property
    def friction_work(self) -> dict[str, float]:
        """Friction work at the contacts whose normal force is an input, by role [J]: ``brake`` (only
        what the normal force causes), ``process`` (at the applied force) and ``process_programmed``
        (the same speeds at the programmed force)."""
        pm, pp, X, U, dt = self.plant, self.params, self.x, self.u, self.dt
        out = {"brake": 0.0, "process": 0.0, "process_programmed": 0.0}
        for name, role in self.roles.items():
            c = pm.contact_of_input(name)
            if role == "brake":
                out["brake"] += contact_work(pm, pp, X, U, c.name, dt, caused_by_normal=True)
            else:
                Up = U.copy()
                Up[:, pm.inputs.index(name)] = self.programme[:, pm.inputs.index(name)]
                out["process"] += contact_work(pm, pp, X, U, c.name, dt)
                out["process_programmed"] += contact_work(pm, pp, X, Up, c.name, dt)
        return out

    @cached_property
    def call_times(self) -> dict[str, dict[str, float]]:
        """:func:`solve_time_stats` [s] of every controller call (``"solve"``) and of the planning
        calls only (``"plan"``)."""
        r = self.result
        plans = self.plan_calls
        return {"solve": solve_time_stats(r.solve_times),
                "plan": solve_time_stats(np.asarray(r.solve_times)[plans] if len(r.solve_times) else r.solve_times)}

    @cached_property
    def plan_calls(self) -> np.ndarray:
        """(calls,) whether each controller call planned (not a hold)."""
        r = self.result
        return r.plan_calls if r.plan_calls is not None else np.ones(len(r.solve_times), bool)


class SweepWindow(RunWindow):
    """One point of a parameter sweep after its settling time.

    Parameters
    ----------
    speed : (n,) the sweep's speed state [rad/s]
    amplitude_signal : (n,) the state whose half peak-to-peak is the amplitude (its own unit)
    dt : sample period [s]
    threshold : amplitude above which a sustained swing is a limit cycle (the state's unit)
    stuck_speed : |speed| at or below which the body is stuck [rad/s]
    """

    kind = "sweep"
    has = frozenset({"sweep_point"})

    def __init__(self, speed: np.ndarray, amplitude_signal: np.ndarray, dt: float, threshold: float,
                 stuck_speed: float):
        self.speed, self.amplitude_signal = speed, amplitude_signal
        self.dt, self.threshold, self.stuck_speed = dt, threshold, stuck_speed

    @cached_property
    def growth(self) -> float:
        """The late half's amplitude over the early half's [-] (1 for no swing at all, inf from none)."""
        amp = self.amplitude_signal
        h = len(amp) // 2
        a_early, a_late = amplitude(amp[:h]), amplitude(amp[h:])
        return a_late / a_early if a_early > 0 else (1.0 if a_late == 0 else float("inf"))

    @cached_property
    def limit_cycle(self) -> bool:
        """A sustained swing, not a decaying transient: the amplitude above the threshold and the late
        half swinging at least 80 % of the early half."""
        return bool(amplitude(self.amplitude_signal) > self.threshold and self.growth >= 0.8)
