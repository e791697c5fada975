"""One number per run in the ranking's order: what ``mitigate tune`` minimises.

The ranking compares entries lexicographically with intervals (:mod:`mitigate.benchmark.stats`); a
tuner needs one number per trial.  The declared score keeps the ranking's order: whether the run did
the job first, then every ranked metric (:func:`mitigate.metrics.ranked`) in its rank, each squashed
into [0, 1) and weighted ten times less than the one before::

    score = J + sum_i 10^-i g(x_i)        g(x) = x / (1 + x)

- ``J`` = 0 for a run that did the job (:func:`mitigate.benchmark.stats.did_job`), 1 for one that left
  the programme's bands or stalled, 2 for a failed run (every ``g`` then 1), :data:`NOT_APPLICABLE`
  where the rig cannot host the controller;
- ``x_i`` is the i-th ranked metric made scale-free: a time [s] in stick-slip periods (the run's
  ``period``), a rate [1/s] times the period, a ratio as it is; ``inf`` gives ``g = 1``, NaN (a metric
  the rig does not have) 0; a metric where higher is better enters as ``1 / x``.

Since the terms after ``J`` add up to less than 0.12, a run that did the job always scores below one
that did not; within the job, a difference in what the rig sees outweighs any later term once it
exceeds 10 % of their span, and so on: the ranking's order, up to ties the intervals would declare.
"""

from __future__ import annotations

import math

from mitigate.metrics import get, ranked
from mitigate.record import RunRecord

__all__ = ["run_score", "NOT_APPLICABLE", "describe"]

#: the score of a run the rig could not host
NOT_APPLICABLE = 10.0


def _x(name: str, v: float, period: float) -> float:
    m = get(name)
    if m.unit == "s" and math.isfinite(period) and period > 0:
        v = v / period
    elif m.unit == "1/s" and math.isfinite(period) and period > 0:
        v = v * period
    v = abs(v)
    return 1.0 / v if m.better == "higher" and v > 0 else (math.inf if m.better == "higher" else v)


def _g(x: float) -> float:
    if math.isnan(x):
        return 0.0
    if math.isinf(x):
        return 1.0
    return x / (1.0 + x)


def run_score(r: RunRecord) -> float:
    """The score of one run (module docstring); lower is better."""
    from mitigate.benchmark.stats import did_job
    if not r.applicable:
        return NOT_APPLICABLE
    levels = ranked()
    if r.failed:
        return 2.0 + sum(10.0 ** -i for i in range(1, len(levels) + 1))
    period = r.metrics.get("period", math.nan)
    s = 0.0 if did_job(r) else 1.0
    for i, m in enumerate(levels, start=1):
        s += 10.0 ** -i * _g(_x(m.name, float(r.metrics.get(m.name, math.nan)), float(period)))
    return s


def describe() -> str:
    """The score in one line (stored with tuned results)."""
    return ("mean over the tuning runs of J + sum_i 10^-i x_i / (1 + x_i): J = 0 job done, 1 band or stall, 2 failed; "
            "x_i the ranked metrics in order (" + ", ".join(m.name for m in ranked()) + "), scale-free")
