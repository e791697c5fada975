"""Moving-horizon estimator on any rig: Gauss-Newton RTI on a multiple-shooting window.

Window of ``N`` samples, nodes ``x_0 .. x_N`` (the EKF's estimator state, same augmented
unknowns, :mod:`estimators.online.model`).  The decision variables are the node states;
the inputs, measurements, masks, the arrival prior and the parameters are data.  The cost
is a least-squares sum::

    |W0 (x_0 - xbar)|^2 + sum_k |(x_{k+1} - F(x_k, uh_{k+1})) / sqrt(q(x_k))|^2
                        + sum_k |m_k (y_k - h(x_k, uh_k)) / sqrt(r)|^2

(process noise is the multiple-shooting gap, weighted by the EKF's process covariance,
whose stick part depends on the state; ``|W0 v|^2 = v' Pbar^-1 v``).  The measurement function
is nonlinear (rig3's reaction torque), so every node has its own Jacobian ``C_k =
dh/dx(x_k)``.

Solver: ``max_iter`` Gauss-Newton iterations per sample (default 1: real-time iteration),
each ``min 1/2 d'J'Jd + (J'r)'d``: by default (``qpsol = "ldl"``) the unconstrained step by
CasADi's sparse LDL of the block-tridiagonal Hessian, inside the one Function, projected
onto the state bounds (``load:`` in [0, 5], ``gain:`` in [0.05, 20]); or OSQP for the
bound-constrained step.  The weights ``1/sqrt(q(x_k))`` are frozen within an iteration
(their derivative is left out of the Gauss-Newton Jacobian).

Arrival cost: EKF-style.  ``(xbar, Pbar)`` is the EKF's prediction of the window's first
node: its estimate one sample before the window, propagated through ``F`` with the Riccati
step.  It holds no measurement of the window, so no sample is counted twice (taking the
previous window's smoothed ``x_1`` as ``xbar`` with a filtered covariance counts them again;
on rig3 that locked the estimate onto a wrong point of the weakly observable twist / load /
offset direction), and the weight follows the data, it is not fixed.

Warm start: the previous solution shifted by one node, the new last node the EKF's.

Robustness: an EKF runs alongside every step.  Until the window is full, and whenever the
step fails or returns non-finite numbers, the estimate is the EKF's (``Status.FALLBACK``
after the window is full, counted).  The reported covariance is the last node's marginal
of the inverse Gauss-Newton Hessian.

Speed: the shooting-stage and measurement Functions are SX, mapped over the window inside one MX
Function that returns the Gauss-Newton step and the last node's covariance (sparse LDL, no
threaded BLAS: on a loaded 2-core machine a threaded dense Cholesky made the step 3 ms).  With
``compile=True`` (and ``qpsol = "ldl"``) the whole update -- the EKF alongside, the window, the
arrival prior, the step, the projection, the fallback -- is one C call (``csrc/ss_mhe.c``,
:class:`estimators.online.compiled.CompiledMHE`, cached on disk), the same C an exported library
runs: rig3, window 20, a median 0.74 ms a sample against 1.16 ms for the Python update over
gcc-built stage Functions and 4 ms uncompiled (both cores busy).  Its estimates equal the Python
update's bit for bit on rig3 (tests/test_mhe.py) and the drill string; on the four-disc rig they part
at rounding level (1e-12 at the 41st sample) and the differences grow to 1.8e-6 relative in the
covariance along a poorly observable twist (the window's Hessian is ill-conditioned there), with the
same statuses and messages.  With OSQP the stage Functions alone are built with gcc.
"""

from __future__ import annotations

from collections import deque

import casadi as ca
import numpy as np

from estimators.base import Estimate, EstimatorContext, StateEstimator
from estimators.online.compiled import MHE_FAILURES, CompiledMHE
from estimators.online.ekf import EKF, ObservabilityMixin
from estimators.online.options import MHEOptions, for_rig
from models.codegen import compile_cached
from models.errors import PluginError, SolverFailure
from models.sensors import FLOOR
from models.status import Status

__all__ = ["MHE"]


