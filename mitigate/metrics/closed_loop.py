"""The metrics of a closed-loop run, each one declaration over a :class:`ClosedLoopWindow`.

Of the objective body's TRUE speed (rig3: R1, "the bit") after the control start: what stays
(normalised by the PROGRAMMED speed: a run's own mean would reward a controller that runs the bit
fast and is 0/0 for a stuck bit), how fast it goes, how far above the programme, whether the run kept
the programme's bands; then effort, the friction work split by what a contact is for
(:func:`mitigate.metrics.quantities.force_roles`: the process load gives ``cutting_work``, a brake
``pin_work``), the literature's severity ``sss`` kept for continuity, the controller's and the
estimator's counts and call times.  Declaration order is the order of every table and CSV.
"""

from __future__ import annotations

import math

import numpy as np

from mitigate.metrics.registry import evaluate, metric
from mitigate.metrics.quantities import MetricOptions
from mitigate.metrics.window import ClosedLoopWindow
from mitigate.severity import rms, severity, stuck_fraction, time_to_suppress, total_variation
from models.status import Status

__all__ = ["closed_loop_metrics"]

_CTRL = ("controlled",)
_TABLES = ("ranking", "scenario")


def closed_loop_metrics(result, scenario, options: MetricOptions | None = None, uncontrolled=None) -> dict[str, float]:
    """Every closed-loop metric of the registry on a run after its control start, from the TRUE plant
    trajectory (only ``stuck_fraction_measured`` uses a measured channel).

    Parameters
    ----------
    result : mitigate.closedloop.ClosedLoopResult
    scenario : its scenario (the plant's model and true parameters, the programme)
    options : :class:`MetricOptions` (default: every window and threshold from the scenario)
    uncontrolled : the uncontrolled run's objective speed from t = 0 at the run's samples [rad/s]
        (:class:`ClosedLoopWindow`; the benchmark's), or None

    Returns
    -------
    dict : ``{name: value}`` of :func:`mitigate.metrics.registry.columns` ``("closed_loop")`` (units:
    :func:`mitigate.metrics.registry.unit`), with the per-input entries ``normal_force_mean_<input>``
    [N] and ``normal_force_ratio_<input>`` [-] of every servo input; ``period`` and
    ``residual_window`` [s] say which windows were used.
    """
    return evaluate(ClosedLoopWindow(result, scenario, options, uncontrolled))


# --------------------------------------------------------------------------- ranked: what stays, how fast
@metric("residual_severity", "-", "the oscillation that stays in the TRUE speed (not ranked: below what a rig's "
        "sensors resolve, measured_severity is): (max - min) / (2 w_prog) of the objective body's true speed over the "
        "residual window (the last few stick-slip periods); a body stuck throughout counts 1", needs=_CTRL,
        show=_TABLES + ("terminal", "report", "bars"), header="true what stays", percent=True)
def residual_severity(w: ClosedLoopWindow) -> float:
    return severity(w.tail, w.ref, w.stuck_speed)


@metric("time_to_suppress", "s", "from the switch-on to the start of the first moving window from which the moving "
        "severity of the TRUE speed stays below the threshold (0: never above; inf: never suppressed)", needs=_CTRL,
        show=("bars",), header="true t suppress", inf="never")
def time_to_suppress_(w: ClosedLoopWindow) -> float:
    return time_to_suppress(w.speed, w.dt, w.moving_window, w.options.suppress_threshold, w.ref, w.stuck_speed)


# --------------------------------------------------------------------------- shown beside the ranks
@metric("peak_overshoot", "-", "what the controller added to the speed's peak: how far the true speed's peak after "
        "the switch-on rises above the peak of the uncontrolled run over the same window (the slip under way at the "
        "switch-on and the stick-slip cycle are the rig's), over the programme; 0 when it stays below",
        needs=_CTRL + ("programmed_speed", "uncontrolled_run"), show=_TABLES, header="overshoot", percent=True)
def peak_overshoot(w: ClosedLoopWindow) -> float:
    unc = w.uncontrolled[np.isfinite(w.uncontrolled)]
    if unc.size == 0:
        return float("nan")
    return max(0.0, (float(np.max(w.speed)) - max(float(np.max(unc)), w.ref)) / abs(w.ref))


@metric("setpoint_variation", "1/s", "effort: total variation of every commanded input per second, each scaled by "
        "its programme (a servo by its range)", needs=_CTRL, rank=6, show=_TABLES + ("terminal", "report", "bars"),
        header="set-point var.")
