"""Identification and online estimation checked against logs of the independent simulator
(tests/independent_rig3.py: scipy only, written from the thesis' description, no code of ours).

The figures they are held to are BENCHMARKS.md's ("Online estimators", case (d): EKF and MHE
twist RMSE 0.7 % of the twist's range over 60 s; "Identification", independent simulator:
k1 <= +0.24 %, k2 -0.05...+0.07 %, mu_k +-0.2 % over 60 s logs), with margins for the shorter logs
here (20 s and 10 s, to keep these tests under ~20 s of CPU).
"""

import math

import numpy as np
import pytest

import independent_rig3 as ir
from estimators import IdentifyOptions, estimate_log, identify
from estimators.online.replay import true_twists
from models import get_model
from models.logs import read_csv

pytestmark = pytest.mark.slow

#: the operating point of BENCHMARKS.md's estimator case (d): 30 rpm, N1 = 20 N
W_REF, N1 = math.pi, 20.0


def _csv(tmp_path, name, raw, power_on=0.0):
    """The simulator's log as the rig's CSV, encoders zeroed at ``power_on`` [s] (rows before dropped)."""
    k0 = int(round(power_on / 0.01))
    n = len(raw["t"])
    cut = {c: np.asarray(v, float)[k0:].copy() for c, v in raw.items() if np.ndim(v) == 1 and len(v) == n}
    cut["t"] -= cut["t"][0]
    for c in ("theta1", "theta2", "theta3"):
        cut[c] -= cut[c][0]
    path = tmp_path / name
    ir.write_csv(path, cut)
    return read_csv(path)


@pytest.fixture(scope="module")
def powered_on(tmp_path_factory):
    """25 s of stick-slip; the DAQ powers on at 5 s on the twisted shaft (encoders zeroed there)."""
    raw = ir.simulate_log(ir.RigOptions(), W_REF, N1, 0.0, duration=25.0, seed=7)
    log = _csv(tmp_path_factory.mktemp("ind"), "powered_on.csv", raw, power_on=5.0)
    model = get_model("rig3")
    return log, model, true_twists(log, model), {k: estimate_log(log, k, model) for k in ("ekf", "mhe")}


def test_the_log_carries_both_true_twists(powered_on):
    log, model, truth, _ = powered_on
    assert sorted(truth) == ["twist_shaft1", "twist_shaft2"]
    assert all(np.ptp(v[200:]) > 0.3 for v in truth.values())      # stick-slip: a range to compare with


@pytest.mark.parametrize("kind", ["ekf", "mhe"])
def test_twist_rmse_against_the_independent_simulator(powered_on, kind):
    log, _, truth, results = powered_on
    res = results[kind]
    assert res.success and res.counts["failures"] == 0 and res.counts["fallbacks"] == 0, res.message
    assert res.x.shape == (len(log.t), len(res.names)) and res.units[res.names.index("twist_shaft1")] == "rad"
    for name, true in truth.items():
        rel = res.rmse(name, true, after=2.0) / np.ptp(true[200:])
        # BENCHMARKS.md: 0.7 % over 60 s; measured 1.2 % (shaft1) / 0.9 % (shaft2) over these 20 s
        assert rel < 0.02, f"{kind} {name}: twist RMSE {100 * rel:.2f} % of its range"
        # the filter's own standard deviation is honest: the error is within a few of them
        err = res.state(name)[201:] - true[201:]
        std = res.std[201:, res.names.index(name)]
        assert np.mean(np.abs(err) <= 3 * std) > 0.9


def test_ekf_and_mhe_agree(powered_on):
    _, _, truth, results = powered_on
    ekf, mhe = results["ekf"], results["mhe"]
    assert ekf.names == mhe.names and ekf.channels == mhe.channels
    for name, true in truth.items():
        gap = np.sqrt(np.mean((ekf.state(name)[200:] - mhe.state(name)[200:]) ** 2))
        assert gap < 0.005 * np.ptp(true[200:]), f"{name}: EKF and MHE differ by {gap:.3g} rad RMS"


@pytest.mark.parametrize("seed, options", [
    (1, dict(encoder_zero="untwisted")),
    (4, dict(encoder_zero="free")),
])
def test_identification_recovers_k1_k2_mu_k(tmp_path, seed, options):
    ic = {} if seed == 1 else dict(initial_condition="twisted", initial_twist12=0.1, initial_twist23=-0.2)
    raw = ir.simulate_log(ir.RigOptions(**ic), W_REF, N1, 0.0, duration=10.0, seed=seed)
    log = _csv(tmp_path, f"ind{seed}.csv", raw)
    true = get_model("rig3").published()      # the thesis' values, which the simulator uses too
    fit = identify(log, "rig3", None, IdentifyOptions(free=("k1", "k2", "mu_k"), input_row="start", **options))
    assert fit.success, fit.message
    err = {n: (e - true[n]) / true[n] for n, e in zip(fit.names, fit.estimate)}
    # BENCHMARKS.md (60 s logs, 6 free): k1 <= +0.24 %, k2 -0.05...+0.07 %, mu_k +-0.2 %; 10 s logs here
    assert abs(err["k1"]) < 0.01 and abs(err["k2"]) < 0.01 and abs(err["mu_k"]) < 0.01, err
