"""IPOPT with the exact Hessian on the NMPC's OCP: the reference the Gauss-Newton solvers are
checked against (tests/test_nmpc.py), 10-100 times slower (shared/CASADI-FACTS.md)."""

from __future__ import annotations

import casadi as ca
import numpy as np

from models.errors import SolverFailure
from models.status import Status
from mitigate.controllers.nmpc.layout import OCPSpec
from mitigate.controllers.nmpc.ocp import OCPSolver

__all__ = ["IpoptSolver"]


class IpoptSolver(OCPSolver):
    """The OCP as one NLP (multiple shooting, the mapped stage functions) solved by IPOPT, warm-
    started from the shifted plan and the last multipliers."""

    solver = "ipopt"
    compiled = False

    def __init__(self, model, spec: OCPSpec):
        super().__init__(model, spec)
        L, N = self.layout, self.N
        nz = L.nxa + L.nv
        w = ca.MX.sym("w", N * nz + L.nxa)
        q = ca.MX.sym("q", L.nq)
        Z = ca.reshape(w[:N * nz], nz, N)
        X, V = Z[:L.nxa, :], Z[L.nxa:, :]
        xN = w[N * nz:]
        xn = self.F.map(N)(X, V, ca.repmat(q, 1, N))
        r, l = self.cost_fn.map(N)(X, V, ca.repmat(q, 1, N))
        _, _, cN, _ = self.term_fn(xN, q)
        obj = 0.5 * ca.sumsqr(r) + ca.sum2(l) + cN
        gaps = xn - ca.horzcat(X[:, 1:], xN)
        rows = ca.DM(L.C) @ X + ca.DM(L.D) @ V
        self._ipopt = ca.nlpsol(f"{self.model.cname}_nmpc_ipopt", "ipopt",
                                {"x": w, "p": q, "f": obj, "g": ca.vec(ca.vertcat(gaps, rows))},
                                {"print_time": False, "error_on_fail": False,
                                 "ipopt": {"print_level": 0, "sb": "yes", "max_iter": 200, "tol": 1e-8,
                                           "warm_start_init_point": "yes"}})

    def _solve_impl(self, xa0, q, bnd):
        L, N = self.layout, self.N
        nz = L.nxa + L.nv
        lbv, ubv, lbw, ubw, dg = bnd
        lb = np.full((N + 1, nz), -np.inf)
        ub = np.full((N + 1, nz), np.inf)
        lb[:N, L.nxa:], ub[:N, L.nxa:] = lbv, ubv
        lb[0, :L.nxa] = ub[0, :L.nxa] = xa0
        if L.drive:
            lb[1:, L.i_wprev], ub[1:, L.i_wprev] = lbw, ubw
        lbx, ubx = lb.ravel()[:N * nz + L.nxa], ub.ravel()[:N * nz + L.nxa]
        lbg = np.zeros((N, L.nxa + L.ns))
        ubg = np.zeros((N, L.nxa + L.ns))
        lbg[:, L.nxa:], ubg[:, L.nxa:] = -dg, dg
        w0 = np.concatenate([np.hstack([self.X[:N], self.V]).ravel(), self.X[N]])
        w0[:L.nxa] = xa0
        args = dict(x0=w0, p=q, lbx=lbx, ubx=ubx, lbg=lbg.ravel(), ubg=ubg.ravel())
        if self._lam is not None:
            args["lam_g0"] = self._lam
        sol = self._ipopt(**args)
        st = self._ipopt.stats()
        if not st.get("success", False):
            raise SolverFailure(f"IPOPT failed: {st.get('return_status', '?')}")
        self._lam = np.array(sol["lam_g"]).ravel()
        w = np.array(sol["x"]).ravel()
        Z = w[:N * nz].reshape(N, nz)
        X = np.vstack([Z[:, :L.nxa], w[N * nz:]])
        V = Z[:, L.nxa:].copy()
        it = int(st.get("iter_count", 0))
        return X, V, float(sol["f"]), it, 0, Status.OK, f"ipopt: {st['return_status']} in {it} iterations"
