"""Plants that differ from the model in structure (a scenario's ``[structure]``).

Each key is checked against the physics it stands for, not against the code that implements it:
torque definitions at steady sliding, calibration of the channels, the PI loop's side, DAQ delays,
gearbox backlash (play and mesh mode), lumped shaft elements (static compliance and modes), the
friction law, and wear.  The controllers and the estimator keep the nominal model throughout.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from mitigate.closedloop import run_closed_loop
from mitigate.controllers.base import Action, Controller
from mitigate.controllers.factory import context_for, make_controller
from mitigate.scenario import load_scenario, make_scenario, parse_scenario
from models import get_model
from models.errors import ConfigError
from models.modal import chain_matrices, linearise, modes
from models.plant import Plant, SimOptions
from models.status import Status

ROOT = Path(__file__).resolve().parents[1]
W60 = 2 * math.pi          # 60 rpm [rad/s]: steady sliding at N1 = 20 N is stable and no limit cycle exists


def _sc(structure, omega="60 rpm", **kw):
    return make_scenario(name="s", duration=5.0, inputs={"omega_ref": omega, "n1": 20.0}, estimator="fd",
                         structure=structure, **kw)


def _sliding(sc, model=None, params=None, seconds=2.0, sensors=None, drift=None):
    """Ideal readings (no noise) of a plant started in steady sliding, after ``seconds``."""
    model = model or sc.plant_model
    params = params or sc.plant_params
    plant = Plant(model, params, SimOptions(dt=0.01, start="sliding"), sensors=sensors, u0=sc.programme(0.0),
                  drift=drift)
    ys = [plant.measure()]
    xs = [plant.x.copy()]
    for _ in range(int(round(seconds / 0.01))):
        ys.append(plant.step(sc.programme(0.0)))
        xs.append(plant.x.copy())
    return plant, ys, np.array(xs)


def test_torque_definition_reaction_vs_electromagnetic_at_steady_sliding():
    """At constant speed the reaction of the free-mounted gear motor is the torque into the shaft,
    eta (KT i - Tf - Cm eta w); the electromagnetic torque eta KT i exceeds it by eta (Tf + Cm eta w)
    (RIG-FACTS: 8 x (0.1196 + 1.784e-4 x 8 x 2 pi) = 1.0285 N m at 60 rpm)."""
    sc = _sc({"torque_definition": "electromagnetic"})
    assert sc.plant_model.sensor_of("motor_torque").definition == "electromagnetic"
    assert sc.model.sensor_of("motor_torque").definition == "reaction"
    _, y_em, x = _sliding(sc)
    _, y_re, x_re = _sliding(sc, sc.model, sc.model_params)
    np.testing.assert_array_equal(x, x_re)           # the same plant dynamics: only the sensor differs
    p = sc.model_params
    eta, w = p["eta"], x[-1, sc.model.states.index("omega_R3")]
    assert w == pytest.approx(W60, rel=1e-6)
    i = x[-1, sc.model.states.index("current")]
    assert y_em[-1]["motor_torque"] == pytest.approx(eta * p["KT"] * i, rel=1e-9)
    diff = y_em[-1]["motor_torque"] - y_re[-1]["motor_torque"]
    assert diff == pytest.approx(eta * (p["Tf"] + p["Cm"] * eta * w), rel=1e-6)
    assert diff == pytest.approx(1.0285, abs=1e-4)
    # and the reaction balances the load at constant speed: pin 1 friction = k2 x twist of shaft 2
    assert y_re[-1]["motor_torque"] == pytest.approx(-p["k2"] * x[-1, sc.model.states.index("twist_shaft2")],
                                                     rel=1e-6)


def test_sensor_offsets_and_gains_shift_and_scale_the_channels():
    sc = _sc({"sensor_offsets": {"motor_torque": "0.05 N m"}, "sensor_gains": {"n1": 1.05, "motor_torque": 1.1}})
    assert sc.plant_params["motor_torque_offset"] == 0.05 and sc.model_params["motor_torque_offset"] == 0.0
    _, ys, _ = _sliding(sc, seconds=0.5)
    _, ys0, _ = _sliding(sc, sc.model, sc.model_params, seconds=0.5)
    for y, y0 in zip(ys, ys0):
        assert y["motor_torque"] == pytest.approx(1.1 * y0["motor_torque"] + 0.05, rel=1e-12)
        assert y["n1"] == pytest.approx(1.05 * 20.0) and y0["n1"] == 20.0
        assert y["omega1"] == y0["omega1"]                     # the other channels are untouched
    # an encoder has no calibration parameter
    with pytest.raises(ConfigError, match=r"structure\.sensor_offsets\.omega1: no torque sensor"):
        _sc({"sensor_offsets": {"omega1": 0.1}})


def test_pi_error_on_the_motor_side_makes_the_electrical_mode_faster_with_the_same_steady_state():
    """With the PI on the motor-shaft error the loop gain is eta = 8 times the disc-side one: the
    electrical/PI mode moves out (|lambda| from ~400 to ~1000 1/s); the torsional modes (0.43 and
    1.82 Hz) stay and steady sliding is the same state, with the integral eta times smaller
    (V = ki z = eta ki z')."""
    sc = _sc({"pi_error": "motor"})
    u = sc.programme(0.0)
    nom = linearise(sc.model, sc.model_params, u)
    mot = linearise(sc.plant_model, sc.plant_params, u)
    ev_n = sorted(np.linalg.eigvals(nom.A), key=abs)
    ev_m = sorted(np.linalg.eigvals(mot.A), key=abs)
    assert abs(ev_m[-1]) > 2.0 * abs(ev_n[-1])
    tors_n = [e for e in ev_n if e.imag > 0 and abs(e) < 100]
    tors_m = [e for e in ev_m if e.imag > 0 and abs(e) < 100]
    assert len(tors_n) == 2 and np.abs(tors_n) / (2 * np.pi) == pytest.approx([0.43, 1.82], abs=0.01)
    np.testing.assert_allclose(np.abs(tors_m), np.abs(tors_n), rtol=0.01)
    i_z = sc.model.states.index("pi_integral")
    np.testing.assert_allclose(np.delete(mot.x_op, i_z), np.delete(nom.x_op, i_z), rtol=1e-9, atol=1e-12)
    p = sc.model_params
    assert mot.x_op[i_z] == pytest.approx(nom.x_op[i_z] / p["eta"], rel=1e-9)
    # the armature at steady state: V = ki z = R i + KE eta w
    i = nom.x_op[sc.model.states.index("current")]
    assert p["ki"] * nom.x_op[i_z] == pytest.approx(p["R"] * i + p["KE"] * p["eta"] * W60, rel=1e-9)
    # in time: the same speed after the transient
    _, _, x = _sliding(sc, seconds=1.0)
    assert x[-1, sc.model.states.index("omega_R1")] == pytest.approx(W60, rel=1e-6)


def test_delay_shifts_channels_by_whole_samples():
    sc = _sc({"delay": 3}, omega="30 rpm")
    sc1 = _sc({"delay": {"omega1": 2}}, omega="30 rpm")      # the encoder that writes omega1 (and theta1)
    nom = make_scenario(name="s", duration=2.0, inputs={"omega_ref": "30 rpm", "n1": 20.0}, estimator="fd")
    out = {}
    for key, s in (("nom", nom), ("all", sc), ("one", sc1)):
        plant = Plant(s.plant_model, s.plant_params, SimOptions(dt=0.01, seed=5), sensors=s.sensors,
                      u0=s.programme(0.0))
        out[key] = [plant.measure()] + [plant.step(s.programme(0.0)) for _ in range(150)]
    for ch in ("theta1", "omega1", "omega3", "motor_torque", "n1"):
        a = np.array([y[ch] for y in out["nom"]])
        d = np.array([y[ch] for y in out["all"]])
        np.testing.assert_array_equal(d[3:], a[:-3], err_msg=ch)       # noise included: the same draws, late
        np.testing.assert_array_equal(d[:3], a[0], err_msg=ch)          # until then, the first reading
        o = np.array([y[ch] for y in out["one"]])
        np.testing.assert_array_equal(o[2:], a[:-2] if ch in ("theta1", "omega1") else a[2:], err_msg=ch)
    assert np.ptp([y["omega1"] for y in out["nom"]]) > 1.0        # the channel does move


def test_backlash_the_motor_turns_a_gap_before_the_output_moves_and_the_mesh_mode_is_there():
    gap = math.radians(20.0)
    sc = _sc({"backlash": {"gap": "20 deg", "stiffness": "200 N m/rad", "inertia": "1e-3 kg m^2",
                           "damping": 0.0}}, omega="30 rpm")
    pm = sc.plant_model
    assert pm.drive_body == "R3_rotor" and sc.model.drive_body == "R3"
    # the rotor starts on the back flank (after a reversal): it must cross the whole play
    x0 = np.zeros(pm.nx)
    x0[pm.states.index("twist_R3_mesh")] = -gap / 2
    plant = Plant(pm, sc.plant_params, SimOptions(dt=0.01), sensors=None, x0=x0, u0=sc.programme(0.0))
    th, w3, wr = [], [], []
    for _ in range(100):
        y = plant.step(sc.programme(0.0))
        th.append(y["theta3"])                   # the motor encoder sits on the rotor
        w3.append(plant.x[pm.states.index("omega_R3")])
        wr.append(plant.x[pm.states.index("omega_R3_rotor")])
    th, w3, wr = map(np.array, (th, w3, wr))
    k = int(np.argmax(w3 != 0.0))
    assert k > 3 and np.all(w3[:k] == 0.0)                  # the output does not move inside the play
    # ... until the rotor has turned the gap (to within the last sample's travel)
    assert th[k - 1] <= gap <= th[k] + 1e-12
    assert th[k] - gap <= wr[k] * 0.01 + 1e-9
    # the mesh mode: rotor eta^2 Jm against the output J_out through k_mesh (teeth in contact),
    # f = sqrt(k (1/J_rotor + 1/J_out)) / 2 pi = 72.7 Hz; with the rotor held, sqrt((k + k2)/J_out) / 2 pi
    p = sc.plant_params
    J_rot, J_out, k = p["eta"] ** 2 * p["Jm"], 1e-3, 200.0
    f_two_mass = math.sqrt(k * (1 / J_rot + 1 / J_out)) / (2 * math.pi)
    f_held = math.sqrt((k + p["k2"]) / J_out) / (2 * math.pi)
    free = modes(pm, sc.plant_params, "free").freq_hz
    clamped = modes(pm, sc.plant_params, "clamped").freq_hz
    assert f_two_mass == pytest.approx(72.66, abs=0.01)
    assert np.min(np.abs(np.array(free) - f_two_mass)) / f_two_mass < 0.01
    assert np.min(np.abs(np.array(clamped) - f_held)) / f_held < 1e-3
    assert max(modes(sc.model, sc.model_params, "free").freq_hz) < 2.0     # the model has no such mode


def test_shaft_elements_keep_the_compliance_and_the_first_modes_and_add_higher_ones():
    sc = _sc({"shaft_elements": {"count": 3, "inertia": "2e-4 kg m^2"}})
    pm, p = sc.plant_model, sc.plant_params
    assert pm.nx == sc.model.nx + 8              # 2 nodes in each of 2 sections: a speed and a twist each
    # static twist of the drive-held chain under 1 N m on R1: 1/k1 + 1/k2 in both
    for m, par in ((sc.model, sc.model_params), (pm, p)):
        _, _, K, dofs = chain_matrices(m, par, clamped=True)
        f = np.zeros(len(dofs))
        f[dofs.index("theta_R1")] = 1.0
        theta = np.linalg.solve(K, f)
        assert theta[dofs.index("theta_R1")] == pytest.approx(1 / par["k1"] + 1 / par["k2"], rel=1e-12)
        assert theta[dofs.index("theta_R2")] == pytest.approx(1 / par["k2"], rel=1e-12)
    fm = modes(sc.model, sc.model_params, "clamped", damped=False).freq_hz
    fp = modes(pm, p, "clamped", damped=False).freq_hz
    assert len(fm) == 2 and len(fp) == 6
    np.testing.assert_allclose(fp[:2], fm, rtol=0.01)           # 0.4285 and 1.818 Hz stay within 1 %
    assert min(fp[2:]) > 3 * max(fm)                             # the elements' own modes, far above


def test_friction_law_steady_sliding_torque_follows_the_new_law():
    """bit_rock: T = c_b |w| + N r [mu_cb + (mu_sb - mu_cb) exp(-|w|/v_b)]; at constant speed the
    spring shaft 1 carries R1's friction torque, k1 |twist|."""
    law = {"law": "bit_rock", "mu_sb": 0.5, "mu_cb": 0.306, "v_b": 1.0, "c_b": 0.005}
    sc = _sc({"friction": law})
    c = next(c for c in sc.plant_model.spec.contacts if c.name == "pin1")
    assert c.law == "bit_rock" and next(c for c in sc.model.spec.contacts if c.name == "pin1").law == "stribeck"
    _, _, x = _sliding(sc, seconds=5.0)
    i1 = sc.plant_model.states.index("twist_shaft1")
    assert np.ptp(x[-100:, sc.plant_model.states.index("omega_R1")]) < 1e-4      # still sliding steadily
    T = sc.plant_params["k1"] * abs(x[-1, i1])
    N, r1 = 20.0, sc.plant_params["r1"]
    expected = law["c_b"] * W60 + N * r1 * (law["mu_cb"] + (law["mu_sb"] - law["mu_cb"]) * math.exp(-W60 / law["v_b"]))
    assert T == pytest.approx(expected, rel=1e-6)
    p = sc.model_params
    stribeck = N * r1 * (p["mu_k"] + (p["mu_s"] - p["mu_k"]) * math.exp(-W60 / p["v_s"]))
    assert abs(T - stribeck) > 0.09 * stribeck                 # the model's law would say 10 % less


def test_drift_makes_the_friction_grow_linearly_in_time():
    """drift mu_k = 1 %/s: mu_k(t) = mu_k (1 + 0.01 t); the pin torque at steady sliding follows it."""
    sc = _sc({"drift": {"mu_k": 0.01}})
    assert sc.drift == {"mu_k": 0.01} and sc.plant_params["mu_k"] == sc.model_params["mu_k"]
    plant, _, x = _sliding(sc, seconds=30.0, drift=sc.drift)
    p = sc.model_params
    i1 = sc.plant_model.states.index("twist_shaft1")
    N, r1 = 20.0, p["r1"]

    def T(t):
        mu_k = p["mu_k"] * (1 + 0.01 * t)
        return N * r1 * (mu_k + (p["mu_s"] - mu_k) * math.exp(-W60 / p["v_s"]))

    assert p["k1"] * abs(x[0, i1]) == pytest.approx(T(0.0), rel=1e-6)
    assert p["k1"] * abs(x[-1, i1]) == pytest.approx(T(30.0), rel=2e-3)
    assert T(30.0) / T(0.0) == pytest.approx(1.3, rel=0.01)
    assert plant.p[sc.plant_model.param_names.index("mu_k")] == pytest.approx(p["mu_k"] * (1 + 0.01 * 29.99))


@pytest.mark.parametrize("structure, match", [
    ({"wobble": 1}, r"structure\.wobble: unknown key"),
    ({"torque_definition": "magnetic"}, r"structure\.torque_definition must be 'reaction' or 'electromagnetic'"),
    ({"pi_error": "up"}, r"structure\.pi_error must be 'disc' or 'motor'"),
    ({"delay": -1}, r"structure\.delay must be an integer in \[0, 100\]"),
    ({"delay": 1.5}, r"structure\.delay must be an integer"),
    ({"delay": {"omega9": 1}}, r"structure\.delay\.omega9: no sensor writes channel"),
    ({"backlash": {"gap": "-1 deg"}}, r"structure\.backlash\.gap must be a finite number >= 0"),
    ({"backlash": {"gapp": "1 deg"}}, r"structure\.backlash\.gapp: unknown key"),
    ({"backlash": {"stiffness": "0 N m/rad"}}, r"structure\.backlash\.stiffness must be a finite number > 0"),
    ({"shaft_elements": {"count": 0, "inertia": 1e-3}}, r"structure\.shaft_elements\.count must be an integer"),
    ({"shaft_elements": {"count": 2}}, r"structure\.shaft_elements must be a table \{count, inertia\}"),
    ({"friction": {"law": "nope"}}, r"structure\.friction\.law must be one of"),
    ({"friction": {"law": "bit_rock", "mu_sb": 0.5}}, r"structure\.friction\.mu_cb: missing field"),
    ({"friction": {"law": "coulomb", "mu_k": 0.3, "zeta": 1}}, r"structure\.friction\.zeta: not a parameter"),
    ({"drift": {"k9": 0.1}}, r"structure\.drift\.k9: not a parameter of rig 'rig3'"),
    ({"drift": {"mu_k": "fast"}}, r"structure\.drift\.mu_k"),
    ({"sensor_gains": {"n1": "x"}}, r"structure\.sensor_gains\.n1 must be a number"),
    ({"sensor_gains": 3}, r"structure\.sensor_gains must be a table"),
])
def test_bad_structure_is_a_one_line_error_naming_the_key(structure, match):
    data = {"scenario": {"name": "t", "duration": 1.0}, "inputs": {"omega_ref": 3.0, "n1": 20.0},
            "estimator": {"kind": "fd"}, "structure": structure}
    with pytest.raises(ConfigError, match=match) as ei:
        parse_scenario(data, "t.toml")
    assert "\n" not in str(ei.value) and str(ei.value).startswith("t.toml: ")


class Spy(Controller):
    def __init__(self, options, context):
        super().__init__(options, context)
        self.estimates = []

    def _step_impl(self, t, measurement, estimate):
        self.estimates.append(estimate)
        return Action({})


def test_the_controllers_and_the_estimator_keep_the_nominal_model():
    sc = load_scenario(ROOT / "scenarios" / "realistic.toml")
    rig3 = get_model("rig3")
    assert sc.model.spec == rig3.spec and np.array_equal(sc.model_params.vector(), rig3.published().vector())
    assert sc.plant_model.spec != rig3.spec and sc.plant_model.nx > rig3.nx
    sc = sc.replace(duration=1.0, control=sc.control.replace(start=0.5), estimator={"kind": "fd"})
    for i, spec in enumerate(sc.controllers):
        if spec.kind != "nmpc":
            c = make_controller(spec, context_for(sc, i))
            assert c.context.model is sc.model and c.context.params is sc.model_params
    spy = Spy(None, context_for(sc))
    r = run_closed_loop(sc, spy)
    assert r.x.shape[1] == sc.plant_model.nx and r.xhat.shape[1] == rig3.nx
    assert spy.estimates[-1].names == rig3.states
    # the model's twists are reported from the plant's elements: twist_shaft1 = element 1 + element 2
    S = r.x[:, [sc.plant_model.states.index("twist_shaft1"), sc.plant_model.states.index("twist_shaft1_1")]]
    np.testing.assert_allclose(r.twists["twist_shaft1"], S.sum(axis=1), rtol=1e-12, atol=1e-15)


def test_realistic_scenario_runs_10_s_with_pi():
    sc = load_scenario(ROOT / "scenarios" / "realistic.toml")
    sc = sc.replace(duration=10.0, control=sc.control.replace(start=5.0), estimator={"kind": "fd"})
    i = next(i for i, c in enumerate(sc.controllers) if c.kind == "pi")
    r = run_closed_loop(sc, make_controller(sc.controllers[i], context_for(sc, i)))
    assert r.status is Status.OK and r.t[-1] == pytest.approx(10.0)
    assert np.all(np.isfinite(r.x)) and np.max(np.abs(r.state("omega_R1"))) < 10.0
    assert np.mean(r.state("omega_R3")[r.t > 5]) == pytest.approx(math.pi, rel=0.05)   # the drive holds 30 rpm
    # the N1 load cell reads 3 % high (sensor_gains), with 0.2 N of noise
    assert np.median(r.y["n1"]) == pytest.approx(1.03 * 20.0, abs=0.1)
    assert sc.messages == () or all("nsub" in m for m in sc.messages)


def test_functions_are_cached_per_model_object_not_per_name(monkeypatch):
    """A plant with lumped shaft elements has more states than its nominal model of the same
    name.  A benchmark worker builds and frees such models in turn, and CPython reuses a freed
    object's ``id``: a function cache keyed by ``id(model)`` once handed the 11-state plant the
    7-state model's step ("could not broadcast (13,) into (7,)").  Here every object gets the same
    id, which is what id reuse looks like to such a cache."""
    import builtins

    import models.modal as modal
    import models.plant.simulator as simulator

    for mod in (simulator, modal):
        monkeypatch.setattr(mod, "id", lambda obj: 0, raising=False)
    assert builtins.id is not simulator.id
    sc = _sc({"shaft_elements": {"count": 2, "inertia": "5e-4 kg m^2"}})
    assert sc.plant_model.nx > sc.model.nx and sc.plant_model.key == sc.model.key
    for spec in (sc.model.spec, sc.plant_model.spec, sc.model.spec):
        m = type(sc.model)(spec, sc.model.key)
        F = simulator.step_function(m, SimOptions(dt=0.01))
        assert F.size1_in(0) == m.nx
        lin = modal.linearise(m, m.published(), sc.programme(0.0))
        assert lin.A.shape == (m.nx, m.nx)
