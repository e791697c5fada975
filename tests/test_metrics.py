"""Closed-loop metrics against hand-computed values."""

import math

import numpy as np
import pytest

from mitigate import metrics as M
from mitigate.closedloop import ClosedLoopResult
from models.params import published


def test_rms_hand_computed():
    assert M.rms(np.array([3.0, 4.0])) == pytest.approx(math.sqrt(12.5))
    assert M.rms(np.array([-2.0, -2.0, -2.0])) == pytest.approx(2.0)


def test_friction_work_coulomb_and_stribeck():
    # Coulomb (mu_s = mu_k): mu N r |w| T = 0.3 * 10 N * 0.04 m * 2 rad/s * 1 s = 0.24 J
    w = np.full(100, 2.0)
    assert M.friction_work(w, np.full(100, 10.0), 0.04, 0.3, 0.3, 1.0, 0.01) == pytest.approx(0.24)
    # sign of the speed does not matter; Stribeck raises mu by (mu_s - mu_k) exp(-|w|/v_s)
    mu = 0.306 + (0.5 - 0.306) * math.exp(-2.0)
    assert M.friction_work(-w, np.full(100, 10.0), 0.04, 0.5, 0.306, 1.0, 0.01) == pytest.approx(mu * 10 * 0.04 * 2)
    # no normal force or no sliding: no work
    assert M.friction_work(w, np.zeros(100), 0.04, 0.5, 0.3, 1.0, 0.01) == 0.0
    assert M.friction_work(np.zeros(100), np.full(100, 10.0), 0.04, 0.5, 0.3, 1.0, 0.01) == 0.0


def test_solve_time_stats():
    s = M.solve_time_stats(np.arange(1, 101) / 1000.0)
    assert s["median"] == pytest.approx(0.0505)
    assert s["p95"] == pytest.approx(0.09505)
    assert s["max"] == pytest.approx(0.1)
    assert all(math.isnan(v) for v in M.solve_time_stats(np.array([])).values())


def _result(omega1, phi12, n2, i, control_start, dt=0.1):
    n = len(omega1)
    t = np.arange(n) * dt
    x = np.zeros((n, 7))
    x[:, 0] = phi12
    x[:, 2] = omega1
    x[:, 3] = omega1
    x[:, 5] = i
    u = np.zeros((n, 3))
    u[:, 2] = n2
    return ClosedLoopResult(t=t, x=x, y={"omega1": np.asarray(omega1, float)}, xhat=x.copy(),
                            xhat_names=("phi12", "phi23", "omega1", "omega2", "omega3", "i", "z"),
                            action_n2=u[:, 2], action_omega_ref=np.full(n, 1.0), u=u,
                            controller_active=t >= control_start, controller_ok=np.ones(n, bool),
                            solve_times=np.array([0.001, 0.002, 0.003]), plan_calls=np.array([False, True, True]),
                            estimator_times=np.zeros(n),
                            controller_counts={"steps": 3, "failures": 1, "fallbacks_shift": 2,
                                               "fallbacks_baseline": 1},
                            estimator_counts={"steps": n, "failures": 0, "fallbacks": 0, "dropouts": 4},
                            states=("phi12", "phi23", "omega1", "omega2", "omega3", "i", "z"),
                            inputs=("omega_ref", "n1", "n2"), control_start=control_start)


def test_closed_loop_metrics_hand_computed():
    p = published("rig3")
    # before the start (t < 0.4 s) wild values that must be ignored
    w1 = np.array([50.0, -50.0, 50.0, -50.0, 0.0, 2.0, 0.0, 2.0, 0.0, 2.0])
    phi = np.array([9, 9, 9, 9, 0.1, -0.1, 0.1, -0.1, 0.1, -0.1])
    cur = np.array([9, 9, 9, 9, 1.0, 3.0, 1.0, 3.0, 1.0, 3.0])
    n2 = np.array([0, 0, 0, 0, 5.0, 5.0, 5.0, 5.0, 5.0, 5.0])
    m = M.closed_loop_metrics(_result(w1, phi, n2, cur, control_start=0.4), p, window=0.2)
    # after the start omega1 alternates 0, 2: mean 1, SSS = (2 - 0) / (2 * 1) = 1
    assert m["sss"] == pytest.approx(1.0)
    assert m["sss_window_max"] == pytest.approx(1.0)
    assert m["sss_final"] == pytest.approx(1.0)
    assert m["stuck_fraction"] == pytest.approx(0.5)
    assert m["stuck_fraction_measured"] == pytest.approx(0.5)
    assert m["mean_omega1"] == pytest.approx(1.0)
    assert m["rms_twist12"] == pytest.approx(0.1)
    assert m["std_twist12"] == pytest.approx(0.1)
    # motor torque eta KT i alternates eta KT (1, 3): std = eta KT * 1
    assert m["motor_torque_std"] == pytest.approx(p.eta * p.KT)
    # three sliding samples at 2 rad/s, 5 N, 0.1 s each
    mu = p.mu_k + (p.mu_s - p.mu_k) * math.exp(-2.0 / p.v_s)
    assert m["friction_work_pin2"] == pytest.approx(3 * mu * 5.0 * p.r2 * 2.0 * 0.1)
    assert m["mean_n2"] == pytest.approx(5.0)
    assert m["solve_median_ms"] == pytest.approx(2.0)
    assert m["solve_max_ms"] == pytest.approx(3.0)
    # planning calls only (the first call was a hold): 2 and 3 ms
    assert m["plan_median_ms"] == pytest.approx(2.5) and m["plan_max_ms"] == pytest.approx(3.0)
    assert m["plan_calls"] == 2
    assert m["controller_fallbacks"] == 3 and m["controller_failures"] == 1
    assert m["estimator_dropouts"] == 4
    assert set(m) == set(M.METRIC_UNITS)
