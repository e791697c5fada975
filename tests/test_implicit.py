"""The implicit step of the integration rule (models.sdirk, models.discretise): accuracy and order
against scipy's Radau at tight tolerances, the exact Coulomb stick-slip cycle at a regularisation
explicit RK4 could not afford, Newton's convergence along stick-slip, and Jacobians that agree
with finite differences (what Gauss-Newton uses).

The references: scipy's Radau IIA (order 5, adaptive, rtol 1e-11) on the same regularised ODE,
and the analytic Coulomb cycle of one disc on an undamped spring (tests/test_coulomb_cycle.py).
"""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from models import get_model
from models.discretise import Integration, integration
from models.sdirk import GAMMA

N, OMEGA = 20.0, math.pi


def _stepper(model, integ, eps, residual=False):
    f = model.ode(eps)
    x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
    out = integ.advance(lambda a, b, c: f(a, b, c), x, u, p, residual=residual)
    outs = list(out) if isinstance(out, tuple) else [out]
    return ca.Function("F", [x, u, p], outs)


def _run(model, params, integ, eps, u, duration, residual=False):
    F = _stepper(model, integ, eps, residual)
    pv, x = params.vector(), np.zeros(model.nx)
    X, R = [x], []
    for _ in range(int(round(duration / integ.dt))):
        out = F(x, u, pv)
        x = np.array(out[0] if residual else out).ravel()
        X.append(x)
        if residual:
            R.append(float(out[1]))
    return (np.array(X), np.array(R)) if residual else np.array(X)


def _radau(model, params, eps, u, t):
    f = model.ode(eps)
    x = ca.SX.sym("x", model.nx)
    fx = ca.Function("fx", [x], [f(x, u, params.vector())])
    jx = ca.Function("jx", [x], [ca.jacobian(fx(x), x)])
    sol = solve_ivp(lambda _, y: np.array(fx(y)).ravel(), (0.0, t[-1]), np.zeros(model.nx), method="Radau",
                    t_eval=t, rtol=1e-11, atol=1e-13, jac=lambda _, y: np.array(jx(y)))
    assert sol.success
    return sol.y.T


@pytest.fixture(scope="module")
def disc():
    m = get_model("disc")
    return m, m.published().replace(d=0.0, v_s=1e-3)


def test_rule_takes_the_implicit_step_where_rk4_is_hopeless(disc):
    m, p = disc
    u = np.array([OMEGA, N])
    stiff = integration(m, m.published(), 0.01, u=u, eps=1e-5)
    assert stiff.implicit and stiff.nsub == 1 and stiff.stiff == (m.contacts[0],)
    assert "implicit SDIRK2" in stiff.note and "explicit RK4 would need" in stiff.note
    # a Stribeck fall over 1e-3 rad/s (5.7e3 1/s) is resolved: gamma h lambda+ <= 0.5
    steep = integration(m, p, 0.01, u=u, eps=1e-5)
    assert steep.implicit and GAMMA * steep.h * 5.7e3 <= 0.5 < GAMMA * 0.01 / (steep.nsub - 1) * 5.7e3
    # rig3 at the regularisations its consumers have always used keeps RK4 (results unchanged)
    r3 = get_model("rig3")
    for eps, floor in ((0.005, 1), (0.05, 4)):
        assert integration(r3, r3.published(), 0.01, eps=eps, min_nsub=floor).method == "rk4"
    # asked for RK4 substeps: RK4, and never refused for the implicit step's sake
    assert integration(m, p, 0.01, u=u, eps=1e-5, nsub=3).method == "rk4"


def test_order_two_against_radau(disc):
    """A smooth stiff problem (eps = 1e-3 rad/s: rate 1.6e4 1/s at rest, explicit RK4 needs 66 substeps
    per 10 ms): start from rest through the first stick and slip; the error against Radau falls as
    h^2 (measured orders 2.0-2.1)."""
    m, p = disc
    u, eps, T = np.array([OMEGA, N]), 1e-3, 1.0
    ref = _radau(m, p, eps, u, np.arange(0, T + 1e-9, 0.01))
    errs = []
    for nsub in (2, 4, 8, 16):
        X = _run(m, p, Integration(0.01, nsub, method="sdirk2", stiff=(1,), band=eps), eps, u, T)
        errs.append(np.max(np.abs(X[:, 1] - ref[:, 1])) / np.max(np.abs(ref[:, 1])))
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders > 1.7) and np.all(orders < 2.5), (errs, orders)
    assert errs[-1] < 1e-3


