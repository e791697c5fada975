"""Baseline controllers: PI only, the semi-active R2 brake, the speed-raise supervisor, and the factory."""

import math

import numpy as np
import pytest

from estimators.base import Estimate
from mitigate.closedloop import run_closed_loop
from mitigate.controllers.brake import BrakeController, BrakeOptions
from mitigate.controllers.factory import context_for, make_controller
from mitigate.controllers.pi import PIOnly, PIOptions
from mitigate.controllers.supervisor import SpeedSupervisor, SupervisorOptions
from mitigate.scenario import parse_scenario
from models import get_model
from models.errors import ConfigError
from models.status import Status

STATES = get_model("rig3").states      # twist_shaft1, twist_shaft2, omega_R1, omega_R2, omega_R3, current, pi_integral


def _scenario(controllers=({"name": "p", "kind": "pi"},), omega_rpm=30.0 * 3 / math.pi, duration=1.0, start=0.0):
    """A rig3 scenario whose programmed set-point is 3 rad/s (``omega_rpm`` rpm)."""
    return parse_scenario({"scenario": {"name": "t", "duration": duration},
                           "inputs": {"omega_ref": {"kind": "constant", "value": omega_rpm, "unit": "rpm"}, "n1": 20},
                           "control": {"start": start},
                           "estimator": {"kind": "fd"}, "controllers": list(controllers)}, "t.toml")


def _meas(w1=3.0, w2=3.0, w3=3.0):
    return {"omega1": w1, "omega2": w2, "omega3": w3, "theta1": 0.0, "theta2": 0.0, "theta3": 0.0,
            "motor_torque": 0.3, "n1": 20.0, "n2": 0.0, "omega_ref": 3.0}


def _est(w1, w2, w3):
    return Estimate(0.0, np.array([0, 0, w1, w2, w3, 0, 0], float), np.eye(7), STATES)


def test_pi_only_leaves_every_input_to_the_programme():
    sc = _scenario()
    c = PIOnly(PIOptions(), context_for(sc))
    a = c.step(0.0, _meas(), None)
    assert a.u == {} and a.status is Status.OK and a.success
    assert context_for(sc).scheduled(0.0, "omega_ref") == pytest.approx(3.0)


def test_brake_law_hand_computed():
    sc = _scenario()
    o = BrakeOptions(gain_overspeed=10.0, gain_relative=4.0, deadband=0.0, n_max=40.0, filter_tau=0.0)
    c = BrakeController(o, context_for(sc))
    assert (c.input, c.body, c.drive_body) == ("n2", "R2", "R3")
    # R2 0.5 rad/s above the 3 rad/s set-point and 0.25 rad/s above R3: 10 x 0.5 + 4 x 0.25 = 6 N
    assert c.step(0.0, _meas(w2=3.5, w3=3.25), None).u == {"n2": pytest.approx(6.0)}
    # R2 slower than the set-point and the motor: no braking (a brake cannot push)
    assert c.step(0.01, _meas(w2=2.0, w3=3.0), None).u["n2"] == 0.0
    # saturation at n_max
    assert c.step(0.02, _meas(w2=20.0, w3=3.0), None).u["n2"] == 40.0
    # the set-point is never touched
    assert set(c.step(0.03, _meas(w2=20.0), None).u) == {"n2"}


def test_brake_deadband_estimate_and_filter():
    sc = _scenario()
    c = BrakeController(BrakeOptions(gain_overspeed=10.0, deadband=0.2, filter_tau=0.0), context_for(sc))
    assert c.step(0.0, _meas(w2=3.1), None).u["n2"] == 0.0
    assert c.step(0.01, _meas(w2=3.5), None).u["n2"] == pytest.approx(3.0)         # 10 x (0.5 - 0.2)
    # the estimate wins over the measurement when given
    assert c.step(0.02, _meas(w2=3.0), _est(3, 4.2, 3)).u["n2"] == pytest.approx(10.0)
    # ... unless use_estimate is off
    c2 = BrakeController(BrakeOptions(gain_overspeed=10.0, filter_tau=0.0, use_estimate=False), context_for(sc))
    assert c2.step(0.0, _meas(w2=3.0), _est(3, 4.2, 3)).u["n2"] == 0.0
    # a first-order filter: one step of dt = tau moves 1 - exp(-1) of the way
    f = BrakeController(BrakeOptions(gain_overspeed=1.0, filter_tau=0.01), context_for(sc))
    f.step(0.0, _meas(w2=3.0), None)
    assert f.step(0.01, _meas(w2=4.0), None).u["n2"] == pytest.approx(1 - math.exp(-1.0))


