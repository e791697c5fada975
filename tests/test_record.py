"""Typed run records (mitigate.record, issue 25 item 5): a record is converted only at the store, and
the stores still read what they wrote before the records were typed."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mitigate.benchmark.execute import RunStore
from mitigate.record import BenchmarkRun, RunRecord, SweepPoint
from mitigate.sweep.store import SweepStore
from models.errors import DataError
from models.status import Status

RUN = BenchmarkRun("drill/pi_only/p1_s0", "drill", "PI only", 1, 0, 1.1234, 123456, {"gain": 2.0})


def _record(**kw):
    values = {"residual_severity": 0.25, "time_to_suppress": math.inf, "peak_overshoot": math.nan,
              "controller_steps": 500, "band_violation": 0, "plan_p95_ms": 1.5, "controller_deadline_misses": 3}
    return RunRecord.measured(RUN, Status.WARNING, "2 fallbacks", values, elapsed=4.5, actuator_class="drive", **kw)


def test_timings_are_kept_apart_from_the_results():
    r = _record()
    assert set(r.timings) == {"elapsed_s", "plan_p95_ms", "controller_deadline_misses"}
    assert "plan_p95_ms" not in r.metrics and r.metrics["controller_steps"] == 500
    assert r.value("plan_p95_ms") == 1.5 and r.value("residual_severity") == 0.25 and math.isnan(r.value("nope"))
    assert r.success and not r.failed
    assert RunRecord(RUN, Status.FAILED, "no servo", applicable=False).failed is False   # not due: not a failure
    assert RunRecord(RUN, Status.DIVERGED, "diverged").failed


def test_a_record_survives_the_benchmark_store(tmp_path):
    store = RunStore(tmp_path, {"a": 1})
    r = _record()
    store.write(r)
    back = store.read(RUN.key)
    assert back.run == RUN and back.status is Status.WARNING and back.actuator_class == "drive"
    assert back.metrics.keys() == r.metrics.keys() and back.timings == r.timings
    assert back.metrics["time_to_suppress"] == math.inf and math.isnan(back.metrics["peak_overshoot"])
    assert isinstance(back.metrics["controller_steps"], int) and back.metrics["residual_severity"] == 0.25
    text = store.path(RUN.key).read_text()
    assert '"inf"' in text and '"nan"' in text and "Infinity" not in text and "NaN" not in text   # strict JSON
    assert RunRecord.from_json(json.loads(text)).to_json() == r.to_json()
    p = SweepPoint("sweep-rig3", "", "rest", 7)
    sw = RunRecord(p, Status.OK, "ok", {"amplitude": 0.5})
    assert RunRecord.from_json(json.loads(json.dumps(sw.to_json()))) == sw


def test_the_benchmark_store_reads_a_record_written_before_they_were_typed(tmp_path):
    """Format 1: the run's identity at the top level, "not applicable" / "failed" statuses, a
    redundant ``failed`` int, the call times among the metrics, ``elapsed``."""
    store = RunStore(tmp_path, {"a": 1})
    old = {"key": RUN.key, "scenario": "drill", "controller": "PI only", "phase": 1, "seed": 0, "switch_on": 1.1234,
           "run_seed": 123456, "options": {"gain": 2.0}, "applicable": True, "status": "ok", "message": "ok",
           "failed": 0, "class": "drive", "metrics": {"residual_severity": 0.25, "time_to_suppress": "inf",
                                                       "plan_p95_ms": 1.5, "controller_steps": 500}, "elapsed": 4.5}
    store.path(RUN.key).parent.mkdir(parents=True)
    store.path(RUN.key).write_text(json.dumps(old))
    r = store.read(RUN.key)
    assert r.run == RUN and r.status is Status.OK and r.timings == {"elapsed_s": 4.5, "plan_p95_ms": 1.5}
    assert r.metrics == {"residual_severity": 0.25, "time_to_suppress": math.inf, "controller_steps": 500}
    na = RunRecord.from_json(old | {"applicable": False, "status": "not applicable", "metrics": {}})
    assert not na.applicable and na.status is Status.FAILED and not na.failed
    assert RunRecord.from_json(old | {"status": "failed", "failed": 1}).failed
    store.path(RUN.key).write_text(json.dumps({"record": 2, "kind": "benchmark"}))
    with pytest.raises(DataError, match=r"p1_s0\.json: not a run record \(KeyError: 'run'\); delete it to rerun"):
        store.read(RUN.key)


def test_the_sweep_store_round_trips_records_and_reads_old_chunks(tmp_path):
    store = SweepStore(tmp_path, {"a": 1})
    recs = [RunRecord(SweepPoint("s", "", "rest", 4), Status.OK, "ok", {"amplitude": 0.1 + 0.2, "limit_cycle": 1.0}),
            RunRecord(SweepPoint("s", "", "rest", 5), Status.FAILED, "no steady sliding, so from rest",
                      {"amplitude": math.nan, "limit_cycle": math.nan})]
    store.write_records("rest_00000", recs)
    d = store.read_chunk("rest_00000")
    assert d["index"].tolist() == [4.0, 5.0] and list(d["status"]) == [Status.OK, Status.FAILED]
    assert list(d["message"]) == ["ok", "no steady sliding, so from rest"]
    assert d["amplitude"][0] == 0.1 + 0.2 and np.isnan(d["amplitude"][1])       # exact round trip
    # a chunk written before the points had records: an ``ok`` column of floats
    store.chunk_path("rest_00001").write_text("index,amplitude,ok\n6.0,0.5,1.0\n7.0,nan,0.0\n")
    d = store.read_chunk("rest_00001")
    assert "ok" not in d and list(d["status"]) == [Status.OK, Status.FAILED] and d["amplitude"][0] == 0.5
    store.chunk_path("rest_00002").write_text("index,status\n8.0,splendid\n")
    with pytest.raises(DataError, match=r"rest_00002\.csv: unreadable chunk .*; delete it to recompute it$"):
        store.read_chunk("rest_00002")