def test_exact_coulomb_cycle_at_a_tiny_regularisation(disc):
    """eps = 1e-6 rad/s (explicit RK4: 65,000 substeps per 10 ms) under a Stribeck fall over 1e-3
    rad/s (instant against the slip's 6 rad/s, wide against the band, so the regularised law keeps its
    static peak): the rule's implicit step reproduces the exact Coulomb cycle's period and peak speed
    within 1 % and creeps at most ~eps in stick."""
    m, p = disc
    u, eps = np.array([OMEGA, N]), 1e-6
    integ = integration(m, p, 0.01, u=u, eps=eps)
    assert integ.implicit and integ.nsub < 100
    X, R = _run(m, p, integ, eps, u, 12.0, residual=True)
    t = np.arange(X.shape[0]) * 0.01
    w = X[:, 1]
    delta = N * p["r"] * (p["mu_s"] - p["mu_k"])
    wn = math.sqrt(p["k"] / p["J"])
    period = 2 * delta / (p["k"] * OMEGA) + (2 * math.pi - 2 * math.atan(wn * delta / (p["k"] * OMEGA))) / wn
    wmax = OMEGA + math.sqrt(OMEGA ** 2 + (wn * delta / p["k"]) ** 2)
    slip = np.abs(w) > 0.1
    onsets = t[1:][slip[1:] & ~slip[:-1]]
    assert len(onsets) >= 6
    assert np.mean(np.diff(onsets)[1:]) == pytest.approx(period, rel=0.01)
    assert w[t > 2].max() == pytest.approx(wmax, rel=0.01)
    stuck = (np.abs(w) < 1e-3) & (t > 2)         # a thousandth of the slip's speed
    assert stuck.mean() > 0.05                   # stuck 9 % of the time
    assert np.percentile(np.abs(w[stuck]), 90) < 5 * eps     # the creep is the band's, not a slide
    # every stage's Newton iteration converged: to round-off but for a breakaway or two, still within
    # 1 % of the band there (measured: largest 1.8e-9 rad/s, median 1e-17)
    assert np.max(R) < 0.01 * eps and np.median(R) < 1e-14


def test_jacobian_agrees_with_finite_differences(disc):
    """The step's derivatives (through the unrolled Newton iterations) with respect to the state and
    the parameters equal central differences: Gauss-Newton gets the step's true Jacobian."""
    m, p = disc
    eps = 1e-4
    integ = integration(m, p, 0.01, u=np.array([OMEGA, N]), eps=eps)
    assert integ.implicit
    f = m.ode(eps)
    x, u, q = ca.SX.sym("x", m.nx), ca.SX.sym("u", m.nu), ca.SX.sym("p", m.n_p)
    xn = integ.advance(lambda a, b, c: f(a, b, c), x, u, q)
    F = ca.Function("F", [x, u, q], [xn, ca.jacobian(xn, ca.vertcat(x, q))])
    pv, uv = p.vector(), np.array([OMEGA, N])
    for x0 in (np.array([0.2, 0.5]), np.array([-0.1, 2.0]), np.array([0.05, 3 * eps])):
        _, Jc = F(x0, uv, pv)
        Jc = np.array(Jc)
        z0 = np.concatenate([x0, pv])
        for j in range(z0.size):
            hj = 1e-7 * max(abs(z0[j]), 1e-3)
            zp, zm = z0.copy(), z0.copy()
            zp[j] += hj
            zm[j] -= hj
            fd = (np.array(F(zp[:2], uv, zp[2:])[0]) - np.array(F(zm[:2], uv, zm[2:])[0])).ravel() / (2 * hj)
            np.testing.assert_allclose(Jc[:, j], fd, rtol=1e-4, atol=1e-6 * max(1.0, np.max(np.abs(fd))))


