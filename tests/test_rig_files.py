"""Rig description files (models.rig): the shipped rigs, the builder, and one-line errors for
malformed files.  The builder's regression against the published figures lives with each
figure: thesis tables (test_thesis_tables), modes (test_modal), the exact Coulomb cycle
(test_coulomb_cycle)."""

import math

import numpy as np
import pytest

from models import get_model, shipped_rigs
from models.errors import ConfigError
from models.plant import SimOptions, simulate
from models.rig import load_rig

RIG3 = get_model("rig3").spec.path


def _variant(tmp_path, old, new, name="bad.toml", count=1):
    text = open(RIG3).read()
    assert old in text, old
    p = tmp_path / name
    p.write_text(text.replace(old, new, count))
    return p


def test_shipped_rigs_load():
    assert {"rig3", "rig2", "leadscrew", "disc", "four_disc"} <= set(shipped_rigs())
    for n in shipped_rigs():
        m = get_model(n)
        assert m.nx == len(m.states) and m.n_p == len(m.published().names())
        assert m.published().names() == m.param_names


def test_rig3_states_inputs_and_channels():
    m = get_model("rig3")
    assert m.states == ("twist_shaft1", "twist_shaft2", "omega_R1", "omega_R2", "omega_R3", "current",
                        "pi_integral")
    assert m.inputs == ("omega_ref", "n1", "n2")
    assert m.contacts == (2, 3) and m.contact_bodies == ("R1", "R2")
    assert m.commands == ("omega_ref", "n2")
    assert {"theta1", "omega1", "theta3", "omega3", "motor_torque", "n1", "n2"} <= set(m.measured)


@pytest.mark.parametrize("old, new, match", [
    # a body that nothing connects
    ('[bodies.R3]\ninertia = 0.0', '[bodies.R3]\ninertia = 0.0\n[bodies.R4]\ninertia = "0.01 kg m^2"',
     r"bodies\.R4: nothing connects this body"),
    # a contact on a body that does not exist
    ('[contacts.pin1]\nbody = "R1"', '[contacts.pin1]\nbody = "R9"', r"contacts\.pin1\.body: no body 'R9'"),
    # a negative inertia
    ('J1 = { value = 0.02888,', 'J1 = { value = -0.02888,', r"bodies\.R1\.inertia must be >= 0 kg m\^2, got -0.02888"),
    ('[bodies.R3]\ninertia = 0.0', '[bodies.R3]\ninertia = -0.1', r"bodies\.R3\.inertia must be >= 0 kg m\^2, got -0.1"),
    # a sensor on a missing body
    ('kind = "encoder"           # LS Mecapion, 1000 ticks/rev (thesis Sect. 3.1.1)\nbody = "R1"',
     'kind = "encoder"\nbody = "R7"', r"sensors\.enc1\.body: no body 'R7'"),
    # a unit that does not convert
    ('k1 = { value = 1.1175, unit = "N m/rad"', 'k1 = { value = 1.1175, unit = "N m"',
     r"parameters\.k1\.unit: unit \[N m\] does not convert to a stiffness"),
    ('J2 = { value = 0.01496, unit = "kg m^2"', 'J2 = { value = 0.01496, unit = "furlongs"',
     r"parameters\.J2\.unit: unit \[furlongs\] does not convert"),
    # other mistakes a user makes
    ('law = "stribeck"', 'law = "sticky"', r"contacts\.pin1\.law must be one of"),
    ('mu_s = "mu_s"\nmu_k = "mu_k"\nv_s = "v_s"\n[contacts.pin2]', 'mu_s = "mu_s"\nmu_k = "mu_k"\n[contacts.pin2]',
     r"contacts\.pin1\.v_s: missing field"),
    ('between = ["R1", "R2"]', 'between = ["R1", "R1"]', r"connections\.shaft1\.between must join two different"),
    ('[connections.shaft2]\nbetween = ["R2", "R3"]', '[connections.shaft2]\nbetween = ["R2", "R1"]',
     r"connections\.shaft2: closes a loop of springs"),
    ('kind = "dc_motor"', 'kind = "steam_engine"', r"drive\.kind must be one of dc_motor, speed, torque"),
    ('input = "n2"\nn_min', 'input = "n1x"\nn_min', r"actuators\.servo2\.input must be a contact's normal-force input"),
    ('ticks = 1000\nangle = "theta1"', 'ticks = 0\nangle = "theta1"', r"sensors\.enc1\.ticks\\? must be an integer >= 1"),
    ('definition = "reaction" ', 'definition = "psychic" ', r"sensors\.motor_torque\.definition\\? must be 'reaction' or"),
    ('r2 = { value = 0.040, unit = "m"', 'r2 = { value = 2.5, unit = "m"',
     r"parameters\.r2\.value must be > 0 and <= 1 m, got 2.5"),
    ('[bodies.R1]\ninertia = "J1"', '[bodies.R1]\ninertia = "J1"\ncolour = "red"', r"bodies\.R1\.colour: unknown key"),
])
def test_malformed_rig_files_are_one_line_errors(tmp_path, old, new, match):
    with pytest.raises(ConfigError, match=match) as exc:
        load_rig(_variant(tmp_path, old, new))
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("bad.toml: ")


