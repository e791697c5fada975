"""NMPC on any rig (mitigate.controllers.nmpc): its options, the OCP, the QP and the RTI step, the
fallbacks and the measured inputs it holds.

Independent checks: the QP solved by hpipm directly against an exact active-set solve (qrqp);
one RTI step at an equilibrium against a discrete LQR (numpy Riccati recursion, itself checked
against python-control ``dlqr``); Gauss-Newton SQP against IPOPT on the same NLP; the fallback
chain.  The closed loops are in tests/test_nmpc_closed_loop.py.
No compilation here (``compile=False``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from estimators.base import Estimate
from mitigate.controllers.factory import make_controller
from mitigate.controllers.nmpc import MAX_HORIZON, NMPCOptions, NMPCWeights, stage_functions
from mitigate.controllers.nmpc.stage import prediction_rhs
from mitigate.controllers.nmpc.qp import ConicQP, HpipmQP
from models import get_model
from models.errors import ConfigError
from models.plant import Plant, SimOptions
from models.status import Status

from nmpc_setup import M, P, U0, W0, apply_action as _apply, context as _ctx, estimate as _est, nmpc as _nmpc


# ----------------------------------------------------------------------------- options
@pytest.mark.parametrize("opts, match", [
    ({"horizon": 1}, r"^controllers\[3\]\.horizon must be an integer >= 2, got 1$"),
    ({"horizon": MAX_HORIZON + 1}, rf"^controllers\[3\]\.horizon must be <= {MAX_HORIZON} .*got {MAX_HORIZON + 1}$"),
    ({"dt": -0.05}, r"^controllers\[3\]\.dt must be > 0 s, got -0.05$"),
    ({"solver": "acados"}, r"^controllers\[3\]\.solver must be one of rti, sqp, ipopt, got 'acados'$"),
    ({"qp_solver": "gurobi"}, r"^controllers\[3\]\.qp_solver must be one of"),
    ({"weights": {"speed": -1.0}}, r"^controllers\[3\]\.weights\.speed must be >= 0, got -1.0$"),
    ({"weights": {"d_ref": 0.0}}, r"^controllers\[3\]\.weights\.d_ref must be > 0"),
    ({"weights": {"spead": 1.0}}, r"^controllers\[3\]\.weights\.spead: unknown key \(did you mean 'speed'\?\); expected one of d_force, "),
    ({"horizn": 20}, r"^controllers\[3\]\.horizn: unknown key \(did you mean 'horizon'\?\); expected one of body, "),
    ({"compile": "yes"}, r"^controllers\[3\]\.compile must be true or false, got 'yes'$"),
    ({"inputs": "brake"}, r"^controllers\[3\]\.inputs must be one of both, pin, motor or a list"),
    ({"inputs": []}, r"^controllers\[3\]\.inputs must be a non-empty list"),
    ({"inputs": ["n1"]}, r"^controllers\[3\]\.inputs: rig 'rig3' cannot set 'n1' \(it can set: omega_ref, n2\)$"),
    ({"inputs": ["n2", "omega_ref", "speed"]}, r"^controllers\[3\]\.inputs: rig 'rig3' cannot set 'speed'"),
    ({"body": "R9"}, r"^controllers\[3\]\.body must be a body of rig 'rig3' \(R1, R2, R3\), got 'R9'$"),
    ({"dt": 0.005}, r"^controllers\[3\]\.dt must be >= the DAQ period 0.01 s, got 0.005$"),
    ({"force_band": [1.2, 1.5]}, r"^controllers\[3\]\.force_band must have low < 1 <= high, got \[1.2, 1.5\]$"),
    ({"force_band": [0.8]}, r"^controllers\[3\]\.force_band must be \[low, high\] \(ratios to the programme\), got"),
    ({"qp_condensing": "dense"}, r"^controllers\[3\]\.qp_condensing must be one of none, full, partial, got 'dense'$"),
    ({"qp_blocks": 0}, r"^controllers\[3\]\.qp_blocks must be >= 1, got 0$"),
    ({"qp_mode": "fast"}, r"^controllers\[3\]\.qp_mode must be one of speed_abs, speed, balance, robust, got 'fast'$"),
    ({"qp_mu0": 0.0}, r"^controllers\[3\]\.qp_mu0 must be > 0, got 0"),
    ({"qp_mode": "speed", "qp_solver": "osqp"},
     r"^controllers\[3\]\.qp_mode: hpipm's setting needs qp_solver \"hpipm\" and solver rti or sqp; got qp_solver 'osqp'"),
    ({"qp_mu0": 0.01, "solver": "ipopt"}, r"^controllers\[3\]\.qp_mu0: hpipm's setting needs .*solver 'ipopt'$"),
    ({"qp_condensing": "full", "implementation": "python"},
     r"^controllers\[3\]\.qp_condensing: \"full\" needs the compiled C step .*implementation 'python', compile false"),
])
def test_bad_options_name_the_field(opts, match):
    with pytest.raises(ConfigError, match=match):
        _nmpc(opts, where="controllers[3]")


def test_pin_on_a_rig_without_servo_is_refused():
    with pytest.raises(ConfigError, match=r"^nmpc\.inputs = 'pin' needs a servo input, and rig 'disc' has none"):
        _nmpc({"inputs": "pin"}, model="disc", programme=[W0, 20.0])


def test_options_defaults_and_from_mapping():
    o = NMPCOptions.from_mapping({"weights": {"speed": 2.0}, "inputs": ["n2"]}, "x")
    assert o.weights.speed == 2.0 and o.weights.ref == NMPCWeights().ref
    assert o.solver == "rti" and o.horizon == 20 and o.inputs == ("n2",) and o.weights.where == "x.weights"
    assert NMPCOptions(weights={"rel": 0.5}).weights == NMPCWeights(rel=0.5, where="nmpc.weights")
    with pytest.raises(ConfigError, match=r"^nmpc\.weights\.terminal must be >= 0, got -1$"):
        NMPCOptions(weights={"terminal": -1})


@pytest.mark.parametrize("inputs, states, decisions, action", [
    ("both", ("servo:n2", "previous:omega_ref"), ("change:omega_ref", "command:n2"), {"omega_ref", "n2"}),
    ("pin", ("servo:n2",), ("command:n2",), {"n2"}),
    ("motor", ("previous:omega_ref",), ("change:omega_ref",), {"omega_ref"}),
    (["n2", "omega_ref"], ("servo:n2", "previous:omega_ref"), ("change:omega_ref", "command:n2"), {"omega_ref", "n2"}),
])
def test_augmented_state_and_decisions_follow_the_inputs(inputs, states, decisions, action):
    c = _nmpc({"inputs": inputs, "horizon": 5})
    assert c.layout.states == M.states + states
    assert c.layout.decisions == decisions
    a = c.step(0.0, {"n1": 20.0, "n2": 0.0}, _est(0.0, M.steady_sliding(U0, P)))
    assert a.status is Status.OK, a.message
    assert set(a.u) == action


# ----------------------------------------------------------------------------- model and QP
def test_prediction_model_is_the_rig_model_with_a_friction_factor():
    """fc = 1 reproduces model.ode; fc = 2 on R1's contact adds R1's friction torque once more
    to R1's acceleration and changes nothing else."""
    f, rhs = M.ode(0.05), prediction_rhs(M, 0.05)
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = rng.normal(size=M.nx)
        u = np.array([3.0, 20.0, 10.0])
        a = np.array(f(x, u, P.vector())).ravel()
        np.testing.assert_allclose(np.array(rhs(x, u, P.vector(), [1.0, 1.0])).ravel(), a, rtol=1e-12, atol=1e-12)
        b = np.array(rhs(x, u, P.vector(), [2.0, 1.0])).ravel()
        Tf = float(M.contact_friction(0, x[2], u, P.as_dict(), 0.05))
        i1 = M.speed_index("R1")
        assert abs(Tf) > 1e-3
        assert b[i1] - a[i1] == pytest.approx(Tf / P["J1"], rel=1e-9)
        np.testing.assert_allclose(np.delete(b, i1), np.delete(a, i1), rtol=1e-12, atol=1e-12)


