"""The drilling industry's stick-slip laws on lab rigs: SoftSpeed, Z-Torque (NORCE Simulator4nDOF,
Dwars SPE/IADC-173037) and D-OSKIL (Canudas de Wit et al., IEEE TCST 2008).

Their tuning from a rig file is checked by hand, their effect on the established stick-slip of the
thesis rig (30 rpm, N1 = 20 N) against PI alone, and that they need nothing but measured channels.
Step times are a benchmark fact (benchmarks/industry_tuning.py), not a test.
"""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from estimators.base import Estimate
from mitigate.closedloop import run_closed_loop
from mitigate.controllers.factory import context_for, make_controller
from mitigate.controllers.tuning import tuning_for
from mitigate.metrics import closed_loop_metrics
from mitigate.scenario import make_scenario, parse_scenario
from models import get_model
from models.errors import ConfigError
from models.rig import RIGS_DIR
from models.status import Status

LAWS = ("softspeed", "ztorque", "doskil")


def test_auto_tuning_on_rig3_hand_computed():
    """Z = sqrt(k J) with k = 1/(1/k1 + 1/k2) = 0.2756 N m/rad and J = J1 + J2 = 0.04384 kg m^2
    (thesis Table 3.2, eq. 3-7): 0.1099 N m s/rad; f_ss: the drive-held chain's first mode, 0.4285 Hz;
    D-OSKIL's matched gain Z / (r2 mu_k) = 0.1099 / (0.040 x 0.306) = 8.98 N s/rad, doubled by default.
    The defaults' factors (SoftSpeed Kp = 2 Z, Z-Torque z = 0.35, D-OSKIL x2) come from the gain sweep
    (benchmarks/industry_tuning.py)."""
    m = get_model("rig3")
    p = m.published()
    t = tuning_for(m, p)
    k = 1 / (1 / 1.1175 + 1 / 0.3659)
    J = 0.02888 + 0.01496
    assert (t.k_string, t.J_string) == (pytest.approx(k, rel=1e-12), pytest.approx(J, rel=1e-12))
    assert t.Z == pytest.approx(math.sqrt(k * J), rel=1e-12) and t.Z == pytest.approx(0.1099, abs=1e-4)
    assert t.f_ss == pytest.approx(0.4285, abs=1e-4)
    assert t.J_drive == pytest.approx(8.0 ** 2 * 0.370e-3, rel=1e-12)      # eta^2 Jm: R3 itself has none
    sc = make_scenario(duration=1.0, controllers=list(LAWS), estimator="fd")
    ss, zt, dk = (make_controller(c, context_for(sc, i)) for i, c in enumerate(sc.controllers))
    assert ss.f_t == pytest.approx(0.4172, abs=1e-4)        # the absorber's mode, near the drive-held 0.4285 Hz
    assert ss.Kp == pytest.approx(2 * t.Z) and ss.Ki == pytest.approx((2 * math.pi * ss.f_t) ** 2 * t.J_drive)
    assert zt.gain == pytest.approx(0.35 / t.Z) and zt.tau_hp == pytest.approx(2.0 / t.f_ss)
    assert dk.gain == pytest.approx(2 * t.Z / (0.040 * 0.306), rel=1e-12) and dk.gain == pytest.approx(17.96, abs=0.01)
    assert (dk.input, dk.body_ch, dk.top_ch, dk.n_max) == ("n2", "omega2", "omega3", 40.0)
    # the options override the derived values
    sc2 = make_scenario(duration=1.0, controllers=[{"name": "s", "kind": "softspeed", "kp_factor": 3.0, "f_t": 0.5},
                                                   {"name": "d", "kind": "doskil", "gain": 20.0}], estimator="fd")
    s2, d2 = (make_controller(c, context_for(sc2, i)) for i, c in enumerate(sc2.controllers))
    assert s2.Kp == pytest.approx(3 * t.Z) and s2.Ki == pytest.approx((2 * math.pi * 0.5) ** 2 * t.J_drive)
    assert d2.gain == 20.0


@pytest.fixture(scope="module")
def established():
    """rig3 at 30 rpm, N1 = 20 N from rest: stick-slip established by 20 s, control from 20 s to 60 s."""
    sc = make_scenario(name="established", duration=60.0, seed=1, inputs={"omega_ref": "30 rpm", "n1": 20.0},
                       controllers=["pi", *LAWS], estimator="fd", control_start=20.0)
    pi = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    return sc, closed_loop_metrics(pi, sc)


