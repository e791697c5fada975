"""The open benchmark (mitigate.benchmark) on a tiny suite: ranking by severity, written outputs,
controllers a rig cannot host reported as not applicable, bad suite files as one-line errors."""

import csv
import json
import re

import pytest

from mitigate.benchmark import load_suite, render_ranking, run_benchmark, write_benchmark
from models.errors import ConfigError
from models.rig import RIGS_DIR
from models.status import Status

SCENARIO = """
[scenario]
name = "{name}"
model = "{model}"
duration = {duration}
seed = 1
[plant]
max_speed = {max_speed}
[inputs]
omega_ref = "30 rpm"
n1 = 20.0
{n2}
[control]
start = {start}
[estimator]
kind = "fd"
"""

SUITE = """
[suite]
name = "tiny"
description = "two short scenarios and a broken one"
scenarios = ["established.toml", "no_servo.toml", "runaway.toml"]

[[controllers]]
name = "PI only"
kind = "pi"

[[controllers]]
name = "brake"
kind = "brake"
gain_overspeed = 80.0
filter_tau = 0.0

[[controllers]]
name = "SoftSpeed"
kind = "softspeed"
"""


@pytest.fixture(scope="module")
def suite_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("suite")
    rig = (RIGS_DIR / "rig3.toml").read_text()
    rig = re.sub(r"^\[actuators\.servo2\]\n(?:(?!\[).*\n)*", "", rig, flags=re.M).replace('name = "rig3"',
                                                                                        'name = "rig3_no_servo"', 1)
    (d / "rig3_no_servo.toml").write_text(rig)
    (d / "established.toml").write_text(SCENARIO.format(name="established", model="rig3", duration=15.0,
                                                        max_speed=100.0, n2="", start=7.0))
    (d / "no_servo.toml").write_text(SCENARIO.format(name="no_servo", model="rig3_no_servo.toml", duration=15.0,
                                                     max_speed=100.0, n2="n2 = 0.0", start=7.0))
    # a plant limit below the programmed speed: every run there diverges within a second
    (d / "runaway.toml").write_text(SCENARIO.format(name="runaway", model="rig3", duration=2.0, max_speed=2.0,
                                                    n2="", start=0.0))
    (d / "suite.toml").write_text(SUITE)
    return d


@pytest.fixture(scope="module")
def result(suite_dir):
    suite = load_suite(suite_dir / "suite.toml", extra_controllers=[{"name": "D-OSKIL", "kind": "doskil"}])
    return run_benchmark(suite, jobs=1)


def test_load_suite(suite_dir):
    s = load_suite(suite_dir / "suite.toml", extra_controllers=[{"name": "D-OSKIL", "kind": "doskil"}])
    assert (s.name, s.description) == ("tiny", "two short scenarios and a broken one")
    assert [sc.name for sc in s.scenarios] == ["established", "no_servo", "runaway"]
    assert [c.name for c in s.controllers] == ["PI only", "brake", "SoftSpeed", "D-OSKIL"]
    for sc in s.scenarios:                  # the suite's controllers replace the scenarios' own
        assert [c.name for c in sc.controllers] == ["PI only", "brake", "SoftSpeed", "D-OSKIL"]
    assert s.scenarios[1].model.servo_inputs == ()
    only = load_suite(suite_dir / "suite.toml", only=["no_servo"])
    assert [sc.name for sc in only.scenarios] == ["no_servo"]


def test_ranking_is_by_severity_and_not_applicable_is_not_a_failure(result):
    cells, ranks = result.cells, result.ranks
    for c in ("brake", "D-OSKIL"):
        v = cells[("no_servo", c)]
        assert v["applicable"] is False and v["status"] == "not applicable" and "has no actuator" in v["message"]
        assert ("no_servo", c) not in ranks
    for s, names in (("established", ["PI only", "brake", "SoftSpeed", "D-OSKIL"]), ("no_servo", ["PI only",
                                                                                                 "SoftSpeed"])):
        by_sss = sorted(names, key=lambda n: cells[(s, n)]["sss"])
        assert [ranks[(s, n)] for n in by_sss] == list(range(1, len(names) + 1))
        assert all(cells[(s, n)]["failed"] == 0 for n in names)
    # PI alone keeps the stick-slip of the established scenario: it ranks last there
    assert ranks[("established", "PI only")] == 4
    # the diverged runs fail, and a failed run ranks last whatever its severity
    for n in ("PI only", "brake", "SoftSpeed", "D-OSKIL"):
        v = cells[("runaway", n)]
        assert v["failed"] == 1 and v["status"] == Status.DIVERGED.value and "plant.max_speed" in v["message"]
    assert result.status is Status.FAILED and result.message == "4 run(s) failed or diverged"


def test_the_table(result):
    t = {r["controller"]: r for r in result.table}
    assert [r["mean_rank"] for r in result.table] == sorted(r["mean_rank"] for r in result.table)
    assert (t["PI only"]["scenarios"], t["brake"]["scenarios"], t["D-OSKIL"]["scenarios"]) == (3, 2, 2)
    for name, row in t.items():
        mine = [k for k in result.ranks if k[1] == name]
        assert row["mean_rank"] == pytest.approx(sum(result.ranks[k] for k in mine) / len(mine))
        assert row["failed"] == 1
        assert row["lowest_fraction"] == pytest.approx(sum(result.ranks[k] == 1 for k in mine) / len(mine))
    # the physical metrics are averaged over the runs that finished (the diverged one is "failed")
    sss = [result.cells[(s, "SoftSpeed")]["sss"] for s in ("established", "no_servo")]
    assert t["SoftSpeed"]["sss"] == pytest.approx(sum(sss) / 2)
    stuck = [result.cells[(s, "brake")]["stuck_fraction"] for s in ("established",)]
    assert t["brake"]["stuck_fraction"] == pytest.approx(stuck[0])
    assert t["PI only"]["time_to_suppress"] == float("inf")          # never suppressed where it ran


