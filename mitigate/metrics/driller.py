"""The benchmark's ranked metrics: what a rig can measure, in the order a driller cares about.

The oscillation is ranked on the objective body's speed AS THE RIG'S SENSORS MEASURE IT (its
encoder's whole counts per DAQ sample, or its speed sensor's noisy reading: the closed loop's
measured channel), never finer than the channel resolves: below the sensor's ripple floor
(:func:`models.sensors.ripple_floor`) a run counts as suppressed, and suppressed runs tie.  After
whether and how fast the stick-slip goes, the loads that damage hardware (the string's peak torque,
the drive's peak current or torque against its limit, the set-point's excursion above the programme),
then the effort (:func:`mitigate.metrics.closed_loop.setpoint_variation`, rank 6).  Whether the job
was done (the run kept the programme's bands and did not stall or fail) comes before all of them
(:mod:`mitigate.benchmark.stats`).  The true-speed residual (``residual_severity``) is reported
beside, not ranked.

Declared before :mod:`mitigate.metrics.closed_loop`: the ranked metrics lead every table.
"""

from __future__ import annotations

import math

import numpy as np

from mitigate.metrics.registry import metric
from mitigate.metrics.window import ClosedLoopWindow
from mitigate.severity import severity, time_to_suppress

__all__ = ["measured_severity", "speed_floor", "suppressed", "measured_time_to_suppress", "string_torque_peak",
           "drive_load_peak", "setpoint_excursion"]

_MEASURED = ("controlled", "programmed_speed", "measured_speed")
_TABLES = ("ranking", "scenario")


#: relative tolerance of "at the floor": a ripple of exactly two counts computes to the floor up to rounding
_AT_FLOOR = 1e-9


def _tail(w: ClosedLoopWindow) -> np.ndarray:
    v = w.measured_speed[-w.n_res:]
    return v[np.isfinite(v)]


@metric("speed_floor", "-", "the resolution floor of what the rig sees: the peak-to-peak ripple the objective body's "
        "speed channel cannot tell from a steady speed over the residual window (two encoder counts per DAQ sample, "
        "or a speed sensor's noise band), over 2 w_prog", needs=_MEASURED, show=("entries",), header="floor",
        percent=True)
def speed_floor(w: ClosedLoopWindow) -> float:
    return w.ripple_floor(len(_tail(w))) / (2 * abs(w.ref))


@metric("measured_severity", "-", "what the rig sees: (max - min) / (2 w_prog) of the objective body's MEASURED speed "
        "over the residual window, never below speed_floor (a run at the floor is suppressed as far as the rig can "
        "tell; suppressed runs tie); a body the channel reads stuck throughout counts 1", needs=_MEASURED, rank=1,
        show=_TABLES + ("terminal", "report", "bars"), header="rig sees", percent=True)
def measured_severity(w: ClosedLoopWindow) -> float:
    tail = _tail(w)
    if tail.size < 2:
        return float("nan")
    sev, floor = severity(tail, w.ref, w.measured[1]), speed_floor(w)
    return floor if sev <= floor * (1 + _AT_FLOOR) else sev


@metric("suppressed", "-", "1 if what the rig sees is at its floor and the body has not stalled (stuck for more "
        "than MetricOptions.stuck_limit of the residual window): the stick-slip is suppressed as far as the rig's "
        "sensors can tell", needs=_MEASURED, kind="flag")
def suppressed(w: ClosedLoopWindow) -> int:
    from mitigate.severity import stuck_fraction
    stalled = stuck_fraction(w.tail, w.stuck_speed) > w.options.stuck_limit
    return int(measured_severity(w) <= speed_floor(w) and not stalled)


@metric("measured_time_to_suppress", "s", "from the switch-on to the start of the first moving window from which "
        "the moving severity of the MEASURED speed stays at or below the larger of the threshold and the sensor's "
        "floor over a moving window (0: never above; inf: never suppressed)", needs=_MEASURED, rank=2,
        show=_TABLES + ("terminal", "report", "bars"), header="t suppress", inf="never")
def measured_time_to_suppress(w: ClosedLoopWindow) -> float:
    n = max(1, int(round(w.moving_window / w.dt)))
    floor = w.ripple_floor(n) / (2 * abs(w.ref))
    # "at or below" (to rounding): time_to_suppress counts a window as suppressed strictly below its threshold
    # (a floor of 0, ideal angles, still lets a window of zero severity count)
    threshold = max(w.options.suppress_threshold, floor * (1 + _AT_FLOOR) + 1e-300)
    return time_to_suppress(w.measured_speed, w.dt, w.moving_window, threshold, w.ref, w.measured[1])


@metric("string_torque_peak", "-", "hardware: the largest torque a spring of the string carries after the switch-on, "
        "over the largest it carries in steady sliding at the programme (the plant's true torque)",
        needs=("controlled", "twist"), rank=3, show=_TABLES, header="string torque peak")
def string_torque_peak(w: ClosedLoopWindow) -> float:
    T, steady = w.string_torque
    if T.size == 0:
        return float("nan")
    peak = float(np.max(np.abs(T)))
    scale = steady if math.isfinite(steady) and steady > 0 else float(np.mean(np.max(np.abs(T), axis=1)))
    return peak / scale if scale > 0 else float("nan")


@metric("drive_load_peak", "-", "hardware: the peak of what the rig limits over its limit after the switch-on (a DC "
        "motor's |armature current| over i_max, a torque drive's |torque| over torque_max; NaN for a speed drive or "
        "a drive without a stated limit); above 1 the run exceeded its drive's limit (the report's verdict says so)", needs=("controlled",), rank=4, show=_TABLES, header="drive load peak",
        percent=True)
def drive_load_peak(w: ClosedLoopWindow) -> float:
    pm = w.plant
    return pm.drive.peak_ratio(pm, w.params, w.x, w.u)     # the drive kind says what it limits (none: NaN)


@metric("setpoint_excursion", "-", "hardware: the largest command above its programme after the switch-on, over the "
        "programme, of every input the loop commands with a positive programme (the drive's set-point, a "
        "programmed normal force); 0 if no command exceeds its programme", needs=("controlled",), rank=5,
        show=_TABLES, header="set-point excursion", percent=True)
def setpoint_excursion(w: ClosedLoopWindow) -> float:
    worst = 0.0
    for name, cmd in w.result.commands.items():
        prog = w.programme[:, w.model.inputs.index(name)]
        c = np.asarray(cmd, float)[w.mask]
        ok = np.isfinite(c) & (prog > 0)
        if np.any(ok):
            worst = max(worst, float(np.max((c[ok] - prog[ok]) / prog[ok])))
    return worst
