"""Tuning (mitigate.tune, mitigate.tunables): declared tunables with scale-free ranges, an Optuna study
that starts from the shipped options, persists in a journal file and resumes, shared by processes,
reported on held-out seeds; the ``mitigate tune`` command."""

import json

import pytest

from mitigate.controllers.factory import context_for, make_controller
from mitigate.scenario import ControllerSpec, make_scenario
from mitigate.tune import tune
from mitigate.tunables import Tunable, actuator_class, set_option, tunables_of
from models.errors import ConfigError

DRILL = """
[scenario]
name = "drill"
model = "drillstring_motor"
duration = 1.6
dt = 0.002
seed = 8
[plant]
nsub = 2
[inputs]
omega_ref = "3 rad/s"
wob = 200.0
[control]
start = 0.8
[estimator]
kind = "fd"
"""


@pytest.fixture(scope="module")
def drill(tmp_path_factory):
    p = tmp_path_factory.mktemp("tune") / "drill.toml"
    p.write_text(DRILL)
    return p


@pytest.mark.slow
def test_tunables_are_declared_scale_free_and_follow_what_the_controller_sets():
    sc = make_scenario(name="t", duration=1.0, inputs={"omega_ref": "30 rpm", "n1": 20.0}, estimator="fd")
    ss = make_controller(ControllerSpec("s", "softspeed", {}), context_for(sc, 0))
    t = tunables_of(ss)
    assert set(t) == {"kp_factor", "f_t"} and actuator_class(sc.model, ss.actuated_inputs()) == "drive"
    # f_t in multiples of rig3's lowest mode with the drive held (0.4285 Hz, thesis rig); Kp in multiples of Z
    assert t["f_t"].unit_value(ss.context) == pytest.approx(0.4285, rel=2e-3)
    assert t["kp_factor"].unit_value(ss.context) == 1.0
    brake = make_controller(ControllerSpec("b", "brake", {}), context_for(sc, 0))
    # the brake's gain in the servo's force range per programmed speed: 40 N / pi rad/s
    assert tunables_of(brake)["gain_overspeed"].unit_value(brake.context) == pytest.approx(40 / 3.14159265, rel=1e-6)
    assert actuator_class(sc.model, brake.actuated_inputs()) == "force"
    motor = make_controller(ControllerSpec("m", "nmpc", {"inputs": "motor"}), context_for(sc, 0))
    pin = make_controller(ControllerSpec("p", "nmpc", {"inputs": "pin"}), context_for(sc, 0))
    assert "weights.force" not in tunables_of(motor) and "weights.ref" in tunables_of(motor)
    assert "weights.force" in tunables_of(pin) and "weights.d_ref" not in tunables_of(pin)
    assert actuator_class(sc.model, pin.actuated_inputs()) == "force"
    assert actuator_class(sc.model, make_controller(ControllerSpec("p", "pi", {}), context_for(sc, 0)).actuated_inputs()) == "none"
    assert set_option({"inputs": "motor"}, "weights.speed", 2.0) == {"inputs": "motor", "weights": {"speed": 2.0}}
    with pytest.raises(ConfigError, match=r"low < high"):
        Tunable(low=2.0, high=1.0)
    with pytest.raises(ConfigError, match=r"log-scale tunable needs low > 0"):
        Tunable(low=0.0, high=1.0)


@pytest.mark.slow
def test_tune_starts_from_the_shipped_options_persists_and_resumes(drill, tmp_path):
    out = tmp_path / "study"
    r = tune(drill, {"name": "SS", "kind": "softspeed", "kp_factor": 2.0}, budget=6, phases=2, seeds=1,
             held_out_seeds=1, out=out)
    assert (r.scenario, r.controller, r.kind, r.n_trials) == ("drill", "SS", "softspeed", 6)
    assert set(r.best_params) == {"kp_factor", "f_t"} and (out / "drill__ss.journal").exists()
    assert r.best_options["kp_factor"] == pytest.approx(r.best_params["kp_factor"])
    assert r.best_options["f_t"] == pytest.approx(r.best_params["f_t"] * r.tunables["f_t"]["unit"])
    # the held-out report: other seeds, at the benchmark's own 6 phases; the ranking's metrics and score
    assert set(r.held_out) == {"defaults", "tuned"} and r.held_out["tuned"]["n_runs"] == 6
    assert {"measured_severity", "measured_time_to_suppress", "score"} <= set(r.held_out["tuned"])
    # continued, not redone: the same budget runs nothing more; a larger one adds the difference
    again = tune(drill, {"name": "SS", "kind": "softspeed", "kp_factor": 2.0}, budget=6, phases=2, seeds=1,
                 held_out_seeds=0, out=out)
    assert again.n_trials == 6 and again.best_params == r.best_params
    more = tune(drill, {"name": "SS", "kind": "softspeed", "kp_factor": 2.0}, budget=8, phases=2, seeds=1,
                held_out_seeds=0, out=out)
    assert more.n_trials == 8 and more.best_value <= r.best_value
    # another starting point in the same study is refused, not mixed
    with pytest.raises(ConfigError, match="was made for other options"):
        tune(drill, {"name": "SS", "kind": "softspeed", "kp_factor": 3.0}, budget=8, out=out)


