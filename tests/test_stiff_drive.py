"""Stiff drives, one rule (issue 18 item 2): a user's two-disc rig with a small DC gear motor.

The rig is written here as a user would (L = 1 mH, R = 2 ohm: L/R = 0.5 ms; a brake pin on a
freely named input).  Before the integration rule (models.discretise.integration) the EKF's
model diverged at its operating point and the NMPC fell back; now every consumer integrates
through the rule: the EKF and the NMPC run in closed loop with zero fallbacks, and over
L/R = 0.05, 0.5 and 5 ms the rule's discretisation agrees with CVODES at 1e-10.
"""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from models import get_model
from models.discretise import integration
from models.plant import SimOptions, hybrid_step_function, plant_integration

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_stiff_drive.py"


SMALL_MOTOR = Path(__file__).resolve().parent / "data" / "small_motor.toml"


def _rig_text(L_henry: float) -> str:
    """The user's rig (tests/data/small_motor.toml) with the armature inductance ``L_henry`` [H]."""
    text = SMALL_MOTOR.read_text()
    assert 'L = { value = 1.0, unit = "mH" }' in text
    return text.replace('L = { value = 1.0, unit = "mH" }', f'L = {{ value = {L_henry!r}, unit = "H" }}')


def _rig(tmp_path, lr_ms: float):
    path = tmp_path / f"tworig_{str(lr_ms).replace('.', 'p')}.toml"
    path.write_text(_rig_text(lr_ms * 1e-3 * 2.0))
    return get_model(path)


def _programme(t):
    return np.array([3.0 if t < 0.5 else 6.0, 10.0 if t < 0.8 else 25.0])


def test_user_rig_small_motor_runs_ekf_and_nmpc_with_zero_fallbacks(tmp_path):
    from estimators.base import EstimatorContext
    from estimators.online.factory import make_estimator
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.scenario import make_scenario

    m = _rig(tmp_path, 0.5)
    sc = make_scenario(name="small_motor", model=m, duration=3.0, inputs={"omega_ref": "30 rpm", "brake_force": 15},
                       controllers=[{"name": "NMPC", "kind": "nmpc"}], control_start=1.0)
    ekf = make_estimator(sc.estimator, EstimatorContext(m, sc.model_params, sc.dt, sc.sensors, None, "estimator"))
    # the estimator states how it integrates the stiff motor
    assert "current treated quasi-statically: L/R = 0.5 ms" in ekf.em.integration.note
    ctrl = make_controller(sc.controllers[0], context_for(sc, 0))
    assert ctrl.integration.quasi_static and "quasi-statically" in ctrl.integration.note
    res = run_closed_loop(sc, ctrl, estimator=ekf)
    assert res.status.success, res.message
    assert res.controller_counts["steps"] > 0
    assert res.controller_counts["fallbacks"] == 0 and res.controller_counts["failures"] == 0
    assert res.estimator_counts["fallbacks"] == 0 and res.estimator_counts["failures"] == 0
    # the estimate follows the true speeds (the EKF is not a diverged model held in check)
    i = res.xhat_names.index("omega_B")
    late = res.t > 2.0
    err = np.abs(res.xhat[late, i] - res.x[late, m.speed_index("B")])
    assert np.max(err) < 0.1 * np.max(np.abs(res.x[late, m.speed_index("B")]))


@pytest.mark.parametrize("lr_ms", [0.05, 0.5, 5.0])
@pytest.mark.parametrize("dt", [0.01, 0.05])
def test_rule_agrees_with_cvodes_over_lr(tmp_path, lr_ms, dt):
    """The rule's step (what the EKF, MHE and NMPC use) against CVODES at 1e-10 on the full model."""
    m = _rig(tmp_path, lr_ms)
    P = m.published()
    p = np.asarray(P.vector(), float)
    integ = integration(m, P, dt, u=np.array([6.0, 25.0]), eps=0.05)
    # L/R far below the substep: quasi-static; 5 ms: the current stays a state at a 10 ms step
    assert integ.quasi_static == (lr_ms * 1e-3 <= integ.h / 4)
    if lr_ms == 0.05:
        assert integ.quasi_static
    f = m.ode(0.05)
    x, u, ps = ca.SX.sym("x", m.nx), ca.SX.sym("u", m.nu), ca.SX.sym("p", m.n_p)
    F = ca.Function("F", [x, u, ps], [integ.advance(lambda a, b, c: f(a, b, c), x, u, ps,
                                                    lambda a, b, c: m.quasi_static_current(a, b, m.unpack(c)))])
    ref = ca.integrator("ref", "cvodes", {"x": x, "p": ca.vertcat(u, ps), "ode": f(x, u, ps)}, 0.0, dt,
                        {"abstol": 1e-10, "reltol": 1e-10})
    xa, xr = np.zeros(m.nx), np.zeros(m.nx)
    spd = [m.speed_index(b) for b in m.bodies]
    err, top = 0.0, 0.0
    for k in range(int(round(1.2 / dt))):
        uk = _programme(k * dt)
        xa = np.array(F(xa, uk, p)).ravel()
        xr = np.array(ref(x0=xr, p=np.concatenate([uk, p]))["xf"]).ravel()
        err = max(err, float(np.max(np.abs(xa[spd] - xr[spd]))))
        top = max(top, float(np.max(np.abs(xr[spd]))))
    assert err < 5e-3 * top, f"speed error {err:.3g} of {top:.3g} rad/s ({integ.note})"


