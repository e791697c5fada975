"""Metrics: every metric declared once (:mod:`.registry`), over one run window (:mod:`.window`).

- :mod:`.registry`: :func:`metric` declares one (name, unit, description, what it needs, whether and
  where it is ranked and shown); everything else asks the registry (:func:`columns`, :func:`ranked`,
  :func:`shown`, :func:`unit`);
- :mod:`.window`: :class:`ClosedLoopWindow` (a closed-loop run after its control start) and
  :class:`SweepWindow` (a sweep point after its settling time);
- :mod:`.quantities`: :class:`MetricOptions` and what a closed-loop window is made of (the stick-slip
  period and its windows, the programmed speed, stuck thresholds, the friction work at a contact);
- :mod:`.closed_loop`: the closed loop's metrics and :func:`closed_loop_metrics`;
- :mod:`.sweep`: a sweep point's metrics.

A new metric is one declaration, anywhere (a plug-in, a test)::

    from mitigate.metrics import metric

    @metric("speed_peak_to_peak", "rad/s", "max - min of the objective body's speed", show=("ranking",))
    def speed_peak_to_peak(w):
        return float(w.speed.max() - w.speed.min())

It is then in :func:`closed_loop_metrics`, ``mitigate run``'s metrics.csv, a sweep's columns (it
needs only the speed), the benchmark's records, entries and tables.  The signal functions the
metrics are built on are in :mod:`mitigate.severity`.
"""

from mitigate.metrics.registry import (COMPARED, METRICS_VERSION, Metric, columns, evaluate, get, in_order, is_count,
                                       is_timing, markdown_table, metric, ranked, registered, shown, unit, units,
                                       unregister)
from mitigate.metrics.quantities import (MetricOptions, contact_work, force_roles, measured_stuck_speed,
                                         programmed_speed, rig_period, solve_time_stats, windows)
from mitigate.metrics.window import ClosedLoopWindow, RunWindow, SweepWindow
from mitigate.metrics import driller as _driller  # noqa: F401 - declares the ranked metrics (they lead every table)
from mitigate.metrics.closed_loop import closed_loop_metrics
from mitigate.metrics import sweep as _sweep  # noqa: F401 - declares the sweep's metrics
from mitigate.severity import (amplitude, moving_severity, rms, severity, stuck_fraction, time_to_suppress,
                               total_variation, windowed_severity)
from models.signals import dominant_frequency

__all__ = ["COMPARED", "METRICS_VERSION", "Metric", "metric", "columns", "evaluate", "get", "in_order", "is_count", "markdown_table", "is_timing", "ranked", "registered", "shown",
           "unit", "units", "unregister", "RunWindow", "ClosedLoopWindow", "SweepWindow", "MetricOptions",
           "closed_loop_metrics", "contact_work", "force_roles", "measured_stuck_speed", "programmed_speed",
           "rig_period", "solve_time_stats", "windows", "severity", "windowed_severity",
           "moving_severity", "time_to_suppress", "stuck_fraction", "amplitude", "rms", "total_variation",
           "dominant_frequency"]
