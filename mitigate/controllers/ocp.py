"""The NMPC optimal control problem of the 3-disc rig, and its solvers.

The OCP is a multiple-shooting problem over ``N`` intervals of ``dt`` [s], each
integrated by RK4 with ``nsub`` substeps (:func:`models.discretise.rk4`) on the
regularised rig3 model.  The state is augmented so that every cost and constraint
stays inside one stage (shared/CASADI-FACTS.md)::

    xa = [phi12, phi23, omega1, omega2, omega3, i, z,   (rig3 state)
          n2_act,                                        (servo pin force [N], 1st-order lag)
          omega_ref_prev, n2_prev]                       (previous input)
    du = [d omega_ref, d n2]                             (decision: input change per interval)
    u  = u_prev + du

Per-stage parameters ``q = [n1, omega_nom, omega_scale, n2_max, weights..., p...]``
(:meth:`OCPSpec.q`): the measured N1 [N] (held over the horizon), the nominal speed
[rad/s], the residual scales, the cost weights and the full rig3 parameter vector.

The cost is a least-squares sum plus a linear pin-force term (friction work at pin 2 is
linear in N2, and a linear cost leaves N2 exactly at zero when it does not pay)::

    sum_k 0.5 |r(xa_k, du_k)|^2 + c_n2 * n2_k   +  0.5 |r_N(xa_N)|^2

so Gauss-Newton gives a positive semi-definite Hessian at no extra cost.

Solvers (:class:`OCPSolver`):

- ``"rti"``: real-time iteration: one Gauss-Newton QP per call (hpipm by default),
  the stage function and its Jacobians compiled with gcc (on-disk cache);
- ``"sqp"``: the same Gauss-Newton SQP iterated to convergence;
- ``"ipopt"``: the default IPOPT setup (exact Hessian), as the reference.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca

from models.codegen import load_compiled
import numpy as np

from models.discretise import rk4
from models.errors import ConfigError, SolverFailure

__all__ = ["OCPSpec", "OCPSolver", "OCPResult", "stage_functions", "rk4_substeps_needed"]

NX = 7          # rig3 state
NXA = NX + 3    # augmented state
NU = 2          # [omega_ref, n2]


@dataclass(frozen=True, kw_only=True)
class OCPSpec:
    """Everything that defines the OCP's functions.

    Only the structural entries (dt, nsub, eps, tau_servo) enter the compiled code; the
    weights and scales travel in the parameter vector ``q`` (see :meth:`OCPSpec.q`), so
    one compiled library serves every tuning.  Residuals are scaled by ``omega_scale``
    [rad/s] and ``n2_max`` [N] so that the weights are dimensionless.
    """

    horizon: int
    dt: float
    nsub: int
    eps: float
    tau_servo: float
    n2_max: float
    omega_scale: float
    w_speed: float
    w_rel: float
    w_ref: float
    w_n2: float
    c_n2: float
    w_dref: float
    w_dn2: float
    w_terminal: float

    def q(self, n1: float, omega_nom: float, p) -> np.ndarray:
        """Stage parameters [n1, omega_nom, omega_scale, n2_max, 8 weights, p...]."""
        return np.concatenate([[n1, omega_nom, self.omega_scale, self.n2_max, self.w_speed, self.w_rel,
                                self.w_ref, self.w_n2, self.c_n2, self.w_dref, self.w_dn2, self.w_terminal],
                               np.asarray(p, float)])


NQ0 = 12  # entries of q before the model parameters


@dataclass(frozen=True)
class OCPResult:
    """One OCP solve: the plan (time on axis 0) and its status."""

    u: np.ndarray          # (N, 2) absolute inputs [omega_ref rad/s, n2 N]
    xa: np.ndarray         # (N+1, 10) predicted augmented states
    cost: float
    iterations: int
    status: str
    success: bool
    solve_time: float


def rk4_substeps_needed(model, params, dt: float, eps: float, n1_max: float, n2_max: float,
                        omega: float) -> int:
    """Substeps that keep RK4 stable over ``dt`` [s] (|h lambda| <= 2.5, lambda from the
    Jacobian at zero and at sliding speed, pin forces at their maximum)."""
    f = model.ode(eps)
    x = ca.SX.sym("x", NX)
    lam = 0.0
    u = np.array([omega, n1_max, n2_max])
    xs = model.sliding_guess(u, params)
    xu = ca.SX.sym("u", 3)
    J = ca.Function("J", [x, xu], [ca.jacobian(f(x, xu, params.vector()), x)])
    for w1 in (0.0, omega):
        for w2 in (0.0, omega):
            xx = xs.copy()
            xx[2], xx[3] = w1, w2
            lam = max(lam, float(np.max(np.abs(np.linalg.eigvals(np.array(J(xx, u)))))))
    return max(1, int(np.ceil(dt * lam / 2.5)))


def stage_functions(model, spec: OCPSpec) -> tuple[ca.Function, ca.Function, ca.Function, ca.Function]:
    """Named SX Functions of one stage.

    Returns
    -------
    F : (xa, du, q) -> xa_next, the discrete augmented dynamics
    cost : (xa, du, q) -> (r, l), stage residual and linear cost
    stage : (xa, du, q) -> (xn, A, B, H, g, r, l): dynamics, Jacobians, GN Hessian block
        (12x12, [xa; du] order), gradient of the stage cost, residual and linear cost
    term : (xa, q) -> (H, g, r): terminal GN Hessian block, gradient and residual
    """
    f = model.ode(spec.eps)
    n_p = model.n_p
    xa = ca.SX.sym("xa", NXA)
    du = ca.SX.sym("du", NU)
    q = ca.SX.sym("q", NQ0 + n_p)
    n1, wnom, p = q[0], q[1], q[NQ0:]
    ws, n2max, w_speed, w_rel, w_ref, w_n2, c_n2, w_dref, w_dn2, w_term = (q[j] for j in range(2, NQ0))
    u = xa[8:10] + du
    tau = spec.tau_servo

    def faug(x_, u_, p_):
        n2_in = x_[7] if tau > 0 else u_[1]
        xdot = f(x_[:NX], ca.vertcat(u_[0], n1, n2_in), p_)
        n2dot = (u_[1] - x_[7]) / tau if tau > 0 else 0 * x_[7]
        return ca.vertcat(xdot, n2dot, 0, 0)

    xn = rk4(faug, xa, u, p, spec.dt, spec.nsub)
    xn = ca.vertcat(xn[:NX], xn[7] if tau > 0 else u[1], u)
    F = ca.Function("nmpc_F", [xa, du, q], [xn], ["xa", "du", "q"], ["xa_next"])

    w1, w2, w3 = xa[2], xa[3], xa[4]
    r = ca.vertcat(
        w_speed * (w1 - wnom) / ws,
        w_rel * (w1 - w2) / ws,
        w_rel * (w2 - w3) / ws,
        w_ref * (u[0] - wnom) / ws,
        w_n2 * u[1] / n2max,
        w_dref * du[0] / ws,
        w_dn2 * du[1] / n2max,
    )
    lin = c_n2 * u[1] / n2max
    cost = ca.Function("nmpc_cost", [xa, du, q], [r, lin], ["xa", "du", "q"], ["r", "l"])
    z = ca.vertcat(xa, du)
    Jr = ca.jacobian(r, z)
    H = ca.densify(Jr.T @ Jr)
    g = ca.densify(Jr.T @ r + ca.jacobian(lin, z).T)
    stage = ca.Function("nmpc_stage", [xa, du, q],
                        [xn, ca.densify(ca.jacobian(xn, xa)), ca.densify(ca.jacobian(xn, du)), H, g, r, lin],
                        ["xa", "du", "q"], ["xn", "A", "B", "H", "g", "r", "l"])
    rN = w_term * ca.vertcat(w_speed * (w1 - wnom) / ws, w_rel * (w1 - w2) / ws, w_rel * (w2 - w3) / ws)
    JN = ca.jacobian(rN, xa)
    term = ca.Function("nmpc_term", [xa, q], [ca.densify(JN.T @ JN), ca.densify(JN.T @ rN), rN],
                       ["xa", "q"], ["H", "g", "r"])
    return F, cost, stage, term


def _compile(functions: list[ca.Function], tag: str) -> dict[str, ca.Function]:
    """Compile the stage functions with gcc -O1 (cached on disk, :mod:`models.codegen`) and load them."""
    try:
        return load_compiled(functions, "-O1", tag)
    except RuntimeError as exc:
        raise SolverFailure(f"compiling the NMPC stage failed: {exc}") from None


class OCPSolver:
    """Multiple-shooting OCP with a warm-started plan; ``solve(xa0, q, bounds)``.

    Parameters
    ----------
    model : rig3 model
    spec : OCPSpec
    solver : "rti" | "sqp" | "ipopt"
    compile : compile the stage functions (gcc, cached) for "rti"/"sqp"
    qp_solver : "hpipm" (structure exploiting), "qrqp" or "osqp"
    qp_tol : QP tolerance (hpipm residuals).  1e-5 is the default: hpipm needs 3 instead of 4
        iterations at N = 50, and the first move differs from a 1e-10 solution by < 3e-3 rad/s
        and < 0.04 N (BENCHMARKS.md; one speed count of the encoders at 10 ms is 0.63 rad/s).  "sqp" uses min(qp_tol, sqp_tol / 10) so that its step test can pass.
    sqp_max_iter, sqp_tol : Gauss-Newton iterations and step tolerance of "sqp"
    """

    def __init__(self, model, spec: OCPSpec, *, solver: str = "rti", compile: bool = True,
                 qp_solver: str = "hpipm", qp_tol: float = 1e-5, sqp_max_iter: int = 20, sqp_tol: float = 1e-6):
        self.spec = spec
        self.solver = solver
        self.N = N = spec.horizon
        self.nz = NXA + NU
        self.nw = N * self.nz + NXA
        self.qp_solver = qp_solver
        self.qp_tol = qp_tol if solver != "sqp" else min(qp_tol, 0.1 * sqp_tol)
        self.sqp_max_iter = sqp_max_iter
        self.sqp_tol = sqp_tol
        F, cost, stage, term = stage_functions(model, spec)
        self.F, self.cost_fn = F, cost
        self._stage, self._term = stage, term
        self._compiled = bool(compile and solver in ("rti", "sqp"))
        self._ix = np.array([k * self.nz + j for k in range(N + 1) for j in range(NXA)])
        self._iu = np.array([k * self.nz + NXA + j for k in range(N) for j in range(NU)])
        self.w = None   # current plan (primal), None until initialised
        self.lam_g = None
        self._prepared = None  # (q, qp data) linearised at the current w (RTI preparation phase)
        self._vb_key, self._vb = None, None  # cached variable-bound templates (_var_bounds)
        if solver in ("rti", "sqp"):
            self._build_qp()
        elif solver == "ipopt":
            self._build_ipopt()
        else:
            raise ConfigError(f"solver must be 'rti', 'sqp' or 'ipopt', got {solver!r}")

    # ------------------------------------------------------------------ QP build
    def _build_qp(self):
        """One Function evaluates every stage (compiled as one C call); the sparse QP
        matrices are filled from its dense blocks by precomputed nonzero maps in numpy
        (assembling them in MX/generated code scaled badly with N)."""
        N, nz = self.N, self.nz
        X = ca.MX.sym("X", NXA, N)
        U = ca.MX.sym("U", NU, N)
        xN = ca.MX.sym("xN", NXA)
        q = ca.MX.sym("q", self._stage.size1_in(2))
        xn, A, B, H, g, r, l = self._stage.map(N)(X, U, ca.repmat(q, 1, N))
        HN, gN, rN = self._term(xN, q)
        self._stages = ca.Function("nmpc_stages", [X, U, xN, q], [xn, A, B, H, g, r, l, HN, gN, rN],
                                   ["X", "U", "xN", "q"], ["xn", "A", "B", "H", "g", "r", "l", "HN", "gN", "rN"])
        if self._compiled:
            self._stages = _compile([self._stages], "nmpc_stages")["nmpc_stages"]
        # Hessian: block diagonal of dense blocks -> CCS nonzeros are the blocks column by column
        self._Hsp = ca.diagcat(*([ca.Sparsity.dense(nz, nz)] * N + [ca.Sparsity.dense(NXA, NXA)]))
        # constraint matrix rows per stage: gap (NXA rows) then u-band (NU rows); columns [x_k u_k x_k+1]
        Aph = ca.SX.sym("a", NXA, NXA * N)
        Bph = ca.SX.sym("b", NXA, NU * N)
        E = np.zeros((NU, NXA))
        E[:, 8:10] = np.eye(NU)
        rows = []
        for k in range(N):
            gap = ca.horzcat(Aph[:, k * NXA:(k + 1) * NXA], Bph[:, k * NU:(k + 1) * NU], -ca.SX.eye(NXA))
            band = ca.horzcat(ca.SX(ca.DM(E)), ca.SX.eye(NU), ca.SX(NU, NXA))
            blk = ca.vertcat(gap, band)
            left, right = k * nz, self.nw - (k * nz + nz + NXA)
            rows.append(ca.horzcat(ca.SX(blk.size1(), left), blk, ca.SX(blk.size1(), right)))
        Asx = ca.vertcat(*rows)
        self._Asp = Asx.sparsity()
        src = ca.vertcat(ca.vec(Aph), ca.vec(Bph))
        pos = {src[i].name(): i for i in range(src.numel())}
        idx, const = [], []
        for e in Asx.nonzeros():
            if e.is_symbolic():
                idx.append(pos[e.name()])
                const.append(0.0)
            else:
                idx.append(-1)
                const.append(float(e))
        self._a_idx = np.array(idx)
        self._a_const = np.array(const)
        self._a_sym = self._a_idx >= 0
        opts: dict = {"error_on_fail": False}
        if self.qp_solver == "hpipm":
            t = self.qp_tol
            opts.update(N=N, nx=[NXA] * (N + 1), nu=[NU] * N + [0], ng=[NU] * N + [0],
                        hpipm={"res_g_max": t, "res_b_max": t, "res_d_max": t, "res_m_max": t, "iter_max": 100,
                               "mode": "speed"})
        elif self.qp_solver == "qrqp":
            opts.update(print_iter=False, print_header=False, print_info=False)
        elif self.qp_solver == "osqp":
            opts.update(osqp={"verbose": False, "eps_abs": self.qp_tol, "eps_rel": self.qp_tol, "polish": True})
        else:
            raise ConfigError(f"qp_solver must be 'hpipm', 'qrqp' or 'osqp', got {self.qp_solver!r}")
        self._qp = ca.conic("nmpc_qp", self.qp_solver, {"h": self._Hsp, "a": self._Asp}, opts)

    # ------------------------------------------------------------------ IPOPT build
    def _build_ipopt(self):
        N, nz = self.N, self.nz
        w = ca.MX.sym("w", self.nw)
        q = ca.MX.sym("q", self.F.size1_in(2))
        Z = ca.reshape(w[:N * nz], nz, N)
        X, U = Z[:NXA, :], Z[NXA:, :]
        xN = w[N * nz:]
        xn = self.F.map(N)(X, U, ca.repmat(q, 1, N))
        r, l = self.cost_fn.map(N)(X, U, ca.repmat(q, 1, N))
        HN, gN, rN = self._term(xN, q)
        obj = 0.5 * ca.sumsqr(r) + ca.sum2(l) + 0.5 * ca.sumsqr(rN)
        gaps = xn - ca.horzcat(X[:, 1:], xN)
        E = ca.DM.zeros(NU, NXA)
        E[:, 8:10] = ca.DM.eye(NU)
        band = E @ X + U
        g = ca.vertcat(ca.vec(ca.vertcat(gaps, band)))
        self._ng = g.size1()
        self._ipopt = ca.nlpsol("nmpc_ipopt", "ipopt", {"x": w, "p": q, "f": obj, "g": g},
                                {"print_time": False, "error_on_fail": False,
                                 "ipopt": {"print_level": 0, "sb": "yes", "max_iter": 200,
                                           "warm_start_init_point": "yes", "tol": 1e-8}})

    # ------------------------------------------------------------------ plan handling
    def initialise(self, xa0: np.ndarray, q: np.ndarray) -> None:
        """Plan = hold the current input; states by forward simulation."""
        w = np.zeros(self.nw)
        x = np.asarray(xa0, float)
        Fq = self.F
        for k in range(self.N):
            w[k * self.nz:k * self.nz + NXA] = x
            x = np.array(Fq(x, np.zeros(NU), q)).ravel()
        w[self.N * self.nz:] = x
        self.w = w
        self.lam_g = None

    @property
    def prepared(self) -> bool:
        """Whether a preparation phase has linearised the current plan."""
        return self._prepared is not None

    def prepare(self, q) -> None:
        """RTI preparation phase: shift the plan by one interval and linearise there now, so the
        next :meth:`solve` only embeds the new initial state and solves the QP (feedback phase).
        The linearisation uses ``q`` as known now (N1 measured at the last plan)."""
        if self.w is None or self.solver == "ipopt":
            return
        self.shift(1)
        q = np.asarray(q, float)
        self._prepared = (q, self.qp_data(self.w, q))

    def shift(self, steps: int = 1) -> None:
        """Shift the plan by ``steps`` intervals (warm start); the tail repeats the last stage."""
        self._prepared = None
        if self.w is None or steps <= 0:
            return
        nz, N = self.nz, self.N
        s = min(steps, N)
        Z = self.w[:N * nz].reshape(N, nz)
        xN = self.w[N * nz:]
        Xall = np.vstack([Z[:, :NXA], xN])          # (N+1, NXA)
        Uall = Z[:, NXA:]                            # (N, NU)
        Xs = np.vstack([Xall[s:], np.repeat(Xall[-1:], s, axis=0)])
        Us = np.vstack([Uall[s:], np.zeros((s, NU))])
        w = np.empty(self.nw)
        w[:N * nz] = np.hstack([Xs[:N], Us]).ravel()
        w[N * nz:] = Xs[N]
        self.w = w
        self.lam_g = None

    def plan(self) -> tuple[np.ndarray, np.ndarray]:
        """Current plan: absolute inputs (N, 2) and states (N+1, NXA)."""
        N, nz = self.N, self.nz
        Z = self.w[:N * nz].reshape(N, nz)
        X = np.vstack([Z[:, :NXA], self.w[N * nz:]])
        U = Z[:, 8:10] + Z[:, NXA:]
        return U, X

    # ------------------------------------------------------------------ bounds
    def _var_bounds(self, rate):
        """Variable bound templates (absolute): du of every stage within +-rate*dt, states free
        (the initial state is set per call).  Cached: the rate limits rarely change."""
        step = np.asarray(rate, float) * self.spec.dt
        key = step.tobytes()
        if self._vb_key != key:
            N = self.N
            lbw = np.full(self.nw, -np.inf)
            ubw = np.full(self.nw, np.inf)
            lbw[:N * self.nz].reshape(N, self.nz)[:, NXA:] = -step   # views: the du of every stage
            ubw[:N * self.nz].reshape(N, self.nz)[:, NXA:] = step
            self._vb_key, self._vb = key, (lbw, ubw, step, np.arange(1, N + 1)[:, None] * step[None, :])
        return self._vb

    def _bounds(self, xa0, lo_u, hi_u, rate):
        """Variable bounds (absolute) and u-band bounds per stage; the band is widened where a
        rate-limited move from the previous input cannot reach it yet (always feasible)."""
        lbt, ubt, step, reach = self._var_bounds(rate)
        lbw, ubw = lbt.copy(), ubt.copy()
        lbw[:NXA] = ubw[:NXA] = xa0
        uprev = xa0[8:10][None, :]
        lo = np.minimum(lo_u[None, :], uprev + reach)
        hi = np.maximum(hi_u[None, :], uprev - reach)
        return lbw, ubw, lo, hi

    # ------------------------------------------------------------------ solve
    def solve(self, xa0, q, lo_u, hi_u, rate) -> OCPResult:
        """Solve (or take one RTI step of) the OCP from ``xa0`` with parameters ``q``.

        ``lo_u``, ``hi_u``: absolute input bounds [omega_ref rad/s, n2 N]; ``rate``: input
        rate limits [rad/s^2, N/s].  Raises :class:`SolverFailure` if the solver fails or
        returns a plan that violates the bounds.
        """
        t0 = time.perf_counter()
        xa0 = np.asarray(xa0, float)
        q = np.asarray(q, float)
        lo_u, hi_u = np.asarray(lo_u, float), np.asarray(hi_u, float)
        if self.w is None:
            self.initialise(xa0, q)
        lbw, ubw, lo, hi = self._bounds(xa0, lo_u, hi_u, rate)
        if self.solver == "ipopt":
            res = self._solve_ipopt(q, lbw, ubw, lo, hi)
        else:
            res = self._solve_gn(q, lbw, ubw, lo, hi)
        w_new, cost, iters, status = res
        if not np.all(np.isfinite(w_new)):
            raise SolverFailure(f"{self.solver}: non-finite plan ({status})")
        # bounds that can be violated: the initial state, |du| <= step and the u band (states are free)
        step = self._vb[2]
        U, X = _plan_from(w_new, self.N, self.nz)
        du = w_new[:self.N * self.nz].reshape(self.N, self.nz)[:, NXA:]
        viol = max(float(np.max(np.abs(w_new[:NXA] - xa0))), float(np.max(np.abs(du) - step)),
                   float(np.max(lo - U)), float(np.max(U - hi)))
        scale = max(1.0, float(np.max(np.abs(xa0))), float(np.max(step)))
        if viol > 1e-4 * scale:
            raise SolverFailure(f"{self.solver}: plan violates bounds by {viol:.3g} ({status})")
        self.w = w_new
        self._prepared = None
        return OCPResult(U, X, cost, iters, status, True, time.perf_counter() - t0)

    def qp_data(self, w, q):
        """Gauss-Newton QP at the plan ``w``: (H, g, A) as DM, gaps (N, NXA) = F(x_k,u_k) - x_{k+1}, cost."""
        N, nz = self.N, self.nz
        Z = w[:N * nz].reshape(N, nz)
        xN = w[N * nz:]
        out = self._stages(Z[:, :NXA].T, Z[:, NXA:].T, xN, q)
        xn, A, B, H, g, r, l, HN, gN, rN = (np.array(v) for v in out)
        hnz = np.concatenate([H.ravel(order="F"), HN.ravel(order="F")])
        src = np.concatenate([A.ravel(order="F"), B.ravel(order="F")])
        anz = self._a_const.copy()
        anz[self._a_sym] = src[self._a_idx[self._a_sym]]
        gq = np.concatenate([g.ravel(order="F"), gN.ravel()])
        Xnext = np.vstack([Z[1:, :NXA], xN[None, :]])
        gaps = xn.T - Xnext
        obj = 0.5 * float(np.sum(r ** 2)) + float(np.sum(l)) + 0.5 * float(np.sum(rN ** 2))
        # constraint rows per stage: gap (A dx + B du - dx+ = -(F - x+)) then the u band (set per call)
        lba = np.empty((N, NXA + NU))
        lba[:, :NXA] = -gaps
        uba = lba.copy()
        ucur = Z[:, 8:10] + Z[:, NXA:]
        return ca.DM(self._Hsp, hnz), gq, ca.DM(self._Asp, anz), (lba, uba, ucur), obj

    def _qp_step(self, w, q, lbw, ubw, lo, hi, data=None):
        H, g, A, (lba, uba, ucur), obj = self.qp_data(w, q) if data is None else data
        lba[:, NXA:] = lo - ucur
        uba[:, NXA:] = hi - ucur
        sol = self._qp(h=H, g=g, a=A, lba=lba.ravel(), uba=uba.ravel(), lbx=lbw - w, ubx=ubw - w)
        if not self._qp.stats()["success"]:
            raise SolverFailure(f"QP ({self.qp_solver}) failed: {self._qp.stats().get('return_status', '?')}")
        return sol["x"].full().ravel(), float(obj)

    def _solve_gn(self, q, lbw, ubw, lo, hi):
        # initial-value embedding: w keeps the plan's x0, the QP bound dx0 = xa0 - x0 moves it
        w = self.w.copy()
        iters = 0
        nmax = 1 if self.solver == "rti" else self.sqp_max_iter
        obj = np.nan
        status = "rti step" if self.solver == "rti" else "max_iter"
        prepared, self._prepared = self._prepared, None
        for it in range(nmax):
            data = prepared[1] if (it == 0 and prepared is not None) else None
            dw, obj = self._qp_step(w, q, lbw, ubw, lo, hi, data)
            w = w + dw
            iters += 1
            if self.solver == "sqp" and np.max(np.abs(dw)) < self.sqp_tol:
                status = "converged"
                break
        return w, obj, iters, status

    def _solve_ipopt(self, q, lbw, ubw, lo, hi):
        N = self.N
        lbg = np.zeros((N, NXA + NU))
        ubg = np.zeros((N, NXA + NU))
        lbg[:, NXA:], ubg[:, NXA:] = lo, hi
        w0 = self.w.copy()
        w0[:NXA] = lbw[:NXA]
        args = dict(x0=w0, p=q, lbx=lbw, ubx=ubw, lbg=lbg.ravel(), ubg=ubg.ravel())
        if self.lam_g is not None:
            args["lam_g0"] = self.lam_g
        sol = self._ipopt(**args)
        st = self._ipopt.stats()
        if not st.get("success", False):
            raise SolverFailure(f"IPOPT failed: {st.get('return_status', '?')}")
        self.lam_g = np.array(sol["lam_g"]).ravel()
        return np.array(sol["x"]).ravel(), float(sol["f"]), int(st.get("iter_count", 0)), st["return_status"]


def _plan_from(w, N, nz):
    Z = w[:N * nz].reshape(N, nz)
    X = np.vstack([Z[:, :NXA], w[N * nz:]])
    U = Z[:, 8:10] + Z[:, NXA:]
    return U, X
