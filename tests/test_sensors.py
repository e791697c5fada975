"""Sensors (models.sensors) as the rig file describes them: encoders that count ticks from
power-on, backward-difference speeds, load cells and torque sensors with noise, offset, gain
and delay."""

import math

import numpy as np
import pytest

from models import get_model
from models.errors import ConfigError
from models.plant import Plant, SimOptions, simulate
from models.sensors import SensorOptions, Sensors, channel_variance, encoder_step, quantise


def _enc(model, channel):
    return model.sensor_of(channel)


def test_resolutions_follow_the_thesis_encoders():
    m = get_model("rig3")
    assert encoder_step(_enc(m, "theta1")) == pytest.approx(2 * math.pi / 1000)   # 1000 ticks/rev on R1, R2
    assert encoder_step(_enc(m, "theta3")) == pytest.approx(2 * math.pi / 8000)   # motor shaft, 8:1 gearbox


def test_quantisation_error_is_within_one_tick_and_has_variance_q2_over_12():
    rng = np.random.default_rng(0)
    m = get_model("rig3")
    q = encoder_step(_enc(m, "theta1"))
    theta = rng.uniform(-50, 50, 200_000)
    err = quantise(theta, q) - theta
    assert np.all((err <= 0) & (err > -q))
    assert np.var(err) == pytest.approx(channel_variance(m, "theta1", 0.01), rel=0.02)


def test_simulated_encoders_and_speeds_error_bounds():
    m = get_model("rig3")
    r = simulate(m, None, np.array([math.pi, 20.0, 0.0]), 10.0, SimOptions(seed=3), sensors=SensorOptions())
    dt = 0.01
    for ch in ("theta1", "theta2", "theta3"):
        q = encoder_step(_enc(m, ch))
        e = r.y[ch] - (r.truth[ch] - r.truth[ch][0])     # the plant starts at rest: zero at power-on
        assert np.all((e <= q + 1e-12) & (e > -q - 1e-12)), ch
        spd = "omega" + ch[-1]
        true_diff = np.diff(r.truth[ch]) / dt          # speed a perfect encoder would give
        e_w = r.y[spd][1:] - true_diff
        assert np.max(np.abs(e_w)) < q / dt + 1e-9, spd   # one tick per sample at most
    # R1 sticks in this run.  While stuck its measured speed must be exactly 0: theta1 is rebuilt
    # from twist coordinates and its ~1e-13 rad round-off must not flip floor() at a tick boundary
    stuck = r.truth["omega_R1"] == 0.0
    both = stuck[1:] & stuck[:-1]
    assert both.sum() > 50
    assert np.all(r.y["omega1"][1:][both] == 0.0)


def test_encoders_read_zero_at_power_on_whatever_the_twist():
    m = get_model("rig3")
    x0 = np.zeros(m.nx)
    x0[0], x0[1] = 0.3, -0.7                         # pre-twisted shaft at power-on
    plant = Plant(m, None, SimOptions(seed=1), x0=x0, u0=np.zeros(3))
    y0 = plant.measure()
    assert y0["theta1"] == y0["theta2"] == y0["theta3"] == 0.0
    # an encoder zeroed at an index ("absolute") reads the twisted angle
    spec = m.spec
    sens = tuple(s.__class__(**{**s.__dict__, "zero": "absolute"}) if s.kind == "encoder" else s for s in spec.sensors)
    from models.rig import RigModel
    m2 = RigModel(spec.with_changes(sensors=sens))
    y2 = Plant(m2, None, SimOptions(seed=1), x0=x0, u0=np.zeros(3)).measure()
    assert y2["theta1"] - y2["theta2"] == pytest.approx(0.3, abs=2 * math.pi / 1000)