def test_brake_acts_on_established_stick_slip():
    sc = _scenario([{"name": "b", "kind": "brake", "gain_overspeed": 80.0, "filter_tau": 0.0}],
                   omega_rpm=30.0, duration=8.0, start=4.0)
    r = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    before, after = r.t < 4.0, r.t >= 4.0
    assert np.all(r.input("n2")[before] == 0.0)
    assert np.max(r.input("n2")[after]) > 1.0          # it brakes R2 when it overspeeds
    assert np.max(r.input("n2")) <= 40.0               # the servo's range (rig3.toml)
    assert r.success


def test_supervisor_raises_when_stuck_and_lowers_after():
    sc = _scenario()
    o = SupervisorOptions(window=0.5, min_window=0.1, raise_max=1.0, rate_up=2.0, rate_down=0.5)
    c = SpeedSupervisor(o, context_for(sc))
    dt = 0.01
    out = np.array([c.step(k * dt, _meas(w1=0.0), None).u["omega_ref"] for k in range(200)])
    assert out[0] == pytest.approx(3.0)           # 2 s stuck: raise at 2 rad/s^2 to the 1 rad/s cap
    assert np.max(np.diff(out)) <= 2.0 * dt + 1e-12
    assert out[-1] == pytest.approx(4.0)
    hold = [c.step(k * dt, _meas(w1=3.0), None).u["omega_ref"] for k in range(200, 240)]
    assert hold[0] == pytest.approx(4.0)          # sliding, but the window still holds stuck samples
    low = np.array([c.step(k * dt, _meas(w1=3.0), None).u["omega_ref"] for k in range(240, 700)])
    assert np.min(np.diff(low)) >= -0.5 * dt - 1e-12       # back to the programme at 0.5 rad/s^2
    assert low[-1] == pytest.approx(3.0)


def test_supervisor_severity_detection():
    sc = _scenario()
    c = SpeedSupervisor(SupervisorOptions(detect="severity", on=0.5, off=0.2, window=1.0, min_window=0.5),
                        context_for(sc))
    for k in range(100):         # 3 +- 2 rad/s: severity 2/3 > on
        c.step(k * 0.01, _meas(w1=3.0 + 2.0 * (-1) ** k), None)
    assert c.mode == "raise" and c.offset > 0
    assert c.indicator() == pytest.approx(4.0 / (2 * 3.0))


def test_supervisor_defaults_come_from_the_rig():
    """Unset, the supervisor's unit-carrying options follow the rig: on rig3 at 30 rpm they are the
    values it was tuned with (window 3 s, raise 2.1 rad/s, rates 0.4 / 0.15 rad/s^2, stuck below half
    an encoder tick per DAQ period); at 60 rpm the raise and its rates double, and a given value wins."""
    from mitigate.controllers.tuning import stick_slip_frequency
    from models.sensors import encoder_step
    sc = _scenario([{"name": "s", "kind": "supervisor"}], omega_rpm=30.0)
    o = make_controller(sc.controllers[0], context_for(sc, 0)).options
    assert o.window == pytest.approx(3.0, rel=1e-3) and o.min_window == pytest.approx(1.0, rel=1e-3)
    assert o.raise_max == pytest.approx(2.1, rel=1e-3)
    assert o.rate_up == pytest.approx(0.4, rel=1e-3) and o.rate_down == pytest.approx(0.15, rel=1e-3)
    m = sc.model
    assert o.stuck_speed == pytest.approx(0.5 * encoder_step(m.sensor_of("omega1")) / sc.dt)
    assert o.window == pytest.approx(1.2856 * (1 / stick_slip_frequency(m, sc.model_params)), rel=1e-3)
    fast = _scenario([{"name": "s", "kind": "supervisor", "window": 2.0}], omega_rpm=60.0)
    f = make_controller(fast.controllers[0], context_for(fast, 0)).options
    assert f.raise_max == pytest.approx(4.2, rel=1e-3) and f.rate_up == pytest.approx(0.8, rel=1e-3)
    assert f.window == 2.0 and f.min_window == pytest.approx(2.0 / 3.0)