def _random_qp(qp, seed):
    """A stage-wise QP with positive definite blocks and bounds that are active at the solution."""
    r = np.random.default_rng(seed)
    N, nx, nu = qp.N, qp.nx, qp.nu
    for k in range(N):
        qp.A[k] = (np.eye(nx) + 0.1 * r.standard_normal((nx, nx))).ravel(order="F")
        qp.B[k] = r.standard_normal((nx, nu)).ravel(order="F")
        qp.b[k] = 0.1 * r.standard_normal(nx)
        J = r.standard_normal((nx + nu + 2, nx + nu))
        H = J.T @ J + 1e-3 * np.eye(nx + nu)
        qp.Q[k], qp.S[k], qp.R[k] = H[:nx, :nx].ravel("F"), H[nx:, :nx].ravel("F"), H[nx:, nx:].ravel("F")
        qp.q[k], qp.r[k] = 3 * r.standard_normal(nx), 3 * r.standard_normal(nu)
    J = r.standard_normal((nx, nx))
    qp.Q[N], qp.q[N] = (J.T @ J).ravel("F"), r.standard_normal(nx)
    qp.lbx0[:] = qp.ubx0[:] = 0.3 * r.standard_normal(nx)
    qp.lbx[:], qp.ubx[:] = -1.0, 1.0
    qp.lbu[:], qp.ubu[:] = -0.5, 0.5
    qp.lg[:], qp.ug[:] = -0.3, 0.3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hpipm_called_directly_matches_an_exact_active_set_solve(seed):
    N, nx, nu = 8, 4, 2
    C, D = np.zeros((1, nx)), np.zeros((1, nu))
    C[0, 3], D[0, 1] = -1.0, 1.0
    sols = []
    for cls, kw in ((HpipmQP, {"tol": 1e-9}), (ConicQP, {"solver": "qrqp"})):
        qp = cls(N, nx, nu, [2], [0, 1], C, D, **kw)
        _random_qp(qp, seed)
        qp.solve()
        sols.append((qp.x.copy(), qp.u.copy()))
    (xh, uh), (xq, uq) = sols
    # some inequality is active at the solution, so the test is not about an unconstrained QP
    active = np.sum(np.isclose(np.abs(uq), 0.5, atol=1e-7)) + np.sum(np.isclose(np.abs(xq[1:, 2]), 1.0, atol=1e-7))
    active += np.sum(np.isclose(np.abs(uq[:, 1] - xq[:-1, 3]), 0.3, atol=1e-7))
    assert active >= 1
    np.testing.assert_allclose(uh, uq, atol=1e-6)
    np.testing.assert_allclose(xh, xq, atol=1e-6)


