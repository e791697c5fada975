"""Stick-slip metrics (mitigate.metrics) against hand-computed values."""

import math

import numpy as np
import pytest

from mitigate import metrics as M
from mitigate.closedloop import ClosedLoopResult
from mitigate.scenario import make_scenario
from models.status import Status


def test_rms_severity_amplitude_stuck_fraction_hand_computed():
    assert M.rms(np.array([3.0, 4.0])) == pytest.approx(math.sqrt(12.5))
    assert M.rms(np.array([-2.0, -2.0, -2.0])) == pytest.approx(2.0)
    assert math.isnan(M.rms(np.array([])))
    # 0, 2, 0, 2: mean 1, span 2: SSS = 2 / (2 x 1) = 1 (the limit cycle of full stick-slip)
    assert M.severity(np.array([0.0, 2.0, 0.0, 2.0])) == pytest.approx(1.0)
    assert M.severity(np.array([-1.0, -3.0])) == pytest.approx(0.5)           # |mean|
    assert M.severity(np.array([1.0, -1.0])) == math.inf
    assert M.amplitude(np.array([1.0, 4.0, 2.0])) == pytest.approx(1.5)
    assert M.stuck_fraction(np.array([0.0, 0.04, -0.05, 0.2]), 0.05) == pytest.approx(0.75)


def test_windowed_and_moving_severity_hand_computed():
    w = np.array([1.0, 3.0, 2.0, 2.0, 0.0, 4.0])
    # windows of 2 samples: (1,3) -> 2/(2*2) = 0.5, (2,2) -> 0, (0,4) -> 4/(2*2) = 1
    np.testing.assert_allclose(M.windowed_severity(w, 0.5, 1.0), [0.5, 0.0, 1.0])
    # moving window of 3 samples: (1,3,2) 2/4, (3,2,2) 1/(14/3), (2,2,0) 2/(8/3), (2,0,4) 4/4
    np.testing.assert_allclose(M.moving_severity(w, 0.5, 1.5), [0.5, 3 / 14, 0.75, 1.0])
    assert M.moving_severity(w, 0.5, 100.0).shape == (1,)          # a window longer than the record
    assert M.moving_severity(np.zeros(4), 1.0, 2.0).tolist() == [math.inf] * 3


def test_time_to_suppress_hand_computed():
    dt = 0.1
    # stick-slip for 1 s, then steady at 2 rad/s; window 0.3 s = 3 samples, threshold 0.1
    w = np.concatenate([np.tile([0.0, 4.0], 5), np.full(20, 2.0)])
    s = M.moving_severity(w, dt, 0.3)
    # the last window above the threshold is (4, 2, 2) at sample 9; (2, 2, 2) at sample 10 stays below
    assert s[9] == pytest.approx(2 / (2 * 8 / 3)) and np.all(s[10:] == 0.0)
    assert M.time_to_suppress(w, dt, 0.3, 0.1) == pytest.approx((10 + 3 - 1) * dt)
    # never above: suppressed at the end of the first window; still above at the end: inf
    assert M.time_to_suppress(np.full(10, 2.0), dt, 0.3, 0.1) == pytest.approx(0.2)
    assert M.time_to_suppress(np.tile([0.0, 4.0], 10), dt, 0.3, 0.1) == math.inf


def test_dominant_frequency_of_a_sine():
    dt = 0.01
    t = np.arange(0, 20, dt)
    assert M.dominant_frequency(3.0 + np.sin(2 * math.pi * 0.45 * t), dt) == pytest.approx(0.45, abs=0.05)
    assert M.dominant_frequency(np.full(50, 3.0), dt) == 0.0


def test_solve_time_stats():
    s = M.solve_time_stats(np.arange(1, 101) / 1000.0)
    assert s["median"] == pytest.approx(0.0505)
    assert s["p95"] == pytest.approx(0.09505)
    assert s["max"] == pytest.approx(0.1)
    assert all(math.isnan(v) for v in M.solve_time_stats(np.array([])).values())


