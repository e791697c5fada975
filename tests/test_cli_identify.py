"""`mitigate identify`: exit codes, outputs, no overwrite, one-line errors."""

import json

import numpy as np
import pytest

from mitigate.cli import main
from models.params import load_params, published
from models.rigs import get_model
from models.plant import SimOptions, simulate


@pytest.fixture(scope="module")
def disc_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_id")
    true = published("disc").replace(k=1.0, mu_k=0.28)
    simulate(get_model("disc"), true, np.array([1.0, 20.0]), 6.0, SimOptions(seed=4)).to_log().write_csv(d / "disc.csv")
    return d / "disc.csv"


def test_identify_writes_params_and_plot(disc_csv, tmp_path, capsys):
    out, png = tmp_path / "fitted.toml", tmp_path / "fit.png"
    rc = main(["identify", str(disc_csv), "--model", "disc", "--free", "k,mu_k", "--out", str(out),
               "--plot", str(png), "--nsub", "10", "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["success"] and set(doc["parameters"]) == {"k", "mu_k"}
    p = load_params(out, "disc")  # every other command accepts it
    assert p.k == pytest.approx(1.0, rel=0.03) and p.mu_k == pytest.approx(0.28, rel=0.05)
    assert p.stderr_of("k") > 0
    assert png.stat().st_size > 10_000
    # never overwrite without --force
    rc = main(["identify", str(disc_csv), "--model", "disc", "--free", "k", "--out", str(out)])
    assert rc == 2
    assert "refusing to overwrite" in capsys.readouterr().err


def test_table_output(disc_csv, tmp_path, capsys):
    rc = main(["identify", str(disc_csv), "--model", "disc", "--free", "k", "--out", str(tmp_path / "f.toml"),
               "--nsub", "10"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "estimate" in text and "published" in text and "N m/rad" in text
    assert "--bootstrap 6" in text  # points to error bars that include the bias
    assert "errors in the variables: n1 0.2" in text and "(detected)" in text  # the load-cell noise, found
    assert (tmp_path / "f.png").stat().st_size > 10_000        # the measured-vs-fitted PNG, by default
    rc = main(["identify", str(disc_csv), "--model", "disc", "--free", "k", "--out", str(tmp_path / "g.toml"),
               "--nsub", "10", "--no-plot"])
    assert rc == 0 and (tmp_path / "g.toml").exists() and not (tmp_path / "g.png").exists()


@pytest.mark.parametrize("args, msg", [
    (["--free", "k,zz"], "unknown parameter 'zz'"),
    (["--free", "k", "--holdout", "0.95"], "--holdout must be"),
    (["--free", "k", "--input-cutoff", "n1"], "--input-cutoff must look like CHANNEL=HZ"),
    (["--free", "k", "--input-cutoff", "n2=0.5"], "n2 is not an input of disc"),
    (["--free", "k", "--input-cutoff", "n1=-1"], "must be a frequency > 0 Hz"),
    (["--free", "k", "--bootstrap", "1"], "--bootstrap must be an integer >= 2"),
    (["--free", "k", "--input-noise", "n1"], "--input-noise must look like CHANNEL=STD"),
    (["--free", "k", "--input-noise", "n2=0.2"], "--input-noise: n2 is not an input of disc"),
    (["--free", "k", "--input-noise", "n1=0"], "--input-noise n1: the std must be a number > 0"),
    (["--free", "k", "--bootstrap", "3", "--systematic"], "--bootstrap and --systematic are alternatives"),
    (["--free", "k", "--bootstrap", "3", "--workers", "0"], "--workers must be an integer >= 1"),
    (["--free", "k", "--bootstrap", "3", "--encoder-ticks", "0"], "sensors.ticks_per_rev must be an integer >= 1"),
    (["--free", "k", "--bootstrap", "3", "--force-noise", "-1"], "sensors.force_noise must be a finite number >= 0"),
])
def test_bad_arguments_exit_2_and_write_nothing(disc_csv, tmp_path, capsys, args, msg):
    out = tmp_path / "f.toml"
    rc = main(["identify", str(disc_csv), "--model", "disc", "--out", str(out)] + args)
    assert rc == 2
    err = capsys.readouterr().err
    assert msg in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_malformed_log_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t [s],omega1 [rad/s],omega3 [rad/s],n1 [N]\n0,1,1,20\n0.01,nan,1,20\n0.02,1,1,20\n")
    out = tmp_path / "f.toml"
    rc = main(["identify", str(bad), "--model", "disc", "--free", "k", "--out", str(out)])
    assert rc == 2
    assert "column 'omega1' row 2" in capsys.readouterr().err
    assert not out.exists()


def test_log_without_model_inputs_exit_2(disc_csv, tmp_path, capsys):
    rc = main(["identify", str(disc_csv), "--model", "rig2", "--free", "k", "--out", str(tmp_path / "f.toml")])
    assert rc == 2
    assert "missing input column 'motor_torque'" in capsys.readouterr().err


def test_systematic_flag_prints_columns_and_writes_total(disc_csv, tmp_path, capsys):
    out = tmp_path / "f.toml"
    rc = main(["identify", str(disc_csv), "--model", "disc", "--free", "k", "--out", str(out), "--nsub", "10",
               "--systematic"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "syst. error" in text and "total error" in text
    assert "TOTAL error" in out.read_text()
    p = load_params(out, "disc")
    rc = main(["identify", str(disc_csv), "--model", "disc", "--free", "k", "--out", str(tmp_path / "g.toml"),
               "--nsub", "10", "--json", "--systematic"])
    doc = json.loads(capsys.readouterr().out)["parameters"]["k"]
    assert rc == 0 and doc["syserr"] >= 0 and doc["error"] >= doc["stderr"]
    assert p.stderr_of("k") == pytest.approx(doc["error"])


def test_bootstrap_writes_rms_error_as_stderr(disc_csv, tmp_path, capsys):
    out = tmp_path / "boot.toml"
    rc = main(["identify", str(disc_csv), "--model", "disc", "--free", "k,mu_k", "--out", str(out),
               "--nsub", "10", "--bootstrap", "2", "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    b = doc["bootstrap"]
    assert b["success"] and b["replicates"] == 2 and b["names"] == ["k", "mu_k"]
    assert np.allclose(b["error"], np.hypot(b["bias"], b["sd"]))
    p = load_params(out, "disc")
    assert p.stderr_of("k") == pytest.approx(b["error"][0]) and p.stderr_of("mu_k") == pytest.approx(b["error"][1])