# ----------------------------------------------------------------------------- LQR
def _riccati_first_gain(A, B, Q, R, S, QN, N):
    """Finite-horizon discrete LQR, cost sum x'Qx + 2x'Su + u'Ru + x_N'QN x_N: gain K_0 (u = -K x)."""
    Pk, K = QN, None
    for _ in range(N):
        G = R + B.T @ Pk @ B
        K = np.linalg.solve(G, B.T @ Pk @ A + S.T)
        Pk = Q + A.T @ Pk @ A - (A.T @ Pk @ B + S) @ K
    return K, Pk


@pytest.mark.parametrize("QP", ["hpipm", "qrqp"])
def test_rti_step_at_equilibrium_matches_lqr(QP):
    """One RTI step from a small deviation of an equilibrium solves the LQ problem exactly."""
    control = pytest.importorskip("control")
    wn, n2 = 2 * np.pi, 10.0
    u_prog = np.array([wn, 20.0, n2])
    c = make_controller({"kind": "nmpc", "horizon": 15, "compile": False, "qp_solver": QP, "qp_tol": 1e-9, "setpoint_rate": 1e3,
                   "weights": {"speed": 1.0, "rel": 0.5, "ref": 0.3, "force": 0.0, "force_linear": 0.0, "d_ref": 0.5,
                               "d_force": 0.5, "terminal": 2.0}}, _ctx(programme=u_prog))
    ocp, L = c.ocp, c.layout
    xs = M.steady_sliding(u_prog, P)
    xa_eq = np.concatenate([xs, [n2, wn]])
    v_eq = L.hold(xa_eq)
    q = L.set_q(c._q.copy(), u_prog, wn)
    F, cost, _, term = stage_functions(M, c.spec)
    assert np.allclose(np.array(F(xa_eq, v_eq, q)).ravel(), xa_eq, atol=1e-8)   # a fixed point with zero cost
    xa, dv = ca.SX.sym("xa", L.nxa), ca.SX.sym("dv", L.nv)
    xn = F(xa, dv, q)
    r, _ = cost(xa, dv, q)
    _, _, _, rN = term(xa, q)
    lin = ca.Function("lin", [xa, dv], [ca.jacobian(xn, xa), ca.jacobian(xn, dv), ca.jacobian(r, xa),
                                        ca.jacobian(r, dv), ca.jacobian(rN, xa)])
    A, B, Jx, Ju, JN = (np.array(v) for v in lin(xa_eq, v_eq))
    Q, R, S, QN = Jx.T @ Jx, Ju.T @ Ju, Jx.T @ Ju, JN.T @ JN
    K0, _ = _riccati_first_gain(A, B, Q, R, S, QN, c.spec.horizon)
    # the recursion itself against python-control's dlqr (long horizon, regularised Q)
    Qr = Q + 1e-6 * np.eye(L.nxa)
    K_inf, _, _ = control.dlqr(A, B, Qr, R, S)
    K_long, _ = _riccati_first_gain(A, B, Qr, R, S, Qr, 3000)
    assert np.allclose(K_long, K_inf, rtol=1e-4, atol=1e-6)

    dx = np.zeros(L.nxa)
    dx[2], dx[0] = 0.02, 0.002  # omega_R1 +0.02 rad/s, twist +2 mrad
    ocp.X = np.tile(xa_eq, (c.spec.horizon + 1, 1))
    ocp.V = np.tile(v_eq, (c.spec.horizon, 1))
    res = ocp.solve(xa_eq + dx, q, [wn - 3, 0.0], [wn + 3, 40.0], [1e3, 1e4])
    du_nmpc = res.u[0] - L.applied(xa_eq, v_eq)   # = v_0 - v_eq (the deviation leaves the servo and set-point states)
    du_lqr = -K0 @ dx
    assert np.abs(du_lqr).max() > 1e-3  # a real move, not a trivial zero
    np.testing.assert_allclose(du_nmpc, du_lqr, rtol=2e-3, atol=2e-5)


