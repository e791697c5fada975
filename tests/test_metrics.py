"""Stick-slip metrics (mitigate.metrics) against hand-computed values."""

import dataclasses
import math

import numpy as np
import pytest

from mitigate import metrics as M
from mitigate.closedloop import ClosedLoopResult
from mitigate.scenario import make_scenario
from models.checks import options_from_mapping
from models.errors import ConfigError
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
    # normalised by a reference speed instead of each window's mean: (1,3,2) 2/(2 x 4), ...
    np.testing.assert_allclose(M.moving_severity(w, 0.5, 1.5, reference=4.0), [0.25, 0.125, 0.25, 0.5])
    # a window in which the body never moves is stopped, not quiet: severity 1 (a full cycle's)
    assert M.moving_severity(np.array([0.0, 0.0, 0.0, 3.0]), 1.0, 3.0, reference=3.0, stuck=0.01).tolist() == [1.0, 0.5]
    assert M.severity(np.zeros(5), stuck=1e-3) == 1.0 and M.severity(np.zeros(5)) == math.inf
    assert M.severity(np.array([1.0, 3.0]), reference=4.0) == pytest.approx(0.25)


def test_time_to_suppress_hand_computed():
    dt = 0.1
    # stick-slip for 1 s, then steady at 2 rad/s; window 0.3 s = 3 samples, threshold 0.1
    w = np.concatenate([np.tile([0.0, 4.0], 5), np.full(20, 2.0)])
    s = M.moving_severity(w, dt, 0.3)
    # the last window above the threshold is (4, 2, 2) at sample 9; (2, 2, 2) from sample 10 on stays
    # below: suppressed from sample 10, 1.0 s (the START of that window, no window length added)
    assert s[9] == pytest.approx(2 / (2 * 8 / 3)) and np.all(s[10:] == 0.0)
    assert M.time_to_suppress(w, dt, 0.3, 0.1) == pytest.approx(10 * dt)
    # never above: 0 s; still above at the end: inf
    assert M.time_to_suppress(np.full(10, 2.0), dt, 0.3, 0.1) == 0.0
    assert M.time_to_suppress(np.tile([0.0, 4.0], 10), dt, 0.3, 0.1) == math.inf
    # stuck for good after 1 s: never suppressed (the stopped windows count as severity 1)
    stop = np.concatenate([np.tile([0.0, 4.0], 5), np.zeros(20)])
    assert M.time_to_suppress(stop, dt, 0.3, 0.1) == math.inf
    assert M.time_to_suppress(stop, dt, 0.3, 0.1, reference=2.0, stuck=1e-3) == math.inf


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
        controller_active=t >= sc.control.start, controller_ok=np.ones(n, bool),
        solve_times=np.asarray(solve_times), plan_calls=np.asarray(plan_calls), estimator_times=np.zeros(n),
        controller_counts={"steps": 3, "failures": 1, "fallbacks": 2, "holds": 1},
        estimator_counts={"steps": n, "failures": 0, "fallbacks": 0, "dropouts": 4},
        controller="test", model=m.name, objective_body="R1", states=m.states, inputs=m.inputs,
        control_start=sc.control.start, status=status)


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
    opts = M.MetricOptions(period=0.1, window_periods=2, moving_periods=2, residual_periods=2, suppress_threshold=0.1)
    m = M.closed_loop_metrics(r, sc, opts)
    assert set(m) == set(M.units()) | {"normal_force_mean_n2", "normal_force_ratio_n2"}
    assert all(M.unit(k) for k in m) and M.unit("normal_force_mean_n2") == "N"
    # after the start omega_R1 alternates 0, 2: mean 1, SSS = (2 - 0) / (2 x 1) = 1
    assert m["sss"] == pytest.approx(1.0)
    # what stays: the last 2 periods (0.2 s, 2 samples: 0, 2) against the programmed 30 rpm = pi rad/s
    assert m["residual_window"] == pytest.approx(0.2) and m["period"] == 0.1
    assert m["residual_severity"] == pytest.approx(2 / (2 * math.pi)) and m["residual_stuck_fraction"] == 0.5
    assert m["speed_ratio"] == pytest.approx(1 / math.pi)
    # the overshoot is what the controller added over the uncontrolled run: none known here, NaN; with
    # an uncontrolled run whose peak is 3.5 rad/s, a run peaking at 4 rad/s added 0.5 / pi
    assert math.isnan(m["peak_overshoot"])
    r4 = _result(sc, 2 * w1, 2 * w1, tw, cur, z, n2, w3, [0.001, 0.002, 0.003], [False, True, True])
    unc = np.full(10, 1.0)
    unc[6] = 3.5
    assert M.closed_loop_metrics(r4, sc, opts, unc)["peak_overshoot"] == pytest.approx(0.5 / math.pi)
    assert M.closed_loop_metrics(r, sc, opts, unc)["peak_overshoot"] == 0.0      # 2 rad/s: below the programme
    # what the rig sees: the measured speed 0.1, 2.1 over the residual window, (2.1 - 0.1) / (2 pi); its
    # floor two counts of rig3's 1000-tick R1 encoder per 0.1 s sample over 2 pi: 2 (2 pi / 1000) / 0.1 / (2 pi)
    assert m["speed_floor"] == pytest.approx(0.02)
    assert m["measured_severity"] == pytest.approx(2.0 / (2 * math.pi)) and m["suppressed"] == 0
    assert m["measured_time_to_suppress"] == math.inf
    # the hardware: the current alternates 1 and 3 A against rig3's i_max = 10 A; the commands equal the
    # programme (n2's programme is 0: no excursion to measure); the string: shaft1 twisted +-0.1 rad (R1
    # and R2 turn together, no damping torque), shaft2 untwisted with R2 at 0 or 2 against R3 at pi (its
    # damping d2), over the steady sliding torque at pi rad/s: pin1's Stribeck friction at 20 N
    assert m["drive_load_peak"] == pytest.approx(0.3) and m["setpoint_excursion"] == 0.0
    steady = 20.0 * p["r1"] * (p["mu_k"] + (p["mu_s"] - p["mu_k"]) * math.exp(-math.pi / p["v_s"]))
    # (the steady state is the regularised model's: its friction differs by ~1e-6 at pi rad/s)
    assert m["string_torque_peak"] == pytest.approx(max(0.1 * p["k1"], math.pi * p["d2"]) / steady, rel=1e-5)
    # the residual window: the body stuck half of it (not more than the stuck limit); a one-period band
    # window is one sample here, and in one the body is stuck: the worst ratio to the programme is 0
    assert m["stalled"] == 0 and m["speed_ratio_worst"] == 0.0
    assert M.closed_loop_metrics(r, sc, dataclasses.replace(opts, stuck_limit=0.4))["stalled"] == 1
    # the rig3 pin1 load (N1 = 20 N, a positive programme) is the process: R1 slides at 2 rad/s for 3
    # samples; the applied force is the programmed one
    mu1 = mu = p["mu_k"] + (p["mu_s"] - p["mu_k"]) * math.exp(-2.0 / p["v_s"])
    assert m["cutting_work"] == pytest.approx(3 * mu1 * 20.0 * p["r1"] * 2.0 * 0.1)
    assert m["cutting_work_ratio"] == pytest.approx(1.0)
    # n2 has a zero programme: a brake, no ratio, no band
    assert m["normal_force_mean_n2"] == pytest.approx(5.0) and math.isnan(m["normal_force_ratio_n2"])
    assert math.isnan(m["normal_force_ratio"]) and m["force_violation"] == 0
    # R1 at a mean 1 rad/s over the residual window against pi: it does not turn at the programmed speed
    assert m["residual_speed_ratio"] == pytest.approx(1 / math.pi) and m["speed_violation"] == 1
    assert m["band_violation"] == 1
    assert m["setpoint_variation"] == 0.0                     # constant commands after the start
    assert m["sss_window_max"] == m["sss_window_mean"] == m["sss_final"] == pytest.approx(1.0)
    assert m["sss_moving_final"] == pytest.approx(1.0) and m["time_to_suppress"] == math.inf
    assert m["stuck_fraction"] == pytest.approx(0.5)
    # the measured 0.1, 2.1 rad/s against half an encoder tick per DAQ period: rig3's R1 encoder counts
    # 1000 ticks per turn, 0.5 x 2 pi / 1000 / 0.1 s = 0.031 rad/s: never stuck; against 0.31: half the time
    assert m["stuck_fraction_measured"] == 0.0
    assert M.closed_loop_metrics(r, sc, dataclasses.replace(opts, stuck_speed_measured=0.31))[
        "stuck_fraction_measured"] == pytest.approx(0.5)
    assert m["mean_speed"] == pytest.approx(1.0)
    assert m["speed_error_rms"] == pytest.approx(math.sqrt(np.mean((np.array([0, 2] * 3) - math.pi) ** 2)))
    assert m["rms_twist"] == pytest.approx(0.1)
    # the torque channel alternates 0.4, 0.6: std 0.1
    assert m["torque_std"] == pytest.approx(0.1)
    # three sliding samples of R2 at 2 rad/s with N2 = 5 N, 0.1 s each (pin2, r2 = 0.04 m)
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
    m = M.closed_loop_metrics(r, sc, M.MetricOptions(period=0.1, window_periods=3, moving_periods=3,
                                                      suppress_threshold=0.1))
    # moving windows of 3 samples (against pi rad/s): (4, 2, 2) at sample 3 is 0.32, from sample 4 on 0:
    # suppressed 0.4 s after the switch-on (the start of the first quiet window)
    assert m["time_to_suppress"] == pytest.approx(0.4)
    assert m["sss_final"] == 0.0 and m["pin_work"] == 0.0 and m["diverged"] == 1
    assert math.isnan(m["solve_median_ms"]) and m["plan_calls"] == 0


