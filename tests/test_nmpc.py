"""NMPC of the 3-disc rig (mitigate.controllers.nmpc / ocp).

Independent checks: the RTI step at an equilibrium against a discrete LQR (numpy Riccati
recursion, itself checked against python-control ``dlqr``); Gauss-Newton SQP against
IPOPT on the same NLP; the fallback chain; bounds and rate limits in closed loop; and
stick-slip of R1 suppressed on the exact stick/slip plant (N1 = 20 N, 30 rpm).
No compilation here (``compile=False``).
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.base import Estimate
from mitigate.controllers.nmpc import NMPCOptions, make_nmpc
from mitigate.controllers.ocp import NU, NXA, applied, hold, stage_functions
from mitigate.metrics import severity
from models import get_model
from models.actuators import ServoOptions
from models.errors import ConfigError
from models.plant import Plant, SimOptions

M = get_model("rig3")
P = M.published()
W0 = np.pi  # 30 rpm [rad/s]


def _est(t, x):
    return Estimate(t=t, x=np.asarray(x, float).copy(), P=None, names=M.states, status="ok", success=True)


# ----------------------------------------------------------------------------- options
@pytest.mark.parametrize("opts, match", [
    ({"horizon": 1}, r"controllers\[3\]\.horizon must be an integer >= 2"),
    ({"dt": -0.05}, r"controllers\[3\]\.dt \[s\] must be > 0"),
    ({"solver": "acados"}, r"controllers\[3\]\.solver must be one of rti, sqp, ipopt"),
    ({"qp_solver": "gurobi"}, r"controllers\[3\]\.qp_solver"),
    ({"weights": {"speed": -1.0}}, r"controllers\[3\]\.weights\.speed must be >= 0"),
    ({"weights": {"spead": 1.0}}, r"controllers\[3\]\.weights: unknown weight"),
    ({"horizn": 20}, r"controllers\[3\]: unknown NMPC option"),
    ({"compile": "yes"}, r"controllers\[3\]\.compile must be true or false"),
])
def test_bad_options_name_the_field(opts, match):
    with pytest.raises(ConfigError, match=match):
        make_nmpc(opts, P, 0.01, W0, ServoOptions(), "controllers[3]")


def test_dt_shorter_than_daq_is_rejected():
    with pytest.raises(ConfigError, match=r"nmpc\.dt must be >= the DAQ period"):
        make_nmpc({"dt": 0.005, "compile": False}, P, 0.01, W0, ServoOptions(), "nmpc")


def test_options_defaults_are_valid():
    o = NMPCOptions.from_mapping({"weights": {"speed": 2.0}}, "x")
    assert o.weights.speed == 2.0 and o.solver == "rti" and o.horizon == 20


# ----------------------------------------------------------------------------- LQR
def _riccati_first_gain(A, B, Q, R, S, QN, N):
    """Finite-horizon discrete LQR, cost sum x'Qx + 2x'Su + u'Ru + x_N'QN x_N: gain K_0 (u = -K x)."""
    Pk = QN
    K = None
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
    opts = {"horizon": 15, "compile": False, "qp_solver": QP, "omega_band": 3.0, "omega_rate": 1e3, "n2_rate": 1e4,
            "weights": {"speed": 1.0, "rel": 0.5, "ref": 0.3, "n2": 0.0, "n2_linear": 0.0, "d_ref": 0.5,
                        "d_n2": 0.5, "terminal": 2.0}}
    c = make_nmpc(opts, P, 0.01, wn, ServoOptions(), "nmpc")
    spec, ocp = c.spec, c.ocp
    xs = M.steady_sliding([wn, 20.0, n2], P)
    xa_eq = np.concatenate([xs, [n2, wn]])
    v_eq = hold(xa_eq)
    q = spec.q(20.0, wn, P.vector())
    F, cost, _, term = stage_functions(M, spec)
    # the equilibrium is a fixed point of the discrete model with zero cost
    assert np.allclose(np.array(F(xa_eq, v_eq, q)).ravel(), xa_eq, atol=1e-8)
    import casadi as ca
    xa, du = ca.SX.sym("xa", NXA), ca.SX.sym("du", NU)
    xn = F(xa, du, q)
    r, _ = cost(xa, du, q)
    _, _, rN = term(xa, q)
    lin = ca.Function("lin", [xa, du], [ca.jacobian(xn, xa), ca.jacobian(xn, du), ca.jacobian(r, xa),
                                        ca.jacobian(r, du), ca.jacobian(rN, xa)])
    A, B, Jx, Ju, JN = (np.array(v) for v in lin(xa_eq, v_eq))
    Q, R, S, QN = Jx.T @ Jx, Ju.T @ Ju, Jx.T @ Ju, JN.T @ JN
    K0, _ = _riccati_first_gain(A, B, Q, R, S, QN, spec.horizon)
    # the recursion itself against python-control's dlqr (long horizon, regularised Q)
    Qr = Q + 1e-6 * np.eye(NXA)
    K_inf, _, _ = control.dlqr(A, B, Qr, R, S)
    K_long, _ = _riccati_first_gain(A, B, Qr, R, S, Qr, 3000)
    assert np.allclose(K_long, K_inf, rtol=1e-4, atol=1e-6)

    dx = np.zeros(NXA)
    dx[2], dx[0] = 0.02, 0.002  # omega1 +0.02 rad/s, twist +2 mrad
    ocp.w = np.concatenate([np.tile(np.concatenate([xa_eq, v_eq]), spec.horizon), xa_eq])
    lo, hi = np.array([wn - 3, 0.0]), np.array([wn + 3, 40.0])
    res = ocp.solve(xa_eq + dx, q, lo, hi, np.array([1e3, 1e4]))
    du_nmpc = res.u[0] - applied(xa_eq, v_eq)  # = v_0 - v_eq (the deviation leaves n2_s, omega_ref_prev alone)
    du_lqr = -K0 @ dx
    assert np.abs(du_lqr).max() > 1e-3  # a real move, not a trivial zero
    # qrqp (active set) solves the QP exactly; hpipm (interior point) stops at ~1e-6 residuals
    atol = 2e-5 if QP == "qrqp" else 1e-3 * np.abs(du_lqr).max()
    np.testing.assert_allclose(du_nmpc, du_lqr, rtol=2e-3, atol=atol)


# ----------------------------------------------------------------------------- SQP vs IPOPT
def test_gauss_newton_sqp_agrees_with_ipopt():
    x0 = M.steady_sliding([W0, 20.0, 0.0], P)
    x0[2] = 0.5  # R1 slowed down (deviation of 2.6 rad/s)
    meas = {"n1": 20.0, "n2": 0.0, "omega_ref": W0}
    moves = {}
    for solver in ("sqp", "ipopt"):
        c = make_nmpc({"horizon": 10, "compile": False, "solver": solver, "sqp_max_iter": 50}, P, 0.01, W0,
                      ServoOptions(), "nmpc")
        a = c.step(0.0, _est(0.0, x0), meas)
        assert a.success, a.status
        moves[solver] = (a.omega_ref, a.n2, c.last_result.cost)
    (w_s, n_s, j_s), (w_i, n_i, j_i) = moves["sqp"], moves["ipopt"]
    assert abs(w_s - w_i) < 1e-3 and abs(n_s - n_i) < 1e-2
    assert abs(j_s - j_i) <= 1e-4 * max(1.0, abs(j_i))


# ----------------------------------------------------------------------------- fallbacks
def test_fallback_chain_shift_then_baseline_is_counted():
    c = make_nmpc({"horizon": 5, "compile": False}, P, 0.01, W0, ServoOptions(), "nmpc")
    x = M.steady_sliding([W0, 20.0, 0.0], P)
    meas = {"n1": 20.0, "n2": 0.0, "omega_ref": W0}
    t_fail = 0.1
    c.inject_failure = lambda t: t >= t_fail - 1e-9
    acts = [c.step(k * 0.01, _est(k * 0.01, x), meas) for k in range(60)]
    solves = [a for k, a in enumerate(acts) if k % 5 == 0]        # plans every 0.05 s
    assert all(a.success for a in solves[:2])                      # t = 0, 0.05
    # failed solves at t = 0.10 .. 0.25 use the plan of t = 0.05 at indices 1..4
    assert [a.fallback for a in solves[2:6]] == ["shift"] * 4
    assert all(not a.success for a in solves[2:])
    # t = 0.30: index 5 is past the 5-interval plan -> baseline (a)
    assert all(a.fallback == "baseline" for a in solves[6:])
    assert all(a.n2 == 0.0 and a.omega_ref == W0 for a in solves[6:])
    n_fail = len(solves) - 2
    assert c.counts.failures == n_fail
    assert c.counts.fallbacks_shift == 4
    assert c.counts.fallbacks_baseline == n_fail - 4
    assert c.counts.steps == 60
    # held actions between plans repeat the last action without being counted again
    assert acts[11].n2 == acts[10].n2 and acts[11].fallback == ""


def test_no_estimate_goes_to_baseline_without_raising():
    c = make_nmpc({"horizon": 5, "compile": False}, P, 0.01, W0, ServoOptions(), "nmpc")
    a = c.step(0.0, None, {"n1": 20.0})
    assert a.fallback == "baseline" and not a.success and c.counts.failures == 1


# ----------------------------------------------------------------------------- closed loop
@pytest.fixture(scope="module")
def stick_slip_runs():
    """Stick-slip established from rest (10 s, N1 = 20 N, 30 rpm), then 8 s without / with NMPC."""
    servo = ServoOptions()
    base = Plant(M, P, SimOptions(seed=0), sensors=None, servo=servo)
    for _ in range(1000):
        base.step([W0, 20.0, 0.0])
    x_start, t_start = base.x.copy(), base.t
    n = 800
    free = Plant(M, P, SimOptions(seed=0), sensors=None, servo=servo, x0=x_start)
    w_free = np.array([free.step([W0, 20.0, 0.0]) and free.x[2] for _ in range(n)])
    plant = Plant(M, P, SimOptions(seed=0), sensors=None, servo=servo, x0=x_start)
    c = make_nmpc({"horizon": 20, "compile": False}, P, 0.01, W0, servo, "nmpc")
    w1, cmds = [], []
    for k in range(n):
        t = t_start + k * 0.01
        force = plant.u_applied[2]  # the servo's force when the command is computed
        a = c.step(t, _est(t, plant.x), plant.measure())
        cmds.append((t, a.omega_ref, a.n2, force))
        plant.step([a.omega_ref, 20.0, a.n2])
        w1.append(plant.x[2])
    return dict(w_free=w_free, w1=np.array(w1), cmds=np.array(cmds), c=c, servo=servo)


def test_stick_slip_of_r1_suppressed(stick_slip_runs):
    r = stick_slip_runs
    tail = slice(-300, None)  # last 3 s
    s_free, s_nmpc = severity(r["w_free"][tail]), severity(r["w1"][tail])
    assert s_free > 0.8          # established stick-slip without control
    assert s_nmpc < 0.1 * s_free  # NMPC brings R1 back to steady sliding
    assert abs(np.mean(r["w1"][tail]) - W0) < 0.05 * W0  # and keeps the mean speed
    assert r["c"].counts.failures == 0


def test_inputs_respect_bounds_and_rate_limits(stick_slip_runs):
    r = stick_slip_runs
    c, servo = r["c"], r["servo"]
    t, wref, n2, force = r["cmds"].T
    o = c.options
    assert np.all(n2 >= -1e-9) and np.all(n2 <= servo.n_max + 1e-9)
    assert np.all(np.abs(wref - W0) <= o.omega_band + 1e-9) and np.all(wref >= 0)
    assert np.max(n2) > 0.5 or np.max(np.abs(wref - W0)) > 0.05  # it did act
    # changes happen only at plan times (every dt); omega_ref by at most rate * dt; a new N2
    # command asks the servo for at most its rate limit: |command - force| <= n2_rate * tau
    d_w, d_n = np.abs(np.diff(wref)), np.abs(np.diff(n2))
    assert np.all(d_w <= o.omega_rate * o.dt * (1 + 1e-6) + 1e-9)
    plans = np.arange(0, len(t), 5)
    assert np.all(np.abs(n2 - force)[plans] <= c.n2_rate * servo.tau * (1 + 1e-6) + 1e-9)
    assert np.max(np.abs(n2 - force)[plans]) > 0.3 * c.n2_rate * servo.tau  # the limit is approached
    changed = np.nonzero((d_w > 1e-12) | (d_n > 1e-12))[0] + 1
    assert np.all(changed % 5 == 0)


def test_preparation_split_gives_the_same_plans():
    """RTI with the preparation phase moved to the held sample after each plan computes the same
    QP (same linearisation point and parameters here: noise-free N1), so the same actions."""
    x0 = M.steady_sliding([W0, 20.0, 0.0], P)
    x0[2] = 1.0
    acts = {}
    for prep in (True, False):
        c = make_nmpc({"horizon": 10, "compile": False, "prepare_ahead": prep}, P, 0.01, W0, ServoOptions(), "n")
        plant = Plant(M, P, SimOptions(seed=0), sensors=None, servo=ServoOptions(), x0=x0)
        out = []
        for k in range(40):
            a = c.step(k * 0.01, _est(k * 0.01, plant.x), {"n1": 20.0, "n2": plant.u_applied[2], "omega_ref": W0})
            out.append((a.omega_ref, a.n2))
            plant.step([a.omega_ref, 20.0, a.n2])
        acts[prep] = np.array(out)
    assert np.ptp(acts[True][:, 0]) > 1e-3  # the controller moved
    np.testing.assert_allclose(acts[True], acts[False], rtol=1e-7, atol=1e-8)


def test_nominal_jump_is_followed_within_the_rate_limit():
    """A speed-programme jump larger than one rate-limited move stays feasible (the band is
    widened where it cannot be reached yet) and omega_ref follows at the rate limit."""
    c = make_nmpc({"horizon": 5, "compile": False, "omega_rate": 10.0}, P, 0.01, W0, ServoOptions(), "n")
    x = M.steady_sliding([W0, 20.0, 0.0], P)
    meas = {"n1": 20.0, "n2": 0.0, "omega_ref": W0}
    wr = [c.step(k * 0.01, _est(k * 0.01, x), meas).omega_ref for k in range(10)]
    c.set_nominal(W0 + 6.0)   # band is now [W0 + 3, W0 + 9]: W0 is 3 rad/s outside it
    wr += [c.step(k * 0.01, _est(k * 0.01, x), meas).omega_ref for k in range(10, 40)]
    assert c.counts.failures == 0
    assert np.max(np.abs(np.diff(wr))) <= 10.0 * 0.05 + 1e-9
    assert wr[-1] > W0 + 2.0


@pytest.mark.parametrize("use, expected", [(True, 1.5 * 20.0), (False, 20.0)])
def test_load_estimate_scales_the_predicted_n1(use, expected, monkeypatch):
    # the EKF/MHE state load1 multiplies N1 in their model; the NMPC predicts with the same factor
    c = make_nmpc({"horizon": 5, "compile": False, "use_load_estimate": use}, P, 0.01, W0, ServoOptions(), "nmpc")
    seen = []
    q_orig = type(c.spec).q

    def spy(self, n1, *args):
        seen.append(n1)
        return q_orig(self, n1, *args)

    monkeypatch.setattr(type(c.spec), "q", spy)
    x = get_model("rig3").steady_sliding([W0, 20.0, 0.0], P)
    est = Estimate(0.0, np.concatenate([x, [1.5]]), np.eye(8), get_model("rig3").states + ("load1",))
    a = c.step(0.0, est, {"n1": 20.0, "omega_ref": W0})
    assert a.success
    assert seen and seen[0] == pytest.approx(expected)


def test_default_qp_tolerance_moves_like_a_tight_solve():
    """The default hpipm tolerance (1e-5, chosen for speed) changes the applied first move by
    less than 3e-3 rad/s and 0.04 N against an exact active-set solve (qrqp) of the same QP,
    from states in stick-slip."""
    x0 = M.steady_sliding([W0, 20.0, 0.0], P)
    meas = {"n1": 20.0, "n2": 0.0, "omega_ref": W0}
    for w1, phi12 in ((0.0, 0.25), (5.0, -0.1), (1.0, 0.0)):
        x = x0.copy()
        x[2], x[0] = w1, x0[0] + phi12
        moves = []
        for qp in ({}, {"qp_solver": "qrqp"}):
            c = make_nmpc({"horizon": 50, "compile": False, **qp}, P, 0.01, W0, ServoOptions(), "n")
            a = c.step(0.0, _est(0.0, x), meas)
            assert a.success, a.status
            moves.append((a.omega_ref, a.n2))
        (w_d, n_d), (w_t, n_t) = moves
        assert abs(w_d - w_t) < 3e-3 and abs(n_d - n_t) < 0.04
        assert abs(w_t - W0) > 1e-3 or n_t > 1e-3  # a real move
