"""Single shooting: the simulation-error refinement of a fit whose continuity gaps did not close.

Multiple shooting lets every interval start from a node of its own and asks the nodes to meet
(the continuity gaps); a model structurally simpler than the rig may never let them meet: the
solver stops with gaps open, and its parameters then belong to no trajectory of the model (the
1-DOF lab string: "the line search failed ... continuity gaps remain (largest 0.4)").  From there
the fit continues as a simulation-error fit: the decision variables are the parameters, the
encoder zeros and each log's initial state; the nodes are no longer free but the model's
simulation from that state through the logged inputs (the input corrections of errors in the
variables held at the multiple-shooting values), so every gap is zero by construction and the
parameters belong to one consistent trajectory.

:class:`SimulationError` is that problem in the form the constrained Gauss-Newton solver
(:func:`~estimators.identify.gauss_newton.solve_gn`) takes.  Its residuals and their Jacobian are
the multiple-shooting problem's on the simulated nodes, condensed: each node's sensitivity to the
parameters and the initial state follows the recursion ``dn_{k+1} = A_k dn_k + B_k dtheta``
through the gaps' Jacobian blocks, and ``J = J_border + J_nodes dn/dv``.  The covariance at the
end is the multiple-shooting formula on those nodes (gaps active: equal to the single-shooting one).

:func:`refine` runs it from a fit (from its multiple-shooting estimate, or from the fit's start where that
simulates the logs better) and returns the refined fit (status and message from
:func:`~estimators.identify.result.fit_status` with ``refined``: "best fit within the model" when
it converges).
"""

from __future__ import annotations

import time
from dataclasses import replace

import casadi as ca
import numpy as np
import scipy.sparse as sp

from estimators.identify.assemble import fit_result
from estimators.identify.continuation import attempt
from estimators.identify.gauss_newton import solve_gn

__all__ = ["SimulationError", "refine", "SS_METHOD"]

SS_METHOD = "single shooting (simulation error), from the multiple-shooting estimate"


class SimulationError:
    """The single-shooting problem of a :class:`~estimators.identify.shooting.ShootingProblem` (see the
    module docstring).

    Parameters
    ----------
    sh : the multiple-shooting problem (its scales, inputs, outputs and weights are kept)
    values : one sample's values-only function ``(x, u, th, p, dt, eps) -> (x_next, y)``
    intervals : per log, its number of shooting intervals (logs in ``sh``'s order)
    deltas : (Nint, ne) input corrections [SI] held fixed (errors in the variables), or None

    Decision vector (scaled as ``sh``'s): ``v = [theta; z; x0 of each log]``.
    """

    def __init__(self, sh, values: ca.Function, intervals, deltas=None):
        self.sh = sh
        self.nx, self.nf, self.nz = sh.nx, sh.nf, sh.nz
        self.nb = sh.nb
        self.intervals = [int(n) for n in intervals]
        self.n_logs = len(self.intervals)
        self.nw = self.nb + self.nx * self.n_logs
        self.first_node = np.cumsum([0] + [n + 1 for n in self.intervals[:-1]])
        self.first_interval = np.cumsum([0] + self.intervals[:-1])
        self.deltas = np.zeros((sh.Nint, sh.ne)) if deltas is None else np.asarray(deltas, float)
        self._values = values
        self._acc: dict[int, ca.Function] = {}
        nx, N = self.nx, sh.Nint
        # the gaps' Jacobian blocks of interval i: rows i nx .. (i+1) nx; node columns of its start
        rows = (np.arange(N)[:, None, None] * nx + np.arange(nx)[None, :, None]).repeat(nx, axis=2)
        cols = sh.nb + nx * sh.starts[:, None, None] + np.arange(nx)[None, None, :]
        self._a_rows, self._a_cols = rows.ravel(), np.broadcast_to(cols, (N, nx, nx)).ravel()
        self.eps = sh.eps

    # ------------------------------------------------------------------ the solver's interface
    def kkt_order(self, n_extra: int) -> np.ndarray:
        """No band to keep: the KKT unknowns in their own order."""
        return np.arange(self.nw + n_extra)

    def start(self, w_ms) -> np.ndarray:
        """``v`` from a multiple-shooting decision vector: its parameters, zeros and first nodes."""
        w_ms = np.asarray(w_ms, float)
        nodes = w_ms[self.sh.nb:self.sh.base_d].reshape(self.sh.n_nodes, self.nx)
        return np.concatenate([w_ms[:self.nb]] + [nodes[k] for k in self.first_node])

    def full(self, v) -> np.ndarray:
        """The multiple-shooting decision vector whose nodes are the simulation from ``v``."""
        sh = self.sh
        v = np.asarray(v, float)
        theta = v[:self.nf] * sh.th_scale
        nodes = np.empty((sh.n_nodes, self.nx))
        M = sh.M
        for j, (n_int, k0, i0) in enumerate(zip(self.intervals, self.first_node, self.first_interval)):
            x0 = v[self.nb + j * self.nx:self.nb + (j + 1) * self.nx] * sh.x_scale
            U = sh.U[i0:i0 + n_int].copy()
            if sh.ne:
                U[:, :, sh.eiv_idx] += self.deltas[i0:i0 + n_int, None, :]
            U = U.reshape(n_int * M, -1)
            n = U.shape[0]
            if n not in self._acc:
                self._acc[n] = self._values.mapaccum("simulate", n)
            th = np.repeat(theta[:, None], n, axis=1)
            P = np.repeat(sh.p_base[:, None], n, axis=1)
            X = np.asarray(self._acc[n](x0, U.T, th, P, np.full((1, n), sh.dt), np.full((1, n), self.eps))[0])
            nodes[k0] = x0
            nodes[k0 + 1:k0 + n_int + 1] = X[:, M - 1::M].T
        d = (self.deltas / sh.d_scale).ravel() if sh.ne else np.zeros(0)
        return np.concatenate([v[:self.nb], (nodes / sh.x_scale).ravel(), d])

    def evaluate(self, v, jac: bool = True):
        """``r, g, J, A, Ypred``: the residuals on the simulated trajectory, no gaps (``g`` empty, ``A`` 0 rows)."""
        sh = self.sh
        w = self.full(v)
        if not np.all(np.isfinite(w)):
            nan = np.full(sh.Nint * sh.M * sh.ny + sh.Nint * sh.ne, np.nan)
            return nan, np.zeros(0), None, None, None
        r, _, Jr, A, Ypred = sh.evaluate(w, jac=jac)
        if not jac:
            return r, np.zeros(0), None, None, Ypred
        return r, np.zeros(0), self._condense(Jr, A), sp.csc_matrix((0, self.nw)), Ypred

    def _condense(self, Jr, A) -> sp.csc_matrix:
        sh, nx, nb = self.sh, self.nx, self.nb
        A = A.tocsr()
        Ax = np.asarray(A[self._a_rows, self._a_cols]).reshape(sh.Nint, nx, nx)
        Ath = A[:, :self.nf].toarray().reshape(sh.Nint, nx, self.nf)
        S = np.zeros((sh.n_nodes, nx, self.nw))
        for j, (n_int, k0, i0) in enumerate(zip(self.intervals, self.first_node, self.first_interval)):
            S[k0, :, nb + j * nx:nb + (j + 1) * nx] = np.eye(nx)
            for i in range(i0, i0 + n_int):
                k = sh.starts[i]
                nxt = Ax[i] @ S[k]
                nxt[:, :self.nf] += Ath[i]
                S[k + 1] = nxt
        Jr = Jr.tocsc()
        J = Jr[:, :nb].toarray()
        J = np.hstack([J, np.zeros((J.shape[0], self.nw - nb))])
        J = J + Jr[:, nb:sh.base_d] @ S.reshape(sh.n_nodes * nx, self.nw)
        return sp.csc_matrix(J)