# ----------------------------------------------------------------------------- solvers agree
@pytest.mark.slow
def test_gauss_newton_sqp_agrees_with_ipopt():
    x0 = M.steady_sliding(U0, P)
    x0[2] = 0.5  # R1 slowed down (deviation of 2.6 rad/s)
    meas = {"n1": 20.0, "n2": 0.0}
    moves = {}
    for solver in ("sqp", "ipopt"):
        c = _nmpc({"horizon": 10, "solver": solver, "sqp_max_iter": 50})
        a = c.step(0.0, meas, _est(0.0, x0))
        assert a.status is Status.OK, a.message
        moves[solver] = (a.u["omega_ref"], a.u["n2"], c.last_result.cost)
        if solver == "sqp":
            assert "converged" in c.last_result.message
    (w_s, n_s, j_s), (w_i, n_i, j_i) = moves["sqp"], moves["ipopt"]
    assert abs(w_s - W0) > 0.1            # it moved the set-point
    assert abs(w_s - w_i) < 1e-3 and abs(n_s - n_i) < 1e-2
    assert abs(j_s - j_i) <= 1e-4 * max(1.0, abs(j_i))


@pytest.mark.slow
def test_default_qp_tolerance_moves_like_a_tight_solve():
    """The default hpipm tolerance changes the applied first move by less than 3e-3 rad/s and
    0.04 N against an exact active-set solve (qrqp) of the same QP, from states in stick-slip."""
    x0 = M.steady_sliding(U0, P)
    meas = {"n1": 20.0, "n2": 0.0}
    for w1, phi12 in ((0.0, 0.25), (5.0, -0.1), (1.0, 0.0)):
        x = x0.copy()
        x[2], x[0] = w1, x0[0] + phi12
        moves = []
        for qp in ({}, {"qp_solver": "qrqp"}):
            c = _nmpc({"horizon": 50, **qp})
            a = c.step(0.0, meas, _est(0.0, x))
            assert a.status is Status.OK, a.message
            moves.append((a.u["omega_ref"], a.u["n2"]))
        (w_d, n_d), (w_t, n_t) = moves
        assert abs(w_d - w_t) < 3e-3 and abs(n_d - n_t) < 0.04
        assert abs(w_t - W0) > 1e-3 or n_t > 1e-3  # a real move


