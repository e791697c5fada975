"""MHE for rig3: stick-slip tracking from a wrong start, agreement with the EKF, arrival cost, fallback, dropouts."""

import math

import numpy as np
import pytest

from estimators.ekf import EKF, EKFOptions
from estimators.factory import make_estimator
from estimators.mhe import MHE, MHEOptions, make_mhe
from models import get_model
from models.errors import ConfigError
from models.sensors import SensorOptions
from models.plant import SimOptions, simulate

M = get_model("rig3")
P3 = M.published()
U = np.array([math.pi, 20.0, 0.0])
SPEEDS_TORQUE = ("omega1", "omega2", "omega3", "motor_torque")


@pytest.fixture(scope="module")
def sim():
    return simulate(M, P3, U, 8.0, SimOptions(seed=5))


def run(est, sim, n=None):
    n = len(sim.t) if n is None else n
    X = np.zeros((n, len(est.names)))
    out = []
    for k in range(1, n):
        e = est.update({c: sim.y[c][k] for c in sim.y}, sim.u[k - 1], sim.t[k])
        X[k] = e.x
        out.append(e)
    return X, out


def test_mhe_tracks_stick_slip_from_wrong_start_and_agrees_with_ekf(sim):
    x0 = sim.x[0].copy()
    x0[0] += 0.3
    x0[1] -= 0.4
    o = dict(channels=SPEEDS_TORQUE, compile=False)
    mhe = MHE(P3, SensorOptions(), 0.01, MHEOptions(window=10, **o), x0=x0)
    ekf = EKF(P3, SensorOptions(), 0.01, EKFOptions(**o), x0=x0)
    X, ests = run(mhe, sim)
    XE, _ = run(ekf, sim)
    late = sim.t > 3.0
    stick = late & (sim.x[:, 2] == 0)
    assert stick.sum() > 50
    rm = np.sqrt(np.mean((X[late, :2] - sim.x[late, :2]) ** 2, axis=0))
    rm_stick = np.sqrt(np.mean((X[stick, :2] - sim.x[stick, :2]) ** 2, axis=0))
    re = np.sqrt(np.mean((XE[late, :2] - sim.x[late, :2]) ** 2, axis=0))
    assert np.all(rm < 0.03) and np.all(rm_stick < 0.03), (rm, rm_stick)
    assert np.all(rm < 1.5 * re + 2e-3), (rm, re)            # no worse than the EKF (within noise)
    assert np.max(np.abs(X[late, :2] - XE[late, :2])) < 0.05  # the two methods agree
    assert mhe.counts.failures == 0 and all(e.success for e in ests)
    assert all(np.all(np.linalg.eigvalsh(e.P) > 0) for e in ests[-5:])


def test_arrival_cost_is_updated_not_fixed(sim):
    mhe = MHE(P3, SensorOptions(), 0.01, MHEOptions(window=5, compile=False))
    run(mhe, sim, n=8)
    P1 = mhe._Pbar.copy()
    run(mhe, type(sim)(sim.t[7:], sim.x[7:], sim.u[7:], {c: v[7:] for c, v in sim.y.items()}, {}), n=3)
    assert not np.allclose(P1, mhe._Pbar)


def test_solver_failure_falls_back_to_ekf_and_is_counted(sim):
    mhe = MHE(P3, SensorOptions(), 0.01, MHEOptions(window=5, compile=False))
    run(mhe, sim, n=10)

    def broken():
        raise RuntimeError("injected solver failure")

    mhe._gn_eval = broken
    k = 10
    e = mhe.update({c: sim.y[c][k] for c in sim.y}, sim.u[k - 1], sim.t[k])
    assert not e.success and "injected solver failure" in e.status and "EKF" in e.status
    np.testing.assert_array_equal(e.x, mhe.ekf.last.x)
    assert mhe.counts.failures == 1 and mhe.counts.fallbacks == 1
    e2 = mhe.update({c: sim.y[c][k + 1] for c in sim.y}, sim.u[k], sim.t[k + 1])
    assert not e2.success and mhe.counts.failures == 2 and np.all(np.isfinite(e2.x))


def test_dropout_is_counted_and_skips_channels(sim):
    mhe = MHE(P3, SensorOptions(), 0.01, MHEOptions(window=5, compile=False))
    run(mhe, sim, n=10)
    meas = {c: sim.y[c][10] for c in sim.y}
    meas["omega2"] = float("nan")
    e = mhe.update(meas, sim.u[9], sim.t[10])
    assert e.success and "omega2" in e.status and mhe.counts.dropouts == 1
    e = mhe.update({}, sim.u[10], sim.t[11])
    assert e.success and not e.corrected and mhe.counts.dropouts == 2 and np.all(np.isfinite(e.x))


def test_factory_and_options():
    est = make_estimator({"kind": "mhe", "window": 4, "compile": False}, P3, SensorOptions(), 0.01)
    assert isinstance(est, MHE) and est.N == 4
    with pytest.raises(ConfigError, match=r"estimator.window must be an integer >= 2"):
        make_mhe({"window": 1}, P3, SensorOptions(), 0.01)
    with pytest.raises(ConfigError, match=r"unknown key 'horizon'"):
        make_mhe({"horizon": 10}, P3, SensorOptions(), 0.01)
    with pytest.raises(ConfigError, match=r"qpsol must be one of"):
        make_mhe({"qpsol": "ipopt"}, P3, SensorOptions(), 0.01)
