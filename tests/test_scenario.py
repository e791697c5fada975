"""Scenarios (mitigate.scenario): Python and TOML build the same thing, the runner takes objects and
writes nothing unless asked, everything pickles for the worker processes, errors name the field."""

import dataclasses
import math
import pickle

import numpy as np
import pytest

from mitigate import make_scenario, parse_scenario, run
from mitigate.scenario import Scenario, load_scenario
from models import get_model
from models.errors import ConfigError
from scenario_text import PI, scenario_toml

TOML = scenario_toml("""
[scenario]
name = "demo"
model = "rig3"
duration = 3.0
dt = 0.01
seed = 4

[plant]
start = "rest"
max_speed = 80.0

[mismatch]
mu_k = 1.1

[structure]
sensor_offsets = { motor_torque = 0.05 }
drift = { mu_k = 0.001 }

[sensors]
noise_scale = 2.0

[actuators.servo2]
n_max = "30 N"

""", inputs='omega_ref = "30 rpm"\nn1 = { kind = "steps", times = [0, 1.5], values = [20, 25] }',
   control="start = 1.0\nevery = 2", controllers=[PI, ("brake", "brake", "gain_overspeed = 80.0")])

KW = dict(name="demo", model="rig3", duration=3.0, dt=0.01, seed=4,
          inputs={"omega_ref": "30 rpm", "n1": {"kind": "steps", "times": [0, 1.5], "values": [20, 25]}},
          controllers=[{"name": "PI only", "kind": "pi"}, {"name": "brake", "kind": "brake", "gain_overspeed": 80.0}],
          estimator="fd", control_start=1.0, control={"every": 2}, plant={"start": "rest", "max_speed": 80.0},
          mismatch={"mu_k": 1.1}, structure={"sensor_offsets": {"motor_torque": 0.05}, "drift": {"mu_k": 0.001}},
          sensors={"noise_scale": 2.0}, actuators={"servo2": {"n_max": "30 N"}})


def _same(a: Scenario, b: Scenario):
    for f in dataclasses.fields(Scenario):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if f.name in ("path",):
            continue
        if f.name in ("model", "plant_model"):
            assert va.spec == vb.spec, f.name
        elif f.name in ("model_params", "plant_params"):
            assert va.names() == vb.names() and np.array_equal(va.vector(), vb.vector()), f.name
        elif f.name == "inputs":
            assert set(va) == set(vb)
            for t in (0.0, 1.0, 1.5, 2.9):
                np.testing.assert_array_equal(a.programme(t), b.programme(t))
        else:
            assert va == vb, f.name


def test_make_scenario_builds_what_the_toml_file_builds(tmp_path):
    p = tmp_path / "demo.toml"
    p.write_text(TOML)
    a = load_scenario(p)
    b = make_scenario(**KW)
    _same(a, b)
    # and the values are the ones written down (SI)
    assert a.programme(0.0) == pytest.approx([math.pi, 20.0, 0.0]) and a.programme(2.0)[1] == 25.0
    assert a.plant_params["mu_k"] == pytest.approx(1.1 * a.model_params["mu_k"])
    assert a.plant_params["motor_torque_offset"] == 0.05 and a.model_params["motor_torque_offset"] == 0.0
    assert a.model.actuator("n2").n_max == 30.0 == a.plant_model.actuator("n2").n_max
    assert (a.control.every, a.sensors.noise_scale, a.max_speed, a.drift) == (2, 2.0, 80.0, {"mu_k": 0.001})
    assert a.where == "demo.toml" and b.where == "demo"


def test_make_scenario_defaults_and_a_model_object():
    m = get_model("rig3")
    sc = make_scenario(model=m, duration=1.0, controllers=["pi"], estimator="fd")
    assert sc.model is m and sc.plant_model is m           # no [structure]: the plant is the model
    # inputs default to the rig file's operating point: 30 rpm, N1 = 20 N, N2 = 0 N
    assert sc.programme(0.0) == pytest.approx([math.pi, 20.0, 0.0])
    assert sc.controllers[0].name == sc.controllers[0].kind == "pi"
    with pytest.raises(ConfigError, match=r"^make_scenario: unknown section 'wobble'"):
        make_scenario(duration=1.0, wobble={})