def test_contact_work_of_the_stribeck_pin_hand_computed():
    """pin2 of rig3 (thesis eq. 3-13, r2 = 0.04 m): T = N r2 [mu_k + (mu_s - mu_k) exp(-|w|/v_s)]."""
    sc = make_scenario(name="w", duration=1.0, inputs={"omega_ref": "30 rpm", "n1": 20.0}, estimator="fd")
    m, p = sc.model, sc.model_params
    n = 100
    x = np.zeros((n, m.nx))
    x[:, m.speed_index("R2")] = -2.0                       # the sign does not matter
    u = np.tile([math.pi, 20.0, 10.0], (n, 1))
    mu = p["mu_k"] + (p["mu_s"] - p["mu_k"]) * math.exp(-2.0 / p["v_s"])
    assert M.contact_work(m, p, x, u, "pin2", 0.01) == pytest.approx(mu * 10.0 * 0.04 * 2.0 * 1.0, rel=1e-12)
    u[:, 2] = 0.0
    assert M.contact_work(m, p, x, u, "pin2", 0.01) == 0.0               # no normal force, no work
    # pin1 at N1 = 20 N, r1 = 0.047 m, R1 at rest: no work
    assert M.contact_work(m, p, np.zeros((n, m.nx)), u, "pin1", 0.01) == 0.0


def _result(sc, w1, w2, twist, current, z, n2, w3, solve_times, plan_calls, status=Status.OK):
    m = sc.model
    n = len(w1)
    t = np.arange(n) * sc.dt
    x = np.zeros((n, m.nx))
    for name, v in (("omega_R1", w1), ("omega_R2", w2), ("omega_R3", w3), ("twist_shaft1", twist),
                    ("current", current), ("pi_integral", z)):
        x[:, m.states.index(name)] = v
    u = np.zeros((n, m.nu))
    u[:, 0] = math.pi
    u[:, 1] = 20.0
    u[:, 2] = n2
    y = {"omega1": np.asarray(w1, float) + 0.1, "motor_torque": 0.3 + 0.1 * np.asarray(current, float)}
    return ClosedLoopResult(
        t=t, x=x, twists={"twist_shaft1": x[:, 0], "twist_shaft2": x[:, 1]}, y=y, xhat=x.copy(),
        xhat_names=m.states, u=u, commands={"omega_ref": u[:, 0], "n2": u[:, 2]},
        controller_active=t >= sc.control_start, controller_ok=np.ones(n, bool),
        solve_times=np.asarray(solve_times), plan_calls=np.asarray(plan_calls), estimator_times=np.zeros(n),
        controller_counts={"steps": 3, "failures": 1, "fallbacks": 2, "holds": 1},
        estimator_counts={"steps": n, "failures": 0, "fallbacks": 0, "dropouts": 4},
        controller="test", model=m.name, objective_body="R1", states=m.states, inputs=m.inputs,
        control_start=sc.control_start, status=status)