def setpoint_variation(w: ClosedLoopWindow) -> float:
    m, prog, model = w.mask, w.programme, w.model
    tv = 0.0
    for name, cmd in w.result.commands.items():
        j = model.inputs.index(name)
        c = np.asarray(cmd, float)[m]
        own = float(np.max(np.abs(c))) if c.size else 0.0       # last resort: the command's own range
        if name in model.servo_inputs:
            a = model.actuator(name)
            scale = float(a.n_max) if a is not None and a.n_max > 0 else max(float(np.max(np.abs(prog[:, j]))), own)
        else:
            scale = max(float(np.mean(np.abs(prog[:, j]))), abs(w.ref) if w.ref else 0.0) or own
        tv += total_variation(c) / scale if scale > 0 else 0.0
    return tv / w.span


@metric("drive_energy", "J", "effort: the DC motor's sum |V i| dt, a torque drive's sum |tau w| dt (NaN for a "
        "speed drive)", needs=_CTRL, show=_TABLES + ("bars",), header="drive energy")
def drive_energy(w: ClosedLoopWindow) -> float:
    pm = w.plant
    power = pm.drive.power(pm, w.params, w.x, w.u)      # the drive kind says what it draws (None: unknown)
    return float(np.sum(np.abs(power)) * w.dt) if power is not None else float("nan")


@metric("pin_work", "J", "brake wear: friction work at the contacts whose normal force is an input with a zero "
        "programme, only the part the normal force causes", needs=_CTRL, show=("ranking", "report", "bars"),
        header="brake wear")
def pin_work(w: ClosedLoopWindow) -> float:
    return w.friction_work["brake"]


@metric("normal_force_ratio", "-", "the mean applied normal force over its programme, the servo input farthest from "
        "it (on a log scale)", needs=_CTRL + ("servo",), show=("ranking",), header="force / programme")
def normal_force_ratio(w: ClosedLoopWindow) -> float:
    ratios = [r for _n, r in w.normal_forces.values() if math.isfinite(r)]
    return max(ratios, key=lambda r: abs(math.log(r)) if r > 0 else math.inf) if ratios else float("nan")


@metric("cutting_work_ratio", "-", "the friction work at the process load over the work the same speeds would do "
        "at the programmed force", needs=_CTRL + ("process_force",), show=("entries",))
def cutting_work_ratio(w: ClosedLoopWindow) -> float:
    f = w.friction_work
    return f["process"] / f["process_programmed"] if f["process_programmed"] > 0 else float("nan")


@metric("speed_ratio", "-", "mean speed over the programmed speed", needs=_CTRL + ("programmed_speed",),
        show=("entries",))
def speed_ratio(w: ClosedLoopWindow) -> float:
    return float(np.mean(w.speed)) / w.ref


@metric("residual_speed_ratio", "-", "mean speed over the residual window over the programmed speed (the bit turning "
        "at its programme once the transient is over)", needs=_CTRL + ("programmed_speed",), show=("ranking",),
        header="speed / programme")
def residual_speed_ratio(w: ClosedLoopWindow) -> float:
    return float(np.mean(w.tail)) / w.ref


# --------------------------------------------------------------------------- the programme's bands
def _worst(ratios) -> float:
    """The ratio farthest from 1 on a log scale (NaN for none)."""
    r = [float(x) for x in ratios if math.isfinite(x)]
    return max(r, key=lambda x: abs(math.log(x)) if x > 0 else math.inf) if r else float("nan")


def _force_ratios(w: ClosedLoopWindow) -> list[float]:
    """Every programmed normal force's mean over the residual window and over every moving band
    window, each over its programme's mean there."""
    out = []
    for name in w.plant.servo_inputs:
        u = w.u[:, w.plant.inputs.index(name)]
        p = w.programme[:, w.model.inputs.index(name)]
        if not float(np.mean(p)) > 0:
            continue                    # a brake (zero programme) has no band
        out.append(float(np.mean(u[-w.n_res:])) / float(np.mean(p[-w.n_res:])))
        mu, mp = w.moving_mean(u), w.moving_mean(p)
        out += list(mu[mp > 0] / mp[mp > 0])
    return out


def _speed_ratios(w: ClosedLoopWindow) -> tuple[list[float], list[float]]:
    """(the objective body's mean speed over the residual window, over every moving band window), each
    over the programme's mean there."""
    if not w.ref:
        return [], []
    ms, mp = w.moving_mean(w.speed), w.moving_mean(w.speed_programme)
    return [residual_speed_ratio(w)], list(ms[mp != 0] / mp[mp != 0])


