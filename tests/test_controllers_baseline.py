"""Baseline controllers: PI only, semi-active R2 brake, speed-raise supervisor, and the factory."""

import numpy as np
import pytest

from estimators.base import Estimate
from mitigate.controllers.brake import BrakeController, BrakeOptions
from mitigate.controllers.factory import make_controller
from mitigate.controllers.pi import PIOnly, PIOptions
from mitigate.controllers.supervisor import SpeedSupervisor, SupervisorOptions
from mitigate.scenario import ControllerSpec, parse_scenario
from models.errors import ConfigError

NAMES = ("phi12", "phi23", "omega1", "omega2", "omega3", "i", "z")


def _meas(w1=3.0, w2=3.0, w3=3.0):
    return {"omega1": w1, "omega2": w2, "omega3": w3, "theta1": 0.0, "theta2": 0.0, "theta3": 0.0}


def _est(w1, w2, w3):
    return Estimate(0.0, np.array([0, 0, w1, w2, w3, 0, 0], float), np.eye(7), NAMES)


def test_pi_only_forwards_the_programme():
    c = PIOnly(PIOptions(), 3.0)
    a = c.step(0.0, None, _meas())
    assert (a.n2, a.omega_ref, a.success) == (0.0, 3.0, True)
    c.set_nominal(4.0)
    assert c.step(0.01, None, _meas()).omega_ref == 4.0


def test_brake_law_hand_computed():
    o = BrakeOptions(gain_overspeed=10.0, gain_relative=4.0, deadband=0.0, n_max=40.0, filter_tau=0.0)
    c = BrakeController(o, 3.0, 0.01)
    # overspeed 0.5 rad/s above the set-point and 0.25 rad/s above R3: 10*0.5 + 4*0.25 = 6 N
    assert c.step(0.0, None, _meas(w2=3.5, w3=3.25)).n2 == pytest.approx(6.0)
    # R2 slower than set-point and motor: no braking (a brake cannot push)
    assert c.step(0.01, None, _meas(w2=2.0, w3=3.0)).n2 == 0.0
    # saturation at n_max
    assert c.step(0.02, None, _meas(w2=20.0, w3=3.0)).n2 == 40.0
    # the set-point is never touched
    assert c.step(0.03, None, _meas(w2=20.0)).omega_ref == 3.0


def test_brake_deadband_estimate_and_filter():
    o = BrakeOptions(gain_overspeed=10.0, deadband=0.2, filter_tau=0.0)
    c = BrakeController(o, 3.0, 0.01)
    assert c.step(0.0, None, _meas(w2=3.1)).n2 == 0.0
    assert c.step(0.01, None, _meas(w2=3.5)).n2 == pytest.approx(3.0)
    # the estimate wins over the measurement when given
    assert c.step(0.02, _est(3, 4.2, 3), _meas(w2=3.0)).n2 == pytest.approx(10.0)
    # first-order filter: one step of dt = tau moves 1 - exp(-1) of the way
    f = BrakeController(BrakeOptions(gain_overspeed=1.0, filter_tau=0.01), 0.0, 0.01)
    f.step(0.0, None, _meas(w2=0.0))
    assert f.step(0.01, None, _meas(w2=1.0)).n2 == pytest.approx(1 - np.exp(-1.0))


def test_supervisor_raises_when_stuck_and_lowers_after():
    o = SupervisorOptions(window=0.5, min_window=0.1, raise_max=1.0, rate_up=2.0, rate_down=0.5)
    c = SpeedSupervisor(o, 3.0, 0.01)
    dt = 0.01
    out = []
    for k in range(200):         # 2 s stuck: raise at 2 rad/s^2 to the 1 rad/s cap
        out.append(c.step(k * dt, None, _meas(w1=0.0)).omega_ref)
    out = np.array(out)
    assert out[0] == 3.0
    assert np.max(np.diff(out)) <= 2.0 * dt + 1e-12
    assert out[-1] == pytest.approx(4.0)
    hold = []
    for k in range(200, 240):    # sliding, but the window still holds stuck samples: keep raised
        hold.append(c.step(k * dt, None, _meas(w1=3.0)).omega_ref)
    assert hold[0] == pytest.approx(4.0)
    low = []
    for k in range(240, 700):    # sliding for long: back to the programme at 0.5 rad/s^2
        low.append(c.step(k * dt, None, _meas(w1=3.0)).omega_ref)
    low = np.array(low)
    assert np.min(np.diff(low)) >= -0.5 * dt - 1e-12
    assert low[-1] == pytest.approx(3.0)


def test_supervisor_severity_detection():
    c = SpeedSupervisor(SupervisorOptions(detect="severity", on=0.5, off=0.2, window=1.0, min_window=0.5), 3.0, 0.01)
    for k in range(100):         # 3 +- 2 rad/s: severity 2/3 > on
        c.step(k * 0.01, None, _meas(w1=3.0 + 2.0 * (-1) ** k))
    assert c.mode == "raise" and c.offset > 0


def _scenario(controllers):
    return parse_scenario({"scenario": {"name": "t", "duration": 1.0},
                           "inputs": {"omega_ref": {"kind": "constant", "value": 30, "unit": "rpm"}, "n1": 20},
                           "estimator": {"kind": "fd"}, "controllers": controllers}, "t.toml")


def test_factory_builds_each_kind():
    sc = _scenario([{"name": "a", "kind": "pi"}, {"name": "b", "kind": "brake", "gain_overspeed": 5.0},
                    {"name": "c", "kind": "supervisor", "raise_max": 1.0}])
    kinds = [type(make_controller(s, sc, i)).__name__ for i, s in enumerate(sc.controllers)]
    assert kinds == ["PIOnly", "BrakeController", "SpeedSupervisor"]
    assert make_controller(sc.controllers[1], sc, 1).options.gain_overspeed == 5.0
    assert make_controller(sc.controllers[0], sc, 0).omega_nominal == pytest.approx(np.pi)


@pytest.mark.parametrize("spec, match", [
    ({"name": "b", "kind": "brake", "gain_overspeed": -1.0}, r"controllers\[0\]\.gain_overspeed must be >= 0"),
    ({"name": "b", "kind": "brake", "gain": 1.0}, r"controllers\[0\]\.gain: unknown option"),
    ({"name": "b", "kind": "brake", "use_estimate": "yes"}, r"controllers\[0\]\.use_estimate must be true or false"),
    ({"name": "s", "kind": "supervisor", "on": 0.1, "off": 0.2}, r"controllers\[0\]\.off must be < on"),
    ({"name": "s", "kind": "supervisor", "detect": "x"}, r"controllers\[0\]\.detect must be"),
    ({"name": "p", "kind": "pi", "gain": 1}, r"controllers\[0\]\.gain: unknown option"),
    ({"name": "p", "kind": "lqr"}, r"controllers\[0\]\.kind must be one of"),
])
def test_factory_one_line_errors(spec, match):
    sc = _scenario([spec])
    with pytest.raises(ConfigError, match=match) as ei:
        make_controller(sc.controllers[0], sc, 0)
    assert "\n" not in str(ei.value) and str(ei.value).startswith("t.toml: ")


def test_failure_in_law_is_a_counted_fallback():
    c = BrakeController(BrakeOptions(), 3.0, 0.01)
    a = c.step(0.0, None, {"omega2": 1.0})   # omega1 missing -> KeyError inside the law
    assert (a.n2, a.omega_ref, a.success, a.fallback) == (0.0, 3.0, False, "baseline")
    assert c.counts.failures == 1 and c.counts.fallbacks_baseline == 1
