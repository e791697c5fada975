"""A new metric is one declaration (issue 25 item 3's target).

The metric below is declared HERE and nowhere else: the peak-to-peak of the measured body's true
speed, a function of the speed alone, so it belongs to every kind of run.  Declared once, it is in
the closed loop's result (``mitigate.run`` and its metrics.csv and report), a sweep's results.csv,
and the benchmark's records, entries and tables; a ranked one is read by the ranking in its order and
direction.  Each check compares the declared value with the same quantity computed another way (a
sweep's amplitude is half of it; the closed loop's from the run's own trajectory).
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import pytest

from mitigate.benchmark.stats import Entry, rank
from mitigate.metrics import get, metric, ranked, registered, shown, unregister
from models.errors import ConfigError

sys.path.insert(0, str(Path(__file__).parent))
from scenario_text import PI, scenario_toml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NAME = "speed_peak_to_peak"


@pytest.fixture(scope="module")
def declared():
    @metric(NAME, "rad/s", "max - min of the measured body's true speed over the window",
            show=("ranking", "scenario", "report", "bars"), header="speed p2p")
    def speed_peak_to_peak(w):
        return float(np.max(w.speed) - np.min(w.speed))

    yield get(NAME)
    unregister(NAME)


def test_the_declaration_is_all_the_registry_needs(declared):
    assert declared.runs == ("closed_loop", "sweep") and declared.rank is None
    assert declared in shown("entries") and declared in shown("ranking") and declared.label == "speed p2p [rad/s]"
    with pytest.raises(ConfigError, match=rf"^metric '{NAME}' is already declared"):
        metric(NAME, "rad/s", "again")(lambda w: 0.0)


def test_it_is_in_the_closed_loop_result_its_csv_and_report(declared, tmp_path):
    from mitigate import run
    p = tmp_path / "s.toml"
    p.write_text(scenario_toml('[scenario]\nname = "p2p"\nduration = 1.5', controllers=[PI]))
    res = run(p, out=tmp_path / "out", jobs=1)
    r = res.runs[0]
    cl = r.result
    w = cl.objective_speed[cl.t >= cl.control_start - 1e-12]
    assert r.metrics[NAME] == float(w.max() - w.min()) > 0
    head = (tmp_path / "out" / "metrics.csv").read_text().splitlines()[0]
    assert f"{NAME} [rad/s]" in head.split(",")
    rep = (tmp_path / "out" / "report.md").read_text()
    assert "| speed p2p [rad/s] |" in next(ln for ln in rep.splitlines() if ln.startswith("| controller |"))


def test_it_is_a_column_of_a_sweep(declared, tmp_path):
    from mitigate.sweep import sweep
    res = sweep(ROOT / "scenarios" / "sweep_rig3.toml", ["omega_ref=2:4:2"], out=tmp_path / "s", duration=2.0,
                settle=1.0, start="rest", workers=1, backend="vm", stability=False, chunk=2, maps=False)
    assert res.success
    rows = list(csv.DictReader((tmp_path / "s" / "results.csv").open()))
    assert len(rows) == 2 and f"{NAME}_rest" in rows[0]
    # the sweep's speed and amplitude state are both omega_R1: the amplitude is half the peak-to-peak
    for row, p2p in zip(rows, res.maps["rest"][NAME]):
        assert float(row[f"{NAME}_rest"]) == p2p == 2 * float(row["amplitude_rest"]) > 0


def test_it_is_in_the_benchmarks_records_entries_and_tables(declared, tmp_path):
    from test_benchmark import _write_suite
    from mitigate.benchmark import load_suite, run_benchmark, write_benchmark
    from mitigate.benchmark.render import render_ranking
    _write_suite(tmp_path)
    res = run_benchmark(load_suite(tmp_path / "suite.toml", only=["drill"]), phases=1, seeds=1, jobs=1)
    rec = next(r for r in res.records if r.run.controller == "PI only")
    assert len(res.records) == 3 and all(r.metrics[NAME] > 0 for r in res.records)
    assert res.entry("drill", "PI only").metrics[NAME] == {"median": rec.metrics[NAME], "ci_low": rec.metrics[NAME],
                                                          "ci_high": rec.metrics[NAME]}
    md = render_ranking(res)
    assert md.count("speed p2p [rad/s]") >= 2            # the class table and the scenario's table
    write_benchmark(res, tmp_path / "out")
    entries = {e["controller"]: e for e in csv.DictReader((tmp_path / "out" / "entries.csv").open())}
    assert float(entries["PI only"][f"{NAME}_median [rad/s]"]) == pytest.approx(rec.metrics[NAME], rel=1e-5)
    runs = {r["controller"]: r for r in csv.DictReader((tmp_path / "out" / "results.csv").open())}
    assert float(runs["PI only"][f"{NAME} [rad/s]"]) == pytest.approx(rec.metrics[NAME], rel=1e-5)
    row = next(ln for ln in md.splitlines() if ln.startswith("| PI only |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    hdr = [c.strip() for c in next(ln for ln in md.splitlines() if ln.startswith("| controller | class |"))
           .strip("|").split("|")]
    assert float(cells[hdr.index("speed p2p [rad/s]")]) == pytest.approx(rec.metrics[NAME], rel=5e-3)   # 3 digits


def test_a_ranked_metric_is_read_by_the_ranking_in_its_order_and_direction():
    """Two controllers tied on every ranked metric: one more ranked metric, higher better, after the
    others decides; without it they share a rank."""
    shipped = [m.name for m in ranked()]

    def entry(name, cut):
        e = Entry("s", name, "k", "drive", n_runs=6)
        e.metrics = {m: {"ci_low": 0.01, "median": 0.02, "ci_high": 0.03} for m in shipped}
        e.metrics["rate_of_cut"] = dict(zip(("ci_low", "median", "ci_high"), cut))
        return e
    a, b = entry("a", (1.0, 1.5, 2.0)), entry("b", (3.0, 3.5, 4.0))
    assert rank([a, b]) == {"a": 1, "b": 1}
    metric("rate_of_cut", "m/s", "a test's rate of penetration", rank=len(shipped) + 1,
           better="higher")(lambda w: 0.0)
    try:
        assert [m.name for m in ranked()] == shipped + ["rate_of_cut"]
        assert rank([a, b]) == {"a": 2, "b": 1}
    finally:
        unregister("rate_of_cut")
    assert rank([a, b]) == {"a": 1, "b": 1}


def test_the_ranking_order_and_what_is_shown_beside_it():
    """Issue 27: ranked on what the rig sees, then how fast, then the loads that damage hardware, then
    the effort; the true-speed residual and the overshoot are shown beside, not ranked; no timing
    metric is ranked or among the compared results."""
    assert [m.name for m in ranked()] == ["measured_severity", "measured_time_to_suppress", "string_torque_peak",
                                          "drive_load_peak", "setpoint_excursion", "setpoint_variation"]
    for name in ("peak_overshoot", "residual_severity"):
        m = get(name)
        assert m.rank is None and {"ranking", "scenario", "entries"} <= m.show
    from mitigate.metrics import COMPARED
    assert all(not (m.show & COMPARED) and m.rank is None for m in registered() if m.timing)
    with pytest.raises(ConfigError, match=r"a timing metric .* is never ranked nor shown in entries"):
        metric("bad_timing", "ms", "a wall-clock one", timing=True, show=("entries",))


@pytest.mark.parametrize("kw, match", [
    ({"needs": ("servo", "gearbox")}, r"needs 'gearbox' is not one of controlled, "),
    ({"show": ("poster",)}, r"show 'poster' is not one of entries, "),
    ({"rank": 1}, r"rank 1 is already 'measured_severity''s"),
    ({"kind": "flag", "rank": 7}, r"only a single value can be ranked"),
    ({"better": "up"}, r"better must be \"lower\" or \"higher\", got 'up'"),
])
def test_a_bad_declaration_is_a_one_line_error(kw, match):
    with pytest.raises(ConfigError, match=match) as ei:
        metric("bad_metric", "-", "a bad one", **kw)
    assert "\n" not in str(ei.value) and "bad_metric" not in {m.name for m in registered()}
    with pytest.raises(ConfigError, match=r"unit must be a non-empty string"):
        metric("bad_metric", "", "no unit")
