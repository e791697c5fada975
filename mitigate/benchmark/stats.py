"""Statistics of the benchmark: per (scenario, controller) medians with bootstrap intervals, ranks
with ties, and the tables per actuator class.

Each entry (a controller on a scenario, over its phases and seeds) gives ``n_runs`` and, per metric
the registry shows in ``"entries"`` (:func:`mitigate.metrics.shown`: the ranked ones first), the
median over the runs that DID THE JOB and its 95 % bootstrap interval (:func:`scipy.stats.bootstrap`,
percentile method, a fixed seed: the same runs give the same interval); the registry's counts are
summed over those runs.  A run did the job when it finished (no failure, no divergence) and kept the
programme (:func:`did_job`: the ``band_violation`` flag is 0: the objective body's speed and every
programmed normal force inside their bands over the residual window and over every moving band window,
and the body not stalled).  Any other run is a FAILED run of the benchmark: it is counted, never a
median entry.  The timing metrics (this machine's wall clock) are summarised apart (``timings``).

**Ranks.**  Within a table (a scenario, over a set of controllers), A is *clearly better* than B when
A did the job in every run and B did not, or, both alike, in the registry's ranking order
(:func:`mitigate.metrics.ranked`: what the rig sees, the time to suppress, the string's peak torque,
the drive's peak load, the set-point's excursion, the effort): at the first ranked metric whose
intervals do not overlap, A's lies entirely on the better side of B's.  Two entries that both failed
runs are ordered by their failed runs only (fewer is better).  A controller's rank is one plus the
number of controllers clearly better than it: controllers whose intervals overlap share a rank (a tie
is declared, not broken by a decimal).  An entry with a failed run is never counted first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import numpy as np

from mitigate.metrics import Metric, ranked, registered, shown
from mitigate.record import RunRecord
from mitigate.tunables import ACTUATOR_CLASSES

__all__ = ["interval", "summarise", "rank", "class_tables", "Entry", "clearly_better", "deciding", "entry_metrics",
           "did_job", "timing_metrics"]

CONFIDENCE = 0.95


def entry_metrics() -> tuple[str, ...]:
    """The metrics an entry summarises (median and interval): the registry's ``"entries"``."""
    return tuple(m.name for m in shown("entries"))


def timing_metrics() -> tuple[str, ...]:
    """The timing metrics an entry summarises apart (medians of this machine's wall clock)."""
    return tuple(m.name for m in registered() if m.timing and m.kind == "value")


def did_job(r: RunRecord) -> bool:
    """The run finished and kept the programme (its ``band_violation`` flag is 0)."""
    return r.applicable and not r.failed and not _flag(r, "band_violation")


def interval(values, *, seed: int = 0) -> tuple[float, float, float]:
    """``(median, ci_low, ci_high)`` of ``values``: the median and its 95 % percentile bootstrap
    interval (2000 resamples, seeded).  ``inf`` values (never suppressed) count as the largest; NaN
    values are dropped; one value or equal values give a zero-width interval; none: NaNs."""
    from scipy.stats import bootstrap

    v = np.asarray([x for x in values if not (isinstance(x, float) and math.isnan(x))], float)
    if v.size == 0:
        return (math.nan,) * 3
    med = float(np.median(v))
    if v.size == 1 or np.all(v == v[0]):
        return med, float(v[0]) if v.size == 1 else med, float(v[0]) if v.size == 1 else med
    finite = v[np.isfinite(v)]
    big = 1e6 * (float(np.max(np.abs(finite))) + 1.0) if finite.size else 1.0     # stands in for inf
    fin = np.where(np.isinf(v), np.sign(v) * big, v)
    res = bootstrap((fin,), np.median, confidence_level=CONFIDENCE, n_resamples=2000, method="percentile",
                    random_state=np.random.default_rng(seed))
    back = lambda x: float(math.copysign(math.inf, x)) if abs(x) >= big / 2 else float(x)   # noqa: E731
    return med, back(res.confidence_interval.low), back(res.confidence_interval.high)