def test_explicit_rk4_at_the_old_estimator_substeps_diverges_on_a_fast_motor(tmp_path):
    """Why the rule exists: 4 RK4 substeps per 10 ms (the EKF's old fixed choice) blow up at L/R = 0.05 ms."""
    m = _rig(tmp_path, 0.05)
    from models.discretise import rk4_function
    F = rk4_function(m, 0.01, 4)
    xk = np.zeros(m.nx)
    with np.errstate(all="ignore"):
        for k in range(50):
            xk = np.array(F(xk, _programme(0.0), m.published().vector())).ravel()
    assert not np.all(np.isfinite(xk)) or np.max(np.abs(xk)) > 1e6


def test_exact_plant_treats_a_fast_current_quasi_statically_and_matches_fine_substeps(tmp_path):
    m = _rig(tmp_path, 0.05)
    P = m.published()
    integ = plant_integration(m, P, SimOptions(dt=0.01, nsub=10), _programme(0.0))
    assert integ.quasi_static and integ.nsub == 10
    p = np.asarray(P.vector(), float)
    runs = []
    for F in (hybrid_step_function(m, 0.01, integ.nsub, quasi_static=True), hybrid_step_function(m, 0.01, 200)):
        xk, th = np.zeros(m.nx), 0.0
        out = []
        for k in range(150):
            xn, thn = F(xk, th, _programme(k * 0.01), p)
            xk, th = np.array(xn).ravel(), float(thn)
            out.append(xk)
        runs.append(np.array(out))
    spd = [m.speed_index(b) for b in m.bodies]
    assert np.all(np.isfinite(runs[0]))
    assert np.max(np.abs(runs[0][:, spd] - runs[1][:, spd])) < 0.01 * np.max(np.abs(runs[1][:, spd]))


def test_scenario_states_how_its_plant_integrates_a_fast_motor(tmp_path):
    from mitigate.scenario import make_scenario

    m = _rig(tmp_path, 0.05)
    sc = make_scenario(name="fast", model=m, duration=1.0, controllers=["pi"])
    assert any("plant: current treated quasi-statically: L/R = 0.05 ms" in msg for msg in sc.messages), sc.messages


def test_rig3_integrates_as_before():
    """rig3 (L/R = 2.6 ms): no quasi-static current; the plant keeps its 10 substeps, the EKF its 4."""
    m = get_model("rig3")
    P = m.published()
    assert not plant_integration(m, P, SimOptions()).quasi_static
    assert plant_integration(m, P, SimOptions()).nsub == 10
    ekf = integration(m, P, 0.01, eps=0.05, min_nsub=4)
    assert ekf.nsub == 4 and not ekf.quasi_static


def test_benchmark_script_has_help_and_quick_mode():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, str(BENCH), "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "--quick" in out.stdout


def test_mhe_on_a_0_05_ms_motor_tracks_without_failures(tmp_path):
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.scenario import make_scenario

    m = _rig(tmp_path, 0.05)
    sc = make_scenario(name="mhe_fast", model=m, duration=3.0, inputs={"omega_ref": "30 rpm", "brake_force": 15},
                       controllers=["pi"], estimator="mhe")
    r = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    assert r.status.success and r.estimator_counts["failures"] == 0 and r.estimator_counts["fallbacks"] == 0
    i, j = r.xhat_names.index("omega_B"), m.speed_index("B")
    late = r.t > 1.5
    assert np.max(np.abs(r.xhat[late, i] - r.x[late, j])) < 0.05 * np.max(np.abs(r.x[:, j]))


@pytest.mark.slow
def test_identification_on_a_0_05_ms_motor_recovers_the_friction(tmp_path):
    import warnings

    from estimators.identify import IdentifiabilityWarning, IdentifyOptions, identify
    from models.plant import simulate

    m = _rig(tmp_path, 0.05)
    true = m.published().replace(mu_k=0.27)
    r = simulate(m, true, np.array([2.0, 15.0]), 6.0, SimOptions(seed=2))
    assert r.success and np.mean(r.state("omega_B") == 0.0) > 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        fit = identify(r.to_log(), m, m.published(), IdentifyOptions(free=("mu_k",), encoder_zero="untwisted"))
    assert fit.problem.integration.quasi_static and "quasi-statically" in fit.problem.integration.note
    assert fit.success and fit.estimate[0] == pytest.approx(0.27, rel=0.02), fit.message
