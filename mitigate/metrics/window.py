"""The run window every metric is a function of (:mod:`mitigate.metrics.registry`).

- :class:`ClosedLoopWindow`: a closed-loop run after its control start, from the TRUE plant trajectory
  (the objective body's speed; the programme; the true states and applied inputs; the controller's
  commands, counts and call times; the measured channels), with the windows the stick-slip period sets
  (the residual window, non-overlapping and moving severity windows) and the stuck threshold;
- :class:`SweepWindow`: one point of a parameter sweep after its settling time (the speed and the
  amplitude state, the limit-cycle threshold).

All arrays are sampled at a constant period ``dt`` [s].
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from mitigate.metrics.quantities import (MetricOptions, contact_work, force_roles, measured_stuck_speed,
                                         programmed_speed, rig_period, solve_time_stats, windows)
from mitigate.severity import amplitude, moving_severity, windowed_severity
from models.errors import ConfigError

__all__ = ["RunWindow", "ClosedLoopWindow", "SweepWindow"]


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
    uncontrolled : (m,) the objective body's TRUE speed in the uncontrolled run (the programme alone)
        of the same scenario switched on at the same instant, sampled at the run's ``t`` from t = 0
        [rad/s]; None: unknown (what needs it is NaN)

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

    def __init__(self, result, scenario, options: MetricOptions | None = None, uncontrolled=None):
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
            | ({"torque_sensor"} if self.torque_channel and self.torque_channel in result.y else set())
            | ({"uncontrolled_run"} if uncontrolled is not None else set()))
        if uncontrolled is not None:       # the same samples as the run's; NaN where the reference ran shorter
            unc = np.full(len(result.t), np.nan)
            v = np.asarray(uncontrolled, float)[:len(result.t)]
            unc[:len(v)] = v
            self.uncontrolled = unc[m]

    @cached_property
    def measured(self) -> tuple[str | None, float]:
        """(the objective body's measured speed channel, its stuck threshold [rad/s]): :func:`measured_stuck_speed`."""
        return measured_stuck_speed(self.scenario, self.speed_scale, self.options.stuck_speed_measured)

    @cached_property
    def measured_speed(self) -> np.ndarray:
        """(n,) the objective body's speed as the DAQ recorded it (its encoder's counts per sample, or
        its speed sensor's noisy reading) [rad/s]; dropouts are NaN."""
        return np.asarray(self.result.y[self.measured[0]], float)[self.mask]

    def ripple_floor(self, n: int) -> float:
        """The peak-to-peak ripple [rad/s] the objective body's speed channel cannot tell from a steady
        speed over ``n`` samples (:func:`models.sensors.ripple_floor`)."""
        from models.sensors import ripple_floor
        return ripple_floor(self.scenario.model, self.measured[0], self.dt, n, self.scenario.sensors)

    @cached_property
    def band_windows(self) -> tuple[int, int]:
        """(samples of a moving band window, index of the first sample the band checks cover)."""
        o = self.options
        n = max(1, min(len(self.t), int(round(o.band_periods * self.period / self.dt))))
        return n, min(len(self.t), int(round(o.band_after * self.period / self.dt)))

    def moving_mean(self, x: np.ndarray) -> np.ndarray:
        """The mean of ``x`` (n,) over every moving band window from the first the checks cover
        (:attr:`band_windows`); empty when the run is shorter than that."""
        n, k0 = self.band_windows
        x = np.asarray(x, float)[k0:]
        if len(x) < n:
            return np.zeros(0)
        c = np.concatenate(([0.0], np.cumsum(x)))
        return (c[n:] - c[:-n]) / n

    @cached_property
    def string_torque(self) -> tuple[np.ndarray, float]:
        """((n, springs) the torque every spring of the PLANT carries [N m], the largest a spring carries
        in steady sliding at the programme at the switch-on [N m] (NaN if there is none))."""
        from mitigate.metrics.loads import steady_string_torque, string_torques
        return (string_torques(self.plant, self.params, self.x, self.u),
                steady_string_torque(self.plant, self.params,
                                     [self.programme[0][self.model.inputs.index(n)] for n in self.plant.inputs]))

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
