"""The multiple-shooting residuals and continuity gaps of a fit, with their sparse Jacobians.

- :func:`sample_function`: ONE DAQ sample of the regularised model (the integration rule's
  method: RK4 with ``nsub`` substeps or the L-stable implicit step, zero-order-hold input, speeds
  averaged over the sample by the method's quadrature) with its
  forward sensitivities: ``S(x, u, p, dt, eps) -> (x_next, y, A, B, C, D[, E, F])``,
  ``A = dx_next/dx``, ``B = dx_next/dp``, ``C = dy/dx``, ``D = dy/dp``, ``E = dx_next/du``,
  ``F = dy/du``.  ``u`` holds the LOGGED inputs: the function corrects them through the rig's
  load cells (:meth:`models.rig.RigModel.input_from_measured`), so a load cell's offset and
  gain can be fitted.  ``dt`` and ``eps`` are inputs, so one compiled library serves every
  sample period and regularisation.
- :func:`compiled_or_none`: the same Function built with gcc and cached on disk
  (:func:`models.codegen.load_compiled`); None if that is not possible.
- :class:`ShootingProblem`: residuals, gaps and Jacobians for all intervals at once: the
  sample function mapped over the intervals (2 threads), the sensitivities chained over the
  ``M`` samples of an interval in numpy.

Decision vector (all scaled)::

    w = [theta / th_scale;  z / z_scale;  nodes / x_scale;  deltas / d_scale]

``theta`` the free parameters, ``z`` the encoder zeros (one per twist channel and log),
``nodes`` the state at every shooting node (row-major per node, logs one after another),
``deltas`` the input corrections of errors in the variables (one per interval and noisy
input).  ``theta`` and ``z`` together are the *border* variables: every residual may depend
on them; a node only touches the residuals of its interval.
"""

from __future__ import annotations


import math

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from models import codegen
from models.discretise import Integration

__all__ = ["sample_function", "compiled_or_none", "ShootingProblem", "KKTFactor"]

_COMPILED: dict = {}


def sample_function(model, integ, h: ca.Function, avg, free_idx=None, *, values_only: bool = False,
                    input_jac: bool = False) -> ca.Function:
    """One sample with sensitivities (see the module docstring).

    Parameters
    ----------
    model : the rig
    integ : how a sample is integrated (:class:`models.discretise.Integration`: RK4 with ``nsub``
        substeps, a DC motor's current quasi-static, or the L-stable implicit step); its ``dt`` and
        ``band`` are replaced by the function's inputs ``dt`` and ``eps``; an int: RK4 with that
        many substeps
    h : ``y = h(x, u, p)`` (:func:`estimators.identify.outputs.output_function`), ``u`` the model inputs
    avg : per output, True if it is returned as its mean over the sample
    free_idx : indices of the free parameters: the function takes them as a separate input
        ``th`` (overriding those entries of ``p``) and differentiates with respect to ``th`` only
        (``B = dx_next/dth``, ``D = dy/dth``); None: all parameters free
    values_only : only ``(x_next, y)``
    input_jac : also ``E``, ``F`` (errors in the variables)

    Returns
    -------
    ``S(x, u, th, p, dt, eps)``
    """
    if isinstance(integ, int):
        integ = Integration(1.0, integ)              # RK4 with that many substeps
    free_idx = list(range(model.n_p)) if free_idx is None else [int(i) for i in free_idx]
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    th = ca.SX.sym("th", len(free_idx))
    p = ca.SX.sym("p", model.n_p)
    dt = ca.SX.sym("dt")
    eps = ca.SX.sym("eps")
    parts = [p[i] for i in range(model.n_p)]
    for k, i in enumerate(free_idx):
        parts[i] = th[k]
    pe = ca.vertcat(*parts)
    um = ca.vertcat(*model.input_from_measured([u[i] for i in range(model.nu)], model.unpack(pe)))
    idx_avg = [i for i, a in enumerate(avg) if a]

    def rhs(xx, uu, pp):
        return ca.vertcat(*model.smooth_rhs(xx, um, pe, eps))

    def quad(xx, uu, pp):
        y_ = h(xx, um, pe)
        return ca.vertcat(*[y_[i] for i in idx_avg]) if idx_avg else ca.SX(0, 1)

    def fast_value(xx, uu, pp):
        return model.quasi_static_current(xx, um, model.unpack(pe))

    xn, q = integ.advance(rhs, x, u, p, fast_value, quad=quad, dt=dt, band=eps)
    yend = h(xn, um, pe)
    ys, jq = [], 0
    for i, a in enumerate(avg):
        if a:
            ys.append(q[jq] / dt)
            jq += 1
        else:
            ys.append(yend[i])
    y = ca.vertcat(*ys)
    import hashlib
    ftag = hashlib.sha1(",".join(map(str, free_idx)).encode()).hexdigest()[:8]
    itag = {"rk4": "n", "sdirk2": "i"}[integ.method]
    tag = f"{model.cname}_id_{itag}{integ.nsub}{'q' if integ.quasi_static else ''}_y{len(avg)}_f{ftag}"
    args, argn = [x, u, th, p, dt, eps], ["x", "u", "th", "p", "dt", "eps"]
    if values_only:
        return ca.Function(f"{tag}_val", args, [xn, y], argn, ["x_next", "y"])
    # one Jacobian of [x_next; y] with respect to [x; th; (u)]: the separate Jacobians would each
    # propagate derivatives through the whole RK4 chain again
    wrt = ca.vertcat(x, th, u) if input_jac else ca.vertcat(x, th)
    Jall = ca.jacobian(ca.vertcat(xn, y), wrt)
    nt, ny_ = len(free_idx), y.numel()
    nx = model.nx
    A_, B_ = Jall[:nx, :nx], Jall[:nx, nx:nx + nt]
    C_, D_ = Jall[nx:nx + ny_, :nx], Jall[nx:nx + ny_, nx:nx + nt]
    outs = [xn, y, ca.densify(A_), ca.densify(B_), ca.densify(C_), ca.densify(D_)]
    names = ["x_next", "y", "A", "B", "C", "D"]
    if input_jac:
        outs += [ca.densify(Jall[:nx, nx + nt:]), ca.densify(Jall[nx:nx + ny_, nx + nt:])]
        names += ["E", "F"]
    return ca.Function(f"{tag}_sens{'_u' if input_jac else ''}", args, outs, argn, names)