def test_unused_parameter_and_missing_unit(tmp_path):
    p = _variant(tmp_path, "[bodies.R1]", 'spare = { value = 1.0, unit = "m" }\n\n[bodies.R1]')
    text = p.read_text().replace('spare = { value = 1.0, unit = "m" }\n\n[bodies.R1]', "[bodies.R1]")
    text = text.replace('r2 = { value = 0.040', 'spare = { value = 1.0, unit = "m" }\nr2 = { value = 0.040')
    p.write_text(text)
    with pytest.raises(ConfigError, match=r"parameters\.spare: declared but not used"):
        load_rig(p)
    with pytest.raises(ConfigError, match=r"parameters\.k2\.unit: missing field \(expected a unit of stiffness"):
        load_rig(_variant(tmp_path, 'k2 = { value = 0.3659, unit = "N m/rad",', 'k2 = { value = 0.3659,', "b2.toml"))


def test_units_in_a_rig_file_are_converted(tmp_path):
    m = load_rig(_variant(tmp_path, 'J1 = { value = 0.02888, unit = "kg m^2", max = 10,',
                          'J1 = { value = 288.8, unit = "kg cm^2", max = 100000,'))
    assert m.published().J1 == pytest.approx(0.02888)
    m2 = load_rig(_variant(tmp_path, 'n_max = "40 N"', 'n_max = "0.04 kN"', "b2.toml"))
    assert m2.actuator("n2").n_max == pytest.approx(40.0)


def test_a_rig_picked_by_path_works_like_a_shipped_one(tmp_path):
    p = _variant(tmp_path, 'name = "rig3"', 'name = "my rig"', "mine.toml")
    m = get_model(str(p))
    assert m.name == "my rig" and m.cname == "my_rig" and m.key == str(p.resolve())
    r = simulate(str(p), None, np.array([math.pi, 20.0, 0.0]), 2.0, SimOptions(seed=1))
    ref = simulate("rig3", None, np.array([math.pi, 20.0, 0.0]), 2.0, SimOptions(seed=1))
    np.testing.assert_allclose(r.x, ref.x, rtol=1e-12, atol=1e-12)


def test_four_disc_rig_from_the_file_alone():
    """Four discs, the thesis motor, pins on D1 and D3, a servo on D2: the builder gives its
    model; it sticks at the rig file's operating point (30 rpm, N1 = 20 N, N3 = 10 N)."""
    m = get_model("four_disc")
    assert m.inputs == ("omega_ref", "n1", "n2", "n3") and m.commands == ("omega_ref", "n2")
    assert m.contact_bodies == ("D1", "D2", "D3")
    r = simulate(m, None, np.array([math.pi, 20.0, 0.0, 10.0]), 30.0, SimOptions(seed=1))
    w = r.state("omega_D1")[1500:]
    assert np.mean(w == 0.0) > 0.1                      # R1 is stuck a good part of the time
    assert np.mean(r.state("omega_M")[1500:]) == pytest.approx(math.pi, rel=0.02)


def test_speed_drive_and_torque_drive_rigs():
    disc = get_model("disc")
    assert disc.drive_kind == "speed" and disc.states == ("twist_spring", "omega_disc")
    rig2 = get_model("rig2")
    assert rig2.drive_kind == "torque" and rig2.commands == ("motor_torque",)
    u, x = rig2.operating_point(1.0, np.zeros(1), rig2.published())
    p = rig2.published()
    assert u[0] == pytest.approx(p.Tc, rel=1e-3)          # pure Coulomb, no damping to ground
    assert x[1] == x[2] == 1.0
