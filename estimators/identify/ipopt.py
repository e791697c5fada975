"""IPOPT on the same multiple-shooting problem, with the Gauss-Newton Hessian (cross-check solver).

The residuals and gaps of a :class:`~estimators.identify.shooting.ShootingProblem` are rebuilt
as a CasADi MX graph (the values-only sample function, mapped over the intervals and chained
over the samples of an interval), handed to IPOPT with the Hessian ``J^T J`` of the weighted
residuals (``hess_lag``) and the linear inequalities as general constraints.  Uncompiled and
10-20x slower than :func:`~estimators.identify.gauss_newton.solve_gn`; it reaches the same
optimum (tests/test_identify.py).  Errors in the variables are not supported here.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["IpoptResult", "solve_ipopt"]


@dataclass(frozen=True)
class IpoptResult:
    """What :func:`solve_ipopt` returns (``reason``: IPOPT's return status)."""

    w: np.ndarray
    iterations: int
    reason: str
    success: bool
    max_gap: float = 0.0


def solve_ipopt(prob, S_val: ca.Function, w0, G=None, h=None, *, max_iter: int = 100, tol: float = 1e-8,
                progress: bool = False, label: str = "identify") -> IpoptResult:
    """IPOPT (GN Hessian) on ``prob`` from ``w0``; ``G w[:nb] <= h`` as general constraints."""
    if prob.ne:
        raise ValueError("solve_ipopt does not support errors in the variables")
    nf, nb, nz, nx, N, M, ny = prob.nf, prob.nb, prob.nz, prob.nx, prob.Nint, prob.M, prob.ny
    nw = prob.nw
    w = ca.MX.sym("w", nw)
    th = w[:nf] * ca.DM(prob.th_scale)
    TH = ca.repmat(th, 1, N)
    P = ca.DM(prob._P)
    xs = ca.DM(prob.x_scale)
    nodes = ca.reshape(w[nb:nb + nx * prob.n_nodes], nx, prob.n_nodes) * ca.repmat(xs, 1, prob.n_nodes)
    X = nodes[:, list(prob.starts)]
    Fv = S_val.map(N, "thread", 2)
    res = []
    for k in range(M):
        X, Yk = Fv(X, ca.DM(prob.U[:, k, :].T), TH, P, prob.dt, prob.eps)      # Yk (ny, N)
        Yk = Yk.T                                                            # (N, ny)
        if nz:
            zsc = w[nf:nb] * ca.DM(prob.z_scale)
            cols = []
            for c in range(ny):
                zc = [zsc[int(j)] if j >= 0 else ca.MX(0) for j in prob.zmap[:, c]]
                cols.append(Yk[:, c] - ca.vertcat(*zc))
            Yk = ca.horzcat(*cols)
        res.append((Yk - ca.DM(prob.Ymeas[:, k, :])) * ca.DM(prob.wgt[:, k, :]))
    r = ca.vec(ca.horzcat(*res))
    gap = ca.vec((X - nodes[:, [s + 1 for s in prob.starts]]) / ca.repmat(xs, 1, N))
    G = np.zeros((0, nb)) if G is None else np.asarray(G, float)
    h = np.zeros(0) if h is None else np.asarray(h, float)
    lin = ca.mtimes(ca.DM(G), w[:nb]) if G.shape[0] else ca.MX(0, 1)
    gall = ca.vertcat(gap, lin)
    J_r = ca.jacobian(r, w)
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", gall.numel())
    pp = ca.MX.sym("pp", 0)
    hess = ca.Function("gn_hess", [w, pp, lam_f, lam_g], [ca.triu(lam_f * ca.mtimes(J_r.T, J_r))],
                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    its = {"n": 0}

    class _Cb(ca.Callback):
        def __init__(self):
            ca.Callback.__init__(self)
            self.construct("id_progress", {})

        def get_n_in(self):
            return ca.nlpsol_n_out()

        def get_n_out(self):
            return 1

        def get_name_in(self, i):
            return ca.nlpsol_out(i)

        def get_name_out(self, i):
            return "ret"

        def get_sparsity_in(self, i):
            n = ca.nlpsol_out(i)
            if n == "f":
                return ca.Sparsity.scalar()
            if n in ("x", "lam_x"):
                return ca.Sparsity.dense(nw)
            if n in ("g", "lam_g"):
                return ca.Sparsity.dense(gall.numel())
            return ca.Sparsity(0, 0)

        def eval(self, arg):
            its["n"] += 1
            if progress:
                sys.stderr.write(f"\r{label}: IPOPT iteration {its['n']:3d}, cost {float(arg[1]):.6g}   ")
                sys.stderr.flush()
            return [0]

    cb = _Cb()
    opts = {"hess_lag": hess, "print_time": False, "iteration_callback": cb,
            "ipopt": {"print_level": 0, "sb": "yes", "max_iter": max_iter, "tol": tol, "acceptable_tol": 1e-5,
                      "linear_solver": "mumps", "mu_strategy": "adaptive"}}
    solver = ca.nlpsol("identify_ipopt", "ipopt", {"x": w, "f": 0.5 * ca.dot(r, r), "g": gall}, opts)
    lbg = np.r_[np.zeros(gap.numel()), np.full(G.shape[0], -np.inf)]
    ubg = np.r_[np.zeros(gap.numel()), h]
    sol = solver(x0=w0, lbg=lbg, ubg=ubg)
    if progress:
        sys.stderr.write("\n")
    stats = solver.stats()
    wv = np.array(sol["x"]).ravel()
    status = str(stats.get("return_status", "unknown"))
    ok = bool(stats.get("success", False)) or status == "Solved_To_Acceptable_Level"
    gv = np.array(sol["g"]).ravel()[:gap.numel()]
    return IpoptResult(wv, int(stats.get("iter_count", its["n"])), status, ok,
                       float(np.max(np.abs(gv))) if gv.size else 0.0)