@pytest.mark.slow
def test_tune_shares_a_study_between_processes(drill, tmp_path):
    r = tune(drill, "doskil", budget=4, phases=1, seeds=1, held_out_seeds=0, out=tmp_path, n_jobs=2)
    assert r.n_trials == 4 and r.n_complete + r.n_pruned == 4


def test_tune_refuses_what_it_cannot_tune(drill):
    with pytest.raises(ConfigError, match=r"controller 'pi' \(pi\) declares no tunables"):
        tune(drill, "pi", budget=2)
    with pytest.raises(ConfigError, match=r"^budget must be an integer >= 1, got 0$"):
        tune(drill, "softspeed", budget=0)


@pytest.mark.slow
def test_the_tune_command(drill, tmp_path, capsys):
    from mitigate.cli import main
    code = main(["tune", str(drill), "--controller", "Z=ztorque,z=0.5", "--budget", "3", "--phases", "1",
                 "--held-out-seeds", "0", "--json", "--out", str(tmp_path)])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0 and doc["controller"] == "Z" and set(doc["best_params"]) == {"z", "tau_hp"}
    assert json.loads((tmp_path / "tune_drill__z.json").read_text())["n_trials"] == 3
    assert main(["tune", str(drill), "--controller", "softspeed", "--budget", "0"]) == 2
    assert "--budget must be an integer >= 1, got 0" in capsys.readouterr().err
    assert main(["tune", str(drill), "--controller", "lqr", "--budget", "2"]) == 2


@pytest.mark.slow
def test_the_tuned_benchmark_mode_tunes_every_controller_with_the_same_budget(drill, tmp_path):
    from mitigate.benchmark import load_suite, render_ranking, run_benchmark
    from mitigate.tune import tune_suite
    (tmp_path / "drill.toml").write_text(drill.read_text())
    (tmp_path / "suite.toml").write_text('[suite]\nname = "t"\nscenarios = ["drill.toml"]\n'
                                         '[[controllers]]\nname = "PI"\nkind = "pi"\n'
                                         '[[controllers]]\nname = "SS"\nkind = "softspeed"\n'
                                         '[[controllers]]\nname = "DK"\nkind = "doskil"\n')
    suite = load_suite(tmp_path / "suite.toml")
    tuned = tune_suite(suite, budget=3, out=tmp_path / "tuning", phases=1)
    assert set(tuned) == {("drill", "SS"), ("drill", "DK")}          # PI has nothing to tune
    doc = json.loads((tmp_path / "tuning" / "tuning.json").read_text())
    studies = doc["studies"]
    assert [s["n_trials"] for s in studies] == [3, 3] and all(s["budget"] == 3 for s in studies)
    # how it was tuned, stored with the results: the budget, TPE's start-up trials for it, phases the
    # benchmark never scores (halfway between its own), the score in the ranking's order
    how = doc["settings"]
    assert how["budget"] == 3 and "2 random start-up trials" in how["sampler"]
    assert how["phase_fractions"] == [(0 + 0.5) / 6] and "measured_severity" in how["score"]
    res = run_benchmark(suite, phases=1, seeds=1, jobs=1, tuned=tuned, tuning=how)
    assert res.mode == "tuned" and res.tuned == tuned and res.as_dict()["tuning"]["budget"] == 3
    assert {r.run.controller: r.run.options for r in res.records}["SS"] == tuned[("drill", "SS")]
    assert "## Tuned values" in render_ranking(res) and "f_t = " in render_ranking(res)


@pytest.mark.slow
def test_a_continued_study_proposes_what_an_uninterrupted_one_does(drill, tmp_path):
    """One process: the sampler is seeded by the trials finished so far, so 3 trials then 3 more give
    the very trials (values and parameters) of 6 in one go."""
    spec = {"name": "DK", "kind": "doskil"}
    kw = dict(phases=1, seeds=1, held_out_seeds=0)
    tune(drill, spec, budget=3, out=tmp_path / "a", **kw)
    a = tune(drill, spec, budget=6, out=tmp_path / "a", **kw)
    b = tune(drill, spec, budget=6, out=tmp_path / "b", **kw)
    assert a.n_trials == b.n_trials == 6
    assert a.best_params == b.best_params and a.best_value == b.best_value
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    def trials(folder):
        st = optuna.load_study(study_name="drill__dk",
                               storage=JournalStorage(JournalFileBackend(str(folder / "drill__dk.journal"))))
        return [(t.params, t.value, t.state.name) for t in st.trials]
    assert trials(tmp_path / "a") == trials(tmp_path / "b")