@dataclass
class Entry:
    """One controller on one scenario, over its runs (see :func:`summarise`)."""

    scenario: str
    controller: str
    kind: str
    klass: str = ""
    applicable: bool = True
    n_runs: int = 0
    n_failed: int = 0
    n_violations: int = 0
    n_force_violations: int = 0
    n_speed_violations: int = 0
    n_suppressed: int = 0
    n_stalled: int = 0
    metrics: dict = field(default_factory=dict)        # key -> {"median", "ci_low", "ci_high"}
    timings: dict = field(default_factory=dict)        # timing metric -> median (this machine's wall clock)
    counts: dict = field(default_factory=dict)
    messages: list = field(default_factory=list)
    rank: int | None = None
    class_rank: int | None = None
    options: dict = field(default_factory=dict)

    @property
    def job_done(self) -> bool:
        """Every run did the job (:func:`did_job`): none failed, none left the programme's bands or stalled."""
        return self.applicable and self.n_runs > 0 and self.n_failed + self.n_violations == 0

    @property
    def n_bad(self) -> int:
        """Runs that did not do the job (failed, left a band, stalled)."""
        return self.n_failed + self.n_violations

    def value(self, key: str, what: str = "median") -> float:
        return float(self.metrics.get(key, {}).get(what, math.nan))

    def as_dict(self) -> dict[str, Any]:
        return {"scenario": self.scenario, "controller": self.controller, "kind": self.kind, "class": self.klass,
                "applicable": self.applicable, "n_runs": self.n_runs, "n_failed": self.n_failed,
                "n_violations": self.n_violations, "n_force_violations": self.n_force_violations,
                "n_speed_violations": self.n_speed_violations, "n_stalled": self.n_stalled,
                "n_suppressed": self.n_suppressed, "job_done": self.job_done, "rank": self.rank,
                "class_rank": self.class_rank, "metrics": self.metrics, "counts": self.counts,
                "messages": self.messages[:5], "options": self.options}


def _flag(r: RunRecord, name: str) -> int:
    v = r.value(name)
    return int(v) if math.isfinite(v) else 0


def summarise(records: Iterable[RunRecord], kinds: Mapping[str, str], *, seed: int = 0) -> dict[tuple, Entry]:
    """``{(scenario, controller): Entry}`` from run records (:func:`mitigate.benchmark.execute.run_task`)."""
    groups: dict[tuple, list[RunRecord]] = {}
    for r in records:
        groups.setdefault((r.run.scenario, r.run.controller), []).append(r)
    counts = [m.name for m in registered() if m.kind == "count" and not m.timing]
    out = {}
    for (s, c), recs in groups.items():
        e = Entry(s, c, kinds.get(c, ""), options=dict(recs[0].run.options))
        app = [r for r in recs if r.applicable]
        if not app:
            e.applicable = False
            e.messages = [recs[0].message]
            out[(s, c)] = e
            continue
        e.klass = next((r.actuator_class for r in app if r.actuator_class), "")
        e.n_runs = len(app)
        ok = [r for r in app if not r.failed]
        e.n_failed = len(app) - len(ok)
        e.n_violations = sum(_flag(r, "band_violation") for r in ok)
        e.n_force_violations = sum(_flag(r, "force_violation") for r in ok)
        e.n_speed_violations = sum(_flag(r, "speed_violation") for r in ok)
        e.n_stalled = sum(_flag(r, "stalled") for r in ok)
        done = [r for r in ok if did_job(r)]
        e.n_suppressed = sum(_flag(r, "suppressed") for r in done)
        e.messages = sorted({r.message for r in app if r.failed or r.message not in ("ok", "")})
        for key in entry_metrics():
            med, lo, hi = interval([r.value(key) for r in done], seed=seed)
            e.metrics[key] = {"median": med, "ci_low": lo, "ci_high": hi}
        for key in timing_metrics():
            v = [x for r in ok if math.isfinite(x := r.value(key))]
            e.timings[key] = float(np.median(v)) if v else math.nan
        e.counts = {k: int(sum(v for r in ok if math.isfinite(v := r.value(k)))) for k in counts}
        out[(s, c)] = e
    return out


def _better(a: Entry, b: Entry, m: Metric) -> bool:
    """A's interval of metric ``m`` lies entirely on the better side of B's."""
    if m.better == "lower":
        return m.better_than(a.value(m.name, "ci_high"), b.value(m.name, "ci_low"))
    return m.better_than(a.value(m.name, "ci_low"), b.value(m.name, "ci_high"))


