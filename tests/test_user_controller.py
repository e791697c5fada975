"""Your own controller: a Controller subclass in any importable module, named ``module:Class`` in a
scenario, runs in the loop beside the built-in ones with the same estimator, metrics and report.

The example is ``tests/plugins/my_controller.py`` (docs/plugins.md quotes it; tests/test_docs.py checks the quote); this test puts the
repository root on ``sys.path`` so that ``tests.plugins.my_controller`` imports, as a user's own
folder would be on theirs.
"""

import builtins
import json
from pathlib import Path

import numpy as np
import pytest

from mitigate import run
from mitigate.controllers.factory import context_for, controller_class, make_controller
from mitigate.scenario import parse_scenario
from models.errors import ConfigError
from scenario_text import PI, scenario_toml

ROOT = Path(__file__).resolve().parents[1]
REF = "tests.plugins.my_controller:HighPassTorque"

SCENARIO = scenario_toml('[scenario]\nname = "mine"\nduration = 35.0\nseed = 1', control="start = 15.0",
                         controllers=[PI, ("my law", REF, "gain = 2.0", "tau = 5.0")])


@pytest.fixture(autouse=True)
def _on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT))


@pytest.mark.slow
def test_the_example_runs_in_the_loop_with_metrics_and_report(tmp_path):
    sc_path = tmp_path / "mine.toml"
    sc_path.write_text(SCENARIO)
    out = tmp_path / "out"
    res = run(sc_path, out=out, jobs=2)           # each controller in its own (spawned) worker process
    assert res.success
    pi, mine = res.run("PI only"), res.run("my law")
    assert mine.kind == REF and mine.result.controller == "high_pass_torque"
    assert mine.result.estimator_counts["steps"] == pi.result.estimator_counts["steps"] == 3501
    assert mine.metrics["controller_steps"] == 2001 and mine.metrics["controller_failures"] == 0
    # it sets the drive's set-point (g = 2 rad/s per N m times the high-passed torque), nothing else
    on = mine.result.t >= 15.0
    assert np.ptp(mine.result.commands["omega_ref"][on]) > 0.1
    np.testing.assert_array_equal(mine.result.commands["n2"], 0.0)
    # a simple law, and it does suppress this stick-slip (PI alone does not)
    assert mine.metrics["sss_final"] < 0.05 < 1.0 < pi.metrics["sss_final"]
    rep = (out / "report.md").read_text()
    assert "| my law | tests.plugins.my_controller:HighPassTorque |" in rep
    assert (out / "log_my_law.csv").is_file() and (out / "timeseries_my_law.png").is_file()
    doc = json.loads((out / "metrics.json").read_text())
    assert [c["name"] for c in doc["controllers"]] == ["PI only", "my law"]


def _scenario(kind, **options):
    return parse_scenario({"scenario": {"name": "t", "duration": 1.0}, "inputs": {"omega_ref": 3.0, "n1": 20.0},
                           "estimator": {"kind": "fd"},
                           "controllers": [{"name": "a", "kind": "pi"}, {"name": "b", "kind": kind, **options}]},
                          "t.toml")


def test_its_options_are_validated_like_the_built_in_ones():
    sc = _scenario(REF, gain=-1.0)
    with pytest.raises(ConfigError, match=r"^t\.toml: controller 2 '[^']*'\.gain must be >= 0 rad/s per N m, got -1\.0$"):
        make_controller(sc.controllers[1], context_for(sc, 1))
    sc = _scenario(REF, gian=1.0)
    with pytest.raises(ConfigError, match=r"^t\.toml: controller 2 '[^']*'\.gian: unknown key \(did you mean 'gain'\?\); expected one of gain, tau"):
        make_controller(sc.controllers[1], context_for(sc, 1))


@pytest.mark.parametrize("kind, match", [
    ("no_such_module:X", r"controller 2 '[^']*'\.kind: module 'no_such_module' not found"),
    ("tests.plugins.my_controller:Nope", r"controller 2 '[^']*'\.kind: module 'tests\.plugins\.my_controller' has no 'Nope'"),
    ("tests.plugins.my_controller:HighPassTorqueOptions",
     r"controller 2 '[^']*'\.kind: 'tests\.plugins\.my_controller:HighPassTorqueOptions' is not a Controller subclass"),
    ("os:system", r"controller 2 '[^']*'\.kind: 'os:system' is not a Controller subclass"),
    ("a b c", r"controller 2 '[^']*'\.kind must be one of pi, brake, .* or 'module:Class', got 'a b c'"),
    ("__import__('os').getcwd()", r"controller 2 '[^']*'\.kind must be one of"),
])
def test_a_bad_reference_is_a_one_line_error_naming_the_kind(kind, match):
    sc = _scenario(kind)
    with pytest.raises(ConfigError, match=match) as ei:
        make_controller(sc.controllers[1], context_for(sc, 1))
    assert "\n" not in str(ei.value) and str(ei.value).startswith("t.toml: controller 2 'b'.kind")


def test_a_module_that_fails_to_import_is_a_one_line_error(tmp_path, monkeypatch):
    (tmp_path / "broken_dep.py").write_text("import numpyy_not_installed\n")
    (tmp_path / "broken_syntax.py").write_text("def f(:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for mod, why in (("broken_dep", "ModuleNotFoundError: No module named 'numpyy_not_installed'"),
                     ("broken_syntax", "SyntaxError")):
        sc = _scenario(f"{mod}:C")
        with pytest.raises(ConfigError) as ei:
            make_controller(sc.controllers[1], context_for(sc, 1))
        msg = str(ei.value)
        assert msg.startswith(f"t.toml: controller 2 'b'.kind: module '{mod}' could not be imported: {why}")
        assert "\n" not in msg


def test_loading_uses_importlib_never_eval(monkeypatch):
    def no_eval(*a, **k):
        raise AssertionError("eval called")

    monkeypatch.setattr(builtins, "eval", no_eval)
    monkeypatch.setattr(builtins, "exec", no_eval)
    cls = controller_class(REF, "t.toml: controllers[1]")
    assert cls.__name__ == "HighPassTorque" and cls.__module__ == "tests.plugins.my_controller"


def test_the_example_law_hand_computed():
    """omega_ref = programme - g (T - LP(T)): a torque step of 1 N m moves the set-point by -g (1 - a)
    at once, with a = 1 - exp(-dt / tau), and the high-pass decays by (1 - a) per sample."""
    import math
    sc = _scenario(REF, gain=2.0, tau=5.0)
    c = make_controller(sc.controllers[1], context_for(sc, 1))
    c.reset()
    assert c.step(0.0, {"motor_torque": 0.3}, None).u == {"omega_ref": pytest.approx(3.0)}
    a = 1 - math.exp(-0.01 / 5.0)
    assert c.step(0.01, {"motor_torque": 1.3}, None).u["omega_ref"] == pytest.approx(3.0 - 2.0 * (1 - a))
    assert c.step(0.02, {"motor_torque": 1.3}, None).u["omega_ref"] == pytest.approx(3.0 - 2.0 * (1 - a) ** 2)