# ----------------------------------------------------------------------------- fallbacks
def test_fallback_chain_shift_then_programme_is_counted():
    c = _nmpc({"horizon": 5})
    x = M.steady_sliding(U0, P)
    x[2] = 1.0
    meas = {"n1": 20.0, "n2": 0.0}
    c.inject_failure = lambda t: t >= 0.1 - 1e-9
    acts = [c.step(k * 0.01, meas, _est(k * 0.01, x)) for k in range(60)]
    plans = acts[::5]                                              # plans every 0.05 s
    assert [a.status for a in plans[:2]] == [Status.OK, Status.OK]  # t = 0, 0.05
    # failed solves at t = 0.10 .. 0.25 take the plan of t = 0.05 at indices 1..4
    plan = c.last_result.u
    for j, a in enumerate(plans[2:6], start=1):
        assert a.status is Status.FALLBACK and f"shifted plan [{j}]" in a.message
        assert a.u == pytest.approx(dict(zip(c.inputs, plan[j])))
    # t = 0.30: index 5 is past the 5-interval plan -> the programme (an empty action)
    assert all(a.status is Status.FALLBACK and a.u == {} and "the programme" in a.message for a in plans[6:])
    n_fail = len(plans) - 2
    assert c.counts.failures == c.counts.fallbacks == n_fail
    assert c.counts.steps == 60 and c.counts.holds == 60 - len(plans)
    # held samples repeat the last action with Status.HOLD, without counting it again
    assert acts[11].u == acts[10].u and acts[11].status is Status.HOLD


def test_a_numerical_error_is_a_counted_failure_and_a_bug_fails_the_run(monkeypatch):
    """CasADi's RuntimeError in a solve is a SolverFailure (the shifted plan answers, counted);
    any other exception is a bug: step raises PluginError and the run is FAILED."""
    from models.errors import PluginError
    c = _nmpc({"horizon": 5})
    x = M.steady_sliding(U0, P)
    meas = {"n1": 20.0, "n2": 0.0}
    assert c.step(0.0, meas, _est(0.0, x)).status is Status.OK
    monkeypatch.setattr(type(c.ocp), "_solve_impl", lambda *a: (_ for _ in ()).throw(RuntimeError("Error in Function::call")))
    a = c.step(0.05, meas, _est(0.05, x))
    assert a.status is Status.FALLBACK and "RuntimeError" in a.message and c.counts.failures == 1
    monkeypatch.setattr(type(c.ocp), "_solve_impl", lambda *a: (_ for _ in ()).throw(KeyError("bug")))
    with pytest.raises(PluginError, match="KeyError"):
        c.step(0.10, meas, _est(0.10, x))


def test_the_compiled_step_keeps_the_plug_in_rule(monkeypatch):
    """The compiled step runs without the plug-in wrapper (its C checks its own plan), but with the
    rule's outcome: an error of its Python glue fails the run (PluginError naming it), so does a call
    longer than the loop's timeout; a failed plan is still a counted fallback."""
    from dataclasses import replace
    from models.errors import PluginError
    x = M.steady_sliding(U0, P)
    meas = {"n1": 20.0, "n2": 0.0}
    c = make_controller({"kind": "nmpc", "horizon": 5}, _ctx())
    assert c.compiled is not None
    assert c.step(0.0, meas, _est(0.0, x)).status is Status.OK
    assert c.last_decision is not None and c.last_decision.weight_factor > 0
    c.inject_failure = lambda t: True
    a = c.step(0.05, meas, _est(0.05, x))
    assert a.status is Status.FALLBACK and "injected failure" in a.message and c.counts.failures == 1
    c.inject_failure = None
    monkeypatch.setattr(c.compiled, "step", lambda *a: (_ for _ in ()).throw(KeyError("bug")))
    with pytest.raises(PluginError, match="KeyError"):
        c.step(0.10, meas, _est(0.10, x))
    ctx = _ctx()
    slow = make_controller({"kind": "nmpc", "horizon": 5}, replace(ctx, control=replace(ctx.control, timeout=1e-9)))
    with pytest.raises(PluginError, match=r"^TimeoutError: step did not return within 1e-09 s \(it took "):
        slow.step(0.0, meas, _est(0.0, x))


def test_no_estimate_falls_back_to_the_programme_without_raising():
    c = _nmpc({"horizon": 5})
    a = c.step(0.0, {"n1": 20.0}, None)
    assert a.status is Status.FALLBACK and a.u == {} and "no state estimate" in a.message
    assert c.counts.failures == 1 and c.counts.fallbacks == 1


def test_estimate_of_another_rig_is_a_failure_not_a_wrong_plan():
    c = _nmpc({"horizon": 5})
    est = Estimate(0.0, M.steady_sliding(U0, P), None, ("phi12", "phi23", "omega1", "omega2", "omega3", "i", "z"))
    a = c.step(0.0, {"n1": 20.0}, est)
    assert a.status is Status.FALLBACK and "are not the rig's" in a.message