def compiled_or_none(fn: ca.Function) -> ca.Function | None:
    """``fn`` gcc-built at -O1 (:func:`models.codegen.compiled_or_none`, cached on disk), memoised
    in this process by the Function's serialisation; None without a compiler or when the build fails."""
    key = fn.serialize()
    if key not in _COMPILED:
        _COMPILED[key] = codegen.compiled_or_none(fn, "-O1")
    return _COMPILED[key]


class ShootingProblem:
    """Residuals and continuity gaps of a multiple-shooting fit and their sparse Jacobians.

    Parameters
    ----------
    S : :func:`sample_function` for ``free_idx`` (sensitivities; with ``input_jac`` when ``eiv_idx`` is given)
    nx, n_p : state and parameter dimensions
    p_base : (n_p,) full parameter vector; the free entries are replaced by ``theta``
    free_idx : indices of the free parameters
    th_scale : (nf,) scales of the free parameters
    x_scale : (nx,) scales of the states
    U : (Nint, M, nu) logged inputs held over each sample
    Ymeas : (Nint, M, ny) measured outputs at the end of each sample
    wgt : (Nint, M, ny) or broadcastable: 1 / noise std of each residual
    starts : (Nint,) node index of each interval's start (its end is the next node)
    dt, eps : sample period [s] and regularisation [rad/s]
    zmap : (Nint, ny) index of the encoder zero subtracted from each predicted output, -1 if none
    z_scale : (nz,) scales of the encoder zeros
    eiv_idx, eiv_scale : inputs with errors in the variables and the prior std of their
        per-interval corrections (the correction's residual is ``delta / eiv_scale``)
    S_val : values-only sample function (line searches)

    Residual order: interval, sample, channel, then the priors of the input corrections.
    Gap order: interval, state.
    """

    def __init__(self, S: ca.Function, nx: int, n_p: int, p_base, free_idx, th_scale, x_scale, U, Ymeas, wgt,
                 starts, dt: float, eps: float, *, zmap=None, z_scale=(), threads: int = 2,
                 S_val: ca.Function | None = None, eiv_idx=(), eiv_scale=None):
        self.nx, self.n_p = nx, n_p
        self.p_base = np.asarray(p_base, float)
        self.free_idx = np.asarray(free_idx, int)
        self.nf = len(self.free_idx)
        self._P = np.repeat(self.p_base[:, None], len(np.asarray(starts)), axis=1)
        self.th_scale = np.asarray(th_scale, float)
        self.x_scale = np.asarray(x_scale, float)
        self.U = np.asarray(U, float)
        self.Ymeas = np.asarray(Ymeas, float)
        self.Nint, self.M, self.ny = self.Ymeas.shape
        self.wgt = np.broadcast_to(np.asarray(wgt, float), self.Ymeas.shape)
        self.starts = np.asarray(starts, int)
        self.n_nodes = int(self.starts.max()) + 2 if self.Nint else 0
        self.z_scale = np.asarray(z_scale, float)
        self.nz = self.z_scale.size
        self.zmap = np.full((self.Nint, self.ny), -1, int) if zmap is None else np.asarray(zmap, int)
        if self.zmap.shape != (self.Nint, self.ny) or self.zmap.max(initial=-1) >= self.nz:
            raise ValueError("zmap must be (Nint, ny) with entries < nz")
        self.nb = self.nf + self.nz
        self.eiv_idx = np.asarray(eiv_idx, int)
        self.ne = len(self.eiv_idx)
        self.d_scale = np.asarray(eiv_scale if eiv_scale is not None else np.ones(self.ne), float)
        if self.ne and S.n_out() < 8:
            raise ValueError("errors in the variables need sample_function(..., input_jac=True)")
        self.base_d = self.nb + nx * self.n_nodes
        self.nw = self.base_d + self.Nint * self.ne
        self.dt, self.eps = float(dt), float(eps)
        self.F = codegen.BufferedFunction(S.map(self.Nint, "thread", threads) if threads > 1 else S.map(self.Nint))
        Sv = S_val if S_val is not None else S
        self.Fv = codegen.BufferedFunction(Sv.map(self.Nint, "thread", threads) if threads > 1 else Sv.map(self.Nint))
        self._build_patterns()

    # ------------------------------------------------------------------ structure
    def kkt_order(self, n_extra: int) -> np.ndarray:
        """Symmetric permutation of the KKT unknowns ``[w; gap multipliers; extra rows]`` to a
        banded matrix with a border: per node its states, then the input corrections and gaps of
        the interval it starts; the border variables and the ``n_extra`` constraint rows last."""
        nb, nx = self.nb, self.nx
        ng = self.Nint * nx
        gap_of = -np.ones(self.n_nodes, int)
        gap_of[self.starts] = np.arange(self.Nint)
        blocks = []
        for n in range(self.n_nodes):
            blocks.append(nb + nx * n + np.arange(nx))
            if gap_of[n] >= 0:
                blocks.append(self.base_d + self.ne * gap_of[n] + np.arange(self.ne))
                blocks.append(self.nw + nx * gap_of[n] + np.arange(nx))
        blocks.append(np.arange(nb))
        blocks.append(self.nw + ng + np.arange(n_extra))
        return np.concatenate(blocks)

    def split(self, w):
        """``(theta, z, nodes)`` in SI units from the scaled decision vector."""
        w = np.asarray(w, float)
        theta = w[:self.nf] * self.th_scale
        z = w[self.nf:self.nb] * self.z_scale
        nodes = w[self.nb:self.base_d].reshape(self.n_nodes, self.nx) * self.x_scale
        return theta, z, nodes

    def deltas(self, w):
        """(Nint, ne) input corrections of the errors-in-variables channels [SI]."""
        return np.asarray(w[self.base_d:], float).reshape(self.Nint, self.ne) * self.d_scale

    def _build_patterns(self):
        nf, nb, nx, M, ny, N = self.nf, self.nb, self.nx, self.M, self.ny, self.Nint
        rows = np.arange(N * M * ny).reshape(N, M, ny)
        node_cols = nb + nx * self.starts[:, None, None, None] + np.arange(nx)[None, None, None, :]
        jr_rows = [np.broadcast_to(rows[..., None], (N, M, ny, nf)).ravel(),
                   np.broadcast_to(rows[..., None], (N, M, ny, nx)).ravel()]
        jr_cols = [np.broadcast_to(np.arange(nf), (N, M, ny, nf)).ravel(),
                   np.broadcast_to(node_cols, (N, M, ny, nx)).ravel()]
        # encoder zeros: one column per residual that subtracts a zero
        zr = np.broadcast_to(self.zmap[:, None, :], (N, M, ny))
        self._zmask = zr >= 0
        jr_rows.append(rows[self._zmask])
        jr_cols.append(nf + zr[self._zmask])
        grow = np.arange(N * nx).reshape(N, nx)
        gcs = nb + nx * self.starts[:, None, None] + np.arange(nx)[None, None, :]
        a_rows = [np.broadcast_to(grow[..., None], (N, nx, nf)).ravel(),
                  np.broadcast_to(grow[..., None], (N, nx, nx)).ravel(), grow.ravel()]
        a_cols = [np.broadcast_to(np.arange(nf), (N, nx, nf)).ravel(), np.broadcast_to(gcs, (N, nx, nx)).ravel(),
                  (nb + nx * (self.starts[:, None] + 1) + np.arange(nx)[None, :]).ravel()]
        ne = self.ne
        if ne:
            dcol = self.base_d + ne * np.arange(N)[:, None] + np.arange(ne)[None, :]        # (N, ne)
            jr_rows += [np.broadcast_to(rows[..., None], (N, M, ny, ne)).ravel(), N * M * ny + np.arange(N * ne)]
            jr_cols += [np.broadcast_to(dcol[:, None, None, :], (N, M, ny, ne)).ravel(), dcol.ravel()]
            a_rows.append(np.broadcast_to(grow[..., None], (N, nx, ne)).ravel())
            a_cols.append(np.broadcast_to(dcol[:, None, :], (N, nx, ne)).ravel())
        self._jr_rows, self._jr_cols = np.concatenate(jr_rows), np.concatenate(jr_cols)
        self._a_rows, self._a_cols = np.concatenate(a_rows), np.concatenate(a_cols)

    # ------------------------------------------------------------------ evaluation
    def predict(self, w) -> np.ndarray:
        """(Nint, M, ny) predicted outputs (encoder zeros subtracted)."""
        return self.evaluate(w, jac=False)[4]

    def evaluate(self, w, jac: bool = True):
        """``r, g, Jr, A, Ypred`` (``Jr``, ``A`` sparse CSC, None unless ``jac``)."""
        nf, nx, M, ny, N, ne = self.nf, self.nx, self.M, self.ny, self.Nint, self.ne
        w = np.asarray(w, float)
        theta, z, nodes = self.split(w)
        TH = np.repeat(theta[:, None], N, axis=1)
        P = self._P
        X = nodes[self.starts].T.copy()                      # (nx, N)
        if ne:
            wd = w[self.base_d:]
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
            out = (self.F if jac else self.Fv)(X, Uk.T, TH, P, self.dt, self.eps)
            xn = np.asarray(out[0])
            Ypred[:, k, :] = np.asarray(out[1]).T
            if jac:
                A = np.asarray(out[2]).reshape(nx, N, nx).transpose(1, 0, 2)
                B = np.asarray(out[3]).reshape(nx, N, nf).transpose(1, 0, 2)
                C = np.asarray(out[4]).reshape(ny, N, nx).transpose(1, 0, 2)
                D = np.asarray(out[5]).reshape(ny, N, nf).transpose(1, 0, 2)
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
        if self.nz:
            zr = np.broadcast_to(self.zmap[:, None, :], (N, M, ny))
            Ypred = Ypred - np.where(zr >= 0, z[np.maximum(zr, 0)], 0.0)
        r = ((Ypred - self.Ymeas) * self.wgt).ravel()
        if ne:
            r = np.concatenate([r, wd])                      # priors of the input corrections
        xs = self.x_scale
        g = ((X.T - nodes[self.starts + 1]) / xs).ravel()
        if not jac:
            return r, g, None, None, Ypred
        wq = self.wgt[..., None]
        parts_r = [(Jy_t * wq * self.th_scale).ravel(), (Jy_s * wq * xs).ravel()]
        if self.nz:
            zr = np.broadcast_to(self.zmap[:, None, :], (N, M, ny))
            parts_r.append(-(self.wgt * self.z_scale[np.maximum(zr, 0)])[self._zmask])
        else:
            parts_r.append(np.zeros(0))
        if ne:
            parts_r += [(Jy_d * wq * self.d_scale).ravel(), np.ones(N * ne)]
        Jr = sp.csc_matrix((np.concatenate(parts_r), (self._jr_rows, self._jr_cols)),
                           shape=(N * M * ny + N * ne, self.nw))
        parts_a = [(Sp / xs[None, :, None] * self.th_scale).ravel(),
                   (Sx / xs[None, :, None] * xs[None, None, :]).ravel(),
                   -np.ones(N * nx)]
        if ne:
            parts_a.append((Sd / xs[None, :, None] * self.d_scale).ravel())
        A = sp.csc_matrix((np.concatenate(parts_a), (self._a_rows, self._a_cols)), shape=(N * nx, self.nw))
        return r, g, Jr, A, Ypred


