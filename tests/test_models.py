"""Rig models: Jacobians, friction symmetry, energy, RK4 vs CVODES and RK4's order."""

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from models.errors import ConfigError

from models import friction as fr
from models import get_model
from models.discretise import rk4_function
from models.plant import SimOptions, simulate


# ---------------------------------------------------------------- Jacobians vs finite differences
@settings(max_examples=20, deadline=None)
@given(st.sampled_from(["rig3", "rig2", "leadscrew", "disc"]), st.integers(0, 2 ** 31 - 1))
def test_casadi_jacobian_matches_finite_differences(name, seed):
    m = get_model(name)
    p = m.published().vector()
    rng = np.random.default_rng(seed)
    x = rng.normal(size=m.nx)
    for i in m.contacts:      # keep contact speeds away from the regularisation layer, either sign
        x[i] = rng.choice([-1, 1]) * rng.uniform(0.5, 5.0)
    u = rng.uniform(0.5, 5.0, size=m.nu)
    if name == "leadscrew":
        u[1] = rng.uniform(50, 300)
    f = m.ode()
    xs, us = ca.SX.sym("x", m.nx), ca.SX.sym("u", m.nu)
    J = ca.Function("J", [xs, us], [ca.jacobian(f(xs, us, p), ca.vertcat(xs, us))])
    Ja = np.array(J(x, u))
    z = np.concatenate([x, u])
    g = lambda zz: np.array(f(zz[:m.nx], zz[m.nx:], p)).ravel()  # noqa: E731
    h = 1e-6 * np.maximum(1.0, np.abs(z))
    Jf = np.column_stack([(g(z + hk * e) - g(z - hk * e)) / (2 * hk) for hk, e in zip(h, np.eye(z.size))])
    np.testing.assert_allclose(Ja, Jf, rtol=1e-5, atol=1e-6 * max(1.0, np.abs(Ja).max()))


# ---------------------------------------------------------------- friction is odd in velocity
@settings(max_examples=100, deadline=None)
@given(st.floats(-50, 50), st.floats(0.01, 1.0), st.floats(0.0, 1.0), st.floats(0.01, 10.0), st.floats(1e-3, 1.0))
def test_regularised_stribeck_is_odd(v, mu_s, frac, v_s, eps):
    law = fr.get_law("stribeck")
    P = dict(mu_s=mu_s, mu_k=frac * mu_s, v_s=v_s)
    a, b = law.smooth(v, 20.0, 0.047, P, eps), law.smooth(-v, 20.0, 0.047, P, eps)
    assert a == pytest.approx(-b, abs=1e-14)
    assert a * v <= 0          # dissipative: the torque opposes the motion


@settings(max_examples=100, deadline=None)
@given(st.floats(-100, 100), st.floats(0.0, 0.5), st.floats(0.0, 0.1), st.floats(-1e-3, 0.0),
       st.floats(0.0, 5.0), st.floats(1.0, 100.0))
def test_vahid_araghi_law_is_odd(v, mu1, mu2, mu3, r0, r1):
    law = fr.get_law("vahid_araghi")
    P = dict(mu1=mu1, mu2=mu2, mu3=mu3, r0=r0, sm=1.0)
    assert law.smooth(v, 300.0, 5e-3, P, 0.05) == pytest.approx(-law.smooth(-v, 300.0, 5e-3, P, 0.05), abs=1e-15)


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 30.0), st.floats(0.1, 0.8), st.floats(0.0, 1.0), st.floats(0.05, 5.0), st.floats(0.0, 0.5))
def test_bit_rock_law_weakens_then_strengthens(v, mu_sb, frac, v_b, c_b):
    """Bit-rock law (Navarro-Lopez & Cortes 2007): T(0) = W R mu_sb; the Stribeck part only falls;
    with c_b > 0 the torque has a minimum and rises again (velocity strengthening)."""
    law = fr.get_law("bit_rock")
    P = dict(mu_sb=mu_sb, mu_cb=frac * mu_sb, v_b=v_b, c_b=c_b)
    scale = 100.0 * 0.1
    T = lambda w: law.magnitude(w, scale, **P)  # noqa: E731
    assert T(0.0) == pytest.approx(scale * mu_sb)
    assert T(v) >= scale * P["mu_cb"] + c_b * v - 1e-12
    if c_b > 0 and frac < 1:
        w_big = 50 * v_b + scale * mu_sb / c_b + 1.0
        assert T(w_big) > T(v_b) or T(v_b) < T(0.0)


def test_registry_adds_a_law_and_rejects_duplicates():
    def coulomb_viscous(v_abs, scale, *, mu_k, c_v):
        return scale * mu_k + c_v * v_abs
    name = "test_coulomb_viscous"
    fr.LAWS.pop(name, None)
    law = fr.register(fr.FrictionLaw(name, coulomb_viscous, (fr.Param("mu_k", "level"), fr.Param("c_v", "damping"))))
    assert fr.get_law(name) is law
    assert law.torque(2.0, -1.0, 10.0, 0.1, dict(mu_k=0.3, c_v=0.01)) == pytest.approx(0.3 + 0.02)
    with pytest.raises(ConfigError, match="already registered"):
        fr.register(law)
    with pytest.raises(ConfigError, match="must be one of"):
        fr.get_law("no_such_law")
    fr.LAWS.pop(name)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.05, 10.0), st.floats(0.0, 40.0))