@pytest.mark.parametrize("cond", ["full", "partial"])
def test_condensing_moves_like_the_structured_qp(cond):
    """qp_condensing = "full" (the QP condensed onto the inputs in the preparation, hpipm's dense IPM in
    the feedback) and "partial" (condensed to ceil(N / 5) = 4 stages, Riccati on those) solve the same QP
    as hpipm's Riccati IPM on the OCP QP, with x0 eliminated and folded into stage 0 (b0 + A0 dx0,
    r0 + S0 dx0, the servo rows): from states in stick-slip the first moves agree to the QP's tolerance
    (the bar of the tight-solve test above); fed the same disturbed estimates (so that the plan's start
    and the estimate differ, dx0 != 0) at a tight QP tolerance they agree to 1e-6 at every call."""
    x0 = M.steady_sliding(U0, P)
    meas = {"n1": 20.0, "n2": 0.0}
    for w1, phi12 in ((0.0, 0.25), (5.0, -0.1)):
        x = x0.copy()
        x[2], x[0] = w1, x0[0] + phi12
        moves = []
        for how in ("none", cond):
            c = _nmpc({"horizon": 20, "qp_condensing": how, "compile": True})
            a = c.step(0.0, meas, _est(0.0, x))
            assert a.status is Status.OK, a.message
            assert c.compiled.info.qp_iterations > 0
            moves.append((a.u["omega_ref"], a.u["n2"]))
        (w_s, n_s), (w_c, n_c) = moves
        assert abs(w_s - w_c) < 3e-3 and abs(n_s - n_c) < 0.04
        assert abs(w_s - W0) > 1e-3 or n_s > 1e-3  # a real move
    x0[2] = 1.0
    cs = {how: _nmpc({"horizon": 20, "qp_condensing": how, "compile": True, "qp_tol": 1e-11}) for how in ("none", cond)}
    plant = Plant(M, P, SimOptions(seed=0), sensors=None, x0=x0, u0=U0)
    rng = np.random.default_rng(4)
    worst, moved = 0.0, []
    for k in range(60):
        xe = plant.x + rng.normal(0.0, 0.05, plant.x.size)       # the same disturbed estimate for both
        acts = {how: c.step(k * 0.01, plant.measure(), _est(k * 0.01, xe)) for how, c in cs.items()}
        u = np.array([[acts[h].u["omega_ref"], acts[h].u["n2"]] for h in ("none", cond)])
        worst = max(worst, float(np.max(np.abs(u[0] - u[1]))))
        moved.append(u[0, 0])
        plant.step(_apply(M, U0, acts["none"]))
    assert all(c.counts.failures == 0 for c in cs.values())
    assert np.ptp(moved) > 1e-3 and worst < 1e-6, worst


def test_hpipm_speed_mode_with_a_small_mu0_is_closer_to_the_exact_qp():
    """qp_mode "speed" (stops when every residual is below qp_tol) with qp_mu0 = 0.01, and the main
    scenario's shipped setting (partial condensing, "speed" from a smaller mu0), against the
    default ("speed_abs": stops on the complementarity alone, from hpipm's mu0 = 10): fed the same
    disturbed estimates out of stick-slip, each beside a QP solved to 1e-11, the first moves are
    closer to it (the iterations: benchmarks/bench_acados.py, on the undisturbed loop 4 against 9;
    here about as many); the compiled step and the Python reference (hpipm called through ctypes)
    make the same moves with these settings."""
    from pathlib import Path
    from mitigate.scenario import load_scenario
    main = load_scenario(Path(__file__).resolve().parent.parent / "scenarios" / "stick_slip_30rpm.toml")
    shipped = {k: v for k, v in next(c for c in main.controllers if c.kind == "nmpc").options.items()
               if k in ("qp_condensing", "qp_mode", "qp_mu0")}
    assert shipped["qp_mode"] == "speed" and shipped["qp_mu0"] < 0.01, shipped   # what the docstring says
    from mitigate.export import FAST_QP
    assert shipped == FAST_QP     # the export's hint names the setting the main scenario ships
    x0 = M.steady_sliding(U0, P)
    x0[2] = 1.0
    tight = {"horizon": 20, "compile": True, "qp_tol": 1e-11, "qp_mode": "speed"}
    cases = {"default": {}, "speed": {"qp_mode": "speed", "qp_mu0": 0.01}, "shipped": shipped}
    cs = {name: _nmpc({"horizon": 20, "compile": True, **o}) for name, o in cases.items()}
    cs["tight"] = _nmpc(tight)
    cs["python"] = _nmpc({"horizon": 20, "compile": False, "implementation": "python", **cases["speed"]})
    plant = Plant(M, P, SimOptions(seed=0), sensors=None, x0=x0, u0=U0)
    rng = np.random.default_rng(4)
    worst = {name: 0.0 for name in cs}
    for k in range(60):
        xe = plant.x + rng.normal(0.0, 0.05, plant.x.size)
        acts = {name: c.step(k * 0.01, plant.measure(), _est(k * 0.01, xe)) for name, c in cs.items()}
        u = {name: np.array([a.u["omega_ref"], a.u["n2"]]) for name, a in acts.items()}
        for name in cs:
            worst[name] = max(worst[name], float(np.max(np.abs(u[name] - u["tight"]))))
        plant.step(_apply(M, U0, acts["tight"]))
    assert all(c.counts.failures == 0 for c in cs.values())
    assert max(worst["speed"], worst["shipped"]) < 1e-4 < worst["default"], worst
    np.testing.assert_allclose(u["python"], u["speed"], rtol=1e-9, atol=1e-9)