#: iterative refinement steps of a KKT solve at most: four always, then more while each one at least
#: halves the backward error (on the lead screw's log the diagonal-pivot factors need 5-7 steps to reach
#: 1e-12; stopping at 4 sent 236 of 481 factorisations to threshold pivoting, whose fill made them
#: 60x slower)
_REFINE_MAX = 12


class KKTFactor:
    """LU of a KKT matrix ``K`` (unknowns ``[w; gap multipliers; n_extra rows]``) in the banded
    order of :meth:`ShootingProblem.kkt_order`, with :meth:`solve` in the original order.

    The regularised KKT matrix is quasi-definite, so the factorisation takes the diagonal pivots
    in that order (no row interchanges: threshold pivoting pulled the dense border rows into the
    band; on a 60 s rig3 log the factors had 20.6 M instead of 0.35 M entries and took 2.1 s
    instead of 0.11 s).  Every solve is refined iteratively until its normwise
    backward error ``|K x - b| / (|K| |x| + |b|)`` is below 1e-12: four steps, then more (up to
    ``_REFINE_MAX``) while each step at least halves the backward error, then GMRES preconditioned
    by the same factors; if that still misses 1e-12, SuperLU with threshold pivoting (0.1) is used
    instead.
    """

    def __init__(self, prob: ShootingProblem, K, n_extra: int = 0):
        self.perm = prob.kkt_order(n_extra)
        self.Kp = K[self.perm][:, self.perm].tocsc()
        self.norm = float(abs(self.Kp).sum(axis=1).max()) if self.Kp.nnz else 1.0
        self.pivoting = False
        try:
            self.lu = spla.splu(self.Kp, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                                options={"SymmetricMode": True})
        except RuntimeError:
            self._pivot()

    def _pivot(self):
        self.lu = spla.splu(self.Kp, permc_spec="NATURAL", diag_pivot_thresh=0.1)
        self.pivoting = True

    def _backward(self, x, b) -> float:
        """The normwise backward error ``|K x - b| / (|K| |x| + |b|)`` (inf if x is not finite)."""
        if not np.all(np.isfinite(x)):
            return math.inf
        r = self.Kp @ x - b
        return float(np.max(np.abs(r)) / (self.norm * np.max(np.abs(x)) + np.max(np.abs(b)) + 1e-300))

    def _backward_ok(self, x, b) -> bool:
        return self._backward(x, b) <= 1e-12

    def _solve_p(self, b):
        x = self.lu.solve(b)
        err = self._backward(x, b)
        for i in range(_REFINE_MAX):
            if err <= 1e-12:
                break
            x_new = x + self.lu.solve(b - self.Kp @ x)
            err_new = self._backward(x_new, b)
            if i >= 4 and not err_new < 0.5 * err:
                break           # refinement stalled: the caller falls back to threshold pivoting
            x, err = x_new, err_new
        if err > 1e-12 and np.isfinite(err):
            x = self._krylov(x, b)
        return x

    def _krylov(self, x, b):
        """GMRES on ``K``, preconditioned by the diagonal-pivot factors, from the refined ``x``: where
        plain refinement converges slowly or not monotonically (the lead screw's log: backward errors
        1e-10 after 4 steps, 5-9 GMRES iterations to 1e-18, against a threshold-pivoting factorisation
        60x slower)."""
        n = self.Kp.shape[0]
        M = spla.LinearOperator((n, n), matvec=self.lu.solve, dtype=float)
        cols = x.reshape(n, -1).copy()
        bb = b.reshape(n, -1)
        for j in range(cols.shape[1]):
            xj, _ = spla.gmres(self.Kp, bb[:, j], x0=cols[:, j], M=M, rtol=1e-10, atol=0.0, restart=20, maxiter=3)
            if np.all(np.isfinite(xj)):
                cols[:, j] = xj
        return cols.reshape(x.shape)

    def solve(self, rhs):
        """``K^-1 rhs`` (rhs of shape (n,) or (n, k)), original order."""
        rhs = np.asarray(rhs, float)
        b = rhs[self.perm]
        xp = self._solve_p(b)
        if not self._backward_ok(xp, b) and not self.pivoting:
            self._pivot()
            xp = self._solve_p(b)
        out = np.empty_like(xp)
        out[self.perm] = xp
        return out
