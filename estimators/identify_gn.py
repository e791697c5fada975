"""Hand-written constrained Gauss-Newton for multiple-shooting identification.

Used by :func:`estimators.identify.identify` (``solver="gn"``, the default).

- :func:`sample_function`: ONE DAQ sample of the regularised model (RK4, ``nsub`` substeps,
  zero-order-hold input, speeds averaged over the sample by quadrature) with its forward
  sensitivities: ``S(x, u, p, dt, eps) -> (x_next, y, A, B, C, D)`` with
  ``A = dx_next/dx``, ``B = dx_next/dp``, ``C = dy/dx``, ``D = dy/dp`` (``p`` the full
  parameter vector).  ``dt`` and ``eps`` are inputs, so one compiled library serves every
  sample period and regularisation of a model / substep count / output set.
- :func:`compiled_or_none`: the same Function generated to C, built with gcc and cached on
  disk by the hash of its source (:func:`models.codegen.load_compiled`, cache folder
  ``$XDG_CACHE_HOME/stickslip``); None if gcc is missing or fails (the caller then uses the
  CasADi virtual machine, same numbers, ~10x slower).
- :class:`ShootingProblem`: residuals, continuity gaps and their sparse Jacobians for all
  intervals at once (the sample function mapped over the intervals, sensitivities chained
  over the ``M`` samples of an interval in numpy).
- :func:`solve_gn`: SQP with the Gauss-Newton Hessian ``J^T J``: each iteration solves the
  sparse KKT system ``[[J^T J + mu I, A^T], [A, 0]]`` (scipy SuperLU), bounds on the
  parameters by a small active set, step length by backtracking on the l1 merit function
  ``0.5 |r|^2 + nu |g|_1``.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from models.codegen import compiler, load_compiled
from models.rigs import RigModel

__all__ = ["sample_function", "compiled_or_none", "ShootingProblem", "solve_gn", "GNResult"]

_COMPILED: dict = {}


def sample_function(model: RigModel, nsub: int, h_all: ca.Function, avg: list[bool], *,
                    values_only: bool = False, input_jac: bool = False) -> ca.Function:
    """One sample with sensitivities; see the module docstring.

    ``h_all(x, u, p)`` stacks the compared outputs; ``avg[i]`` marks outputs returned as
    means over the sample (quadrature) rather than end values.  ``values_only``: only
    ``(x_next, y)`` (for line searches and simulation).  ``input_jac``: also
    ``E = dx_next/du`` and ``F = dy/du`` (errors-in-variables fits).
    """
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_p)
    dt = ca.SX.sym("dt")
    eps = ca.SX.sym("eps")
    rhs = model.smooth_rhs(x, u, p, eps)
    rhs = ca.vertcat(*rhs) if isinstance(rhs, list) else rhs
    yexpr = h_all(x, u, p)
    idx_avg = [i for i, a in enumerate(avg) if a]
    q_rhs = ca.vertcat(*[yexpr[i] for i in idx_avg]) if idx_avg else ca.SX(0, 1)
    fa = ca.Function("fa", [x, u, p, eps], [ca.vertcat(rhs, q_rhs)])
    nx, nq = model.nx, len(idx_avg)
    hs = dt / nsub
    xa = ca.vertcat(x, ca.SX.zeros(nq))
    for _ in range(nsub):
        k1 = fa(xa[:nx], u, p, eps)
        k2 = fa(xa[:nx] + hs / 2 * k1[:nx], u, p, eps)
        k3 = fa(xa[:nx] + hs / 2 * k2[:nx], u, p, eps)
        k4 = fa(xa[:nx] + hs * k3[:nx], u, p, eps)
        xa = xa + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    xn = xa[:nx]
    yend = h_all(xn, u, p)
    ys, jq = [], 0
    for i in range(len(avg)):
        if avg[i]:
            ys.append(xa[nx + jq] / dt)
            jq += 1
        else:
            ys.append(yend[i])
    y = ca.vertcat(*ys)
    if values_only:
        return ca.Function(f"{model.name}_id_val_n{nsub}_y{len(avg)}", [x, u, p, dt, eps], [xn, y],
                           ["x", "u", "p", "dt", "eps"], ["x_next", "y"])
    outs = [xn, y, ca.jacobian(xn, x), ca.jacobian(xn, p), ca.jacobian(y, x), ca.jacobian(y, p)]
    names = ["x_next", "y", "A", "B", "C", "D"]
    if input_jac:
        outs += [ca.jacobian(xn, u), ca.jacobian(y, u)]
        names += ["E", "F"]
    return ca.Function(f"{model.name}_id_sens_n{nsub}_y{len(avg)}{'_u' if input_jac else ''}",
                       [x, u, p, dt, eps], outs, ["x", "u", "p", "dt", "eps"], names)


def compiled_or_none(fn: ca.Function) -> ca.Function | None:
    """``fn`` as a gcc-built, disk-cached external Function, or None if that is not possible."""
    key = fn.serialize()
    if key in _COMPILED:
        return _COMPILED[key]
    out = None
    if compiler() is not None:
        try:
            out = load_compiled(fn, "-O1")[fn.name()]
        except Exception as exc:  # noqa: BLE001 - fall back to the virtual machine
            sys.stderr.write(f"identify: compiling {fn.name()} failed ({exc}); using the uncompiled function\n")
            out = None
    _COMPILED[key] = out
    return out


class ShootingProblem:
    """Residuals and continuity gaps of a multiple-shooting fit and their sparse Jacobians.

    Decision vector ``w = [theta / th_scale; nodes / x_scale; deltas / d_scale]`` (nodes
    row-major per node, logs one after another).  Residual order: interval, sample, channel,
    then the priors of the input corrections.  Gap order: interval, state.

    Errors in the variables (``eiv_idx``): the logged inputs of those channels carry noise.
    Each shooting interval gets a constant correction ``delta`` per channel, added to the
    logged input, with the prior ``delta ~ N(0, d_scale^2)`` (``d_scale`` = the noise std over
    sqrt(samples per interval): the error of the interval's mean).  The corrections absorb the
    slow part of the input noise, which the dynamics do not filter out and which otherwise
    biases damping and friction.  ``S`` must then come from ``sample_function(...,
    input_jac=True)``.
    """

    def __init__(self, S: ca.Function, nx: int, n_p: int, p_base, free_idx, th_scale, x_scale,
                 U, Ymeas, wgt, starts, dt: float, eps: float, threads: int = 2,
                 S_val: ca.Function | None = None, eiv_idx=(), eiv_scale=None):
        # U (Nint, M, nu), Ymeas (Nint, M, ny), starts (Nint,) node index of each interval start
        self.nx, self.n_p = nx, n_p
        self.p_base = np.asarray(p_base, float)
        self.free_idx = np.asarray(free_idx, int)
        self.nf = len(free_idx)
        self.th_scale = np.asarray(th_scale, float)
        self.x_scale = np.asarray(x_scale, float)
        self.U = U
        self.Ymeas = Ymeas
        self.wgt = np.broadcast_to(np.asarray(wgt, float), Ymeas.shape)  # 1/noise per residual
        self.starts = np.asarray(starts, int)
        self.Nint, self.M, self.ny = Ymeas.shape
        self.n_nodes = int(self.starts.max()) + 2 if self.Nint else 0
        self.eiv_idx = np.asarray(eiv_idx, int)
        self.ne = len(self.eiv_idx)
        self.d_scale = np.asarray(eiv_scale if eiv_scale is not None else np.ones(self.ne), float)
        if self.ne and S.n_out() < 8:
            raise ValueError("errors in the variables need sample_function(..., input_jac=True)")
        self.base_d = self.nf + nx * self.n_nodes
        self.nw = self.base_d + self.Nint * self.ne
        self.dt, self.eps = float(dt), float(eps)
        self.F = S.map(self.Nint, "thread", threads) if threads > 1 else S.map(self.Nint)
        Sv = S_val if S_val is not None else S
        self.Fv = Sv.map(self.Nint, "thread", threads) if threads > 1 else Sv.map(self.Nint)
        self._build_patterns()

    def kkt_order(self, n_extra: int) -> np.ndarray:
        """Symmetric permutation of the KKT unknowns ``[w; gap multipliers; extra rows]`` to
        a banded matrix with a border: per node its states then the gaps of the interval it
        starts; the parameters and the ``n_extra`` bound rows last."""
        nf, nx = self.nf, self.nx
        ng = self.Nint * nx
        gap_of = -np.ones(self.n_nodes, int)
        gap_of[self.starts] = np.arange(self.Nint)
        blocks = []
        for n in range(self.n_nodes):
            blocks.append(nf + nx * n + np.arange(nx))
            if gap_of[n] >= 0:
                blocks.append(self.base_d + self.ne * gap_of[n] + np.arange(self.ne))
                blocks.append(self.nw + nx * gap_of[n] + np.arange(nx))
        blocks.append(np.arange(nf))
        blocks.append(self.nw + ng + np.arange(n_extra))
        return np.concatenate(blocks)

    def split(self, w):
        theta = w[:self.nf] * self.th_scale
        nodes = w[self.nf:self.base_d].reshape(self.n_nodes, self.nx) * self.x_scale
        return theta, nodes

    def deltas(self, w):
        """(Nint, ne) input corrections of the EIV channels [SI]."""
        return np.asarray(w[self.base_d:], float).reshape(self.Nint, self.ne) * self.d_scale

    def _build_patterns(self):
        nf, nx, M, ny, N = self.nf, self.nx, self.M, self.ny, self.Nint
        # residual Jacobian: rows (i, k, c), columns theta (nf) and start node of i (nx)
        rows = np.arange(N * M * ny).reshape(N, M, ny)
        cols_t = np.broadcast_to(np.arange(nf), (N, M, ny, nf))
        cols_s = nf + nx * self.starts[:, None, None, None] + np.arange(nx)[None, None, None, :]
        cols_s = np.broadcast_to(cols_s, (N, M, ny, nx))
        self._jr_rows = np.concatenate([np.broadcast_to(rows[..., None], (N, M, ny, nf)).ravel(),
                                        np.broadcast_to(rows[..., None], (N, M, ny, nx)).ravel()])
        self._jr_cols = np.concatenate([cols_t.ravel(), cols_s.ravel()])
        grow = np.arange(N * nx).reshape(N, nx)
        gct = np.broadcast_to(np.arange(nf), (N, nx, nf))
        gcs = np.broadcast_to(nf + nx * self.starts[:, None, None] + np.arange(nx)[None, None, :], (N, nx, nx))
        self._a_rows = np.concatenate([np.broadcast_to(grow[..., None], (N, nx, nf)).ravel(),
                                       np.broadcast_to(grow[..., None], (N, nx, nx)).ravel(), grow.ravel()])
        self._a_cols = np.concatenate([gct.ravel(), gcs.ravel(),
                                       (nf + nx * (self.starts[:, None] + 1) + np.arange(nx)[None, :]).ravel()])
        ne = self.ne
        if ne:
            dcol = self.base_d + ne * np.arange(N)[:, None] + np.arange(ne)[None, :]        # (N, ne)
            self._jr_rows = np.concatenate([self._jr_rows, np.broadcast_to(rows[..., None], (N, M, ny, ne)).ravel(),
                                            N * M * ny + np.arange(N * ne)])
            self._jr_cols = np.concatenate([self._jr_cols, np.broadcast_to(dcol[:, None, None, :], (N, M, ny, ne)).ravel(),
                                            dcol.ravel()])
            self._a_rows = np.concatenate([self._a_rows, np.broadcast_to(grow[..., None], (N, nx, ne)).ravel()])
            self._a_cols = np.concatenate([self._a_cols, np.broadcast_to(dcol[:, None, :], (N, nx, ne)).ravel()])

    def evaluate(self, w, jac: bool = True):
        """Return ``r, g, Jr, A, Ypred`` (``Jr``, ``A`` sparse CSC, None if not ``jac``)."""
        nf, nx, M, ny, N = self.nf, self.nx, self.M, self.ny, self.Nint
        theta, nodes = self.split(np.asarray(w, float))
        p = self.p_base.copy()
        p[self.free_idx] = theta
        P = np.repeat(p[:, None], N, axis=1)
        X = nodes[self.starts].T.copy()                      # (nx, N)
        ne = self.ne
        if ne:
            wd = np.asarray(w, float)[self.base_d:]
            delta = wd.reshape(N, ne) * self.d_scale
        Ypred = np.empty((N, M, ny))
        if jac:
            Sx = np.repeat(np.eye(nx)[None], N, axis=0)      # (N, nx, nx)
            Sp = np.zeros((N, nx, nf))
            Jy_s = np.empty((N, M, ny, nx))
            Jy_t = np.empty((N, M, ny, nf))
            if ne:
                Sd = np.zeros((N, nx, ne))
                Jy_d = np.empty((N, M, ny, ne))
        for k in range(M):
            Uk = self.U[:, k, :]
            if ne:
                Uk = Uk.copy()
                Uk[:, self.eiv_idx] += delta
            out = (self.F if jac else self.Fv)(X, Uk.T, P, self.dt, self.eps)
            xn = np.asarray(out[0])
            Ypred[:, k, :] = np.asarray(out[1]).T
            if jac:
                A = np.asarray(out[2]).reshape(nx, N, nx).transpose(1, 0, 2)
                B = np.asarray(out[3]).reshape(nx, N, self.n_p).transpose(1, 0, 2)[:, :, self.free_idx]
                C = np.asarray(out[4]).reshape(ny, N, nx).transpose(1, 0, 2)
                D = np.asarray(out[5]).reshape(ny, N, self.n_p).transpose(1, 0, 2)[:, :, self.free_idx]
                Jy_s[:, k] = C @ Sx
                Jy_t[:, k] = C @ Sp + D
                if ne:
                    nu = Uk.shape[1]
                    Ei = np.asarray(out[6]).reshape(nx, N, nu).transpose(1, 0, 2)[:, :, self.eiv_idx]
                    Fi = np.asarray(out[7]).reshape(ny, N, nu).transpose(1, 0, 2)[:, :, self.eiv_idx]
                    Jy_d[:, k] = C @ Sd + Fi
                    Sd = A @ Sd + Ei
                Sp = A @ Sp + B
                Sx = A @ Sx
            X = xn
        r = ((Ypred - self.Ymeas) * self.wgt).ravel()
        if ne:
            r = np.concatenate([r, wd])                      # priors of the input corrections
        xs = self.x_scale
        g = ((X.T - nodes[self.starts + 1]) / xs).ravel()
        if not jac:
            return r, g, None, None, Ypred
        wq = self.wgt[..., None]
        parts_r = [(Jy_t * wq * self.th_scale).ravel(), (Jy_s * wq * xs).ravel()]
        if ne:
            parts_r += [(Jy_d * wq * self.d_scale).ravel(), np.ones(N * ne)]
        Jr = sp.csc_matrix((np.concatenate(parts_r), (self._jr_rows, self._jr_cols)),
                           shape=(N * M * ny + N * ne, self.nw))
        parts_a = [(Sp / xs[None, :, None] * self.th_scale).ravel(),
                   (Sx / xs[None, :, None] * xs[None, None, :]).ravel(),
                   -np.ones(N * nx)]
        if ne:
            parts_a.append((Sd / xs[None, :, None] * self.d_scale).ravel())
        vals_a = np.concatenate(parts_a)
        A = sp.csc_matrix((vals_a, (self._a_rows, self._a_cols)), shape=(N * nx, self.nw))
        return r, g, Jr, A, Ypred


@dataclass(frozen=True)
class GNResult:
    w: np.ndarray
    iterations: int
    status: str
    success: bool


def solve_gn(prob: ShootingProblem, w0, lb, ub, *, max_iter: int = 100, tol: float = 1e-8,
             callback=None) -> GNResult:
    """Constrained Gauss-Newton (SQP with ``J^T J``) on a :class:`ShootingProblem`.

    ``lb``/``ub`` bound the scaled parameters ``w[:nf]`` only.  Converged when the scaled
    step is below ``sqrt(tol)`` in max-norm and the scaled gaps below ``100 tol``.
    """
    nf, nw = prob.nf, prob.nw
    w = np.asarray(w0, float).copy()
    w[:nf] = np.clip(w[:nf], lb, ub)
    r, g, Jr, A, _ = prob.evaluate(w)
    nu_pen = 1.0
    lm = 1e-10          # Levenberg-Marquardt damping relative to max diag(J^T J), adapted below
    status, success = "maximum number of iterations reached", False
    it = 0
    for it in range(1, max_iter + 1):
        f = 0.5 * float(r @ r)
        H = (Jr.T @ Jr).tocsc()
        grad = Jr.T @ r
        hd = H.diagonal()
        mu = lm * max(1.0, float(hd.max()))
        fixed: set[int] = set()
        for j in range(nf):  # parameters at a bound whose gradient pushes outward
            if (w[j] <= lb[j] + 1e-12 and grad[j] > 0) or (w[j] >= ub[j] - 1e-12 and grad[j] < 0):
                fixed.add(j)
        ng = A.shape[0]
        for _ in range(nf + 1):
            E = sp.csc_matrix((np.ones(len(fixed)), (np.arange(len(fixed)), sorted(fixed))), shape=(len(fixed), nw))
            Aall = sp.vstack([A, E]).tocsc()
            rhs_c = np.r_[-g, [0.0] * len(fixed)]
            for j_i, j in enumerate(sorted(fixed)):
                rhs_c[ng + j_i] = (min(max(w[j], lb[j]), ub[j]) - w[j])
            K = sp.bmat([[H + mu * sp.identity(nw, format="csc"), Aall.T],
                         [Aall, -1e-12 * sp.identity(Aall.shape[0], format="csc")]], format="csc")
            perm = prob.kkt_order(len(fixed))
            try:
                Kp = K[perm][:, perm].tocsc()
                lu = spla.splu(Kp, permc_spec="NATURAL", diag_pivot_thresh=0.1)
                solp = lu.solve(np.r_[-grad, rhs_c][perm])
            except RuntimeError:
                return GNResult(w, it, "singular KKT matrix", False)
            sol = np.empty_like(solp)
            sol[perm] = solp
            dw, lam = sol[:nw], sol[nw:nw + ng]
            viol = [j for j in range(nf) if j not in fixed and (w[j] + dw[j] < lb[j] - 1e-12 or w[j] + dw[j] > ub[j] + 1e-12)]
            if not viol:
                break
            # fix the most violated one at its bound
            fixed.add(max(viol, key=lambda j: max(lb[j] - w[j] - dw[j], w[j] + dw[j] - ub[j])))
        # truncate the step into the box (remaining small violations)
        t_max = 1.0
        for j in range(nf):
            if dw[j] < 0 and w[j] + dw[j] < lb[j]:
                t_max = min(t_max, (lb[j] - w[j]) / dw[j])
            if dw[j] > 0 and w[j] + dw[j] > ub[j]:
                t_max = min(t_max, (ub[j] - w[j]) / dw[j])
        nu_pen = max(nu_pen, 1.5 * float(np.max(np.abs(lam))) if lam.size else 0.0)
        gl1 = float(np.sum(np.abs(g)))
        phi0 = f + nu_pen * gl1
        dphi = float(grad @ dw) - nu_pen * gl1
        step_inf = float(np.max(np.abs(dw))) if nw else 0.0
        if callback is not None:
            callback(it, f, float(np.max(np.abs(g))) if g.size else 0.0, step_inf)
        gmax = float(np.max(np.abs(g))) if g.size else 0.0
        if step_inf < math.sqrt(tol) and gmax < 100 * tol:
            status, success = "converged (small step)", True
            break
        # predicted GN decrease of the cost negligible and the gaps small: converged
        pred = -float(grad @ dw) - 0.5 * float(np.sum((Jr @ dw) ** 2))
        # (the cost is in units of noise-normalised squares: a decrease of 1e-4 s^2 moves the
        # parameters by ~0.01 standard errors)
        s2 = max(1.0, 2 * f / max(r.size - nw + g.size, 1))
        if 0 <= pred <= max(tol * f, 1e-4 * s2) and gmax < 1e-5:
            status, success = "converged (no predicted decrease)", True
            break
        alpha = t_max
        accepted = False
        for ls in range(30):
            wt = w + alpha * dw
            wt[:nf] = np.clip(wt[:nf], lb, ub)
            rt, gt, _, _, _ = prob.evaluate(wt, jac=False)
            if np.all(np.isfinite(rt)) and np.all(np.isfinite(gt)):
                phit = 0.5 * float(rt @ rt) + nu_pen * float(np.sum(np.abs(gt)))
                if phit <= phi0 + 1e-4 * alpha * min(dphi, 0.0):
                    accepted = True
                    break
                if ls == 0:
                    # second-order correction (Nocedal & Wright 18.3): the minimum-norm (in the
                    # GN metric) change that removes the gaps left by the full step, from the same
                    # factorisation; counters the Maratos effect of the l1 merit function
                    rhs = np.r_[np.zeros(nw), -gt, np.zeros(Aall.shape[0] - ng)]
                    cp = lu.solve(rhs[perm])
                    corr = np.empty_like(cp)
                    corr[perm] = cp
                    ws = wt + corr[:nw]
                    ws[:nf] = np.clip(ws[:nf], lb, ub)
                    rs, gs, _, _, _ = prob.evaluate(ws, jac=False)
                    if np.all(np.isfinite(rs)) and np.all(np.isfinite(gs)):
                        phis = 0.5 * float(rs @ rs) + nu_pen * float(np.sum(np.abs(gs)))
                        if phis <= phi0 + 1e-4 * alpha * min(dphi, 0.0):
                            wt, accepted = ws, True
                            break
            alpha *= 0.5
        if not accepted and lm < 1e-3:
            lm = max(lm * 100, 1e-8)      # shorter, more gradient-like steps; retry from w
            continue
        if not accepted:
            if np.max(np.abs(g)) < 1e-6 and step_inf < 1e-3:
                status, success = "converged (no further decrease)", True
            else:
                status, success = "line search failed", False
            break
        w = wt
        lm = max(lm / 10, 1e-12) if alpha >= 0.5 * t_max else min(lm * 10, 1e-2)
        r, g, Jr, A, _ = prob.evaluate(w)
    return GNResult(w, it, status, success)