def test_write_benchmark(result, tmp_path):
    out = tmp_path / "bench"
    files = write_benchmark(result, out, command="mitigate benchmark suite.toml")
    assert sorted(p.name for p in out.iterdir()) == ["benchmark.png", "ranking.md", "results.csv", "results.json"]
    md = (out / "ranking.md").read_text()
    assert "# Benchmark `tiny`" in md and "mitigate benchmark suite.toml" in md
    assert re.search(r"\| no_servo \| [^|]+ \| n/a \| [^|]+ \| n/a \|", md)
    assert "FAILED (diverged)" in md and "- brake on no_servo: " in md
    lines = md.splitlines()
    first_row = lines[next(i for i, ln in enumerate(lines) if ln.startswith("|---|")) + 1]
    assert first_row.startswith(f"| {result.table[0]['controller']} | {result.table[0]['kind']} |")
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 12 and sum(r["applicable"] == "False" for r in rows) == 2
    doc = json.loads((out / "results.json").read_text())
    assert doc["suite"] == "tiny" and len(doc["cells"]) == 12 and doc["files"]["png"].endswith("benchmark.png")
    assert (out / "benchmark.png").stat().st_size > 5000
    assert files["ranking"] == out / "ranking.md"
    with pytest.raises(ConfigError, match="exists"):
        write_benchmark(result, out)
    assert render_ranking(result) == md.replace("Made with:\n\n```bash\nmitigate benchmark suite.toml\n```\n\n", "")


@pytest.mark.parametrize("edit, match", [
    (("[suite]", "[wobble]\n[suite]"), r"suite\.toml: wobble: unknown section"),
    (('name = "tiny"', 'name = "tiny"\ncolour = "red"'), r"suite\.toml: suite\.colour: unknown key"),
    (('scenarios = ["established.toml", "no_servo.toml", "runaway.toml"]', 'scenarios = "established.toml"'),
     r"suite\.toml: suite\.scenarios must be a list of scenario files"),
    (('scenarios = ["established.toml"', 'scenarios = ["nope.toml"'), r"nope\.toml.*not found"),
    (('name = "SoftSpeed"', 'name = "brake"'), r"suite\.toml: controllers\[2\]\.name: duplicate controller name"),
    (('kind = "softspeed"', 'kind = "lqr"'), r"suite\.toml: controllers\[2\]\.kind must be one of"),
    (("gain_overspeed = 80.0", "gain_overspeed = -80.0"), r"suite\.toml: controllers\[1\]\.gain_overspeed must be >= 0"),
    (("gain_overspeed = 80.0", "gain_overspeed = 80.0\ngian = 1"), r"suite\.toml: controllers\[1\]\.gian: unknown option"),
])
def test_bad_suite_files_are_one_line_errors(suite_dir, tmp_path, edit, match):
    for f in suite_dir.iterdir():
        (tmp_path / f.name).write_text(f.read_text())
    text = SUITE.replace(*edit)
    assert text != SUITE
    (tmp_path / "suite.toml").write_text(text)
    with pytest.raises(ConfigError, match=match) as ei:
        load_suite(tmp_path / "suite.toml")
    assert "\n" not in str(ei.value)


def test_bad_arguments(suite_dir, tmp_path):
    (tmp_path / "empty.toml").write_text('[suite]\nscenarios = ["a.toml"]\n')
    with pytest.raises(ConfigError, match=r"^empty\.toml: controllers: list at least one"):
        load_suite(tmp_path / "empty.toml")
    (tmp_path / "bad_scenario.toml").write_text(SCENARIO.format(name="b", model="rig3", duration=-1.0, max_speed=100.0,
                                                                n2="", start=0.0))
    (tmp_path / "s.toml").write_text(SUITE.replace('"established.toml", "no_servo.toml", "runaway.toml"',
                                                   '"bad_scenario.toml"'))
    with pytest.raises(ConfigError, match=r"^bad_scenario\.toml: scenario\.duration must be > 0"):
        load_suite(tmp_path / "s.toml")
    with pytest.raises(ConfigError, match=r"^scenario 'x' is not in the suite \(established, no_servo, runaway\)$"):
        load_suite(suite_dir / "suite.toml", only=["x"])
    with pytest.raises(ConfigError, match=r"^controller name 'brake' is already in the suite$"):
        load_suite(suite_dir / "suite.toml", extra_controllers=[{"name": "brake", "kind": "pi"}])
    with pytest.raises(ConfigError, match=r"^controller 'Mine'\.gain must be >= 0"):
        load_suite(suite_dir / "suite.toml", extra_controllers=[{"name": "Mine", "kind": "doskil", "gain": -1.0}])
    with pytest.raises(ConfigError, match=r"^jobs must be an integer >= 1, got 0$"):
        run_benchmark(load_suite(suite_dir / "suite.toml", only=["runaway"]), jobs=0)
