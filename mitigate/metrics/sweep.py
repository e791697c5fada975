"""The metrics of a sweep point, each one declaration over a :class:`SweepWindow` (the point's run after
the settling time; seed 002 Sect. 9.8's maps).  The metrics that need only the speed (``sss``,
``stuck_fraction``, ``mean_speed``: :mod:`mitigate.metrics.closed_loop`) are a sweep's columns too."""

from __future__ import annotations

from mitigate.metrics.registry import metric
from mitigate.metrics.window import SweepWindow
from mitigate.severity import amplitude as half_peak_to_peak
from mitigate.severity import severity as own_mean_severity
from models.signals import dominant_frequency

__all__ = ["AMPLITUDE_UNIT"]

_SWEEP = ("sweep_point",)
#: the amplitude's unit: that of the sweep's ``amplitude_of`` state (rad/s for a speed, rad for a twist)
AMPLITUDE_UNIT = "as amplitude_of"


@metric("amplitude", AMPLITUDE_UNIT, "half the peak-to-peak of the sweep's amplitude state (in that state's unit)",
        needs=_SWEEP, show=("map",), header="stick-slip amplitude")
def amplitude(w: SweepWindow) -> float:
    return half_peak_to_peak(w.amplitude_signal)


@metric("severity", "-", "the literature's severity (max - min) / (2 mean) of the sweep's speed, without a stuck rule "
        "(inf for a body stopped throughout)", needs=_SWEEP, show=("map",), header="severity SSS")
def severity(w: SweepWindow) -> float:
    return own_mean_severity(w.speed)


@metric("frequency", "Hz", "dominant frequency of the speed, of a limit cycle only (else NaN: the spectrum of "
        "rounding noise)", needs=_SWEEP, show=("map",), header="dominant frequency")
def frequency(w: SweepWindow) -> float:
    return dominant_frequency(w.speed, w.dt) if w.limit_cycle else float("nan")


@metric("growth", "-", "the late half's amplitude over the early half's (1 without any swing)", needs=_SWEEP)
def growth(w: SweepWindow) -> float:
    return float(w.growth)


@metric("limit_cycle", "-", "1 for a sustained swing: the amplitude above the threshold and the late half swinging "
        "at least 80 % of the early half", needs=_SWEEP, kind="flag")
def limit_cycle(w: SweepWindow) -> float:
    return float(w.limit_cycle)