def test_rig3_contact_torque_odd_in_speed(v, n1):
    m = get_model("rig3")
    P = m.published().as_dict()
    x, u = np.zeros(m.nx), np.array([0.0, n1, n1])
    t_pos = m.contact_friction(0, v, u, P, 0.05)
    t_neg = m.contact_friction(0, -v, u, P, 0.05)
    assert float(t_pos) == pytest.approx(-float(t_neg), abs=1e-14)


# ---------------------------------------------------------------- energy of the chain
def _chain_params(damped: bool):
    """rig3 reduced to its mechanical chain: no motor electrics acting (KE = kp = ki = 0, i(0) = 0),
    no motor friction; optionally without shaft damping."""
    p = get_model("rig3").published()
    kw = dict(KE=0.0, kp=0.0, ki=0.0, Tf=0.0, Cm=0.0)
    if not damped:
        kw.update(d1=0.0, d2=0.0)
    return p.replace(**kw)


def _energy(p, x):
    x = np.atleast_2d(x)
    return 0.5 * (p.J1 * x[:, 2] ** 2 + p.J2 * x[:, 3] ** 2 + p.eta ** 2 * p.Jm * x[:, 4] ** 2
                  + p.k1 * x[:, 0] ** 2 + p.k2 * x[:, 1] ** 2)


def test_undamped_chain_conserves_energy():
    """RK4 (10 substeps of 1 ms) keeps the energy of the free, undamped chain to 1e-7 relative
    over 60 s (measured drift ~1e-10)."""
    p = _chain_params(damped=False)
    x0 = np.array([0.3, -0.2, 1.0, -0.5, 0.2, 0.0, 0.0])
    r = simulate(get_model("rig3"), p, np.zeros(3), 60.0, SimOptions(method="smooth"), sensors=None, x0=x0)
    E = _energy(p, r.x)
    assert np.max(np.abs(E / E[0] - 1)) < 1e-7


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.floats(0.0, 40.0), st.floats(0.0, 10.0))
def test_energy_does_not_grow_without_input(seed, n1, n2):
    """Shaft damping and pin friction only dissipate: with omega_ref = 0 and no motor drive,
    the chain's energy is non-increasing from random initial states."""
    p = _chain_params(damped=True)
    rng = np.random.default_rng(seed)
    x0 = np.concatenate([rng.normal(0, 0.5, 2), rng.normal(0, 2.0, 3), [0.0, 0.0]])
    F = rk4_function(get_model("rig3"), 0.01, 20)
    x, u = x0, np.array([0.0, n1, n2])
    E = [float(_energy(p, x)[0])]
    for _ in range(150):
        x = np.array(F(x, u, p.vector())).ravel()
        E.append(float(_energy(p, x)[0]))
    assert np.all(np.diff(E) <= 1e-9 * E[0] + 1e-15)


# ---------------------------------------------------------------- RK4 vs CVODES, RK4 order
def test_rk4_agrees_with_cvodes_on_the_full_rig3():
    m = get_model("rig3")
    p = m.published()
    prog = lambda t: np.array([math.pi if t < 2.0 else 2.0, 5.0, 2.0])  # noqa: E731
    a = simulate(m, p, prog, 5.0, SimOptions(method="smooth", nsub=20, start="sliding"), sensors=None)
    b = simulate(m, p, prog, 5.0, SimOptions(method="cvodes", start="sliding"), sensors=None)
    scale = np.maximum(np.abs(b.x).max(axis=0), 1e-3)
    assert np.max(np.abs(a.x - b.x) / scale) < 1e-4


def test_rk4_convergence_order_is_four():
    m = get_model("rig3")
    p = _chain_params(damped=True)
    x0 = np.array([0.3, -0.2, 1.0, -0.5, 0.2, 0.0, 0.0])
    u = np.zeros(3)
    x = ca.SX.sym("x", 7)
    ref = ca.integrator("ref", "cvodes", {"x": x, "ode": m.ode()(x, u, p.vector())}, 0.0, 0.5,
                        {"abstol": 1e-13, "reltol": 1e-13})
    x_ref = np.array(ref(x0=x0)["xf"]).ravel()
    errs = []
    for nsub in (16, 32, 64, 128):          # steps of 31 ms ... 3.9 ms (asymptotic range; 1.8 Hz top mode)
        F = rk4_function(m, 0.5, nsub)
        errs.append(np.max(np.abs(np.array(F(x0, u, p.vector())).ravel() - x_ref)))
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((orders > 3.6) & (orders < 4.4)), orders
