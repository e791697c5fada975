"""Friction laws with state (models.friction: ``lugre``, ``rate_state``), through the rig's state.

Each law is checked against an independent simulation written here with scipy (nothing imported
from ``models`` for it) and against published results:

- LuGre (Canudas de Wit, Olsson, Astrom & Lischinsky, IEEE TAC 40(3) 1995): the paper's stick-slip
  example (Sect. IV: 1 kg, 2 N/m, 0.1 m/s, Table I: sigma0 = 1e5 N/m, sigma1 = sqrt(1e5) N s/m,
  sigma2 = 0.4 N s/m, F_c = 1 N, F_s = 1.5 N, v_s = 1 mm/s; ``tests/rigs/lugre_1995.toml``), and its
  presliding behaviour: for displacements far below F_s/sigma0 the contact is a spring of stiffness
  sigma0 (the paper's eq. 3 linearised; its Fig. 3 shows the hysteresis loops).
- Rate-and-state (Dieterich-Ruina, ageing law, arcsinh-regularised as in Rice, Lapusta & Ranjith
  2001): the steady state mu_ss(v) = mu0 + (a - b) ln(v/v0) and the spring-slider's critical stiffness
  k_crit = (b - a) sigma_n / D_c (Ruina, JGR 88 (1983); Rice & Ruina, J. Appl. Mech. 50 (1983))
  (``tests/rigs/rate_state_slider.toml``), and the classic velocity step against the law's textbook
  theta form.
"""

from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from models import get_model
from models import friction as fr
from models.plant import SimOptions, plant_integration, simulate

RIGS = Path(__file__).resolve().parent / "rigs"

# LuGre 1995, Sect. IV and Table I (SI: m, N, s)
M, K, V = 1.0, 2.0, 0.1
S0, S1, S2, FC, FS, VS = 1e5, math.sqrt(1e5), 0.4, 1.0, 1.5, 1e-3


def _lugre_independent(t):
    """The paper's mass-spring example, written from the paper: states x, v, z; drive end at V t."""
    def rhs(tt, y):
        x, v, z = y
        g = FC + (FS - FC) * math.exp(-(v / VS) ** 2)
        zd = v - S0 * abs(v) * z / g
        return [v, (K * (V * tt - x) - (S0 * z + S1 * zd + S2 * v)) / M, zd]
    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0, 0.0], method="Radau", t_eval=t, rtol=1e-10, atol=1e-12)
    assert sol.success
    return sol.y


def _onsets(t, v, threshold):
    slip = v > threshold
    return t[1:][slip[1:] & ~slip[:-1]]


@pytest.fixture(scope="module")
def lugre_run():
    m = get_model(RIGS / "lugre_1995.toml")
    r = simulate(m, m.published(), np.array([V]), 30.0, SimOptions(dt=0.01), sensors=None)
    assert r.success
    return m, r


def test_registry_declares_states_and_the_rig_carries_them(lugre_run, tmp_path):
    m, r = lugre_run
    law = fr.get_law("lugre")
    assert law.stateful and law.state_names == ("z",) and not fr.get_law("stribeck").stateful
    assert fr.get_law("rate_state").rest_free and not law.rest_free
    assert m.states == ("twist_spring", "omega_mass", "z_floor") and m.state_units[-1] == "rad"
    assert m.friction_states == (2,) and m.stateful_contacts == (0,)
    # a DC motor's current and PI integral stay the last two states
    text = (Path(__file__).resolve().parents[1] / "models" / "rigs" / "rig3.toml").read_text()
    text = text.replace('name = "rig3"', 'name = "rig3_lugre"').replace('law = "stribeck"', 'law = "lugre"')
    text = text.replace('v_s = "v_s"', 'v_s = "v_s"\nsigma0 = "1e4 1/rad"\nsigma1 = "10 s/rad"\nsigma2 = 0.0')
    text = text.replace('mu_k = "mu_k"', 'mu_c = "mu_k"')
    path = tmp_path / "rig3_lugre.toml"
    path.write_text(text)
    r3 = get_model(path)
    assert r3.states[-2:] == ("current", "pi_integral")
    assert r3.states[5:7] == ("z_pin1", "z_pin2") and r3.current_index == r3.nx - 2


