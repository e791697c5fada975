"""Beyond ``models.discretise.FOLD_ABOVE`` substeps a step's Jacobians are a loop over ONE substep with the
chain rule carried along (CasADi ``fold``): the NMPC's stage and forward step, the EKF's prediction.
They must give the numbers of the unrolled expression (up to rounding): checked here against the
unrolled build of the same functions at random points."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mitigate.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def _rel(a, b) -> float:
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300))


def test_the_nmpc_stage_folded_over_22_substeps_equals_the_unrolled_one(monkeypatch):
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.controllers.nmpc import stage
    sc = load_scenario(ROOT / "scenarios" / "stick_slip_30rpm.toml")
    i, spec = next((i, s) for i, s in enumerate(sc.controllers) if s.name == "NMPC")
    c = make_controller(spec, context_for(sc, i))
    assert c.spec.nsub == 22 and c.spec.method == "rk4"
    F, _, S, _ = stage.stage_functions(c.model, c.spec)
    assert S.is_a("MXFunction") and F.is_a("MXFunction")          # the loops
    monkeypatch.setattr(stage, "FOLD_ABOVE", 1000)
    F0, _, S0, _ = stage.stage_functions(c.model, c.spec)
    assert S0.is_a("SXFunction") and S0.n_instructions() > 50 * S.n_nodes()
    rng = np.random.default_rng(3)
    for _ in range(10):
        xa = 3.0 + 0.5 * rng.normal(size=c.layout.nxa)
        v = 0.1 * rng.normal(size=c.layout.nv)
        for a, b in zip(S0(xa, v, c._q), S(xa, v, c._q)):            # xn, A, B and the Gauss-Newton blocks
            assert _rel(a, b) <= 1e-12
        assert _rel(F0(xa, v, c._q), F(xa, v, c._q)) <= 1e-14


def test_the_ekf_prediction_folded_over_7_substeps_equals_the_unrolled_one():
    from estimators.online.ekf import ekf_step_function
    from mitigate.export import _estimator
    est = _estimator(load_scenario(ROOT / "scenarios" / "sweep_leadscrew.toml"))
    em = est.em
    assert em.integration.nsub == 7 and em.FA is not None
    folded, unrolled = ekf_step_function(em), ekf_step_function(dataclasses.replace(em, FA=None))
    rng = np.random.default_rng(5)
    for _ in range(10):
        args = [em.x0 + 0.3 * rng.normal(size=em.nx), np.diag(rng.uniform(0.1, 1.0, em.nx)).ravel(),
                3.0 + rng.normal(size=em.nuh), rng.normal(size=len(em.channels)), np.ones(len(em.channels)), em.p,
                em.q, em.r]
        for a, b in zip(unrolled(*args), folded(*args)):
            assert _rel(a, b) <= 1e-12
    xa, A = em.FA(args[0], args[2], em.p)
    assert _rel(em.F(args[0], args[2], em.p), xa) <= 1e-14
