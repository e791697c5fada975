"""`mitigate identify`: exit codes, outputs, no overwrite, one-line errors in the flags' words."""

import json
import shutil

import numpy as np
import pytest

import mitigate.cli as cli
from models import get_model, published
from models.rig import load_params
from models.plant import SimOptions, simulate
from models.rig import RIGS_DIR

main = cli.main


@pytest.fixture(scope="module")
def disc_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_id")
    true = published("disc").replace(k=1.0, mu_k=0.28)
    simulate(get_model("disc"), true, np.array([1.0, 20.0]), 6.0, SimOptions(seed=4)).to_log().write_csv(d / "disc.csv")
    return d / "disc.csv"


def _run(disc_csv, out, *args):
    return main(["identify", str(disc_csv), "--model", "disc", "--out", str(out), "--encoder-zero", "untwisted",
                 "--nsub", "10", *args])


@pytest.mark.slow
def test_identify_writes_params_and_plot(disc_csv, tmp_path, capsys):
    out, png = tmp_path / "fitted.toml", tmp_path / "fit.png"
    rc = _run(disc_csv, out, "--free", "k,mu_k", "--plot", str(png), "--json")
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["success"] and doc["status"] == "ok" and set(doc["parameters"]) == {"k", "mu_k"}
    assert doc["condition"] > 1 and doc["weak_directions"] and doc["encoder_zero"] == [{}]
    assert doc["rig_file"] == {"k": 1.1175, "mu_k": 0.306} and doc["rig_file_sources"]["mu_k"] == "thesis eq. 3-14"
    p = load_params(out, "disc")  # every other command accepts it
    assert p.k == pytest.approx(1.0, rel=0.03) and p.mu_k == pytest.approx(0.28, rel=0.05)
    assert p.stderr_of("k") > 0
    assert png.stat().st_size > 10_000
    # never overwrite without --force
    rc = _run(disc_csv, out, "--free", "k")
    assert rc == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert _run(disc_csv, out, "--free", "k", "--force", "--no-plot") == 0


@pytest.mark.slow
def test_table_output(disc_csv, tmp_path, capsys):
    rc = _run(disc_csv, tmp_path / "f.toml", "--free", "k")
    assert rc == 0
    text = capsys.readouterr().out
    assert "estimate" in text and "rig file" in text and "N m/rad" in text and "published" not in text
    assert "the rig file's values (disc): k from thesis eq. 3-7 (k1)" in text       # the source says it is the thesis
    assert "status: ok" in text and "conditioning: condition number" in text
    assert "--bootstrap 6" in text                      # points to error bars that include the bias
    assert "errors in the variables: n1 0.2" in text     # the load-cell noise, detected
    assert (tmp_path / "f.png").stat().st_size > 10_000  # the measured-vs-fitted PNG, by default
    rc = _run(disc_csv, tmp_path / "g.toml", "--free", "k", "--no-plot")
    assert rc == 0 and (tmp_path / "g.toml").exists() and not (tmp_path / "g.png").exists()