@pytest.mark.slow
def test_the_tuned_benchmark_mode_gives_the_same_values_with_two_processes(drill, tmp_path):
    """tune_suite runs each study in one process and several studies at a time: --jobs 2 tunes to the
    very values of --jobs 1 (the order of the trials never depends on timing)."""
    from mitigate.benchmark import load_suite
    from mitigate.tune import tune_suite
    (tmp_path / "drill.toml").write_text(drill.read_text())
    (tmp_path / "suite.toml").write_text('[suite]\nname = "t"\nscenarios = ["drill.toml"]\n'
                                         '[[controllers]]\nname = "SS"\nkind = "softspeed"\n'
                                         '[[controllers]]\nname = "DK"\nkind = "doskil"\n')
    suite = load_suite(tmp_path / "suite.toml")
    one = tune_suite(suite, budget=4, out=tmp_path / "one", phases=1, jobs=1)
    two = tune_suite(suite, budget=4, out=tmp_path / "two", phases=1, jobs=2)
    assert one == two and set(one) == {("drill", "SS"), ("drill", "DK")}
    s1 = json.loads((tmp_path / "one" / "tuning.json").read_text())["studies"]
    s2 = json.loads((tmp_path / "two" / "tuning.json").read_text())["studies"]
    assert [s["best_value"] for s in s1] == [s["best_value"] for s in s2]


def test_validation_phases_avoid_the_benchmarks_and_the_tunings():
    from mitigate.tune import tuning_phases, validation_phases
    for grid in (1, 3, 6):
        bench = {k / grid for k in range(grid)}
        for n in range(1, 2 * grid + 1):
            v = validation_phases(n, grid)
            assert len(set(v)) == n and all(0 < f < 1 for f in v)
            assert not set(v) & bench and not set(v) & set(tuning_phases(grid, grid))
    assert validation_phases(0, 3) == []
    with pytest.raises(ConfigError, match=r"^validate must be an integer from 0 to 6 \(twice the benchmark's 3 phases\), got 7$"):
        validation_phases(7, 3)


@pytest.mark.slow
def test_a_validated_choice_is_the_lowest_validation_score_among_the_best_trials_and_the_shipped(drill, tmp_path):
    from mitigate.tune import VALIDATION_CANDIDATES
    r = tune(drill, {"name": "SS", "kind": "softspeed", "kp_factor": 2.0}, budget=6, phases=1, seeds=1,
             held_out_seeds=0, out=tmp_path, validate=2, grid=3)
    v = r.validation
    assert v["phases"] == [1 / 12, 7 / 12]
    trials = [c["trial"] for c in v["candidates"]]
    assert 0 in trials and VALIDATION_CANDIDATES <= len(trials) <= VALIDATION_CANDIDATES + 1
    # the candidates are the best by tuning score (and the shipped options), the chosen the lowest on validation
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend
    study = optuna.load_study(study_name="drill__ss", storage=JournalStorage(JournalFileBackend(r.study)))
    values = sorted(t.value for t in study.trials if t.state.name == "COMPLETE")
    assert [c["tuning"] for c in v["candidates"][:VALIDATION_CANDIDATES]] == values[:VALIDATION_CANDIDATES]
    chosen = next(c for c in v["candidates"] if c["trial"] == v["chosen"])
    assert chosen["validation"] == min(c["validation"] for c in v["candidates"])
    assert r.best_params == chosen["params"] and r.best_value == chosen["tuning"]
    # reproducible: the same study validated again chooses the same, with the same scores
    again = tune(drill, {"name": "SS", "kind": "softspeed", "kp_factor": 2.0}, budget=6, phases=1, seeds=1,
                 held_out_seeds=0, out=tmp_path, validate=2, grid=3)
    assert again.validation == v
    # without validation the same study picks its best tuning score
    plain = tune(drill, {"name": "SS", "kind": "softspeed", "kp_factor": 2.0}, budget=6, phases=1, seeds=1,
                 held_out_seeds=0, out=tmp_path, grid=3)
    assert plain.validation == {} and plain.best_value == min(c["tuning"] for c in v["candidates"])


def test_validate_goes_with_tuned(capsys):
    from mitigate.cli import main
    assert main(["benchmark", "scenarios/benchmark/suite.toml", "--validate", "2", "--quick"]) == 2
    assert "--validate chooses tuned values: give it with --tuned" in capsys.readouterr().err
    assert main(["tune", "scenarios/benchmark/established.toml", "--controller", "softspeed", "--budget", "2",
                 "--grid", "3", "--validate", "9"]) == 2
    assert ("--validate must be an integer from 0 to 6 (twice the benchmark's 3 phases), got 9"
            in capsys.readouterr().err)