def test_a_stuck_bit_is_severity_1_not_inf_and_never_suppressed():
    """Issue 18 item 12: a permanently stuck bit gave severity inf (0/0 normalised by its own mean)."""
    sc = make_scenario(name="m", duration=0.9, dt=0.1, inputs={"omega_ref": "30 rpm", "n1": 20.0}, estimator="fd",
                       control_start=0.0)
    z = np.zeros(10)
    r = _result(sc, z, z, z, np.ones(10), z, z, np.full(10, math.pi), [], [])
    m = M.closed_loop_metrics(r, sc, M.MetricOptions(period=0.2))
    assert m["residual_severity"] == 1.0 and m["sss"] == 1.0 and m["sss_final"] == 1.0
    assert m["time_to_suppress"] == math.inf and m["residual_stuck_fraction"] == 1.0 and m["speed_ratio"] == 0.0
    assert m["cutting_work"] == 0.0            # the bit does not turn: nothing is cut


def test_setpoint_variation_is_the_total_variation_per_second_scaled_by_the_programme():
    sc = make_scenario(name="m", duration=0.9, dt=0.1, inputs={"omega_ref": "30 rpm", "n1": 20.0}, estimator="fd",
                       control_start=0.0)
    w = np.full(10, math.pi)
    r = _result(sc, w, w, np.zeros(10), np.ones(10), np.zeros(10), np.zeros(10), w, [], [])
    cmd = np.array([1.0, 2.0] * 5) * math.pi              # nine jumps of pi rad/s
    n2 = np.array([0.0, 0.0, 40.0, 40.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])   # two jumps of the servo's n_max
    r = dataclasses.replace(r, commands={"omega_ref": cmd, "n2": n2})
    m = M.closed_loop_metrics(r, sc, M.MetricOptions(period=0.2))
    n_max = sc.model.actuator("n2").n_max
    assert m["setpoint_variation"] == pytest.approx((9 * math.pi / math.pi + 80.0 / n_max) / 1.0)