@pytest.mark.slow
def test_rig_file_path_and_guess(disc_csv, tmp_path, capsys):
    rig = tmp_path / "my_disc.toml"
    shutil.copy(RIGS_DIR / "disc.toml", rig)
    rc = main(["identify", str(disc_csv), "--model", str(rig), "--free", "k,mu_k", "--out", str(tmp_path / "f.toml"),
               "--no-plot", "--encoder-zero", "untwisted"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "guess: " in text                              # no --params: starting values from the data
    assert load_params(tmp_path / "f.toml", str(rig)).k == pytest.approx(1.0, rel=0.03)


@pytest.mark.parametrize("args, msg", [
    (["--free", "k,zz"], "unknown parameter 'zz'"),
    (["--free", "k", "--holdout", "0.95"], "--holdout must be a fraction"),
    (["--free", "k", "--input-cutoff", "n1"], "--input-cutoff must look like CHANNEL=FREQUENCY"),
    (["--free", "k", "--input-cutoff", "n2=0.5"], "--input-cutoff n2: not an input of rig 'disc'"),
    (["--free", "k", "--input-cutoff", "n1=-1"], "--input-cutoff n1 must be > 0 Hz"),
    (["--free", "k", "--bootstrap", "1"], "--bootstrap must be an integer >= 2"),
    (["--free", "k", "--input-noise", "n1"], "--input-noise must look like CHANNEL=STD"),
    (["--free", "k", "--input-noise", "n2=0.2"], "--input-noise n2: not an input of rig 'disc'"),
    (["--free", "k", "--input-noise", "n1=0"], "--input-noise n1: expected a force > 0 N"),
    (["--free", "k", "--input-noise", "n1=0.2 N m"], "--input-noise n1: expected a force > 0 N"),
    (["--free", "k", "--input-cutoff", "n1=0.5 N"], "--input-cutoff n1: expected a rate (a number in 1/s, or with"),
    (["--free", "k", "--bootstrap", "3", "--systematic"], "--bootstrap and --systematic are alternatives"),
    (["--free", "k", "--bootstrap", "3", "--workers", "0"], "--workers must be an integer >= 1"),
    (["--free", "k", "--bootstrap", "3", "--noise-scale", "-1"], "--noise-scale must be >= 0"),
    (["--free", "k", "--eps", "-1"], "--eps must be > 0 rad/s"),
    (["--free", "k", "--shoot-every", "0"], "--shoot-every must be an integer >= 1"),
    (["--free", "k", "--constraint", "k <"], "--constraint must read 'EXPRESSION <= NUMBER'"),
    (["--free", "k", "--constraint", "k + zz <= 1"], "--constraint: 'zz' in 'k + zz <= 1' is not a parameter"),
    (["--free", "k", "--outputs", "omega3"], "--outputs: 'omega3' is not an output channel of rig 'disc'"),
    (["--free", "mu_k,mu_s", "--params", "BAD"], "parameter file not found"),
])
def test_bad_arguments_exit_2_and_write_nothing(disc_csv, tmp_path, capsys, args, msg):
    out = tmp_path / "f.toml"
    args = [str(tmp_path / "nope.toml") if a == "BAD" else a for a in args]
    rc = main(["identify", str(disc_csv), "--model", "disc", "--out", str(out)] + args)
    assert rc == 2
    err = capsys.readouterr().err
    assert msg in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_unknown_model_and_malformed_log_exit_2(disc_csv, tmp_path, capsys):
    rc = main(["identify", str(disc_csv), "--model", "rig9", "--free", "k", "--out", str(tmp_path / "f.toml")])
    assert rc == 2 and "model must be a shipped rig" in capsys.readouterr().err
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


def test_unconverged_fit_exits_1_and_says_what_to_try(disc_csv, tmp_path, capsys):
    rc = _run(disc_csv, tmp_path / "f.toml", "--free", "k,d,mu_k,mu_s", "--max-iter", "1", "--no-plot")
    assert rc == 1
    text = capsys.readouterr().out
    assert "status: not converged: stopped at the iteration limit" in text and "Try:" in text
    assert "--max-iter 2" in text


@pytest.mark.slow
def test_systematic_flag_prints_columns_and_writes_total(disc_csv, tmp_path, capsys):
    out = tmp_path / "f.toml"
    rc = _run(disc_csv, out, "--free", "k", "--systematic", "--no-plot")
    assert rc == 0
    text = capsys.readouterr().out
    assert "syst. error" in text and "total error" in text
    assert "TOTAL error" in out.read_text()
    p = load_params(out, "disc")
    rc = _run(disc_csv, tmp_path / "g.toml", "--free", "k", "--json", "--systematic", "--no-plot")
    doc = json.loads(capsys.readouterr().out)["parameters"]["k"]
    assert rc == 0 and doc["syserr"] >= 0 and doc["error"] >= doc["stderr"]
    assert p.stderr_of("k") == pytest.approx(doc["error"])


@pytest.mark.slow
def test_bootstrap_writes_rms_error_as_stderr(disc_csv, tmp_path, capsys):
    out = tmp_path / "boot.toml"
    rc = _run(disc_csv, out, "--free", "k,mu_k", "--bootstrap", "2", "--json", "--no-plot")
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    b = doc["bootstrap"]
    assert b["success"] and b["replicates"] == 2 and b["names"] == ["k", "mu_k"]
    assert np.allclose(b["error"], np.hypot(b["bias"], b["sd"]))
    p = load_params(out, "disc")
    assert p.stderr_of("k") == pytest.approx(b["error"][0]) and p.stderr_of("mu_k") == pytest.approx(b["error"][1])


def test_help_has_examples(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["identify", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text and "--model drillstring" in text and "--encoder-zero untwisted" in text
