"""``mitigate estimate``: output columns, summary, exit codes, refusal to overwrite."""

import json
import math

import numpy as np
import pytest

from mitigate.cli import main
from models import get_model
from models.logs import read_csv
from models.plant import SimOptions, simulate


@pytest.fixture(scope="module")
def log_path(tmp_path_factory):
    m = get_model("rig3")
    sim = simulate(m, m.published(), np.array([math.pi, 20.0, 0.0]), 4.0, SimOptions(seed=2))
    p = tmp_path_factory.mktemp("est") / "stick.csv"
    sim.to_log(include_truth_twist=True).write_csv(p)
    return p


def read_out(path):
    import csv
    with open(path) as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array(rows[1:], dtype=float)


@pytest.mark.parametrize("kind,extra", [("ekf", []), ("mhe", ["--window", "5"]), ("fd", [])])
def test_estimate_writes_csv_and_json_summary(log_path, tmp_path, capsys, kind, extra):
    out = tmp_path / f"est_{kind}.csv"
    rc = main(["estimate", str(log_path), "--estimator", kind, "--out", str(out), "--json", "--no-compile", *extra]
              if kind != "fd" else ["estimate", str(log_path), "--estimator", kind, "--out", str(out), "--json"])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    head, data = read_out(out)
    for col in ("t [s]", "twist12 [rad]", "twist23 [rad]", "twist12_std [rad]", "twist23_std [rad]"):
        assert col in head
    assert data.shape[0] == 401
    assert s["steps"] == 400 and s["failures"] == 0 and s["step_time_median_ms"] > 0
    assert s["step_time_p95_ms"] >= s["step_time_median_ms"]
    if kind != "fd":
        assert s["twist12_rmse_after_1s_rad"] < 0.02 and s["twist23_rmse_after_1s_rad"] < 0.02
        assert s["twist12_rmse_rad"] >= s["twist12_rmse_after_1s_rad"]
        assert np.all(data[50:, head.index("twist12_std [rad]")] < 0.05)


def test_estimate_refuses_overwrite_and_bad_input(log_path, tmp_path, capsys):
    out = tmp_path / "e.csv"
    out.write_text("keep\n")
    assert main(["estimate", str(log_path), "--out", str(out), "--no-compile"]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text() == "keep\n"
    assert main(["estimate", str(log_path), "--out", str(tmp_path / "x.csv"), "--channels", "omega9"]) == 2
    assert "omega9" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("t [s],omega1 [rad/s]\n0,0\n0.01,0\n")
    assert main(["estimate", str(bad), "--out", str(tmp_path / "y.csv")]) == 2
    assert "omega_ref" in capsys.readouterr().err
    assert not (tmp_path / "y.csv").exists()