@metric("force_ratio_worst", "-", "the programmed normal force's mean over the residual window or over any moving "
        "band window (MetricOptions.band_periods, from band_after periods after the switch-on), over its programme "
        "there: the one farthest from 1", needs=_CTRL + ("servo",), show=("entries",))
def force_ratio_worst(w: ClosedLoopWindow) -> float:
    return _worst(_force_ratios(w))


@metric("speed_ratio_worst", "-", "the objective body's mean speed over the residual window or over any moving band "
        "window, over the programme there: the one farthest from 1", needs=_CTRL + ("programmed_speed",),
        show=("entries",))
def speed_ratio_worst(w: ClosedLoopWindow) -> float:
    return _worst(sum(_speed_ratios(w), []))


@metric("force_violation", "-", "1 if a programmed normal force's mean over the residual window or over any moving "
        "band window left MetricOptions.force_band around its programme", needs=_CTRL, kind="flag")
def force_violation(w: ClosedLoopWindow) -> int:
    lo, hi = w.options.force_band
    return int(any(not (lo <= r <= hi) for r in _force_ratios(w) if math.isfinite(r)))


@metric("speed_violation", "-", "1 if the objective body's mean speed over the residual window left "
        "MetricOptions.speed_band, or over any moving band window moving_speed_band, around the programme",
        needs=_CTRL, kind="flag")
def speed_violation(w: ClosedLoopWindow) -> int:
    tail, moving = _speed_ratios(w)
    o = w.options
    return int(any(not (lo <= r <= hi) for rs, (lo, hi) in ((tail, o.speed_band), (moving, o.moving_speed_band))
                   for r in rs if math.isfinite(r)))


@metric("stalled", "-", "1 if the objective body is stuck for more than MetricOptions.stuck_limit of the residual "
        "window (the bit does not drill)", needs=_CTRL, kind="flag")
def stalled(w: ClosedLoopWindow) -> int:
    return int(stuck_fraction(w.tail, w.stuck_speed) > w.options.stuck_limit)


@metric("band_violation", "-", "1 if the run left a band or stalled: it did not drill as programmed (a failed run of "
        "the benchmark)", needs=_CTRL, kind="flag")
def band_violation(w: ClosedLoopWindow) -> int:
    return int(force_violation(w) or speed_violation(w) or stalled(w))


# --------------------------------------------------------------------------- the rest of the run's physics
@metric("residual_stuck_fraction", "-", "fraction of the residual window the body is stuck", needs=_CTRL)
def residual_stuck_fraction(w: ClosedLoopWindow) -> float:
    return stuck_fraction(w.tail, w.stuck_speed)


@metric("speed_error_rms", "rad/s", "RMS of speed - programmed speed", needs=_CTRL)
def speed_error_rms(w: ClosedLoopWindow) -> float:
    return rms(w.speed - w.speed_programme)


@metric("cutting_work", "J", "friction work at the process load (the weight on bit) at the applied force",
        needs=_CTRL + ("process_force",))
def cutting_work(w: ClosedLoopWindow) -> float:
    return w.friction_work["process"]


@metric("normal_force_mean_{input}", "N", "mean applied normal force of each servo input", needs=_CTRL + ("servo",),
        per_input=True)
def normal_force_mean(w: ClosedLoopWindow) -> dict[str, float]:
    return {name: v[0] for name, v in w.normal_forces.items()}


@metric("normal_force_ratio_{input}", "-", "mean applied normal force of each servo input over its mean programme "
        "(NaN for a zero programme)", needs=_CTRL + ("servo",), per_input=True)
def normal_force_ratio_each(w: ClosedLoopWindow) -> dict[str, float]:
    return {name: v[1] for name, v in w.normal_forces.items()}


@metric("mean_pin_force", "N", "mean applied normal force over every servo input (0 without one)", needs=_CTRL)
def mean_pin_force(w: ClosedLoopWindow) -> float:
    cols = [w.u[:, w.plant.inputs.index(n)] for n in w.plant.servo_inputs]
    return float(np.mean(np.concatenate(cols))) if cols else 0.0


@metric("sss", "-", "the literature's stick-slip severity (max - min) / (2 mean) of the speed (a body stuck "
        "throughout counts 1)")
def sss(w) -> float:
    return severity(w.speed, stuck=w.stuck_speed)


@metric("sss_window_mean", "-", "mean of sss over non-overlapping windows (MetricOptions.window_periods)",
        needs=_CTRL)
def sss_window_mean(w: ClosedLoopWindow) -> float:
    return float(np.mean(w.windowed_severity))