def test_lugre_plant_against_an_independent_simulation(lugre_run):
    """Our plant (the rule's implicit step, no event logic) against scipy's Radau on the paper's ODE:
    the spring force within 0.2 % of its range, every slip onset within one sample."""
    m, r = lugre_run
    assert plant_integration(m, m.published(), SimOptions(dt=0.01)).implicit
    x, v, _ = _lugre_independent(r.t)
    F_ind = K * (V * r.t - x)
    F = r.truth["torque_spring"]
    assert np.max(np.abs(F - F_ind)) < 2e-3 * np.ptp(F_ind)
    on, on_ind = _onsets(r.t, r.state("omega_mass"), 0.05), _onsets(r.t, v, 0.05)
    assert len(on) == len(on_ind) == 4 and np.max(np.abs(on - on_ind)) <= 0.011


def test_lugre_1995_stick_slip_example(lugre_run):
    """The paper's example: stick until the spring reaches F_s (1.5 N at 0.2 N/s: 7.5 s), then a
    stick-slip cycle whose period (6.36 s) is within 2 % of the ideal Coulomb-viscous cycle (F_s
    static, F_c + sigma2 v kinetic, exact stick: 6.454 s, computed here by events) -- LuGre's
    presliding compliance and Stribeck curve make the difference."""
    m, r = lugre_run
    F, t = r.truth["torque_spring"], r.t
    on = _onsets(t, r.state("omega_mass"), 0.05)
    assert on[0] == pytest.approx(FS / (K * V), abs=0.1)
    assert F.max() == pytest.approx(FS, rel=0.01)
    stick = (t > 1) & (t < 7)
    assert np.polyfit(t[stick], F[stick], 1)[0] == pytest.approx(K * V, rel=1e-3)

    def slip(tt, y):
        return [y[1], (K * (V * tt - y[0]) - FC - S2 * y[1]) / M]

    def stops(tt, y):
        return y[1]
    stops.terminal, stops.direction = True, -1
    t0, x0, starts = 0.0, 0.0, []
    for _ in range(3):
        ts = max(x0 / V + FS / (K * V), t0)
        starts.append(ts)
        s = solve_ivp(slip, (ts, ts + 20), [x0, 1e-12], events=stops, rtol=1e-11, atol=1e-13, max_step=0.01)
        t0, x0 = s.t_events[0][0], s.y_events[0][0][0]
    coulomb = np.diff(starts)[-1]
    period = np.mean(np.diff(on))
    assert coulomb == pytest.approx(6.454, abs=0.002)
    assert period == pytest.approx(coulomb, rel=0.02) and period == pytest.approx(6.36, abs=0.02)


def test_lugre_presliding_is_a_spring_of_stiffness_sigma0():
    """The law itself under a prescribed displacement x(t) = A sin(2 pi t): for A = 0.1 um (far below
    F_s/sigma0 = 15 um) the friction is sigma0 x + sigma1 x' within 1 % of sigma0 A (presliding: the
    bristles bend, nothing slides; the deviation grows as sigma0 A / F: 3 % at 1 um); at A = 100 um
    the bristles saturate and the loop is wide (gross sliding, friction bounded by F_s + sigma2 |v|)."""
    law = fr.get_law("lugre")
    P = dict(sigma0=S0, sigma1=S1, sigma2=S2, mu_c=FC, mu_s=FS, v_s=VS)
    t = np.linspace(0, 2, 4001)
    for A in (1e-7, 1e-4):
        def rhs(tt, z, A=A):
            v = A * 2 * math.pi * math.cos(2 * math.pi * tt)
            return [float(law.dynamic_torque(v, [z[0]], 1.0, 1.0, P)[1][0])]
        z = solve_ivp(rhs, (0, 2), [0.0], t_eval=t, method="Radau", rtol=1e-10, atol=1e-14).y[0]
        x = A * np.sin(2 * math.pi * t)
        v = A * 2 * math.pi * np.cos(2 * math.pi * t)
        F = np.array([-law.dynamic_torque(vv, [zz], 1.0, 1.0, P)[0] for vv, zz in zip(v, z)])
        if A < 1e-5:
            np.testing.assert_allclose(F, S0 * x + S1 * v, atol=0.01 * S0 * A)
        else:
            late = t > 1
            assert np.max(np.abs(F[late])) <= FS + S2 * np.max(np.abs(v)) + 1e-6
            area = abs(np.trapezoid(F[late], x[late]))
            assert area > 0.5 * 4 * FC * A            # a loop near the Coulomb rectangle's 4 F_c A