def test_the_runner_takes_a_scenario_object_and_writes_nothing_without_out(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    sc = make_scenario(name="obj", duration=1.5, inputs={"omega_ref": "30 rpm", "n1": 20.0},
                       controllers=["pi", "brake"], estimator="fd", control_start=0.5)
    res = run(sc, jobs=1)
    assert list(tmp_path.iterdir()) == []
    assert res.success and res.files == {} and res.scenario is sc
    assert [r.name for r in res.runs] == ["pi", "brake"]
    r = res.run("brake")
    assert r.result.t.shape == (151,) and r.metrics["controller_steps"] == 101
    assert r.result.objective_speed is not None and res.table()[1]["controller"] == "brake"
    with pytest.raises(ConfigError, match="no controller named 'nmpc'"):
        res.run("nmpc")


def test_scenario_and_rig_model_pickle(tmp_path):
    p = tmp_path / "demo.toml"
    p.write_text(TOML.replace("[structure]", "[structure]\nshaft_elements = { count = 2, inertia = 1e-3 }"))
    sc = load_scenario(p)
    assert sc.plant_model.nx == sc.model.nx + 4      # a plant that differs in structure: 2 nodes, 2 springs more
    back = pickle.loads(pickle.dumps(sc))
    _same(sc, back)
    # the rebuilt models give the same CasADi functions
    for m, mb in ((sc.model, back.model), (sc.plant_model, back.plant_model)):
        x = np.linspace(-0.3, 0.9, m.nx)
        u = np.array([math.pi, 20.0, 3.0])
        pv = sc.plant_params.vector() if m is sc.plant_model else sc.model_params.vector()
        np.testing.assert_array_equal(np.array(m.ode()(x, u, pv)), np.array(mb.ode()(x, u, pv)))
    m = get_model("rig3")
    assert pickle.loads(pickle.dumps(m)).states == m.states


BASE = {"scenario": {"name": "t", "duration": 1.0}, "inputs": {"omega_ref": 3.0, "n1": 20.0},
        "estimator": {"kind": "fd"}}


def _with(path, value):
    d = pickle.loads(pickle.dumps(BASE))           # a deep copy
    node = d
    for k in path[:-1]:
        node = node.setdefault(k, {})
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


@pytest.mark.parametrize("path, value, match", [
    (("scenario", "duration"), KeyError, r"scenario\.duration: missing field"),
    (("scenario", "duration"), float("nan"), r"scenario\.duration must be a finite number"),
    (("scenario", "dt"), -0.01, r"scenario\.dt must be > 0"),
    (("scenario", "seed"), 1.5, r"scenario\.seed must be an integer, got 1\.5"),
    (("scenario", "model"), "rig9", r"scenario\.model: model must be a shipped rig"),
    (("scenario", "colour"), "red", r"scenario\.colour: unknown key"),
    (("plant", "method"), "euler", r"plant: sim\.method must be one of"),
    (("plant", "max_speed"), 0.0, r"plant\.max_speed must be > 0"),
    (("mismatch", "k9"), 1.2, r"mismatch\.k9: unknown parameter of rig 'rig3'"),
    (("mismatch", "k1"), -1.0, r"mismatch\.k1 must be > 0"),
    (("inputs", "n1"), KeyError, r"inputs\.n1: missing field"),
    (("inputs", "n7"), 1.0, r"inputs\.n7: unknown key"),
    (("inputs", "n1"), -3.0, r"inputs\.n1"),
    (("control", "every"), 0, r"control\.every must be an integer >= 1, got 0"),
    (("control", "start"), -1.0, r"control\.start must be >= 0"),
    (("sensors", "noise_scale"), -1.0, r"sensors\.noise_scale"),
    (("actuators", "servo9"), {"n_max": 10}, r"actuators\.servo9: rig 'rig3' has no such actuator"),
    (("actuators", "servo2"), {"n_max": -5}, r"actuators\.servo2: need 0 <= n_min < n_max"),
    (("controllers",), [{"name": "a", "kind": "pi"}, {"name": "a", "kind": "pi"}],
     r"controller 2 '[^']*'\.name: duplicate controller name 'a'"),
    (("controllers",), [{"kind": "pi"}], r"controller 1\.name: missing field"),
    (("estimator", "kind"), 3, r"estimator\.kind must be a string"),
    (("wobble",), {}, r"wobble: unknown section"),
])
def test_errors_are_one_line_and_name_the_field(path, value, match):
    with pytest.raises(ConfigError, match=match) as ei:
        parse_scenario(_with(path, value), "t.toml")
    assert "\n" not in str(ei.value) and str(ei.value).startswith("t.toml: ")