def test_closed_loop_metrics_hand_computed():
    sc = make_scenario(name="m", duration=0.9, dt=0.1, inputs={"omega_ref": "30 rpm", "n1": 20.0}, estimator="fd",
                       control_start=0.4)
    p = sc.plant_params
    # before the start (t < 0.4 s) wild values that must be ignored
    w1 = np.array([50.0, -50.0, 50.0, -50.0, 0.0, 2.0, 0.0, 2.0, 0.0, 2.0])
    tw = np.array([9, 9, 9, 9, 0.1, -0.1, 0.1, -0.1, 0.1, -0.1])
    cur = np.array([9, 9, 9, 9, 1.0, 3.0, 1.0, 3.0, 1.0, 3.0])
    n2 = np.array([0, 0, 0, 0, 5.0, 5.0, 5.0, 5.0, 5.0, 5.0])
    w3 = np.full(10, math.pi)
    z = np.full(10, 1.0)            # PI: V = kp (omega_ref - w3) + ki z = ki = 3.5 V (inside both limits)
    r = _result(sc, w1, w1, tw, cur, z, n2, w3, [0.001, 0.002, 0.003], [False, True, True])
    opts = M.MetricOptions(window=0.2, moving_window=0.2, suppress_threshold=0.1)
    m = M.closed_loop_metrics(r, sc, opts)
    assert set(m) == set(M.METRIC_UNITS)
    # after the start omega_R1 alternates 0, 2: mean 1, SSS = (2 - 0) / (2 x 1) = 1
    assert m["sss"] == pytest.approx(1.0)
    assert m["sss_window_max"] == m["sss_window_mean"] == m["sss_final"] == pytest.approx(1.0)
    assert m["sss_moving_final"] == pytest.approx(1.0) and m["time_to_suppress"] == math.inf
    assert m["stuck_fraction"] == pytest.approx(0.5)
    assert m["stuck_fraction_measured"] == pytest.approx(0.5)       # the measured 0.1, 2.1 vs 0.31 rad/s
    assert m["mean_speed"] == pytest.approx(1.0)
    assert m["speed_error_rms"] == pytest.approx(math.sqrt(np.mean((np.array([0, 2] * 3) - math.pi) ** 2)))
    assert m["rms_twist"] == pytest.approx(0.1)
    # the torque channel alternates 0.4, 0.6: std 0.1
    assert m["torque_std"] == pytest.approx(0.1)
    # three sliding samples of R2 at 2 rad/s with N2 = 5 N, 0.1 s each (pin2, r2 = 0.04 m)
    mu = p["mu_k"] + (p["mu_s"] - p["mu_k"]) * math.exp(-2.0 / p["v_s"])
    assert m["pin_work"] == pytest.approx(3 * mu * 5.0 * 0.04 * 2.0 * 0.1)
    assert m["mean_pin_force"] == pytest.approx(5.0)
    # drive energy sum |V i| dt with V = ki z = 3.5 V and i alternating 1, 3 A
    assert m["drive_energy"] == pytest.approx(3.5 * (1 + 3 + 1 + 3 + 1 + 3) * 0.1)
    assert m["solve_median_ms"] == pytest.approx(2.0) and m["solve_max_ms"] == pytest.approx(3.0)
    # planning calls only (the first call was a hold): 2 and 3 ms
    assert m["plan_median_ms"] == pytest.approx(2.5) and m["plan_max_ms"] == pytest.approx(3.0)
    assert m["plan_calls"] == 2
    assert (m["controller_steps"], m["controller_failures"], m["controller_fallbacks"]) == (3, 1, 2)
    assert m["estimator_dropouts"] == 4 and m["diverged"] == 0


def test_a_suppressed_run_and_a_diverged_one():
    sc = make_scenario(name="m", duration=0.9, dt=0.1, inputs={"omega_ref": "30 rpm", "n1": 20.0}, estimator="fd",
                       control_start=0.0)
    w = np.array([0.0, 4.0, 0.0, 4.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0])
    r = _result(sc, w, w, np.zeros(10), np.ones(10), np.zeros(10), np.zeros(10), np.full(10, 2.0), [], [],
                status=Status.DIVERGED)
    m = M.closed_loop_metrics(r, sc, M.MetricOptions(window=0.3, moving_window=0.3, suppress_threshold=0.1))
    # moving windows of 3 samples stay at SSS 0 from sample 4 on: suppressed at the end of that window
    assert m["time_to_suppress"] == pytest.approx((4 + 3 - 1) * 0.1)
    assert m["sss_final"] == 0.0 and m["pin_work"] == 0.0 and m["diverged"] == 1
    assert math.isnan(m["solve_median_ms"]) and m["plan_calls"] == 0