def refine(problem, fit, why: str):
    """``fit`` continued by single shooting (see the module docstring), or None when the refinement
    cannot start (the simulation from the fit's first node is not finite).

    Parameters
    ----------
    problem : the :class:`~estimators.identify.problem.IdentificationProblem` of ``fit``
    fit : a multiple-shooting fit whose gaps did not close
    why : how that fit ended (its message's first part), for the result's message
    """
    t_start = time.perf_counter()
    o = problem.options
    sh = problem.shooting()
    w_ms = problem.decision_vector(fit)
    deltas = sh.deltas(w_ms) if sh.ne else None
    ss = SimulationError(sh, problem.values_function, [d.nint for d in problem.data], deltas)
    # from the better simulation of two: the multiple-shooting end, or the fit's start (on the measured
    # paper slider the stalled end, v_s at its bound, simulated at 6.4 times the start's cost and its
    # refinement failed at once; from the start it converged in 8 iterations)
    starts = [ss.start(w_ms), ss.start(problem.decision_vector(None))]
    costs = []
    for v in starts:
        r = ss.evaluate(v, jac=False)[0]
        costs.append(0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf)
    if not np.isfinite(min(costs)):
        return None
    v0 = starts[int(np.argmin(costs))]
    origin = "the multiple-shooting estimate" if costs[0] <= costs[1] else \
        f"the fit's start (it simulates the logs at cost {costs[1]:.4g}, the multiple-shooting end {costs[0]:.4g})"
    G, h, _ = problem.scaled_constraints()
    # the direct fit and the continuation may both be refined from the fit's start: solved once
    key = (v0.tobytes(), None if deltas is None else np.asarray(deltas, float).tobytes())
    cache = problem.__dict__.setdefault("_refinements", {})
    reused = key in cache
    if not reused:
        cache[key] = solve_gn(ss, v0, G, h, max_iter=o.max_iter, tol=o.tol, trust_radius=o.trust_radius,
                              admissible=problem.rk4_stable)
    res = replace(cache[key], iterations=0) if reused else cache[key]    # (iterations: those that ran)
    if reused:
        origin += ", the same refinement as the other fit's (not run again)"
    w = ss.full(res.w)
    gap = fit.structure.max_gap if fit.structure is not None else float("nan")
    how = SS_METHOD.replace("the multiple-shooting estimate", origin)
    method = f"{fit.method}; then {how} (its gaps did not close: largest {gap:.2g}, scaled)"
    attempts = fit.attempts + (attempt(how, res, t_start),)
    out = fit_result(problem, sh, w, res, method=method, attempts=attempts, initial=fit.initial, t_start=t_start,
                     refined=f"{why}; largest continuity gap {gap:.2g} (scaled)")
    return replace(out, iterations=fit.iterations + res.iterations, wall_time=fit.wall_time + out.wall_time)