def _drill_result(sc, w_bit, wob):
    m = sc.plant_model
    n = len(w_bit)
    x = np.zeros((n, m.nx))
    x[:, m.speed_index("bit")] = w_bit
    x[:, m.speed_index("top")] = 3.0
    u = np.zeros((n, m.nu))
    u[:, m.inputs.index("omega_ref")] = 3.0
    u[:, m.inputs.index("wob")] = wob
    t = np.arange(n) * sc.dt
    return ClosedLoopResult(t=t, x=x, twists={}, y={}, xhat=x.copy(), xhat_names=m.states, u=u,
                            commands={"omega_ref": u[:, 0], "wob": u[:, 1]}, controller_active=t >= 0,
                            controller_ok=np.ones(n, bool), solve_times=np.array([]), plan_calls=np.array([], bool),
                            estimator_times=np.zeros(n), controller="t", model=m.name, objective_body="bit",
                            states=m.states, inputs=m.inputs, control_start=0.0)


def test_weight_on_bit_band_and_cutting_work_against_the_programme():
    """Issue 17 item 4: lifting the weight on bit is not drilling.  The bit-rock law (drillstring_motor
    rig file): T = c_b |w| + W R_b [mu_cb + (mu_sb - mu_cb) exp(-|w|/v_b)]."""
    sc = make_scenario(name="d", model="drillstring_motor", duration=0.9, dt=0.1,
                       inputs={"omega_ref": "3 rad/s", "wob": 200.0}, estimator="fd")
    p = sc.plant_params
    f = p["mu_cb"] + (p["mu_sb"] - p["mu_cb"]) * math.exp(-3.0 / p["v_b"])
    m = M.closed_loop_metrics(_drill_result(sc, np.full(10, 3.0), 100.0), sc, M.MetricOptions(period=0.3))
    assert m["normal_force_mean_wob"] == pytest.approx(100.0) and m["normal_force_ratio_wob"] == pytest.approx(0.5)
    assert m["normal_force_ratio"] == pytest.approx(0.5) and m["force_violation"] == m["band_violation"] == 1
    assert m["speed_violation"] == 0 and m["residual_speed_ratio"] == pytest.approx(1.0)
    cut = lambda W: (p["c_b"] * 3.0 + W * p["R_b"] * f) * 3.0 * 0.1 * 10          # noqa: E731
    assert m["cutting_work"] == pytest.approx(cut(100.0))
    assert m["cutting_work_ratio"] == pytest.approx(cut(100.0) / cut(200.0))
    assert m["pin_work"] == 0.0                    # no brake on this rig: the bit-rock work is not wear
    assert m["speed_ratio"] == pytest.approx(1.0) and m["speed_error_rms"] == pytest.approx(0.0)
    ok = M.closed_loop_metrics(_drill_result(sc, np.full(10, 3.0), 170.0), sc, M.MetricOptions(period=0.3))
    assert ok["band_violation"] == 0 and ok["normal_force_ratio"] == pytest.approx(0.85)
    fast = M.closed_loop_metrics(_drill_result(sc, np.full(10, 3.3), 200.0), sc, M.MetricOptions(period=0.3))
    assert fast["speed_violation"] == fast["band_violation"] == 1 and fast["force_violation"] == 0
    assert fast["residual_speed_ratio"] == pytest.approx(1.1)
    wide = M.closed_loop_metrics(_drill_result(sc, np.full(10, 3.3), 200.0), sc,
                                 M.MetricOptions(period=0.3, speed_band=(0.8, 1.2)))
    assert wide["band_violation"] == 0
    narrow = M.closed_loop_metrics(_drill_result(sc, np.full(10, 3.0), 170.0), sc,
                                   M.MetricOptions(period=0.3, force_band=(0.9, 1.1)))
    assert narrow["band_violation"] == 1