@metric("sss_window_max", "-", "largest sss over non-overlapping windows", needs=_CTRL)
def sss_window_max(w: ClosedLoopWindow) -> float:
    return float(np.max(w.windowed_severity))


@metric("sss_final", "-", "sss over the last non-overlapping window", needs=_CTRL)
def sss_final(w: ClosedLoopWindow) -> float:
    return severity(w.speed[-w.n_win:], stuck=w.stuck_speed)


@metric("sss_moving_mean", "-", "mean of the moving severity (MetricOptions.moving_periods)", needs=_CTRL)
def sss_moving_mean(w: ClosedLoopWindow) -> float:
    return float(np.mean(w.moving_severity))


@metric("sss_moving_final", "-", "the last moving severity", needs=_CTRL)
def sss_moving_final(w: ClosedLoopWindow) -> float:
    return float(w.moving_severity[-1])


@metric("stuck_fraction", "-", "fraction of the time the body is stuck (|speed| at or below the stuck speed)",
        show=("bars", "map"), header="fraction stuck")
def stuck_fraction_(w) -> float:
    return stuck_fraction(w.speed, w.stuck_speed)


@metric("stuck_fraction_measured", "-", "the same from the measured speed, against half an encoder tick per DAQ "
        "period (MetricOptions.stuck_speed_measured)", needs=_CTRL + ("measured_speed",))
def stuck_fraction_measured(w: ClosedLoopWindow) -> float:
    ch, thr = w.measured
    return stuck_fraction(w.result.y[ch][w.mask], thr)


@metric("mean_speed", "rad/s", "mean speed")
def mean_speed(w) -> float:
    return float(np.mean(w.speed))


@metric("rms_twist", "rad", "RMS of the rig's first spring twist", needs=_CTRL + ("twist",))
def rms_twist(w: ClosedLoopWindow) -> float:
    return rms(next(iter(w.result.twists.values()))[w.mask])


@metric("torque_std", "N m", "standard deviation of the first torque sensor's channel",
        needs=_CTRL + ("torque_sensor",))
def torque_std(w: ClosedLoopWindow) -> float:
    return float(np.std(w.result.y[w.torque_channel][w.mask]))


@metric("period", "s", "the stick-slip period that set the windows", needs=_CTRL)
def period(w: ClosedLoopWindow) -> float:
    return w.period


@metric("residual_window", "s", "the residual window's length", needs=_CTRL)
def residual_window(w: ClosedLoopWindow) -> float:
    return w.n_res * w.dt


# --------------------------------------------------------------------------- the controller's calls
def _ms(which: str, stat: str):
    return lambda w: 1e3 * w.call_times[which][stat]


for _which, _what in (("solve", "every controller call"), ("plan", "the planning calls")):
    for _stat, _word in (("median", "median"), ("p95", "95th percentile"), ("max", "largest")):
        metric(f"{_which}_{_stat}_ms", "ms", f"{_word} wall time of {_what}", needs=_CTRL, timing=True,
               show=(("bars",) if (_which, _stat) == ("plan", "median") else ()),
               header=f"{_word} {_which} time")(_ms(_which, _stat))


@metric("plan_calls", "-", "controller calls that planned (not holds)", needs=_CTRL, kind="count")
def plan_calls(w: ClosedLoopWindow) -> int:
    return int(np.sum(w.plan_calls))


def _count(which: str, key: str):
    return lambda w: int(getattr(w.result, f"{which}_counts").get(key, 0))


for _key, _what in (("steps", "calls"), ("failures", "calls that failed"),
                    ("fallbacks", "calls answered by its documented fallback")):
    metric(f"controller_{_key}", "-", f"the controller's {_what}", needs=_CTRL, kind="count")(_count("controller", _key))
metric("controller_deadline_misses", "-", "the controller's calls later than their real-time budget (the fallback "
       "acted; depends on the machine's load)", needs=_CTRL, kind="count", timing=True)(
    _count("controller", "deadline_misses"))
for _key, _what in (("failures", "updates that failed"), ("fallbacks", "updates answered by its fallback"),
                    ("dropouts", "samples with a measurement missing")):
    metric(f"estimator_{_key}", "-", f"the estimator's {_what}", needs=_CTRL, kind="count")(_count("estimator", _key))


@metric("diverged", "-", "1 if the plant left its physical bounds", needs=_CTRL, kind="flag")
def diverged(w: ClosedLoopWindow) -> int:
    return int(w.result.status is Status.DIVERGED)