# ----------------------------------------------------------------------------- rate and state
SN, MU0, A_, B_, V0, DC, VD = 10.0, 0.6, 0.01, 0.015, 1e-6, 1e-5, 1e-5
K_CRIT = (B_ - A_) * SN / DC                    # 5000 N/m


def _rs_independent(k, t, x0):
    """The spring-slider with the ageing law in its textbook theta form (position, speed, theta)."""
    def rhs(tt, y):
        x, v, th = y
        mu = A_ * math.asinh(v / (2 * V0) * math.exp((MU0 + B_ * math.log(V0 * th / DC)) / A_))
        return [v, (k * (VD * tt - x) - SN * mu) / 1.0, 1 - abs(v) * th / DC]
    y0 = [-x0[0], x0[1], DC / V0 * math.exp(x0[2])]
    sol = solve_ivp(rhs, (0.0, t[-1]), y0, method="Radau", t_eval=t, rtol=1e-10, atol=[1e-14, 1e-14, 1e-12])
    assert sol.success
    return sol.y


@pytest.fixture(scope="module")
def rs_model():
    return get_model(RIGS / "rate_state_slider.toml")


def test_rate_state_steady_friction(rs_model):
    """Steady sliding of our model at three drive speeds: the spring carries sigma_n mu_ss(v),
    mu_ss = mu0 + (a - b) ln(v/v0) (Ruina 1983), within 1e-6."""
    m = rs_model
    for v in (1e-5, 1e-4, 1e-3):
        P = m.published()
        xs = m.steady_sliding(np.array([v]), P)
        mu = P["k"] * xs[0] / SN
        assert mu == pytest.approx(MU0 + (A_ - B_) * math.log(v / V0), abs=1e-6)
        assert xs[2] == pytest.approx(math.log(V0 / v), abs=1e-6)    # theta = d_c / v (|v| rounded at 1e-6 v0)


def test_rate_state_velocity_step_against_the_theta_form():
    """A velocity step 1 -> 10 um/s: the law (our psi form) and the textbook theta form, both
    integrated by scipy, agree to 1e-9; friction jumps by a ln 10 and settles, over a few d_c of slip,
    to (a - b) ln 10 below its start (Dieterich 1979; Ruina 1983)."""
    law = fr.get_law("rate_state")
    P = dict(mu0=MU0, a=A_, b=B_, v0=V0, d_c=DC)
    t = np.linspace(0, 20, 2001)

    def vel(tt):
        return 1e-6 if tt < 5 else 1e-5

    psi = solve_ivp(lambda tt, z: [float(law.dynamic_torque(vel(tt), [z[0]], 1.0, 1.0, P)[1][0])], (0, 20), [0.0],
                    t_eval=t, method="Radau", rtol=1e-11, atol=1e-13, max_step=0.01).y[0]
    th = solve_ivp(lambda tt, y: [1 - vel(tt) * y[0] / DC], (0, 20), [DC / V0], t_eval=t, method="Radau",
                   rtol=1e-11, atol=1e-13, max_step=0.01).y[0]
    v = np.array([vel(tt) for tt in t])
    mu = np.array([-law.dynamic_torque(vv, [pp], 1.0, 1.0, P)[0] for vv, pp in zip(v, psi)])
    mu_theta = A_ * np.arcsinh(v / (2 * V0) * np.exp((MU0 + B_ * np.log(V0 * th / DC)) / A_))
    np.testing.assert_allclose(mu, mu_theta, atol=1e-9)
    before, jump, after = mu[t < 5][-1], mu[(t > 5)][0], mu[-1]
    assert before == pytest.approx(MU0, abs=1e-7)
    assert jump - before == pytest.approx(A_ * math.log(10), rel=0.02)
    assert after - before == pytest.approx((A_ - B_) * math.log(10), abs=1e-6)


