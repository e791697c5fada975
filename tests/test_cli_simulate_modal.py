"""`mitigate simulate` and `mitigate modal`: outputs, scenarios, exit codes, no overwrite."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mitigate.scenario import load_scenario
from models import get_model
from models.errors import ConfigError
from models.logs import read_csv
from models.plant import simulate

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "scenarios"

SHORT = """[scenario]
name = "short"
model = "rig3"
duration = 4.0
seed = 2
[inputs]
omega_ref = { kind = "constant", value = 30, unit = "rpm" }
n1 = { kind = "constant", value = 20.0 }
"""






def _runs(mask):
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return np.flatnonzero(d == -1) - np.flatnonzero(d == 1)


@pytest.mark.slow
def test_open_stick_slip_scenario_sticks_exactly_and_open_steady_does_not():
    sc = load_scenario(SCEN / "open_stick_slip.toml")
    assert (sc.name, sc.duration, sc.inputs["n1"](10.0)) == ("open_stick_slip", 60.0, 20.0)
    assert sc.inputs["omega_ref"](10.0) == pytest.approx(math.pi)
    m = get_model("rig3")
    r = simulate(m, sc.plant_params, sc.programme, sc.duration, sc.sim, sensors=None)
    w1 = r.state("omega_R1")
    late = r.t > 30
    stuck = (w1 == 0.0) & late
    assert stuck.sum() / late.sum() > 0.1                  # measured 0.17
    assert np.all(_runs(stuck) >= 10)                      # whole intervals of >= 0.1 s at exactly 0
    assert len(_runs(stuck)) >= 10
    sc2 = load_scenario(SCEN / "open_steady.toml")
    r2 = simulate(m, sc2.plant_params, sc2.programme, sc2.duration, sc2.sim, sensors=None)
    tail = r2.state("omega_R1")[r2.t > 30]
    assert np.all(tail > 0.5 * math.pi)                    # slides, never sticks after start-up
    assert np.ptp(tail) < 0.2 * math.pi


def test_simulate_writes_log_and_png(main, tmp_path, capsys):
    sc = tmp_path / "short.toml"
    sc.write_text(SHORT)
    out = tmp_path / "out"
    assert main(["simulate", str(sc), "--out", str(out), "--truth", "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["status"] == "ok" and 0 < payload["stuck_fraction_true"] < 1 and payload["body"] == "R1"
    log = read_csv(out / "short.csv", required=("omega1", "omega2", "omega3", "motor_torque", "true_twist_shaft1",
                                                "true_twist_shaft2", "true_omega_R1"))
    assert log.t[-1] == pytest.approx(4.0)
    assert (out / "short.png").stat().st_size > 10_000
    # the log is the measured one: quantised R1 angle
    q = 2 * math.pi / 1000
    np.testing.assert_allclose(log["theta1"] / q, np.round(log["theta1"] / q), atol=1e-6)


def test_simulate_refuses_to_overwrite_without_force(main, tmp_path, capsys):
    sc = tmp_path / "short.toml"
    sc.write_text(SHORT)
    out = tmp_path / "out"
    assert main(["simulate", str(sc), "--out", str(out), "--no-plot"]) == 0
    before = (out / "short.csv").read_bytes()
    (out / "short.csv").write_text("sentinel")
    assert main(["simulate", str(sc), "--out", str(out), "--no-plot"]) == 2
    assert "exists" in capsys.readouterr().err
    assert (out / "short.csv").read_text() == "sentinel"
    assert main(["simulate", str(sc), "--out", str(out), "--no-plot", "--force"]) == 0
    assert (out / "short.csv").read_bytes() == before


@pytest.mark.parametrize("text, match", [
    (SHORT + "[plant]\nmethod = \"euler\"\n", "plant.*method"),
    (SHORT + "[structure]\ndelay = -1\n", r"structure\.delay must be an integer"),
    (SHORT.replace("duration = 4.0\n", ""), "scenario.duration: missing field"),
    (SHORT.replace("duration = 4.0", "duration = nan"), "scenario.duration must be a finite number"),
    (SHORT + "[mismatch]\nJ1 = -1.0\n", "mismatch.J1 must be > 0"),
    (SHORT + "[wobble]\nx = 1\n", "wobble: unknown section"),
    (SHORT.replace("n1 = { kind = \"constant\", value = 20.0 }", "n1 = { kind = \"constant\", value = -2.0 }"), "n1"),
])
def test_bad_scenarios_exit_2_and_write_nothing(main, tmp_path, capsys, text, match):
    sc = tmp_path / "bad.toml"
    sc.write_text(text)
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match=match):
        load_scenario(sc)
    assert main(["simulate", str(sc), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mitigate simulate: error:")
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow
def test_bad_scenario_subprocess_no_traceback(tmp_path):
    sc = tmp_path / "bad.toml"
    sc.write_text(SHORT + "[plant]\nparams = \"missing.toml\"\n")
    out = tmp_path / "D"
    r = subprocess.run([sys.executable, "-m", "mitigate.cli", "simulate", str(sc), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert "not found" in r.stderr
    assert not out.exists()


@pytest.mark.slow
def test_modal_json_and_png(main, tmp_path, capsys):
    out = tmp_path / "m"
    assert main(["modal", "--out", str(out), "--json", "--no-map"]) == 0
    d = json.loads(capsys.readouterr().out)
    cmp = {c["mode"]: c for c in d["variants"]["closed"]["comparison"]}
    assert cmp["mode 1"]["model_hz"] == pytest.approx(0.427, abs=2e-3)
    assert cmp["mode 2"]["model_hz"] == pytest.approx(1.817, abs=3e-3)
    assert d["variants"]["free"]["freq_hz"][0] == 0.0
    assert (out / "modal_rig3.png").exists()
    assert main(["modal", "--out", str(out), "--no-map"]) == 2           # exists, no --force
    assert "exists" in capsys.readouterr().err


@pytest.mark.slow
def test_modal_accepts_fitted_params_and_rejects_bad_ones(main, tmp_path, capsys):
    p = get_model("rig3").published().replace(k1=2 * 1.1175)
    f = p.save(tmp_path / "fit.toml")
    assert main(["modal", "--params", str(f), "--variant", "clamped", "--out", str(tmp_path / "o"), "--json",
                 "--no-map"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["variants"]["clamped"]["freq_hz"][1] > 1.9        # stiffer k1 raises the upper mode
    bad = tmp_path / "bad.toml"
    bad.write_text('model = "rig3"\nbase = "published"\n[params]\nJ1 = -1\n')
    assert main(["modal", "--params", str(bad), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert "J1 must be > 0" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o2").exists()
    # any rig file has every variant now; a rig that does not exist, or a negative load, is refused
    assert main(["modal", "--model", "disc", "--variant", "free", "--out", str(tmp_path / "o3"), "--no-map"]) == 0
    capsys.readouterr()
    assert main(["modal", "--model", "rig9", "--out", str(tmp_path / "o4")]) == 2
    assert "model must be a shipped rig" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:         # argparse's own refusal: the flag's type says what it takes
        main(["modal", "--load", "-1", "--out", str(tmp_path / "o5")])
    assert exc.value.code == 2
    assert "argument --load: expected a force >= 0 N" in capsys.readouterr().err
    assert not (tmp_path / "o4").exists() and not (tmp_path / "o5").exists()


def test_help_has_examples(main, capsys):
    for cmd in ("simulate", "modal"):
        with pytest.raises(SystemExit) as exc:
            main([cmd, "--help"])
        assert exc.value.code == 0
        out = capsys.readouterr().out
        assert "mitigate " + cmd in out and "example" in out


def test_modal_without_out_prints_and_writes_nothing(main, tmp_path, monkeypatch, capsys):
    """The issue's check, `mitigate modal --model models/rigs/four_disc.toml --json`, can be run twice."""
    monkeypatch.chdir(tmp_path)
    for _ in range(2):
        assert main(["modal", "--model", str(ROOT / "models" / "rigs" / "four_disc.toml"), "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert len(doc["variants"]["clamped"]["freq_hz"]) == 4 and "png" not in doc
    assert list(tmp_path.iterdir()) == []