@pytest.mark.slow
def test_pi_alone_keeps_the_stick_slip(established):
    sc, m = established
    assert m["sss_final"] > 1.0 and m["stuck_fraction"] > 0.1 and m["time_to_suppress"] == math.inf


@pytest.mark.slow
@pytest.mark.parametrize("kind", LAWS)
def test_each_law_suppresses_the_established_stick_slip(established, kind):
    sc, m_pi = established
    i = 1 + LAWS.index(kind)
    r = run_closed_loop(sc, make_controller(sc.controllers[i], context_for(sc, i)))
    m = closed_loop_metrics(r, sc)
    assert r.status is Status.OK and m["controller_fallbacks"] == 0
    assert m["sss_final"] < 0.05 < 1.0 < m_pi["sss_final"]          # severity over the last 5 s
    assert m["time_to_suppress"] < 20.0 and m["stuck_fraction"] < m_pi["stuck_fraction"]
    # the soft laws let the drive yield to the wave (its speed rises for a while), then return to the
    # programme: over the last 5 s R1 turns at 30 rpm
    last = r.t > 55.0
    assert np.mean(r.state("omega_R1")[last]) == pytest.approx(math.pi, abs=0.01)


class Recording(dict):
    """A measurement that records which channels were read."""

    def __init__(self, *a):
        super().__init__(*a)
        self.read = set()

    def __getitem__(self, k):
        self.read.add(k)
        return super().__getitem__(k)

    def get(self, k, default=None):
        self.read.add(k)
        return super().get(k, default)


@pytest.mark.parametrize("kind", LAWS)
def test_the_laws_use_measured_channels_only_never_the_estimate(kind):
    sc = make_scenario(duration=3.0, seed=2, inputs={"omega_ref": "30 rpm", "n1": 20.0}, controllers=["pi", kind],
                       estimator="fd")
    r = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    a, b = make_controller(sc.controllers[1], context_for(sc, 1)), make_controller(sc.controllers[1], context_for(sc, 1))
    junk = Estimate(0.0, np.full(7, 1e3), np.eye(7), sc.model.states)
    read = set()
    for k in range(len(r.t)):
        y = Recording({c: v[k] for c, v in r.y.items()})
        ua = a.step(r.t[k], y, None).u
        ub = b.step(r.t[k], dict(y), junk).u
        assert ua == ub
        read |= y.read
    assert read and read <= set(sc.model.measured)
    assert a.counts.failures == 0


def _rig_without(tmp_path, section: str, name: str) -> Path:
    """A copy of rig3.toml without one ``[section]`` table, named ``name``."""
    text = (RIGS_DIR / "rig3.toml").read_text()
    text, n = re.subn(rf"^\[{re.escape(section)}\]\n(?:(?!\[).*\n)*", "", text, flags=re.M)
    assert n == 1, section
    text = text.replace('name = "rig3"', f'name = "{name}"', 1)
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def _scenario_on(rig: Path, kind: str, tmp_path):
    inputs = {"omega_ref": 3.0, "n1": 20.0}
    if "n2" not in get_model(rig).servo_inputs:
        inputs["n2"] = 0.0
    return parse_scenario({"scenario": {"name": "t", "duration": 1.0, "model": str(rig)}, "inputs": inputs,
                           "estimator": {"kind": "fd"}, "controllers": [{"name": "c", "kind": kind}]},
                          str(tmp_path / "t.toml"))


@pytest.mark.parametrize("kind", ["softspeed", "ztorque"])
def test_without_the_torque_cell_or_the_motor_encoder_softspeed_and_ztorque_say_so(tmp_path, kind):
    rig = _rig_without(tmp_path, "sensors.motor_torque", "rig3_no_torque")
    assert "motor_torque" not in get_model(rig).measured
    sc = _scenario_on(rig, kind, tmp_path)
    with pytest.raises(ConfigError) as ei:
        make_controller(sc.controllers[0], context_for(sc, 0))
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith("t.toml: controller 1 'c': needs the torque at the drive")
    assert "'rig3_no_torque'" in msg
    rig = _rig_without(tmp_path, "sensors.enc3", "rig3_no_motor_encoder")
    sc = _scenario_on(rig, kind, tmp_path)
    with pytest.raises(ConfigError, match=r"^t\.toml: controller 1 '[^']*': needs the drive's speed \(add an encoder "
                                          r"or speed sensor on body 'R3'\); rig 'rig3_no_motor_encoder' lacks it$"):
        make_controller(sc.controllers[0], context_for(sc, 0))