def test_speed_variance_formula_matches_empirical():
    rng = np.random.default_rng(1)
    m = get_model("disc")
    dt = 0.01
    s = Sensors(m, SensorOptions(), dt, rng)
    theta = np.cumsum(rng.uniform(0.01, 0.05, 20_000))          # a slowly, randomly advancing angle
    w_meas, w_true = [], []
    for k, th in enumerate(theta):
        y = s.measure({"theta1": th, "omega1": 0.0, "theta3": 0.0, "omega3": 0.0, "n1": 0.0})
        if k:
            w_meas.append(y["omega1"])
            w_true.append((th - theta[k - 1]) / dt)
    e = np.array(w_meas) - np.array(w_true)
    assert np.var(e) == pytest.approx(channel_variance(m, "omega1", dt), rel=0.05)


def test_load_cell_and_torque_noise_offset_gain_and_seed():
    m = get_model("rig3")
    u = np.array([math.pi, 20.0, 0.0])
    a = simulate(m, None, u, 5.0, SimOptions(seed=7))
    b = simulate(m, None, u, 5.0, SimOptions(seed=7))
    np.testing.assert_array_equal(a.y["n1"], b.y["n1"])
    assert np.std(a.y["n1"] - a.truth["n1"]) == pytest.approx(0.2, rel=0.1)
    assert np.std(a.y["motor_torque"] - a.truth["motor_torque"]) == pytest.approx(0.01, rel=0.1)
    p = m.published().replace(motor_torque_offset=0.05, n1_gain=1.1)
    c = simulate(m, p, u, 5.0, SimOptions(seed=7))
    assert np.mean(c.y["motor_torque"] - a.y["motor_torque"]) == pytest.approx(0.05, abs=0.02)
    assert np.mean(c.y["n1"]) == pytest.approx(22.0, abs=0.1)       # the load cell reads 1.1 N per N


def test_delay_shifts_a_channel_by_whole_samples():
    m = get_model("rig3")
    sens = tuple(s.__class__(**{**s.__dict__, "delay": 2}) if s.name == "enc1" else s for s in m.spec.sensors)
    from models.rig import RigModel
    md = RigModel(m.spec.with_changes(sensors=sens))
    u = np.array([math.pi, 20.0, 0.0])
    a = simulate(m, None, u, 3.0, SimOptions(seed=2), sensors=SensorOptions(quantise=False))
    b = simulate(md, None, u, 3.0, SimOptions(seed=2), sensors=SensorOptions(quantise=False))
    np.testing.assert_allclose(b.y["theta1"][2:], a.y["theta1"][:-2], atol=1e-12)
    np.testing.assert_allclose(b.y["theta2"], a.y["theta2"], atol=1e-12)


def test_reaction_torque_reads_the_load_not_the_motor_friction():
    """Steady sliding: the free-mounted motor's load cell reads the pin friction torque; the
    electromagnetic torque eta KT i reads it plus the motor's own friction eta (Tf + Cm eta w)
    (README: what the torque load cell measures; RIG-FACTS)."""
    m = get_model("rig3")
    p = m.published()
    w, n1, n2 = math.pi, 20.0, 5.0
    u = np.array([w, n1, n2])
    x = m.steady_sliding(u, p)
    out = dict(zip(m.meas().name_out(), m.meas()(x, u, p.vector(), 0.0)))
    mu = p.mu_k + (p.mu_s - p.mu_k) * math.exp(-w / p.v_s)
    load = n1 * p.r1 * mu + n2 * p.r2 * mu
    assert float(out["motor_torque"]) == pytest.approx(load, rel=1e-5)   # |v| is smoothed at 5e-5 rad/s
    em = float(out["motor_torque_em"])
    assert em == pytest.approx(load + p.eta * (p.Tf * math.tanh(p.eta * w / 0.05) + p.Cm * p.eta * w), rel=1e-5)
    assert em - load == pytest.approx(0.993, abs=0.001)        # eta (Tf + Cm eta w) at 30 rpm: three times the R1 load


def test_bad_sensor_options():
    with pytest.raises(ConfigError, match="noise_scale"):
        SensorOptions(noise_scale=-1.0)
    with pytest.raises(ConfigError, match="quantise"):
        SensorOptions(quantise="yes")
    with pytest.raises(ConfigError, match="no sensor writes channel 'omega9'"):
        channel_variance(get_model("rig3"), "omega9", 0.01)
