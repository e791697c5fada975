"""One run's record: which run it was, what became of it, what it measured, how long it took.

The benchmark's runs and a sweep's points are :class:`RunRecord` objects from the moment they
finish until a store writes them; only the stores convert them (:meth:`RunRecord.to_json` /
:meth:`RunRecord.from_json` for the benchmark's per-run JSON files; the sweep's store writes CSV
columns).  A record keeps its results (``metrics``: the registry's names, :mod:`mitigate.metrics`)
apart from the machine's wall-clock timings (``timings``: the run's ``elapsed_s`` and the metrics
declared ``timing``), so two machines give the same results and differ only in the timings.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from models.errors import DataError
from models.status import Outcome, Status

__all__ = ["RunRecord", "BenchmarkRun", "SweepPoint", "split_timings", "RECORD_FORMAT"]

#: the format of :meth:`RunRecord.to_json` (1: the dictionaries written before the record was typed)
RECORD_FORMAT = 2


@dataclass(frozen=True)
class BenchmarkRun:
    """Which benchmark run: a controller on a scenario switched on at one phase with one noise seed.

    Attributes
    ----------
    key : its store key (``<scenario>/<controller>/p<phase>_s<seed>``, file-name safe)
    scenario, controller : names
    phase, seed : the switch-on phase's and the noise seed's indices
    switch_on : the switch-on time [s]; run_seed : the run's noise seed
    options : the controller's raw options (the suite's or tuned ones)
    """

    key: str
    scenario: str
    controller: str
    phase: int
    seed: int
    switch_on: float
    run_seed: int
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SweepPoint:
    """Which sweep run: point ``index`` of a sweep's grid, started from ``start`` ("rest" or "sliding"),
    open loop (``controller == ""``) or with the scenario's controller of that name."""

    scenario: str
    controller: str
    start: str
    index: int


_RUNS = {"benchmark": BenchmarkRun, "sweep": SweepPoint}


def split_timings(values: Mapping[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    """``(results, timings)``: the metrics declared ``timing`` (:mod:`mitigate.metrics.registry`) apart."""
    from mitigate.metrics import is_timing
    res, tim = {}, {}
    for k, v in values.items():
        (tim if is_timing(k) else res)[k] = v
    return res, tim


@dataclass(frozen=True)
class RunRecord(Outcome):
    """One run's record.

    Attributes
    ----------
    run : which run (:class:`BenchmarkRun` or :class:`SweepPoint`)
    status : what became of it (:class:`models.status.Status`); message : why, in one line
    metrics : ``{name: value}`` of the registry's metrics (empty when the run produced none)
    timings : ``{name: value}`` of this machine's wall-clock numbers: ``elapsed_s`` [s] and the
        metrics declared ``timing`` (call times [ms], deadline misses)
    applicable : False when the rig lacks what the controller needs (the run did not happen;
        ``status`` is FAILED, ``message`` says what is missing)
    actuator_class : what the controller actuates (:func:`mitigate.tunables.actuator_class`), "" if unknown
    """

    run: BenchmarkRun | SweepPoint
    status: Status
    message: str = "ok"
    metrics: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    applicable: bool = True
    actuator_class: str = ""

    @classmethod
    def measured(cls, run, status: Status, message: str, values: Mapping[str, float], *, elapsed: float,
                 applicable: bool = True, actuator_class: str = "") -> "RunRecord":
        """A record from every metric of a run (the timing ones go to ``timings`` with ``elapsed_s``)."""
        res, tim = split_timings(values)
        return cls(run, status, message, res, {"elapsed_s": float(elapsed), **tim}, applicable, actuator_class)

    @property
    def failed(self) -> bool:
        """The run was due (applicable) and did not succeed."""
        return self.applicable and not self.success

    def value(self, name: str) -> float:
        """A metric's value, a result or a timing (NaN if the run has none)."""
        v = self.metrics.get(name, self.timings.get(name, math.nan))
        return float(v)

    def to_json(self) -> dict[str, Any]:
        """The record as JSON data (non-finite numbers as the strings "inf", "-inf", "nan")."""
        from mitigate.cliutil import to_jsonable
        kind = next(k for k, c in _RUNS.items() if isinstance(self.run, c))
        return {"record": RECORD_FORMAT, "kind": kind, "run": to_jsonable(dataclasses.asdict(self.run)),
                "status": self.status.value, "message": self.message, "applicable": self.applicable,
                "class": self.actuator_class, "metrics": _numbers_out(self.metrics),
                "timings": _numbers_out(self.timings)}

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str = "run record") -> "RunRecord":
        """The record of :meth:`to_json`'s data, or of a benchmark run's dictionary as written before
        records were typed (format 1: identity at the top level, ``status`` "not applicable" or
        "failed" or a Status value, the timing metrics among the metrics, ``elapsed``).

        Raises
        ------
        DataError : ``"<where>: ..."`` naming what is missing or wrong.
        """
        if not isinstance(data, Mapping):
            raise DataError(f"{where}: expected a JSON object, got {type(data).__name__}")
        try:
            if "record" not in data:
                return _from_format_1(data)
            if data["record"] != RECORD_FORMAT:
                raise DataError(f"{where}: record format {data['record']!r} is not {RECORD_FORMAT}")
            run = _RUNS[data["kind"]](**data["run"])
            return cls(run, Status(data["status"]), str(data["message"]), _numbers_in(data["metrics"]),
                       _numbers_in(data["timings"]), bool(data["applicable"]), str(data["class"]))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, DataError):
                raise
            raise DataError(f"{where}: not a run record ({type(exc).__name__}: {exc})") from None


def _from_format_1(d: Mapping[str, Any]) -> RunRecord:
    run = BenchmarkRun(d["key"], d["scenario"], d["controller"], int(d["phase"]), int(d["seed"]),
                       float(d["switch_on"]), int(d["run_seed"]), dict(d.get("options", {})))
    applicable = bool(d.get("applicable", True))
    text = d.get("status", "")
    status = Status(text) if text in {s.value for s in Status} else Status.FAILED
    if d.get("failed") and status.success:
        status = Status.FAILED
    res, tim = split_timings(_numbers_in(d.get("metrics", {})))
    return RunRecord(run, status, str(d.get("message", "")), res, {"elapsed_s": float(d.get("elapsed", 0.0)), **tim},
                     applicable, str(d.get("class", "")))


def _numbers_out(values: Mapping[str, float]) -> dict:
    # JSON has neither inf nor nan: they survive a round trip as strings
    return {k: (v if isinstance(v, int) or math.isfinite(v) else
                ("inf" if v == math.inf else "-inf" if v == -math.inf else "nan"))
            for k, v in ((k, v if isinstance(v, int) and not isinstance(v, bool) else float(v))
                         for k, v in values.items())}


def _numbers_in(values: Mapping[str, Any]) -> dict:
    return {str(k): (float(v) if isinstance(v, (str, float)) else int(v)) for k, v in values.items()}