def test_brake_wear_counts_only_what_the_normal_force_causes():
    """Issue 17 item 4: with the pins on the bit-rock law (its viscous c_b |w| acts at zero force), PI
    scored 3.3 J of "pin work" with the pin unloaded."""
    sc = make_scenario(name="f", duration=0.9, dt=0.1, inputs={"omega_ref": "30 rpm", "n1": 20.0}, estimator="fd",
                       structure={"friction": {"law": "bit_rock", "mu_sb": 0.55, "mu_cb": 0.306, "v_b": 1.0,
                                               "c_b": 0.006}})
    pm = sc.plant_model
    x = np.zeros((10, pm.nx))
    x[:, pm.speed_index("R2")] = 2.0
    u = np.tile([math.pi, 20.0, 0.0], (10, 1))
    assert M.contact_work(pm, sc.plant_params, x, u, "pin2", 0.1) == pytest.approx(0.006 * 2.0 * 2.0 * 1.0)
    assert M.contact_work(pm, sc.plant_params, x, u, "pin2", 0.1, caused_by_normal=True) == 0.0
    u[:, 2] = 10.0
    f = 0.306 + (0.55 - 0.306) * math.exp(-2.0)
    assert M.contact_work(pm, sc.plant_params, x, u, "pin2", 0.1, caused_by_normal=True) == \
        pytest.approx(10.0 * sc.plant_params["r2"] * f * 2.0 * 1.0)