def test_without_a_servo_doskil_says_so(tmp_path):
    rig = _rig_without(tmp_path, "actuators.servo2", "rig3_no_servo")
    assert get_model(rig).servo_inputs == ()
    sc = _scenario_on(rig, "doskil", tmp_path)
    with pytest.raises(ConfigError, match=r"^t\.toml: controller 1 '[^']*': needs a servo on a contact's normal "
                                          r"force \(rig 'rig3_no_servo' has no actuator: add an \[actuators\] entry of kind \"servo\"\); "
                                          r"rig 'rig3_no_servo' lacks it$"):
        make_controller(sc.controllers[0], context_for(sc, 0))
    # the speed laws need no servo
    make_controller(_scenario_on(rig, "softspeed", tmp_path).controllers[0], context_for(sc, 0))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["softspeed", "ztorque"])
def test_on_a_torque_drive_the_law_commands_the_torque(kind):
    """rig2 (seed 001): the motor torque is the input.  The law is the speed loop itself: it holds the
    operating point's 1 rad/s against the disc's Coulomb friction (Tc = 0.222 N m); Z-Torque's integral
    (NORCE: Ki = 5 J_drive) is slow, so it gets there within 5 % only after some 20 s."""
    sc = make_scenario(name="r2", model="rig2", duration=30.0, inputs={"motor_torque": 0.0}, controllers=[kind],
                       estimator="fd")
    c = make_controller(sc.controllers[0], context_for(sc, 0))
    a = c.step(0.0, {"omega1": 0.0, "omega3": 0.0, "theta1": 0.0, "theta3": 0.0, "motor_torque": 0.0}, None)
    assert set(a.u) == {"motor_torque"} and a.status is Status.OK
    r = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    assert r.status is Status.OK
    tail = r.t > 25.0
    assert np.mean(r.state("omega_motor")[tail]) == pytest.approx(1.0, abs=0.05)
    assert np.mean(r.commands["motor_torque"][tail]) == pytest.approx(0.222, rel=0.05)   # it carries the friction


def test_softspeed_tuning_frequency_is_the_mode_of_the_string_with_the_law_at_the_top():
    """At f_t SoftSpeed makes the drive a pure damper Kp.  rig2 is one disc (Jd) on a shaft (k, c) from
    the motor: with the motor a massless damper, Jd s^2 (Kp + c) s + k ... written out by hand (the
    cubic of the disc angle and the top angle); without the shaft's damper the mode is exactly
    sqrt(k/Jd) for any Kp (a mass on a spring ended by a damper), here within 1 %."""
    from mitigate.controllers.tuning import absorber_frequency
    m = get_model("rig2")
    p = m.published()
    t = tuning_for(m, p)
    Jd, k, c = 0.01496, 0.3482, 0.0022
    for Kp in (0.5 * t.Z, 2 * t.Z, 8 * t.Z):
        # Jd th'' = -(k + c s)(th - top);  Kp top' = (k + c s)(th - top)
        # => Jd (Kp + c) s^3 + (Jd k + Kp c) s^2 + Kp k s = 0 after eliminating top
        roots = np.roots([Jd * (Kp + c), Jd * k + Kp * c, Kp * k])
        f_hand = max(abs(r) for r in roots if abs(r.imag) > 1e-12) / (2 * math.pi)
        assert absorber_frequency(m, p, Kp) == pytest.approx(f_hand, rel=1e-6)
        assert f_hand == pytest.approx(math.sqrt(k / Jd) / (2 * math.pi), rel=0.03)


def test_softspeed_virtual_drive_is_stable_for_a_tiny_drive_inertia():
    """Kp dt / J_v = 60: the explicit Euler step it replaced made the set-point jump between the ends
    of its band every 10 ms (issue 18: 0.14 / 6.14 rad/s on a student rig); the exact step holds it."""
    sc = make_scenario(name="s", duration=6.0, seed=1, inputs={"omega_ref": "30 rpm", "n1": 20.0},
                       controllers=[{"name": "s", "kind": "softspeed", "J_v": 2 * 0.1099 * 0.01 / 60}],
                       estimator="fd", control_start=3.0)
    c = make_controller(sc.controllers[0], context_for(sc, 0))
    assert c.Kp * 0.01 / c.J_v == pytest.approx(60, rel=1e-3)
    r = run_closed_loop(sc, c)
    assert r.status is Status.OK, r.message
    w = r.commands["omega_ref"][r.t > 3.5]
    assert np.max(np.abs(np.diff(w))) < 0.2 and 0.0 < np.min(w) and np.max(w) < 2 * math.pi