def test_preparation_split_gives_the_same_plans():
    """RTI with the preparation phase moved to the held sample after each plan computes the same
    QP (same linearisation point and parameters here: noise-free N1), so the same actions."""
    x0 = M.steady_sliding(U0, P)
    x0[2] = 1.0
    acts = {}
    for prep in (True, False):
        c = _nmpc({"horizon": 10, "prepare_ahead": prep})
        plant = Plant(M, P, SimOptions(seed=0), sensors=None, x0=x0, u0=U0)
        out = []
        for k in range(40):
            a = c.step(k * 0.01, plant.measure(), _est(k * 0.01, plant.x))
            out.append((a.u["omega_ref"], a.u["n2"]))
            plant.step(_apply(M, U0, a))
        acts[prep] = np.array(out)
    assert np.ptp(acts[True][:, 0]) > 1e-3  # the controller moved
    np.testing.assert_allclose(acts[True], acts[False], rtol=1e-7, atol=1e-8)


def test_programme_jump_is_followed_within_the_rate_limit():
    """A jump of the speed programme larger than one rate-limited move stays feasible (the band
    is widened where it cannot be reached yet) and the set-point follows at the rate limit."""
    prog = lambda t: np.array([W0 + (6.0 if t >= 0.095 else 0.0), 20.0, 0.0])  # noqa: E731
    c = _nmpc({"horizon": 5, "setpoint_rate": 10.0}, programme=prog)
    x = M.steady_sliding(U0, P)
    wr = [c.step(k * 0.01, {"n1": 20.0, "n2": 0.0}, _est(k * 0.01, x)).u["omega_ref"] for k in range(40)]
    assert c.counts.failures == 0
    assert np.max(np.abs(np.diff(wr))) <= 10.0 * 0.05 + 1e-9
    assert wr[9] < W0 + 0.6 and wr[-1] > W0 + 2.0   # band is [W0 + 3, W0 + 9] after the jump


@pytest.mark.parametrize("use, factor", [(True, 1.5), (False, 1.0)])
def test_load_estimate_scales_the_friction_of_its_contact(use, factor, monkeypatch):
    """The EKF's ``load:pin1`` (a factor on R1's friction) reaches the prediction as R1's friction
    factor; a load state of a contact the rig does not have is ignored."""
    c = _nmpc({"horizon": 5, "use_load_estimate": use})
    seen = []
    orig = c.ocp.solve

    def spy(xa0, q, *args):
        seen.append(np.array(q[c.layout.q_fc:c.layout.q_fc + c.layout.n_fc]))
        return orig(xa0, q, *args)

    monkeypatch.setattr(c.ocp, "solve", spy)
    x = M.steady_sliding(U0, P)
    est = Estimate(0.0, np.concatenate([x, [1.5, 7.0]]), np.eye(M.nx + 2), M.states + ("load:pin1", "load:pin9"))
    a = c.step(0.0, {"n1": 20.0, "n2": 0.0}, est)
    assert a.status is Status.OK
    np.testing.assert_allclose(seen[0], [factor, 1.0])   # contact bodies R1 (pin1), R2 (pin2)