def test_implicit_function_theorem_jacobians_equal_the_differentiated_step(disc):
    """``Integration.advance_jacobian`` (what the NMPC's stages use): the implicit step's Jacobians
    with respect to the state, the inputs and the parameters by the implicit function theorem at the
    converged stages, chained over two substeps, equal those obtained by differentiating the unrolled
    Newton iterations and central differences, with a fraction of the operations."""
    m, p = disc
    eps = 1e-4
    integ = dataclasses.replace(integration(m, p, 0.01, u=np.array([OMEGA, N]), eps=eps), nsub=2)
    assert integ.implicit
    f = m.ode(eps)
    x, u, q = ca.SX.sym("x", m.nx), ca.SX.sym("u", m.nu), ca.SX.sym("p", m.n_p)
    xn = integ.advance(lambda a, b, c: f(a, b, c), x, u, q)
    ad = ca.Function("ad", [x, u, q], [xn, ca.jacobian(xn, x), ca.jacobian(xn, u), ca.jacobian(xn, q)])
    xi, jacs = integ.advance_jacobian(lambda a, b, c: f(a, b, c), x, u, q, wrt=("x", "u", "p"))
    ift = ca.Function("ift", [x, u, q], [xi, *jacs])
    assert ift.n_instructions() < 0.5 * ad.n_instructions()
    pv, uv = p.vector(), np.array([OMEGA, N])
    for x0 in (np.array([0.2, 0.5]), np.array([-0.1, 2.0]), np.array([0.05, 3 * eps])):
        a, b = ad(x0, uv, pv), ift(x0, uv, pv)
        np.testing.assert_array_equal(np.array(a[0]), np.array(b[0]))
        for Ja, Jb in zip(a[1:], b[1:]):
            Ja, Jb = np.array(Ja), np.array(Jb)
            np.testing.assert_allclose(Jb, Ja, rtol=1e-7, atol=1e-9 * max(1.0, np.max(np.abs(Ja))))
        # and central differences in the inputs (the NMPC's decisions)
        for j in range(m.nu):
            hj = 1e-7 * max(abs(uv[j]), 1e-3)
            up, um = uv.copy(), uv.copy()
            up[j] += hj
            um[j] -= hj
            fd = (np.array(ift(x0, up, pv)[0]) - np.array(ift(x0, um, pv)[0])).ravel() / (2 * hj)
            np.testing.assert_allclose(np.array(b[2])[:, j], fd, rtol=1e-4, atol=1e-6 * max(1.0, np.max(np.abs(fd))))


def test_l_stable_limit():
    """L-stability: on y' = lambda y with h lambda -> -inf the step goes to 0 (the stiff mode is damped in
    one step, no ringing), and for moderate h lambda it matches the method's stability function
    R(z) = (1 + (1 - 2 gamma) z) / (1 - gamma z)^2."""
    for z in (-1e8, -1e3, -1.0, -0.1):
        lam = z / 0.01
        integ = Integration(0.01, 1, method="sdirk2")
        y = float(integ.advance(lambda a, b, c: lam * a, ca.DM(1.0), 0.0, 0.0))
        R = (1 + (1 - 2 * GAMMA) * z) / (1 - GAMMA * z) ** 2
        assert y == pytest.approx(R, rel=1e-9, abs=1e-12)
    assert abs(float(Integration(0.01, 1, method="sdirk2").advance(lambda a, b, c: -1e10 * a, ca.DM(1.0), 0, 0))) < 1e-6


def test_note_of_an_asked_implicit_substep_count_gives_what_rk4_would_need():
    """A fit's substep raise asks the implicit step for ``nsub`` substeps: the note still states RK4's own
    count (the slider at eps 6.7e-8: ~11,700 a 0.5 ms sample), not the count asked ("would need 6")."""
    from pathlib import Path
    m = get_model(Path(__file__).resolve().parent / "data" / "paper_slider" / "slider_k1002.toml")
    p, eps = m.published(), 6.684507609859605e-08
    free = integration(m, p, 5e-4, u=np.array([4.2e-5]), eps=eps, where="identification")
    asked = integration(m, p, 5e-4, u=np.array([4.2e-5]), eps=eps, nsub=6, method="sdirk2", where="identification")
    assert free.implicit and asked.implicit and asked.nsub == 6
    need = int(free.note.split("explicit RK4 would need ")[1].split()[0])
    assert need > 10000
    assert f"explicit RK4 would need {need} " in asked.note