def test_brake_defaults_come_from_the_rig():
    """Unset, the brake's overspeed gain is pi/2 x the servo's range per programmed speed (rig3 at
    30 rpm: 40 N / pi rad/s x pi/2 = 20 N s/rad, its tuned value) and its filter 3 DAQ periods."""
    sc = _scenario([{"name": "b", "kind": "brake"}], omega_rpm=30.0)
    o = make_controller(sc.controllers[0], context_for(sc, 0)).options
    assert o.gain_overspeed == pytest.approx(20.0) and o.filter_tau == pytest.approx(3 * sc.dt)
    fast = _scenario([{"name": "b", "kind": "brake", "filter_tau": 0.0}], omega_rpm=60.0)
    f = make_controller(fast.controllers[0], context_for(fast, 0)).options
    assert f.gain_overspeed == pytest.approx(10.0) and f.filter_tau == 0.0


def test_factory_builds_each_kind():
    sc = _scenario([{"name": "a", "kind": "pi"}, {"name": "b", "kind": "brake", "gain_overspeed": 5.0},
                    {"name": "c", "kind": "supervisor", "raise_max": 1.0}])
    built = [make_controller(s, context_for(sc, i)) for i, s in enumerate(sc.controllers)]
    assert [type(c).__name__ for c in built] == ["PIOnly", "BrakeController", "SpeedSupervisor"]
    assert built[1].options.gain_overspeed == 5.0 and built[2].options.raise_max == 1.0
    for c in built:
        assert c.context.model is sc.model and c.context.params is sc.model_params
        assert c.context.dt == c.context.period == 0.01


@pytest.mark.parametrize("spec, match", [
    ({"name": "b", "kind": "brake", "gain_overspeed": -1.0}, r"controller 1 '[^']*'\.gain_overspeed must be >= 0"),
    ({"name": "b", "kind": "brake", "gain": 1.0}, r"controller 1 '[^']*'\.gain: unknown key"),
    ({"name": "b", "kind": "brake", "use_estimate": "yes"}, r"controller 1 '[^']*'\.use_estimate must be true or false"),
    ({"name": "b", "kind": "brake", "input": "n1"}, r"controller 1 '[^']*'.*n1"),
    ({"name": "s", "kind": "supervisor", "on": 0.1, "off": 0.2}, r"controller 1 '[^']*'\.off must be < on"),
    ({"name": "s", "kind": "supervisor", "detect": "x"}, r"controller 1 '[^']*'\.detect must be"),
    ({"name": "p", "kind": "pi", "gain": 1}, r"controller 1 '[^']*'\.gain: unknown key"),
    ({"name": "p", "kind": "lqr"}, r"controller 1 '[^']*'\.kind must be one of"),
])
def test_factory_one_line_errors(spec, match):
    sc = _scenario([spec])
    with pytest.raises(ConfigError, match=match) as ei:
        make_controller(sc.controllers[0], context_for(sc, 0))
    assert "\n" not in str(ei.value) and str(ei.value).startswith("t.toml: ")


def test_a_brake_needs_a_servo():
    sc = parse_scenario({"scenario": {"name": "t", "duration": 1.0, "model": "rig2"},
                         "inputs": {"motor_torque": 0.0}, "estimator": {"kind": "fd"},
                         "controllers": [{"name": "b", "kind": "brake"}]}, "t.toml")
    with pytest.raises(ConfigError, match=r"^t\.toml: controller 1 '[^']*': needs a servo on a contact's normal force .*; rig 'rig2' lacks it$"):
        make_controller(sc.controllers[0], context_for(sc, 0))


def test_the_supervisor_refuses_a_torque_drive():
    """Its offset is a speed: added to rig2's motor torque it would be a unit error."""
    sc = parse_scenario({"scenario": {"name": "t", "duration": 1.0, "model": "rig2"},
                         "inputs": {"motor_torque": 0.0}, "estimator": {"kind": "fd"},
                         "controllers": [{"name": "s", "kind": "supervisor"}]}, "t.toml")
    with pytest.raises(ConfigError, match=r"^t\.toml: controller 1 '[^']*': needs a speed-setting drive \(rig 'rig2' has a "
                                          r"torque drive, input 'motor_torque' \[N m\]\); rig 'rig2' lacks it$"):
        make_controller(sc.controllers[0], context_for(sc, 0))


def test_a_dropout_of_a_channel_the_law_reads_is_a_counted_fallback():
    sc = _scenario()
    c = BrakeController(BrakeOptions(), context_for(sc))
    a = c.step(0.0, {"omega1": 1.0}, None)      # omega2 missing: a dropout, answered by the fallback
    assert (a.u, a.status, a.success) == ({}, Status.FALLBACK, False)
    assert "SolverFailure: no reading of channel 'omega2'" in a.message
    assert c.counts.failures == 1 and c.counts.fallbacks == 1 and c.counts.steps == 1
