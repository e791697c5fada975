"""The metric registry: every metric of the workbench is declared once, here or by a plug-in.

A metric is one small function over one run window (:mod:`mitigate.metrics.window`) and its
declaration::

    @metric("residual_severity", "-", "what stays: (max - min) / (2 w_prog) over the residual window",
            needs=("controlled",), rank=1, show=("ranking", "scenario", "terminal", "report", "bars"),
            header="what stays", percent=True)
    def residual_severity(w):
        return severity(w.tail, w.ref, w.stuck_speed)

Everything that speaks of metrics asks the registry instead of keeping its own list: the closed
loop's result (:func:`mitigate.metrics.closed_loop_metrics`), a sweep's columns, the benchmark's
ranking (:func:`ranked`: its order and direction), its tables and CSV headers, the run report, the
bar chart and the units of every CSV header (:func:`unit`).

What a declaration says
-----------------------
``needs`` : what the run must have for the metric to mean something (:data:`NEEDS`).  A run kind
    (:data:`RUN_KINDS`: a closed-loop run, a sweep point) lists the metrics whose needs it can ever
    meet; a run of that kind that lacks one (a rig without a servo input) gives NaN.
``rank`` : the metric's place in the benchmark's lexicographic order (1 first; None: not ranked),
    ``better`` its direction ("lower" or "higher").
``kind`` : "value" (a median with an interval over runs), "count" (events, summed over runs, kept in
    a failed run's row) or "flag" (0 or 1, counted over runs).
``timing`` : a wall-clock measurement of this machine (it varies with the load): kept apart from the
    results in a run record (:class:`mitigate.record.RunRecord`); never ranked, and never among the
    compared results (:data:`COMPARED`).
``show`` : where it is shown (:data:`PLACES`); ``header`` its short column header, ``percent`` shown
    as % (x 100) in the benchmark's tables, ``inf`` what an infinite value reads as.
``per_input`` : the name is a template with ``{input}`` and the function returns ``{input: value}``
    for every servo input of the run.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Callable

from models.errors import ConfigError

__all__ = ["Metric", "metric", "NEEDS", "RUN_KINDS", "PLACES", "KINDS", "COMPARED", "METRICS_VERSION", "registered", "get", "columns", "ranked",
           "shown", "unit", "units", "evaluate", "unregister", "is_timing", "is_count", "in_order",
           "markdown_table"]

#: what a metric may need of a run (a run window's ``has`` says what it has)
NEEDS = {
    "controlled": "a closed-loop run: its programme, stick-slip period and windows, the true plant, "
                  "the controller's commands, counts and call times",
    "programmed_speed": "a programmed speed of the objective body (finite and non-zero)",
    "servo": "a servo input: an actuated normal force",
    "process_force": "a normal force that is an input with a positive programme (the weight on bit)",
    "measured_speed": "a measured speed channel of the objective body",
    "twist": "a spring twist of the rig",
    "torque_sensor": "a torque sensor",
    "uncontrolled_run": "the uncontrolled run (the programme alone) switched on at the same instant (the benchmark's)",
    "sweep_point": "a sweep point: the amplitude state after the settling time and the limit-cycle threshold",
}
#: the needs each kind of run can meet: a metric is a column of a kind when all its needs are here
RUN_KINDS = {"closed_loop": frozenset(NEEDS) - {"sweep_point"}, "sweep": frozenset({"sweep_point"})}
#: where a metric may be shown
PLACES = {
    "entries": "the benchmark's per-entry median and interval (entries.csv, results.json, the class tables)",
    "ranking": "a column of the benchmark's tables per actuator class (ranking.md)",
    "scenario": "a column of the benchmark's table per scenario, with its interval (ranking.md)",
    "terminal": "a column of the table ``mitigate benchmark`` prints",
    "report": "a column of a run's summary table (report.md and the table ``mitigate run`` prints)",
    "bars": "a panel of a run's bar chart (metrics.png)",
    "map": "a map of a sweep (map_<metric>_<start>.png)",
}
KINDS = ("value", "count", "flag")
#: the places whose numbers are compared between machines (a timing metric is never shown there)
COMPARED = frozenset({"entries", "ranking", "scenario", "terminal"})
#: the version of the metrics' definitions: a change to what a metric of the benchmark computes (its
#: code, or MetricOptions' defaults) is a new version (the frozen suite records it; a test holds the
#: code's hash against it, :mod:`mitigate.benchmark.freeze`)
METRICS_VERSION = "1"

_REGISTRY: dict[str, "Metric"] = {}


@dataclass(frozen=True)
class Metric:
    """One metric's declaration (see the module docstring)."""

    name: str
    unit: str
    description: str
    fn: Callable
    needs: frozenset = frozenset()
    rank: int | None = None
    better: str = "lower"
    kind: str = "value"
    timing: bool = False
    show: frozenset = frozenset()
    header: str = ""
    percent: bool = False
    inf: str = "inf"
    per_input: bool = False

    @property
    def runs(self) -> tuple[str, ...]:
        """The kinds of run it is a column of."""
        return tuple(k for k, can in RUN_KINDS.items() if self.needs <= can)

    @property
    def label(self) -> str:
        """``header [unit]`` (the name when it has no header)."""
        return f"{self.header or self.name} [{self.unit}]"

    def matches(self, key: str) -> bool:
        """Whether ``key`` is this metric's name (for a per-input metric: one of its names)."""
        if not self.per_input:
            return key == self.name
        head, _, tail = self.name.partition("{input}")
        return key.startswith(head) and key.endswith(tail) and len(key) > len(head) + len(tail)

    def better_than(self, a: float, b: float) -> bool:
        """``a`` is better than ``b`` (strictly, in this metric's direction; NaN is never better)."""
        if math.isnan(a) or math.isnan(b):
            return False
        return a < b if self.better == "lower" else a > b


