"""Gauss-Newton solvers of the NMPC's OCP: real-time iteration ("rti", one QP per call, with a
preparation/feedback split) and the same SQP iterated to convergence ("sqp").

All N stages and the terminal stage, with their Jacobians and Gauss-Newton blocks, are one
Function (:class:`StageEvaluator`), compiled by gcc (cached on disk) and called through
preallocated buffers; the stage-wise QP goes to hpipm directly or to CasADi's ``conic``
(:mod:`mitigate.controllers.nmpc.qp`).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from models.codegen import CtypesFunction, compile_cached
from models.errors import SolverFailure
from models.status import Status
from mitigate.controllers.nmpc.layout import OCPSpec
from mitigate.controllers.nmpc.ocp import OCPSolver
from mitigate.controllers.nmpc.qp import make_qp

__all__ = ["GaussNewtonSolver", "StageEvaluator"]


class StageEvaluator:
    """All N stages and the terminal stage as one Function ``(X, V, xN, q) -> blocks``, either
    compiled (gcc, cached on disk; called through preallocated buffers) or as CasADi SX."""

    OUT = ("xn", "A", "B", "Q", "S", "R", "gx", "gv", "c", "QN", "gN", "cN")

    def __init__(self, stage: ca.Function, term: ca.Function, N: int, nxa: int, nv: int, nq: int, compiled: bool,
                 tag: str):
        X, V = ca.MX.sym("X", nxa, N), ca.MX.sym("V", nv, N)
        xN, q = ca.MX.sym("xN", nxa), ca.MX.sym("q", nq)
        xn, A, B, Q, S, R, gx, gv, c = stage.map(N)(X, V, ca.repmat(q, 1, N))
        QN, gN, cN, _ = term(xN, q)
        fn = ca.Function(tag, [X, V, xN, q], [xn, A, B, Q, S, R, gx, gv, ca.sum2(c), QN, gN, cN],
                         ["X", "V", "xN", "q"], list(self.OUT))
        self.fn = fn
        self.compiled = compiled
        if compiled:
            try:
                so = compile_cached([fn], "-O1", tag)
            except RuntimeError as exc:
                raise SolverFailure(f"compiling the NMPC stage failed: {exc}") from None
            self._c = CtypesFunction(so, fn)
            self.inputs = self._c.inputs
            self.outputs = self._c.outputs
        else:
            self.inputs = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
            self.outputs = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]

    def __call__(self) -> None:
        if self.compiled:
            self._c()
            return
        args = [ca.DM(self.fn.sparsity_in(i), b) for i, b in enumerate(self.inputs)]
        for buf, val in zip(self.outputs, self.fn(*args)):
            buf[:] = np.array(val).ravel(order="F")


class GaussNewtonSolver(OCPSolver):
    """Gauss-Newton RTI (``iterate=False``: one QP per :meth:`solve`, :meth:`prepare` linearises
    ahead) or SQP to convergence (``iterate=True``); arguments as
    :func:`mitigate.controllers.nmpc.solvers.make_ocp_solver`."""

    def __init__(self, model, spec: OCPSpec, *, iterate: bool = False, compile: bool = True,
                 qp_solver: str = "hpipm", qp_tol: float = 1e-7, sqp_max_iter: int = 20, sqp_tol: float = 1e-6,
                 qp_mode: str = "speed_abs", qp_mu0: float | None = None):
        super().__init__(model, spec)
        self.solver = "sqp" if iterate else "rti"
        L, N = self.layout, self.N
        self.qp_solver = qp_solver
        self.qp_tol = min(qp_tol, 0.1 * sqp_tol) if iterate else qp_tol
        self.sqp_max_iter, self.sqp_tol = sqp_max_iter, sqp_tol
        self.compiled = bool(compile)
        idxbx = [L.i_wprev] if L.drive else []
        self.qp = make_qp(qp_solver, N, L.nxa, L.nv, idxbx, np.arange(L.nv), L.C, L.D, tol=self.qp_tol,
                          mode=qp_mode, mu0=qp_mu0)
        self._ev = StageEvaluator(self.stage_fn, self.term_fn, N, L.nxa, L.nv, L.nq, self.compiled,
                                  f"{model.cname}_nmpc_N{N}")
        self._cost = np.nan

    @property
    def evaluator(self) -> StageEvaluator:
        """All stages' Gauss-Newton blocks as one Function (what the compiled step calls)."""
        return self._ev

    # ------------------------------------------------------------------ linearisation
    def _linearise(self, q) -> None:
        """Evaluate all stages at the plan and fill the QP's dynamics and cost blocks."""
        ev, qp, N = self._ev, self.qp, self.N
        ins, out = ev.inputs, ev.outputs
        ins[0][:] = self.X[:N].ravel()
        ins[1][:] = self.V.ravel()
        ins[2][:] = self.X[N]
        ins[3][:] = q
        ev()
        xn = out[0].reshape(N, -1)
        np.subtract(xn, self.X[1:], out=qp.b)
        qp.A[:] = out[1].reshape(N, -1)
        qp.B[:] = out[2].reshape(N, -1)
        qp.Q[:N] = out[3].reshape(N, -1)
        qp.S[:] = out[4].reshape(N, -1)
        qp.R[:] = out[5].reshape(N, -1)
        qp.q[:N] = out[6].reshape(N, -1)
        qp.r[:] = out[7].reshape(N, -1)
        qp.Q[N] = out[9]
        qp.q[N] = out[10]
        self._cost = float(out[8][0] + out[11][0])

    def prepare(self, q) -> None:
        """RTI preparation phase: shift the plan by one interval and linearise there now, so the
        next :meth:`solve` only embeds the new initial state and solves the QP (feedback phase).
        The linearisation uses ``q`` as known now."""
        if self.X is None:
            return
        self.shift(1)
        self._linearise(np.asarray(q, float))
        self._prepared = True

    def _qp_step(self, xa0, bnd) -> None:
        """Bounds relative to the linearisation point, then one QP; the step goes to the plan."""
        L, qp, X, V = self.layout, self.qp, self.X, self.V
        lbv, ubv, lbw, ubw, dg = bnd
        np.subtract(xa0, X[0], out=qp.lbx0)
        qp.ubx0[:] = qp.lbx0
        np.subtract(lbv, V, out=qp.lbu)
        np.subtract(ubv, V, out=qp.ubu)
        if L.drive:
            qp.lbx[:, 0] = lbw - X[1:, L.i_wprev]
            qp.ubx[:, 0] = ubw - X[1:, L.i_wprev]
        if L.ns:
            g = V[:, L.j_cmd] - X[:-1, L.i_servo]
            np.subtract(-dg, g, out=qp.lg)
            np.subtract(dg, g, out=qp.ug)
        qp.solve()

    def _solve_impl(self, xa0, q, bnd):
        X, V = self.X, self.V
        nmax = 1 if self.solver == "rti" else self.sqp_max_iter
        status, msg = Status.OK, "rti step"
        it = 0
        for it in range(1, nmax + 1):
            if not (it == 1 and self._prepared):
                self._linearise(q)
            self._prepared = False
            self._qp_step(xa0, bnd)
            X += self.qp.x
            V += self.qp.u
            if self.solver == "sqp":
                step = max(np.abs(self.qp.x).max(), np.abs(self.qp.u).max())
                if step < self.sqp_tol:
                    msg = f"converged in {it} Gauss-Newton iterations"
                    break
        else:
            if self.solver == "sqp":
                status, msg = Status.NOT_CONVERGED, f"sqp: {nmax} iterations, last step {step:.2g}"
        return X, V, self._cost, it, self.qp.iterations, status, msg