def test_a_torque_drive_tracks_its_speed_not_its_torque():
    """Issue 18 item 12: speed_error_rms on a torque drive subtracted the programmed TORQUE from the speed."""
    sc = make_scenario(name="t", model="rig2", duration=0.9, dt=0.1, inputs={"motor_torque": 5.0}, estimator="fd")
    m = sc.model
    x = np.zeros((10, m.nx))
    x[:, m.speed_index("disc")] = 1.1             # rig2's operating point: 1 rad/s
    t = np.arange(10) * 0.1
    r = ClosedLoopResult(t=t, x=x, twists={}, y={}, xhat=x, xhat_names=m.states, u=np.full((10, 1), 5.0),
                         commands={"motor_torque": np.full(10, 5.0)}, controller_active=t >= 0,
                         controller_ok=np.ones(10, bool), solve_times=np.array([]), plan_calls=np.array([], bool),
                         estimator_times=np.zeros(10), model=m.name, objective_body="disc", states=m.states,
                         inputs=m.inputs)
    out = M.closed_loop_metrics(r, sc, M.MetricOptions(period=0.3))
    assert out["speed_error_rms"] == pytest.approx(0.1) and out["speed_ratio"] == pytest.approx(1.1)
    # the overshoot the controller added over an uncontrolled run at the programme: 0.1 of it
    assert M.closed_loop_metrics(r, sc, M.MetricOptions(period=0.3), np.full(10, 1.0))["peak_overshoot"] == \
        pytest.approx(0.1)


@pytest.mark.parametrize("kw, match", [
    ({"period": -1.0}, r"^metrics\.period must be > 0 s, got -1\.0$"),
    ({"residual_fraction": 1.5}, r"^metrics\.residual_fraction must be in \(0, 1\], got 1\.5$"),
    ({"force_band": (1.1, 1.2)}, r"^metrics\.force_band must have low < 1 <= high, got \[1\.1, 1\.2\]$"),
    ({"force_band": 0.8}, r"^metrics\.force_band must be \[low, high\]"),
    ({"suppress_threshold": "x"}, r"^metrics\.suppress_threshold must be a finite number > 0, got 'x'$"),
])
def test_metric_options_check_themselves(kw, match):
    with pytest.raises(ConfigError, match=match):
        M.MetricOptions(**kw)
    with pytest.raises(ConfigError, match=r"^suite\.toml: metrics\.windw: unknown key"):
        options_from_mapping(M.MetricOptions, {"windw": 1}, "suite.toml: metrics")
    o = options_from_mapping(M.MetricOptions, {"force_band": [0.7, 1.3]}, "s: metrics")
    assert o.force_band == (0.7, 1.3) and o.where == "s: metrics"
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.period = 2.0


def test_the_docs_list_every_declared_metric():
    from pathlib import Path

    from mitigate.metrics import markdown_table
    page = (Path(__file__).resolve().parents[1] / "docs" / "metric-registry.md").read_text()
    assert page.endswith(markdown_table()), "docs/metric-registry.md: paste mitigate.metrics.markdown_table() again"