def metric(name: str, unit: str, description: str, *, needs=(), rank: int | None = None, better: str = "lower",
           kind: str = "value", timing: bool = False, show=(), header: str = "", percent: bool = False,
           inf: str = "inf", per_input: bool = False) -> Callable:
    """Declare a metric: ``@metric(name, unit, description, ...)`` over ``fn(window) -> float``.

    Returns the function unchanged (it stays callable by other metrics).

    Raises
    ------
    ConfigError : a name declared twice, an unknown need, place or kind, a rank taken twice.
    """
    if not isinstance(name, str) or not re.fullmatch(r"[a-z][a-z0-9_]*(\{input\}[a-z0-9_]*)?", name):
        raise ConfigError(f"metric name must be lower-case letters, digits and _ (a per-input one with "
                          f"{{input}}), got {name!r}")
    if per_input != ("{input}" in name):
        raise ConfigError(f"metric {name!r}: a per-input metric and only one has {{input}} in its name")
    if name in _REGISTRY:
        raise ConfigError(f"metric {name!r} is already declared ({_REGISTRY[name].description})")
    if not isinstance(unit, str) or not unit:
        raise ConfigError(f"metric {name!r}: unit must be a non-empty string (\"-\" for none), got {unit!r}")
    if not isinstance(description, str) or not description:
        raise ConfigError(f"metric {name!r}: description must be a non-empty string")
    bad = [n for n in needs if n not in NEEDS]
    if bad:
        raise ConfigError(f"metric {name!r}: needs {bad[0]!r} is not one of {', '.join(NEEDS)}")
    bad = [p for p in show if p not in PLACES]
    if bad:
        raise ConfigError(f"metric {name!r}: show {bad[0]!r} is not one of {', '.join(PLACES)}")
    if kind not in KINDS:
        raise ConfigError(f"metric {name!r}: kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if better not in ("lower", "higher"):
        raise ConfigError(f"metric {name!r}: better must be \"lower\" or \"higher\", got {better!r}")
    show = frozenset(show)
    if rank is not None:
        if isinstance(rank, bool) or not isinstance(rank, int) or rank < 1:
            raise ConfigError(f"metric {name!r}: rank must be an integer >= 1 or None, got {rank!r}")
        other = next((m.name for m in _REGISTRY.values() if m.rank == rank), None)
        if other:
            raise ConfigError(f"metric {name!r}: rank {rank} is already {other!r}'s")
        if kind != "value" or per_input:
            raise ConfigError(f"metric {name!r}: only a single value can be ranked")
    if timing and (rank is not None or show & COMPARED):
        raise ConfigError(f"metric {name!r}: a timing metric (this machine's wall clock) is never ranked nor shown "
                          f"in {', '.join(sorted(COMPARED))}")
    if rank is not None or show & {"ranking", "scenario", "terminal"}:
        show = show | {"entries"}                 # a ranked or tabled metric has its median and interval
    if per_input and show:
        raise ConfigError(f"metric {name!r}: a per-input metric is not shown in a table")

    def register(fn: Callable) -> Callable:
        _REGISTRY[name] = Metric(name, unit, description, fn, frozenset(needs), rank, better, kind, bool(timing),
                                 show, header, bool(percent), inf, bool(per_input))
        return fn

    return register


def unregister(name: str) -> None:
    """Remove a declared metric (a test's own, when it is done)."""
    _REGISTRY.pop(name, None)


def registered() -> tuple[Metric, ...]:
    """Every declared metric, in declaration order."""
    return tuple(_REGISTRY.values())


def get(name: str) -> Metric:
    """The metric called ``name`` (a per-input one by any of its names)."""
    if name in _REGISTRY:
        return _REGISTRY[name]
    for m in _REGISTRY.values():
        if m.matches(name):
            return m
    raise ConfigError(f"unknown metric {name!r}; declared: {', '.join(_REGISTRY)}")


def columns(run: str) -> tuple[Metric, ...]:
    """The metrics a kind of run (:data:`RUN_KINDS`) has, in declaration order."""
    if run not in RUN_KINDS:
        raise ConfigError(f"run kind must be one of {', '.join(RUN_KINDS)}, got {run!r}")
    return tuple(m for m in _REGISTRY.values() if run in m.runs)


def ranked() -> tuple[Metric, ...]:
    """The ranked metrics, in the ranking's order."""
    return tuple(sorted((m for m in _REGISTRY.values() if m.rank is not None), key=lambda m: m.rank))


def shown(place: str) -> tuple[Metric, ...]:
    """The metrics shown at ``place`` (:data:`PLACES`), in declaration order (the ranked ones first
    for ``"entries"``, in the ranking's order)."""
    if place not in PLACES:
        raise ConfigError(f"place must be one of {', '.join(PLACES)}, got {place!r}")
    out = tuple(m for m in _REGISTRY.values() if place in m.show)
    if place == "entries":
        out = ranked() + tuple(m for m in out if m.rank is None)
    return out


def unit(key: str) -> str:
    """The unit of a metric's name (a per-input one's too); "" if no metric has that name."""
    try:
        return get(key).unit
    except ConfigError:
        return ""


def units(run: str = "closed_loop") -> dict[str, str]:
    """``{name: unit}`` of the single-valued metrics of a kind of run (the per-input ones expand per
    run; :func:`unit` knows them)."""
    return {m.name: m.unit for m in columns(run) if not m.per_input}


def in_order(keys) -> list[str]:
    """Metric names in declaration order (names no metric has last, sorted)."""
    order = registered()

    def place(k):
        return next((i for i, m in enumerate(order) if m.matches(k)), len(order)), k
    return sorted(keys, key=place)


def is_timing(key: str) -> bool:
    """Whether ``key`` is a timing metric's (a wall-clock measurement of this machine)."""
    try:
        return get(key).timing
    except ConfigError:
        return False


def is_count(key: str) -> bool:
    """Whether ``key`` is a count's (kept in a failed run's row)."""
    try:
        return get(key).kind == "count"
    except ConfigError:
        return False


def markdown_table() -> str:
    """Every declared metric as a Markdown table (name, unit, rank, kind, needs, where shown, what it is)."""
    lines = ["| metric | unit | ranked | kind | needs | shown in | what it is |", "|---|---|---|---|---|---|---|"]
    for m in registered():
        rank = f"{m.rank} ({m.better} is better)" if m.rank is not None else "-"
        kind = m.kind + (", timing" if m.timing else "")
        lines.append(f"| `{m.name}` | {m.unit} | {rank} | {kind} | {', '.join(sorted(m.needs)) or '-'} | "
                     f"{', '.join(p for p in PLACES if p in m.show) or '-'} | {m.description} |")
    return "\n".join(lines) + "\n"


def evaluate(window) -> dict[str, float]:
    """Every metric of ``window``'s kind of run on it: ``{name: value}`` (NaN for a metric whose
    needs the run lacks; a per-input metric gives one entry per servo input, none if it lacks them)."""
    out: dict[str, float] = {}
    for m in columns(window.kind):
        able = m.needs <= window.has
        if m.per_input:
            if able:
                out.update({m.name.format(input=k): v for k, v in m.fn(window).items()})
        else:
            out[m.name] = m.fn(window) if able else math.nan
    return out