def clearly_better(a: Entry, b: Entry) -> bool:
    """The order of the module docstring: the job done, then the registry's ranked metrics in order."""
    if a.job_done != b.job_done:
        return a.job_done
    if not a.job_done:
        return a.n_bad < b.n_bad
    for m in ranked():
        if _better(a, b, m):
            return True
        if _better(b, a, m):
            return False
    return False


def deciding(a: Entry, b: Entry) -> str:
    """What decides between two entries in the ranking's order: ``"job done"`` (one did the job in every
    run, the other not), ``"bad runs"`` (neither did; fewer failed runs), the first ranked metric whose
    intervals separate them, or ``"tie"``."""
    if a.job_done != b.job_done:
        return "job done"
    if not a.job_done:
        return "bad runs" if a.n_bad != b.n_bad else "tie"
    for m in ranked():
        if _better(a, b, m) or _better(b, a, m):
            return m.name
    return "tie"


def rank(entries: Iterable[Entry]) -> dict[str, int]:
    """``{controller: rank}``: one plus the number of entries clearly better (ties share a rank).

    "Clearly better" compares two entries at the first ranked column whose intervals do not overlap,
    and that relation need not be transitive: A beats B on one column, B beats C on another, C beats A
    on a third (measured on a tuned scenario: no entry was first).  Entries on such a cycle (a strongly
    connected component of the relation) tie: only entries outside their cycle count against them."""
    from scipy.sparse.csgraph import connected_components

    es = [e for e in entries if e.applicable]
    if not es:
        return {}
    beats = np.array([[i != j and clearly_better(a, b) for j, b in enumerate(es)] for i, a in enumerate(es)], bool)
    _, cycle = connected_components(beats, directed=True, connection="strong")
    return {b.controller: 1 + int(sum(beats[i, j] and cycle[i] != cycle[j] for i in range(len(es))))
            for j, b in enumerate(es)}


def class_tables(entries: Mapping[tuple, Entry], scenarios, controllers) -> dict[str, list[dict]]:
    """Per actuator class (and ``"overall"``), one row per controller: its mean rank over the
    scenarios where it ran, the number of scenarios it ranks first (ties included), how often it did
    the job, and the medians over scenarios of its per-scenario medians (ranked and effort metrics).
    A class's table ranks its controllers among themselves and the programme alone (class "none")."""
    out = {}
    for klass in ("overall",) + tuple(c for c in ACTUATOR_CLASSES if c != "none"):
        members = [c for c in controllers
                   if klass == "overall" or any(entries[(s, c)].klass in (klass, "none")
                                                for s in scenarios if entries[(s, c)].applicable)]
        ranks: dict[tuple, int] = {}
        for s in scenarios:
            es = [entries[(s, c)] for c in members if entries[(s, c)].applicable
                  and (klass == "overall" or entries[(s, c)].klass in (klass, "none"))]
            for c, r in rank(es).items():
                ranks[(s, c)] = r
        rows = []
        for c in members:
            mine = [s for s in scenarios if (s, c) in ranks]
            if not mine:
                continue
            es = [entries[(s, c)] for s in mine]
            row: dict[str, Any] = {"controller": c, "kind": es[0].kind, "class": es[0].klass, "scenarios": len(mine),
                                   "mean_rank": float(np.mean([ranks[(s, c)] for s in mine])),
                                   "first": int(sum(ranks[(s, c)] == 1 and entries[(s, c)].job_done for s in mine)),
                                   "job_done": int(sum(e.job_done for e in es)),
                                   "n_runs": int(sum(e.n_runs for e in es)), "failed": int(sum(e.n_failed for e in es)),
                                   "violations": int(sum(e.n_violations for e in es)),
                                   "force_violations": int(sum(e.n_force_violations for e in es)),
                                   "speed_violations": int(sum(e.n_speed_violations for e in es)),
                                   "stalled": int(sum(e.n_stalled for e in es)),
                                   "fallbacks": int(sum(e.counts.get("controller_fallbacks", 0) for e in es))}
            for key in entry_metrics():
                v = np.array([e.value(key) for e in es], float)
                v = v[~np.isnan(v)]
                row[key] = float(np.median(v)) if v.size else math.nan
            row["ranks"] = {s: ranks[(s, c)] for s in mine}
            rows.append(row)
        rows.sort(key=lambda r: (r["mean_rank"], r["controller"]))
        if any(r["class"] == klass for r in rows) or klass == "overall":
            out[klass] = rows
    return out
