"""The NMPC optimal control problem of the 3-disc rig, and its solvers.

The OCP is a multiple-shooting problem over ``N`` intervals of ``dt`` [s], each
integrated by RK4 with ``nsub`` substeps (:func:`models.discretise.rk4`) on the
regularised rig3 model.  The state is augmented so that every cost and constraint
stays inside one stage (shared/CASADI-FACTS.md)::

    xa = [phi12, phi23, omega1, omega2, omega3, i, z,   (rig3 state)
          n2_s,                                          (servo pin force [N], 1st-order lag tau)
          omega_ref_prev]                                (previous speed set-point [rad/s])
    v  = [d omega_ref, n2_cmd]                           (decision per interval)
    u  = [omega_ref_prev + d omega_ref, n2_cmd]          (applied inputs)

Constraints per stage: ``|d omega_ref| <= omega_rate dt`` and ``n2_cmd`` in [0, n2_max]
(simple bounds); ``omega_ref`` in its band and the servo's rate ``|n2_cmd - n2_s| / tau <=
n2_rate`` (two general rows, :func:`stage_rows`).  Limiting the servo's rate, not the
command's increments, is what the servo physically does, and it needs no previous-command
state: 9 augmented states instead of 10, which makes hpipm's Riccati recursion about a fifth
cheaper.  Without a servo model (``tau_servo = 0``) ``n2_s`` is the previous command and the
row limits the command's change per interval, ``|n2_cmd - n2_prev| <= n2_rate dt``.

Per-stage parameters ``q = [n1, omega_nom, omega_scale, n2_max, weights..., p...]``
(:meth:`OCPSpec.q`): the measured N1 [N] (held over the horizon), the nominal speed
[rad/s], the residual scales, the cost weights and the full rig3 parameter vector.

The cost is a least-squares sum plus a linear pin-force term (friction work at pin 2 is
linear in N2, and a linear cost leaves N2 exactly at zero when it does not pay)::

    sum_k 0.5 |r(xa_k, v_k)|^2 + c_n2 * n2_k   +  0.5 |r_N(xa_N)|^2

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

__all__ = ["OCPSpec", "OCPSolver", "OCPResult", "stage_functions", "stage_rows", "hold", "applied",
           "rk4_substeps_needed"]

NX = 7          # rig3 state
NXA = NX + 2    # augmented state [x, n2_s, omega_ref_prev]
NU = 2          # decision [d omega_ref, n2_cmd]
I_N2, I_WREF = 7, 8   # positions of the servo force and the previous set-point in xa
# general rows per stage: C xa + v = [omega_ref, n2_cmd - n2_s]
_C = np.zeros((NU, NXA))
_C[0, I_WREF] = 1.0
_C[1, I_N2] = -1.0


def stage_rows(xa, v):
    """The general constraint rows of a stage, ``[omega_ref, n2_cmd - n2_s]`` (numpy or CasADi)."""
    return _C @ xa + v


def hold(xa):
    """The decision ``v`` that holds the current inputs: no set-point change, command = servo force."""
    return np.array([0.0, float(xa[I_N2])])


def applied(xa, v):
    """Applied inputs ``[omega_ref, n2_cmd]`` of decision ``v`` at augmented state ``xa``."""
    return np.array([float(xa[I_WREF]) + float(v[0]), float(v[1])])


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

    def servo_step(self, n2_rate: float) -> float:
        """Largest ``|n2_cmd - n2_s|`` [N]: ``n2_rate tau`` (servo at its rate limit), or
        ``n2_rate dt`` without a servo model."""
        return float(n2_rate) * (self.tau_servo if self.tau_servo > 0 else self.dt)

    def q(self, n1: float, omega_nom: float, p) -> np.ndarray:
        """Stage parameters [n1, omega_nom, omega_scale, n2_max, 8 weights, p...]."""
        return np.concatenate([[n1, omega_nom, self.omega_scale, self.n2_max, self.w_speed, self.w_rel,
                                self.w_ref, self.w_n2, self.c_n2, self.w_dref, self.w_dn2, self.w_terminal],
                               np.asarray(p, float)])


NQ0 = 12  # entries of q before the model parameters


@dataclass(frozen=True)
class OCPResult:
    """One OCP solve: the plan (time on axis 0) and its status."""

    u: np.ndarray          # (N, 2) applied inputs [omega_ref rad/s, n2 command N]
    xa: np.ndarray         # (N+1, 9) predicted augmented states
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
    F : (xa, v, q) -> xa_next, the discrete augmented dynamics
    cost : (xa, v, q) -> (r, l), stage residual and linear cost
    stage : (xa, v, q) -> (xn, A, B, H, g, r, l): dynamics, Jacobians, GN Hessian block
        (11x11, [xa; v] order), gradient of the stage cost, residual and linear cost
    term : (xa, q) -> (H, g, r): terminal GN Hessian block, gradient and residual
    """
    f = model.ode(spec.eps)
    n_p = model.n_p
    xa = ca.SX.sym("xa", NXA)
    v = ca.SX.sym("v", NU)
    q = ca.SX.sym("q", NQ0 + n_p)
    n1, wnom, p = q[0], q[1], q[NQ0:]
    ws, n2max, w_speed, w_rel, w_ref, w_n2, c_n2, w_dref, w_dn2, w_term = (q[j] for j in range(2, NQ0))
    u = ca.vertcat(xa[I_WREF] + v[0], v[1])
    tau = spec.tau_servo

    def faug(x_, u_, p_):
        n2_in = x_[I_N2] if tau > 0 else u_[1]
        xdot = f(x_[:NX], ca.vertcat(u_[0], n1, n2_in), p_)
        n2dot = (u_[1] - x_[I_N2]) / tau if tau > 0 else 0 * x_[I_N2]
        return ca.vertcat(xdot, n2dot, 0)

    xn = rk4(faug, xa, u, p, spec.dt, spec.nsub)
    xn = ca.vertcat(xn[:NX], xn[I_N2] if tau > 0 else u[1], u[0])
    F = ca.Function("nmpc_F", [xa, v, q], [xn], ["xa", "v", "q"], ["xa_next"])

    w1, w2, w3 = xa[2], xa[3], xa[4]
    r = ca.vertcat(
        w_speed * (w1 - wnom) / ws,
        w_rel * (w1 - w2) / ws,
        w_rel * (w2 - w3) / ws,
        w_ref * (u[0] - wnom) / ws,
        w_n2 * u[1] / n2max,
        w_dref * v[0] / ws,
        w_dn2 * (v[1] - xa[I_N2]) / n2max,   # servo activity (tau * its rate)
    )
    lin = c_n2 * u[1] / n2max
    cost = ca.Function("nmpc_cost", [xa, v, q], [r, lin], ["xa", "v", "q"], ["r", "l"])
    z = ca.vertcat(xa, v)
    Jr = ca.jacobian(r, z)
    H = ca.densify(Jr.T @ Jr)
    g = ca.densify(Jr.T @ r + ca.jacobian(lin, z).T)
    stage = ca.Function("nmpc_stage", [xa, v, q],
                        [xn, ca.densify(ca.jacobian(xn, xa)), ca.densify(ca.jacobian(xn, v)), H, g, r, lin],
                        ["xa", "v", "q"], ["xn", "A", "B", "H", "g", "r", "l"])
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
        # constraint matrix rows per stage: gap (NXA rows) then the general rows (NU, stage_rows);
        # columns [x_k v_k x_k+1]
        Aph = ca.SX.sym("a", NXA, NXA * N)
        Bph = ca.SX.sym("b", NXA, NU * N)
        E = _C
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
        band = ca.DM(_C) @ X + U
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
        v = hold(x)
        for k in range(self.N):
            w[k * self.nz:k * self.nz + NXA] = x
            w[k * self.nz + NXA:(k + 1) * self.nz] = v
            x = np.array(Fq(x, v, q)).ravel()
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
        Us = np.vstack([Uall[s:], np.repeat([[0.0, Uall[-1, 1]]], s, axis=0)])  # tail holds the last inputs
        w = np.empty(self.nw)
        w[:N * nz] = np.hstack([Xs[:N], Us]).ravel()
        w[N * nz:] = Xs[N]
        self.w = w
        self.lam_g = None

    def plan(self) -> tuple[np.ndarray, np.ndarray]:
        """Current plan: applied inputs (N, 2) and states (N+1, NXA)."""
        return _plan_from(self.w, self.N, self.nz)

    # ------------------------------------------------------------------ bounds
    def _var_bounds(self, rate):
        """Templates of the decision bounds: ``|d omega_ref| <= omega_rate dt`` per stage, the
        states free (the initial state and the n2_cmd range are set per call), and the rows'
        reach per stage.  Cached: the rate limits rarely change."""
        rate = np.asarray(rate, float)
        key = rate.tobytes()
        if self._vb_key != key:
            N = self.N
            lbw = np.full(self.nw, -np.inf)
            ubw = np.full(self.nw, np.inf)
            dw = rate[0] * self.spec.dt
            lbw[:N * self.nz].reshape(N, self.nz)[:, NXA] = -dw   # views: d omega_ref of every stage
            ubw[:N * self.nz].reshape(N, self.nz)[:, NXA] = dw
            ds = self.spec.servo_step(rate[1])
            self._vb_key = key
            self._vb = (lbw, ubw, np.array([dw, ds]), np.arange(1, N + 1) * dw)
        return self._vb

    def input_range(self, xa0, lo_u, hi_u, rate):
        """Range of the first applied inputs ``[omega_ref, n2_cmd]``: the bounds ``lo_u``,
        ``hi_u``, the set-point's rate and the servo's rate from ``xa0``; a bound is widened
        where the rate limit cannot reach it yet, so the range is never empty."""
        _, _, (dw, ds), _ = self._var_bounds(rate)
        lo = np.array([max(lo_u[0], xa0[I_WREF] - dw), max(lo_u[1], xa0[I_N2] - ds)])
        hi = np.array([min(hi_u[0], xa0[I_WREF] + dw), min(hi_u[1], xa0[I_N2] + ds)])
        return np.minimum(lo, np.array([xa0[I_WREF] + dw, xa0[I_N2] + ds])), np.maximum(
            hi, np.array([xa0[I_WREF] - dw, xa0[I_N2] - ds]))

    def _bounds(self, xa0, lo_u, hi_u, rate):
        """Decision bounds (absolute) and the general rows' bounds per stage (N, 2).  The
        omega_ref band and the n2_cmd range are widened where a rate-limited move cannot
        reach them yet (always feasible)."""
        lbt, ubt, (dw, ds), reach = self._var_bounds(rate)
        lbw, ubw = lbt.copy(), ubt.copy()
        lbw[:NXA] = ubw[:NXA] = xa0
        n2s = xa0[I_N2]
        lbw[NXA + 1:self.N * self.nz:self.nz] = min(lo_u[1], n2s + ds)
        ubw[NXA + 1:self.N * self.nz:self.nz] = max(hi_u[1], n2s - ds)
        glo = np.empty((self.N, NU))
        ghi = np.empty((self.N, NU))
        glo[:, 0] = np.minimum(lo_u[0], xa0[I_WREF] + reach)
        ghi[:, 0] = np.maximum(hi_u[0], xa0[I_WREF] - reach)
        glo[:, 1], ghi[:, 1] = -ds, ds
        return lbw, ubw, glo, ghi

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
        # bounds that can be violated: the initial state, the decisions' and the rows' (states are free)
        U, X = _plan_from(w_new, self.N, self.nz)
        V = w_new[:self.N * self.nz].reshape(self.N, self.nz)[:, NXA:]
        G = V + X[:-1] @ _C.T
        vb = lbw[:self.N * self.nz].reshape(self.N, self.nz)[:, NXA:], ubw[:self.N * self.nz].reshape(self.N, self.nz)[:, NXA:]
        viol = max(float(np.max(np.abs(w_new[:NXA] - xa0))), float(np.max(vb[0] - V)), float(np.max(V - vb[1])),
                   float(np.max(lo - G)), float(np.max(G - hi)))
        scale = max(1.0, float(np.max(np.abs(xa0))), float(np.max(self._vb[2])))
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
        # constraint rows per stage: gap (A dx + B dv - dx+ = -(F - x+)) then the general rows (set per call)
        lba = np.empty((N, NXA + NU))
        lba[:, :NXA] = -gaps
        uba = lba.copy()
        gcur = Z[:, NXA:] + Z[:, :NXA] @ _C.T
        return ca.DM(self._Hsp, hnz), gq, ca.DM(self._Asp, anz), (lba, uba, gcur), obj

    def _qp_step(self, w, q, lbw, ubw, lo, hi, data=None):
        H, g, A, (lba, uba, gcur), obj = self.qp_data(w, q) if data is None else data
        lba[:, NXA:] = lo - gcur
        uba[:, NXA:] = hi - gcur
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
    U = np.column_stack([Z[:, I_WREF] + Z[:, NXA], Z[:, NXA + 1]])
    return U, X
