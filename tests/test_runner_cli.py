"""``mitigate run``: outputs, exit codes, refusal to overwrite, JSON."""

import json
from pathlib import Path

import pytest

from mitigate.cli import main
from models.logs import read_csv

TINY = """
[scenario]
name = "tiny"
description = "tiny test scenario"
duration = 2.0
seed = 2

[inputs]
omega_ref = { kind = "constant", value = 30, unit = "rpm" }
n1 = 20

[control]
start = 1.0

[estimator]
kind = "fd"

[[controllers]]
name = "PI only"
kind = "pi"

[[controllers]]
name = "R2 brake"
kind = "brake"

[[controllers]]
name = "supervisor"
kind = "supervisor"
"""

EXPECTED = ["metrics.csv", "metrics.json", "report.md", "comparison.png", "phase.png", "metrics.png",
            "log_pi_only.csv", "log_r2_brake.csv", "log_supervisor.csv", "timeseries_pi_only.png",
            "timeseries_r2_brake.png", "timeseries_supervisor.png"]


@pytest.fixture
def tiny(tmp_path):
    p = tmp_path / "tiny.toml"
    p.write_text(TINY)
    return p


def test_run_writes_all_outputs(tiny, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(tiny), "--out", str(out), "--jobs", "2"]) == 0
    for f in EXPECTED:
        assert (out / f).is_file() and (out / f).stat().st_size > 0, f
    text = capsys.readouterr().out
    assert "PI only" in text and "SSS" in text
    log = read_csv(out / "log_r2_brake.csv", required=("twist12", "twist23", "omega1", "n2", "omega_ref"))
    assert log.t[-1] == pytest.approx(2.0)
    rep = (out / "report.md").read_text()
    assert "comparison.png" in rep and "Where the NMPC does not win" in rep
    header = (out / "metrics.csv").read_text().splitlines()[0]
    assert header.startswith("controller,kind,success,status,sss [-]")


def test_json_parses_and_no_overwrite_without_force(tiny, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", str(tiny), "--out", str(out), "--jobs", "1", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [c["name"] for c in doc["controllers"]] == ["PI only", "R2 brake", "supervisor"]
    assert doc["success"] is True and "sss" in doc["controllers"][0]["metrics"]
    assert json.loads((out / "metrics.json").read_text())["scenario"] == "tiny"
    before = (out / "metrics.csv").stat().st_mtime_ns
    assert main(["run", str(tiny), "--out", str(out), "--jobs", "1"]) == 2
    err = capsys.readouterr().err
    assert "exists" in err and "--force" in err and len(err.strip().splitlines()) == 1
    assert (out / "metrics.csv").stat().st_mtime_ns == before
    assert main(["run", str(tiny), "--out", str(out), "--jobs", "1", "--force"]) == 0


@pytest.mark.parametrize("edit, match", [
    (('kind = "brake"', 'kind = "brake"\ngain_overspeed = -3'), "controllers[1].gain_overspeed must be >= 0"),
    (('kind = "pi"', 'kind = "pid"'), "controllers[0].kind must be one of"),
    (("duration = 2.0", "duration = -2.0"), "scenario.duration must be > 0"),
    (('kind = "fd"', 'kind = "kalman"'), "estimator.kind must be one of"),
])
def test_bad_scenario_exit_2_one_line_no_outputs(tiny, tmp_path, capsys, edit, match):
    tiny.write_text(TINY.replace(*edit))
    out = tmp_path / "bad"
    assert main(["run", str(tiny), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err
    assert not out.exists() or not any(out.iterdir())


def test_missing_file_exit_2(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "not found" in capsys.readouterr().err
