"""Parameter sweeps (mitigate.sweep): grid syntax, name resolution, batched plant vs the simulator,
physics of the maps (seed 002 Sect. 9.8, modal stability), CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mitigate import metrics as mx
from mitigate.scenario import load_scenario
from mitigate.sweep import (Axis, SweepStore, make_tasks, options_from_scenario, parse_axis, plan_sweep, run_chunk,
                            run_sweep, sweep)
from models import get_model
from models.errors import ConfigError
from models.plant import SimOptions, simulate
from models.status import Status

ROOT = Path(__file__).resolve().parents[1]
RIG3 = ROOT / "scenarios" / "sweep_rig3.toml"
LEAD = ROOT / "scenarios" / "sweep_leadscrew.toml"


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("STICKSLIP_CACHE", str(tmp_path_factory.getbasetemp() / "cc_cache"))


def _col(records, name: str) -> np.ndarray:
    """One metric of a chunk's point records, as an array in point order."""
    return np.array([r.metrics[name] for r in records])


def test_parse_axis():
    a = parse_axis("n1=5:40:8")
    assert a == Axis("n1", 5.0, 40.0, 8)
    assert np.allclose(a.values, np.linspace(5, 40, 8))
    assert parse_axis("c=2e-4:2e-4:1").values.tolist() == [2e-4]
    for bad, msg in [("n1", "name=start:stop:count"), ("n1=5:40", "name=start:stop:count"),
                     ("n1=a:40:3", "start and stop must be numbers"), ("n1=5:40:x", "count must be an integer"),
                     ("n1=5:40:1", "count must be >= 2"), ("n1=5:inf:3", "finite")]:
        with pytest.raises(ConfigError, match=msg):
            parse_axis(bad)


def test_plan_resolves_inputs_params_scales_and_mismatch():
    sc = load_scenario(LEAD)
    o = options_from_scenario(sc, duration=0.01, settle=0.0, start="rest")
    plan = plan_sweep(sc, [parse_axis("axial_force=100:300:3"), parse_axis("K_scale=0.5:2:2"),
                           parse_axis("c=1e-4:1e-4:1")], o)
    names = sc.plant_params.names()
    assert plan.n_points == 6
    assert plan.u_cols == (1,)
    assert np.allclose(plan.u_vals[:, 0], [100, 100, 200, 200, 300, 300])
    K = plan.P[:, names.index("K")]
    assert np.allclose(K, sc.plant_params.K * np.array([0.5, 2, 0.5, 2, 0.5, 2]))
    assert np.allclose(plan.P[:, names.index("c")], 1e-4)
    plan2 = plan_sweep(sc, [parse_axis("mismatch.K=2:2:1")], o)
    assert plan2.P[0, names.index("K")] == pytest.approx(2 * sc.model_params.K)
    # the programmed (non-swept) input is kept: omega_drive 40 rad/s
    assert np.all(plan.U[:, 0] == 40.0)
    with pytest.raises(ConfigError, match="unknown name"):
        plan_sweep(sc, [parse_axis("n1=1:2:2")], o)
    with pytest.raises(ConfigError, match="at most once"):
        plan_sweep(sc, [parse_axis("c=1:2:2"), parse_axis("c=1:2:2")], o)
    with pytest.raises(ConfigError, match=">= 0 N"):
        plan_sweep(sc, [parse_axis("axial_force=-5:10:2")], o)
    with pytest.raises(ConfigError, match="settle"):
        options_from_scenario(sc, duration=0.1, settle=0.2)