def _window_functions(em, stage: ca.Function, meas: ca.Function, N: int) -> tuple[ca.Function, ca.Function]:
    """The window's Gauss-Newton Functions of ``stage`` and ``meas`` mapped over ``N`` samples:
    ``gn`` (w and the data -> the Hessian J'J, gradient J'r, cost, step d, the last node's
    covariance) and ``gn_step`` (the same -> d, covariance: what the compiled update evaluates)."""
    nx, ny, nuh, npar = em.nx, em.ny, em.nuh, len(em.p)
    w = ca.MX.sym("w", nx * (N + 1))
    xbar, Pbar = ca.MX.sym("xbar", nx), ca.MX.sym("Pbar", nx, nx)
    UH = ca.MX.sym("UH", nuh, N + 1)
    Ym, Wm = ca.MX.sym("Y", ny, N + 1), ca.MX.sym("Wm", ny, N + 1)     # Wm = mask / sqrt(r)
    pm, qm = ca.MX.sym("p", npar), ca.MX.sym("q", nx)
    X = ca.reshape(w, nx, N + 1)
    gaps, Jas, iqs = stage.map(N)(X[:, :N], X[:, 1:], UH[:, 1:], ca.repmat(pm, 1, N), ca.repmat(qm, 1, N))
    Hs, Cs = meas.map(N + 1)(X, UH, ca.repmat(pm, 1, N + 1))
    r_meas = ca.vec(Wm * (Ym - Hs))
    Jblocks = ca.horzsplit(Jas, nx)
    Iblocks = [ca.diag(iqs[:, k]) for k in range(N)]
    J_dyn = ca.horzcat(ca.diagcat(*Jblocks), ca.MX(nx * N, nx)) + ca.horzcat(ca.MX(nx * N, nx),
                                                                              ca.diagcat(*Iblocks))
    Cblocks = ca.horzsplit(Cs, nx)
    J_meas = ca.diagcat(*[ca.mtimes(ca.diag(Wm[:, k]), Cblocks[k]) for k in range(N + 1)])
    J = ca.vertcat(J_dyn, -J_meas)
    r = ca.vertcat(ca.vec(gaps), r_meas)
    # the arrival term |x_0 - xbar|^2 in the metric Pbar^-1 (an LDL solve, no explicit inverse:
    # Pbar is nearly singular along exact constraints such as a zero: state and its twist)
    Pinv = ca.solve(Pbar + FLOOR * ca.DM.eye(nx), ca.DM.eye(nx), "ldl")
    dx0 = X[:, 0] - xbar
    E0 = ca.vertcat(ca.DM.eye(nx), ca.DM(nx * N, nx))       # structurally sparse: H stays block-tridiagonal
    H = ca.mtimes(J.T, J) + ca.mtimes([E0, Pinv, E0.T])
    g = ca.mtimes(J.T, r) + ca.mtimes(E0, ca.mtimes(Pinv, dx0))
    cost = 0.5 * (ca.sumsqr(r) + ca.dot(dx0, ca.mtimes(Pinv, dx0)))
    # the Gauss-Newton step and the last node's covariance by CasADi's sparse LDL: the Hessian
    # is block-tridiagonal, and no threaded BLAS gets involved (on a loaded 2-core machine a
    # threaded dense Cholesky took 3 ms, an 11 x 11 triangular solve 5 ms)
    E = ca.DM.zeros(nx * (N + 1), nx)
    E[nx * N:, :] = ca.DM.eye(nx)
    d = -ca.solve(H, g, "ldl")
    Pn = ca.solve(H, E, "ldl")[nx * N:, :]
    ins, names = [w, xbar, Pbar, UH, Ym, Wm, pm, qm], ["w", "xbar", "Pbar", "UH", "Y", "Wm", "p", "q"]
    cname = em.model.cname
    gn = ca.Function(f"{cname}_mhe_gn", ins, [H, g, cost, d, Pn], names, ["H", "g", "cost", "d", "P"])
    step = ca.Function(f"{cname}_mhe_step", ins, [d, Pn], names, ["d", "P"])
    return gn, step


