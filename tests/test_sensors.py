"""Encoders and load cells (models.sensors): quantisation, backward-difference speeds, noise."""

import math

import numpy as np
import pytest

from models import get_model
from models.errors import ConfigError
from models.sensors import SensorOptions, Sensors, quantise
from models.simulator import SimOptions, simulate


def test_resolutions_follow_the_thesis_encoders():
    o = SensorOptions()
    assert o.angle_step == pytest.approx(2 * math.pi / 1000)         # 1000 ticks/rev on R1, R2
    assert o.motor_angle_step == pytest.approx(2 * math.pi / 8000)   # motor shaft, 8:1 gearbox


def test_quantisation_error_is_within_one_tick_and_has_variance_q2_over_12():
    rng = np.random.default_rng(0)
    q = SensorOptions().angle_step
    theta = rng.uniform(-50, 50, 200_000)
    err = quantise(theta, q) - theta
    assert np.all((err <= 0) & (err > -q))
    assert np.var(err) == pytest.approx(SensorOptions().angle_variance(), rel=0.02)


def test_simulated_encoders_and_speeds_error_bounds():
    m = get_model("rig3")
    opts = SensorOptions(force_noise=0.0, torque_noise=0.0)
    r = simulate(m, m.published(), np.array([math.pi, 20.0, 0.0]), 10.0, SimOptions(seed=3), sensors=opts)
    dt = 0.01
    for ch, q in (("theta1", opts.angle_step), ("theta2", opts.angle_step), ("theta3", opts.motor_angle_step)):
        e = r.y[ch] - r.truth[ch]
        assert np.all((e <= 1e-12) & (e > -q - 1e-12)), ch
        spd = "omega" + ch[-1]
        true_diff = np.diff(r.truth[ch]) / dt          # speed a perfect encoder would give
        e_w = r.y[spd][1:] - true_diff
        assert np.max(np.abs(e_w)) < q / dt + 1e-9, spd   # one tick per sample at most
    # the motor encoder is 8x finer: its speed error bound is 8x smaller
    assert opts.motor_angle_step / dt == pytest.approx(opts.angle_step / dt / 8)
    # R1 sticks in this run.  While stuck its measured speed must be exactly 0: theta1 is
    # rebuilt from twist coordinates and its ~1e-13 rad round-off used to flip floor() at a
    # tick boundary (3.6 % of stuck samples in this run); the encoder now holds its count
    # while the true angle does not move.
    stuck = r.truth["omega1"] == 0.0
    both = stuck[1:] & stuck[:-1]
    w_stuck = r.y["omega1"][1:][both]
    assert both.sum() > 50
    assert np.all(w_stuck == 0.0)


def test_speed_variance_formula_matches_empirical():
    rng = np.random.default_rng(1)
    opts = SensorOptions()
    dt = 0.01
    s = Sensors(opts, dt, rng)
    theta = np.cumsum(rng.uniform(0.01, 0.05, 20_000))          # a slowly, randomly advancing angle
    w_meas, w_true = [], []
    for k, th in enumerate(theta):
        y = s.measure({"theta1": th, "omega1": 0.0})
        if k:
            w_meas.append(y["omega1"])
            w_true.append((th - theta[k - 1]) / dt)
    e = np.array(w_meas) - np.array(w_true)
    assert np.var(e) == pytest.approx(opts.speed_variance(dt), rel=0.05)


def test_load_cell_noise_level_and_seed():
    m = get_model("rig3")
    u = np.array([math.pi, 20.0, 0.0])
    a = simulate(m, m.published(), u, 5.0, SimOptions(seed=7))
    b = simulate(m, m.published(), u, 5.0, SimOptions(seed=7))
    np.testing.assert_array_equal(a.y["n1"], b.y["n1"])
    assert np.std(a.y["n1"] - a.truth["n1"]) == pytest.approx(0.2, rel=0.1)
    assert np.std(a.y["motor_torque"] - a.truth["motor_torque"]) == pytest.approx(0.01, rel=0.1)


@pytest.mark.parametrize("kw, field", [(dict(ticks_per_rev=0), "ticks_per_rev"), (dict(force_noise=-1.0), "force_noise"),
                                        (dict(motor_ratio=float("nan")), "motor_ratio")])
def test_bad_sensor_options(kw, field):
    with pytest.raises(ConfigError, match=field):
        SensorOptions(**kw)