@pytest.mark.slow
def test_batched_chunk_equals_the_simulator_per_point():
    """Cross-method: the mapped/accumulated step gives the same trajectories as models.plant."""
    sc = load_scenario(RIG3)
    o = options_from_scenario(sc, duration=4.0, settle=2.0, start="rest", chunk=4, block=70, backend="vm")
    plan = plan_sweep(sc, [parse_axis("omega_ref=1.5:6:2"), parse_axis("n1=10:35:2")], o)
    task = [t for t in make_tasks(plan) if t.kind == "simulate"][0]
    res = run_chunk(task)
    m = get_model("rig3")
    for j in range(plan.n_points):
        r = simulate(m, plan.point_params(j), plan.point_input(j), o.duration,
                     SimOptions(dt=o.dt, nsub=o.nsub), sensors=None)
        w = r.x[o.settle_steps + 1:, m.states.index("omega_R1")]
        assert res[j].run.index == j and res[j].status is Status.OK
        assert res[j].metrics["amplitude"] == pytest.approx(mx.amplitude(w), rel=1e-9, abs=1e-12)
        assert res[j].metrics["severity"] == pytest.approx(mx.severity(w), rel=1e-9, abs=1e-12)
        assert res[j].metrics["stuck_fraction"] == pytest.approx(mx.stuck_fraction(w, o.stuck_threshold))


@pytest.mark.slow
def test_compiled_backend_equals_vm():
    sc = load_scenario(LEAD)
    base = dict(duration=0.04, settle=0.02, start="rest", chunk=3, block=64)
    outs = []
    for backend in ("vm", "compiled"):
        o = options_from_scenario(sc, backend=backend, **base)
        plan = plan_sweep(sc, [parse_axis("axial_force=50:350:3")], o)
        outs.append(run_chunk([t for t in make_tasks(plan) if t.kind == "simulate"][0]))
    for k in ("amplitude", "severity", "stuck_fraction"):
        assert np.allclose(_col(outs[0], k), _col(outs[1], k), rtol=1e-9, atol=1e-12), k


def test_leadscrew_threshold_and_speed_trend(tmp_path):
    """Seed 002 Sect. 9.8.1: beyond a force threshold the screw vibrates, and more with speed;
    Fig. 9.32: more support damping moves the threshold to higher force."""
    sc = load_scenario(LEAD)
    o = options_from_scenario(sc, duration=0.2, settle=0.1, start="rest", backend="vm", chunk=12)
    plan = plan_sweep(sc, [parse_axis("omega_drive=30:80:2"), parse_axis("axial_force=60:340:3"),
                           parse_axis("c=2e-4:1e-3:2")], o)
    res = run_sweep(plan, SweepStore(tmp_path / "s", plan.definition()), workers=1, progress=False,
                    stability=False)
    A = res.maps["rest"]["amplitude"]          # (speed, force, c)
    lc = res.maps["rest"]["limit_cycle"]
    assert np.all(lc[:, 0, :] == 0)                          # 60 N: no sustained vibration
    assert A[0, 2, 0] > 0.01 and A[1, 2, 0] > A[0, 2, 0]    # 340 N: vibration, larger at higher speed
    assert np.all(lc[:, 2, 0] == 1)
    # the unstable set shrinks with more damping (monotone in c at every point)
    assert np.all(lc[:, :, 1] <= lc[:, :, 0]) and lc[:, :, 1].sum() < lc[:, :, 0].sum()
    f = res.maps["rest"]["frequency"][1, 2, 0]
    assert 80 < f < 200  # seed 002 Sect. 9.2: ~150 Hz


def test_rig3_sliding_start_agrees_with_linear_stability(tmp_path):
    """From (kicked) steady sliding, a linearly unstable point develops stick-slip, a stable one does not."""
    from models.stability import sliding_stability
    sc = load_scenario(RIG3)
    o = options_from_scenario(sc, duration=20.0, settle=10.0, start="sliding", backend="vm", chunk=2)
    plan = plan_sweep(sc, [parse_axis("omega_ref=1:6:2"), parse_axis("n1=35:35:1")], o)
    m = get_model("rig3")
    stable = [sliding_stability(m, plan.point_params(j), plan.point_input(j))[0] for j in range(2)]
    assert stable == [False, True]
    res = run_chunk([t for t in make_tasks(plan) if t.kind == "simulate"][0])
    assert _col(res, "limit_cycle").tolist() == [1.0, 0.0]
    assert res[0].metrics["stuck_fraction"] > 0.05 and res[1].metrics["stuck_fraction"] == 0.0