def _bind(fn: ca.Function):
    """Zero-copy evaluation: numpy arrays bound once to a Function's argument/result buffers."""
    ins = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
    outs = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
    buf, ev = fn.buffer()
    for i, a in enumerate(ins):
        buf.set_arg(i, memoryview(a))
    for i, a in enumerate(outs):
        buf.set_res(i, memoryview(a))
    return ins, outs, buf, ev


class MHE(ObservabilityMixin, StateEstimator):
    """Moving-horizon estimator (module docstring).

    Parameters
    ----------
    options : :class:`estimators.online.options.MHEOptions`
    context : :class:`estimators.base.EstimatorContext`

    Attributes
    ----------
    ekf : the EKF that runs alongside (window filling, fallback, arrival covariance)
    em : the estimation model; N : window length [samples]
    observability, observability_steady : construction-time reports (see the EKF)
    """

    kind = "mhe"
    options_class = MHEOptions
    model_based = True

    def __init__(self, options: MHEOptions, context: EstimatorContext):
        options = for_rig(options, context.model, context.params)      # unit-carrying defaults from the rig
        super().__init__(options, context)
        from dataclasses import replace
        # the compiled update runs its own EKF (csrc/ss_mhe.c): this one then only gives its model
        c_core = options.compile and options.qpsol == "ldl"
        self.ekf = EKF(replace(options.ekf_options(), check_observability=False,
                               compile=options.ekf_options().compile and not c_core), context)
        em = self.em = self.ekf.em
        self.names, self.channels = em.names, em.channels
        nx, ny, N, nuh, npar = em.nx, em.ny, options.window, em.nuh, len(em.p)
        self.N = N
        self._sr = np.sqrt(em.r)

        # SX pieces: the shooting stage (weighted gap and its Jacobians) and the measurements
        xk, xk1 = ca.SX.sym("xk", nx), ca.SX.sym("xk1", nx)
        uk, p, q = ca.SX.sym("uh", nuh), ca.SX.sym("p", npar), ca.SX.sym("q", nx)
        Fk = em.F(xk, uk, p)
        iq = 1.0 / ca.sqrt(ca.fmax(q + em.stick(xk, uk, p), FLOOR))
        stage = ca.Function(f"{em.model.cname}_mhe_stage", [xk, xk1, uk, p, q],
                            [iq * (xk1 - Fk), -ca.mtimes(ca.diag(iq), ca.jacobian(Fk, xk)), iq],
                            ["x", "x_next", "uh", "p", "q"], ["gap", "J", "iq"])
        hk = em.h(xk, uk, p)
        meas = ca.Function(f"{em.model.cname}_mhe_meas", [xk, uk, p], [hk, ca.jacobian(hk, xk)],
                           ["x", "uh", "p"], ["h", "C"])
        self._lbw = np.tile(em.lb, N + 1)
        self._ubw = np.tile(em.ub, N + 1)

        # arrival prior: the EKF's prediction of the window's first node (its estimate one sample
        # before, propagated): it holds no measurement of the window, so nothing is counted twice
        xa, Pa, ua, pa = ca.SX.sym("x", nx), ca.SX.sym("P", nx, nx), ca.SX.sym("uh", nuh), ca.SX.sym("p", npar)
        xn = em.F(xa, ua, pa)
        A = ca.jacobian(xn, xa)
        Pn = ca.mtimes([A, Pa, A.T]) + ca.diag(ca.DM(em.q) + em.stick(xa, ua, pa))
        self.arrival = ca.Function(f"{em.model.cname}_mhe_arrival", [xa, Pa, ua, pa], [xn, 0.5 * (Pn + Pn.T)],
                                   ["x", "P", "uh", "p"], ["x_next", "P_next"])
        # raw channels -> internal measurements: a linear map, and masks as products
        nc = len(self.channels)
        yr, mr = ca.SX.sym("y", nc), ca.SX.sym("m", nc)
        self._T = np.array(ca.evalf(ca.jacobian(em.to_internal(yr, mr)[0], yr)))
        self._mask_idx = [np.flatnonzero(em.dep[j]) for j in range(ny)]

        # compiled: the whole update (this MHE's window step and its EKF) is one C call (csrc/ss_mhe.c)
        self._c = None
        self.compiled, self.compile_status = False, "not requested"
        if options.compile and options.qpsol == "ldl":
            self.gn, self.gn_step = _window_functions(em, stage, meas, N)
            try:
                self._c = CompiledMHE(self)
                self.compiled, self.compile_status = True, f"compiled ({self._c.library.name})"
            except SolverFailure as exc:
                self.compile_status = f"compile failed, using the CasADi step: {exc}"
        elif options.compile:
            try:
                so = compile_cached([stage, meas], tag=f"{em.model.cname}_mhe")
                stage = ca.external(stage.name(), str(so))
                meas = ca.external(meas.name(), str(so))
                self.compiled, self.compile_status = True, f"compiled ({so.name})"
            except Exception as exc:
                self.compile_status = f"compile failed, using SX: {exc}"
        self.stage, self.meas = stage, meas
        if self._c is None and not hasattr(self, "gn"):
            self.gn, self.gn_step = _window_functions(em, stage, meas, N)
        if options.qpsol == "ldl":
            self.qp = None
        else:
            self.qp = ca.conic("mhe_qp", options.qpsol,
                               {"h": self.gn.sparsity_out(0), "a": ca.Sparsity(0, nx * (N + 1))},
                               {"error_on_fail": False, "osqp": {"verbose": False}})
        self._gn_in, self._gn_out, self._gn_buf, self._gn_eval = _bind(self.gn)
        self._gn_in[6][:] = em.p
        self._gn_in[7][:] = em.q
        self._ar_in, self._ar_out, self._ar_buf, self._ar_eval = _bind(self.arrival)
        self._ar_in[3][:] = em.p

        # the last N+1 samples, and the EKF's estimate one sample before the window
        self._Y = deque(maxlen=N + 1)      # internal measurements (NaN-free)
        self._M = deque(maxlen=N + 1)      # internal masks
        self._UH = deque(maxlen=N + 1)     # input history of the sample ending at each node
        self._XE = deque(maxlen=N + 2)     # EKF estimates (x, P), the first one before the window
        self._XE.append((em.x0.copy(), em.P0.copy()))
        self._w = None
        self.iterations = 0
        self.qp_failures = 0
        self._check_observability()

    def prior(self) -> Estimate:
        """The EKF's prior (the MHE's arrival cost starts from it)."""
        return self.ekf.prior()

    def _internal(self, y, mask):
        yi = self._T @ np.where(mask, y, 0.0)
        mi = np.array([float(mask[ix].all()) for ix in self._mask_idx])
        return yi, mi

    def _update_impl(self, t, y, mask, u):
        if self._c is not None:
            return self._update_compiled(t, y, mask, u)
        e_ekf = self.ekf.update(t, dict(zip(self.channels, y)), u)     # runs every step (fallback, warm start)
        if e_ekf.status is Status.FALLBACK:
            raise SolverFailure(f"EKF alongside failed: {e_ekf.message}")
        yi, mi = self._internal(y, mask)
        if not self._UH:       # the EKF's prior of the first update (it may take the measured speeds)
            self._XE[0] = (self.ekf.x0_used.copy(), self.em.P0.copy())
        self._UH.append(self.ekf._uh.copy())
        self._Y.append(yi)
        self._M.append(mi)
        self._XE.append((e_ekf.x, e_ekf.P))
        nx, N = self.em.nx, self.N
        if len(self._Y) < N + 1:
            status, msg = self._status(mask, e_ekf.P)
            return Estimate(t, e_ekf.x, e_ekf.P, self.names, status,
                            f"{msg}; window filling ({len(self._Y)}/{N + 1}): EKF estimate", e_ekf.corrected)
        try:
            return self._solve(t, mask, e_ekf)
        except (SolverFailure, PluginError):
            raise
        except (RuntimeError, FloatingPointError, np.linalg.LinAlgError) as exc:   # CasADi's and the C step's
            raise SolverFailure(f"{type(exc).__name__}: {exc}") from exc

    def _solve(self, t, mask, e_ekf):
        """The window's Gauss-Newton solve (the EKF has run; the window is full)."""
        nx, N = self.em.nx, self.N
        # warm start: the previous solution shifted by one node, the new node the EKF's
        if self._w is None:
            self._w = np.concatenate([xe for xe, _ in list(self._XE)[1:]])
        else:
            self._w = np.concatenate([self._w[nx:], e_ekf.x])
        a = self._ar_in
        a[0][:] = self._XE[0][0]
        a[1][:] = self._XE[0][1].ravel(order="F")
        a[2][:] = self._UH[0]
        self._ar_eval()
        self._xbar = self._ar_out[0].copy()
        self._Pbar = self._ar_out[1].reshape(nx, nx, order="F")
        UHm = np.array(self._UH).T
        Ym = np.array(self._Y).T
        Wm = (np.array(self._M) / self._sr).T
        w = self._w
        gi = self._gn_in
        gi[1][:] = self._xbar
        gi[2][:] = self._Pbar.ravel(order="F")
        gi[3][:] = UHm.ravel(order="F")
        gi[4][:] = Ym.ravel(order="F")
        gi[5][:] = Wm.ravel(order="F")
        Pw = None
        for _ in range(self.options.max_iter):
            gi[0][:] = w
            self._gn_eval()
            self.iterations += 1
            if self.qp is None:
                d = self._gn_out[3]
                Pw = self._gn_out[4]
            else:
                sol = self.qp(h=ca.DM(self.gn.sparsity_out(0), self._gn_out[0]), g=self._gn_out[1],
                              lbx=self._lbw - w, ubx=self._ubw - w)
                if not self.qp.stats()["success"]:
                    self.qp_failures += 1
                    raise SolverFailure(f"QP ({self.options.qpsol}) failed: {self.qp.stats().get('return_status', '?')}")
                d = np.array(sol["x"]).ravel()
                Pw = self._gn_out[4]
            if not np.all(np.isfinite(d)):
                raise SolverFailure("non-finite Gauss-Newton step")
            w = np.clip(w + d, self._lbw, self._ubw)
        self._w = w
        P = Pw.reshape(nx, nx, order="F")
        P = 0.5 * (P + P.T)
        if not np.all(np.diag(P) > 0):
            raise SolverFailure("Gauss-Newton Hessian not positive definite")
        x = w[-nx:].copy()
        status, msg = self._status(mask, P)
        return Estimate(t, x, P, self.names, status, msg, bool(mask.any()))

    def _update_compiled(self, t, y, mask, u):
        """The same update as one compiled C call (``csrc/ss_mhe.c``, its EKF inside); a failure raises
        SolverFailure and :meth:`_fallback` returns the EKF's estimate the C core kept."""
        c = self._c
        info = c.update(np.where(mask, y, np.nan), u)
        self._c_corrected = bool(info.ekf.corrected)
        if info.failed:
            why = MHE_FAILURES.get(info.failed, f"failure {info.failed}")
            if info.failed == 1:
                why += ": fallback: SolverFailure: non-finite estimate (prediction only)"
            raise SolverFailure(why)
        x, P = c.x, c.P
        status, msg = self._status(mask, P)
        if info.filling:
            return Estimate(t, x, P, self.names, status,
                            f"{msg}; window filling ({info.filling}/{self.N + 1}): EKF estimate", self._c_corrected)
        self.iterations += self.options.max_iter
        return Estimate(t, x, P, self.names, status, msg, bool(mask.any()))

    def _fallback(self, t, y, mask, u, message):
        """The EKF's estimate of this step (it ran before the MHE's solve)."""
        if self._c is not None:
            return Estimate(t, self._c.x, self._c.P, self.names, Status.FALLBACK, f"{message} (EKF estimate)",
                            getattr(self, "_c_corrected", False))
        e = self.ekf.last
        if e is None or e.t != t:
            e = self.ekf.update(t, dict(zip(self.channels, y)), u)
        if self._w is not None:      # restart the window's last node from the EKF
            self._w[-self.em.nx:] = e.x
        return Estimate(t, e.x, e.P, self.names, Status.FALLBACK, f"{message} (EKF estimate)", e.corrected)