def test_rate_state_critical_stiffness(rs_model):
    """Steady sliding of our model loses stability at k_crit = (b - a) sigma_n / d_c = 5000 N/m: the
    Jacobian's rightmost eigenvalue changes sign between 0.99 and 1.01 k_crit."""
    m = rs_model
    re = {}
    for f in (0.99, 1.01):
        P = m.published().replace(k=f * K_CRIT)
        xs = m.steady_sliding(np.array([VD]), P)
        x = ca.SX.sym("x", m.nx)
        J = ca.Function("J", [x], [ca.jacobian(m.ode()(x, VD, P.vector()), x)])
        re[f] = float(np.max(np.linalg.eigvals(np.array(J(xs))).real))
    assert re[0.99] > 0 > re[1.01]


def test_rate_state_spring_slider_against_an_independent_simulation(rs_model):
    """Our plant (the implicit step, the speed bracketed and solved in its logarithm) against scipy's
    Radau on the theta form, from a contact aged by 10 %: below k_crit (0.8 k_crit) the oscillation
    grows into stick-slip, above (1.2 k_crit) it decays to steady sliding; the spring force agrees
    within 1 % of the stick-slip's range over the first 20 s."""
    m = rs_model
    t_end = 80.0
    for f, grows in ((0.8, True), (1.2, False)):
        P = m.published().replace(k=f * K_CRIT)
        x0 = m.steady_sliding(np.array([VD]), P)
        x0[2] += 0.1
        r = simulate(m, P, np.array([VD]), t_end, SimOptions(dt=0.01), sensors=None, x0=x0)
        assert r.success
        y = _rs_independent(f * K_CRIT, r.t, x0)
        F, F_ind = r.truth["torque_spring"], f * K_CRIT * (VD * r.t - y[0])
        v, late = r.state("omega_block"), r.t > t_end - 20
        if grows:
            assert np.max(v[late]) > 10 * VD and np.min(v[late]) < 0.1 * VD      # stick-slip
            early = r.t < 20
            assert np.max(np.abs(F - F_ind)[early]) < 0.01 * np.ptp(F_ind)
        else:
            assert np.max(np.abs(v[late] - VD)) < 0.05 * VD
            assert np.max(np.abs(F - F_ind)) < 1e-3 * SN


@pytest.mark.slow
def test_nmpc_with_the_ekf_suppresses_lugre_stick_slip():
    """Closed loop on the LuGre paper's rig (the plant integrates the law's state; the EKF estimates
    it; the NMPC predicts with it, commanding the drive's speed): PI (the constant programme) keeps
    the stick-slip, the NMPC with the EKF ends it (measured: sss_final 1.52 against 0.00; stuck 52 %
    against 11 % of the whole run, control from t = 20 s)."""
    from mitigate import make_scenario, run

    m = get_model(RIGS / "lugre_1995.toml")
    sc = make_scenario(name="lugre", model=m, duration=60.0, inputs={"v_drive": V},
                       controllers=["pi", {"name": "NMPC", "kind": "nmpc"}], estimator="ekf", control_start=20.0)
    assert any("implicit SDIRK2" in msg for msg in sc.messages)
    res = run(sc, jobs=1)
    pi, nmpc = res.run("pi"), res.run("NMPC")
    assert pi.status.success and nmpc.status.success
    assert pi.metrics["sss_final"] > 1.0
    assert nmpc.metrics["sss_final"] < 0.05 * pi.metrics["sss_final"]