@pytest.mark.slow
def test_cli_maps_json_and_refusal(main, tmp_path, capsys):
    out = tmp_path / "sw"
    argv = ["sweep", str(RIG3), "--vary", "omega_ref=1:6:3", "--vary", "n1=10:35:3", "--duration", "2",
            "--workers", "1", "--backend", "vm", "--out", str(out), "--json", "--chunk", "5", "--no-stability"]
    assert main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["points"] == 9 and doc["chunks_computed"] >= 4 and doc["chunks_reused"] == 0
    for name in ("results.csv", "manifest.json", "map_amplitude_rest.png", "map_amplitude_sliding.png",
                 "map_bistability.png", "map_severity_rest.png", "map_frequency_sliding.png"):
        assert (out / name).is_file(), name
    # same command again: everything reused
    assert main(argv) == 0
    doc2 = json.loads(capsys.readouterr().out)
    assert doc2["chunks_computed"] == 0 and doc2["chunks_reused"] == doc["chunks_computed"]
    # a different grid into the same folder is refused (exit 2), --force accepts it
    argv3 = [a if a != "n1=10:35:3" else "n1=10:35:2" for a in argv] + ["--start", "rest"]
    assert main(argv3) == 2
    assert "different sweep" in capsys.readouterr().err
    assert main(argv3 + ["--force"]) == 0
    capsys.readouterr()
    assert main(["sweep", str(RIG3), "--vary", "bogus=1:2:2", "--out", str(tmp_path / "x")]) == 2
    assert "unknown name" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert main(["sweep", str(RIG3), "--vary", "n1=1:2", "--out", str(tmp_path / "x")]) == 2
    assert main(["sweep", str(RIG3), "--controller", "nope", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_closed_loop_pi_only_equals_open_loop():
    """Cross-check: the closed loop with the 'PI only' controller (programmed set-point, N2 = 0) gives
    the same map as the open-loop batched plant; the brake changes it (how well it mitigates is
    ``mitigate run``'s subject, not this test's)."""
    sc = load_scenario(RIG3)
    o = options_from_scenario(sc, duration=14.0, settle=10.0, start="rest", backend="vm", chunk=2)
    plan = plan_sweep(sc, [parse_axis("omega_ref=2.5:2.5:1"), parse_axis("n1=20:35:2")], o)
    open_ = run_chunk([t for t in make_tasks(plan) if t.kind == "simulate"][0])
    pi = run_chunk([t for t in make_tasks(plan, "PI only") if t.kind == "simulate"][0])
    brake = run_chunk([t for t in make_tasks(plan, "R2 brake") if t.kind == "simulate"][0])
    for k in ("amplitude", "severity", "stuck_fraction"):
        assert np.allclose(_col(pi, k), _col(open_, k), rtol=1e-9, atol=1e-12), k
    assert np.all(_col(open_, "limit_cycle") == 1)
    assert [r.run.controller for r in (open_[0], pi[0], brake[0])] == ["", "PI only", "R2 brake"]
    assert not np.allclose(_col(brake, "amplitude"), _col(open_, "amplitude"), rtol=1e-3)   # the brake acts from 10 s
    with pytest.raises(ConfigError, match="controllers"):
        make_tasks(plan, "nope")


@pytest.mark.slow
def test_python_entry_point_resumes_and_sweeps_a_structured_plant(tmp_path):
    """``mitigate.sweep.sweep`` from Python: maps, files, resuming; on a scenario whose plant differs
    in structure (shaft elements) the plant's own states are simulated."""
    from mitigate.scenario import make_scenario
    kw = dict(duration=2.0, settle=1.0, start="rest", workers=1, backend="vm", stability=False, chunk=2)
    res = sweep(RIG3, ["omega_ref=2:4:2", "n1=10:30:2"], out=tmp_path / "a", **kw)
    assert res.success and res.computed == 2 and res.reused == 0
    assert res.maps["rest"]["amplitude"].shape == (2, 2)
    assert {"results", "map_amplitude_rest"} <= set(res.files) and res.files["results"].is_file()
    again = sweep(RIG3, ["omega_ref=2:4:2", "n1=10:30:2"], out=tmp_path / "a", **kw)
    assert (again.computed, again.reused) == (0, 2)
    np.testing.assert_array_equal(again.maps["rest"]["amplitude"], res.maps["rest"]["amplitude"])
    sc = make_scenario(name="elements", duration=2.0, inputs={"omega_ref": 3.0, "n1": 20.0}, estimator="fd",
                       structure={"shaft_elements": {"count": 2, "inertia": 1e-3}})
    r2 = sweep(sc, ["n1=10:30:2"], out=tmp_path / "b", maps=False, **kw)
    assert r2.success and r2.statuses["rest"].tolist() == [Status.OK, Status.OK]
    # the elements' inertia and modes change the response: not the nominal plant's numbers
    nominal = sweep(sc.replace(plant_model=sc.model, plant_params=sc.model_params, structure={}), ["n1=10:30:2"],
                    out=tmp_path / "c", maps=False, **kw)
    assert not np.allclose(r2.maps["rest"]["amplitude"], nominal.maps["rest"]["amplitude"], rtol=1e-6)
    with pytest.raises(ConfigError, match="axes must be"):
        sweep(RIG3, [3], out=tmp_path / "d", **kw)


@pytest.mark.parametrize("text", ["{not json", "[1, 2]"])
def test_an_unreadable_manifest_is_one_data_error_for_the_sweep_and_the_benchmark(tmp_path, text):
    from mitigate.benchmark.execute import RunStore
    from models.errors import DataError
    for cls, what, force in ((SweepStore, "sweep", "--force"), (RunStore, "benchmark", "force")):
        root = tmp_path / what
        root.mkdir()
        (root / "manifest.json").write_text(text)
        with pytest.raises(DataError, match=rf"manifest\.json: unreadable {what} manifest \(.*\); use {force} to "
                                            r"start over$"):
            cls(root, {"a": 1})


def test_unit_carrying_defaults_come_from_the_rig(tmp_path):
    """threshold, stuck_threshold and perturbation: rig3's values on rig3 (30 rpm), carried by the
    nominal speed to a field string (5 rad/s, 1.6x) and by the steady twist for a twist's amplitude;
    a value the scenario gives wins."""
    from mitigate.scenario import make_scenario
    from estimators.online.options import REFERENCE, rig_scales
    rig3 = options_from_scenario(load_scenario(ROOT / "scenarios" / "stick_slip_30rpm.toml"))
    assert (rig3.threshold, rig3.stuck_threshold, rig3.perturbation) == pytest.approx((0.05, 1e-6, 0.01))
    field = ROOT / "tests" / "rigs" / "field_drillstring.toml"
    m = get_model(str(field))
    w0 = abs(m.nominal_speed())
    assert w0 > 1.5 * 3.1416                          # not rig3's scale
    sc = make_scenario(name="f", model=str(field), duration=10.0, controllers=[])
    o = options_from_scenario(sc)
    ratio = w0 / REFERENCE.speed
    assert (o.threshold, o.stuck_threshold, o.perturbation) == pytest.approx((0.05 * ratio, 1e-6 * ratio, 0.01 * ratio))
    twist = next(s for s in m.states if s.startswith("twist_"))
    o = options_from_scenario(sc, amplitude_of=twist)
    assert o.threshold == pytest.approx(0.05 * rig_scales(m, m.published()).twist / REFERENCE.twist)
    assert options_from_scenario(sc, threshold=0.2).threshold == 0.2