def test_held_normal_force_is_read_through_its_load_cell():
    """N1 and N2 are held at their load cells' readings corrected for the cells' gain and offset
    (the first reading as it is); a lost reading keeps the last deviation from the programme."""
    p = P.replace(n1_gain=2.0, n1_offset=1.0)
    c = make_controller({"kind": "nmpc", "horizon": 5, "compile": False, "inputs": "motor"}, _ctx(params=p))
    seen = []
    orig = c.ocp.solve
    c.ocp.solve = lambda xa0, q, *a: seen.append(q[:M.nu].copy()) or orig(xa0, q, *a)
    c.step(0.0, {"n1": 41.0, "n2": 3.0}, _est(0.0, M.steady_sliding(U0, P)))
    np.testing.assert_allclose(seen[0], [W0, 20.0, 3.0])
    c.step(0.05, {"n1": float("nan")}, _est(0.05, M.steady_sliding(U0, P)))
    np.testing.assert_allclose(seen[1], [W0, 20.0, 3.0])


def test_held_normal_force_filters_the_load_cell_noise_and_follows_the_programme_at_once():
    """Load-cell noise reaches the plan low-passed (time constant ``force_filter``): +-1 N of
    alternating noise on N1 moves the held force by < 0.1 N; a programme step of N1 (20 -> 30 N)
    reaches it in the same sample.  With ``force_filter = 0`` the raw reading is held."""
    prog = lambda t: np.array([W0, 20.0 if t < 1.0 else 30.0, 0.0])   # noqa: E731
    x = M.steady_sliding(U0, P)
    for tau, tol in ((0.2, 0.1), (0.0, None)):
        c = make_controller({"kind": "nmpc", "horizon": 5, "compile": False, "inputs": "motor", "force_filter": tau}, _ctx(programme=prog))
        seen = []
        orig = c.ocp.solve
        c.ocp.solve = lambda xa0, q, *a, seen=seen, orig=orig: seen.append(q[:M.nu].copy()) or orig(xa0, q, *a)
        for k in range(150):
            t = 0.01 * k
            c.step(t, {"n1": float(prog(t)[1]) + (1.0 if k % 2 else -1.0), "n2": 0.0}, _est(t, x))
        n1 = np.array([s[1] for s in seen])       # one plan every 5 samples: t = 0, 0.05, ...
        if tol is None:
            assert np.all(np.abs(np.abs(n1 - np.where(np.arange(len(n1)) < 20, 20.0, 30.0)) - 1.0) < 1e-9)
        else:
            assert np.max(np.abs(n1[12:20] - 20.0)) < tol   # the first reading (-1 N) has decayed
            assert abs(n1[20] - 30.0) < tol        # t = 1.0 s: the step of the programme, at once


def test_too_stiff_a_rig_for_the_interval_is_a_config_error():
    """The lead screw (seed 002) at dt = 0.05 s would need tens of thousands of RK4 substeps, and as
    many implicit ones (its friction falls steeply with speed: the implicit substep must resolve it)."""
    m = get_model("leadscrew")
    with pytest.raises(ConfigError, match=r"^nmpc\.substeps: rig 'leadscrew' needs \d+ implicit \(SDIRK2\) substeps "
                                          r"per 0.05 s interval .* the limit is 200"):
        make_controller({"kind": "nmpc", "compile": False, "dt": 0.05}, _ctx(model=m, programme=[40.3, 314.3]))


def test_a_rig_beyond_the_rk4_limit_gets_the_implicit_step():
    """A generated benchmark rig (tests/data/gen_1_5_rig.toml, 1 body on the bit-rock law) whose
    prediction needs 212 RK4 substeps per interval, more than MAX_SUBSTEPS: the NMPC predicts with
    the implicit step (its stage's Jacobians by the implicit function theorem) instead of being
    'not applicable', as it was in the generated set of 2026-11-28."""
    from pathlib import Path
    m = get_model(str(Path(__file__).parent / "data" / "gen_1_5_rig.toml"))
    c = make_controller({"kind": "nmpc", "compile": False},
                        _ctx(model=m, programme=[0.4372436599306485, 104157.96083718371], dt=0.002731362210862317))
    assert c.integration.method == "sdirk2" and c.nsub <= 4, c.integration.note
    assert "explicit RK4 would need 2" in c.integration.note
    assert c.ocp.stage_fn.n_instructions() < 200_000


def test_substeps_asked_beyond_the_limit_are_refused():
    m = get_model("leadscrew")
    with pytest.raises(ConfigError, match=r"substeps must be <= 200, got 201"):
        make_controller({"kind": "nmpc", "compile": False, "dt": 0.05, "substeps": 201},
                        _ctx(model=m, programme=[40.3, 314.3]))
