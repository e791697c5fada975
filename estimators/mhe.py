"""Moving-horizon estimator for the 3-disc rig: Gauss-Newton RTI on a multiple-shooting window.

Window of ``N`` samples, nodes ``x_0 .. x_N`` (the estimator state of
:mod:`estimators.ekf`, with the same augmented unknowns).  The decision variables are
the node states only; the known inputs ``u_k``, the measurements, their masks, the
arrival prior and the model parameters are NLP *parameters*.  The cost is a
least-squares sum::

    |W0 (x_0 - xbar)|^2 + sum_k |(x_{k+1} - F(x_k, u_k)) / sqrt(q)|^2 + sum_k |m_k (y_k - C x_k) / sqrt(r)|^2

(process noise is the multiple-shooting gap, weighted by the EKF's process covariance;
``W0' W0 = Pbar^-1``).  Simple bounds on all states (``EstimationModel.lb/ub``).

Solver: ``max_iter`` Gauss-Newton SQP iterations per sample (default 1: real-time
iteration), each a bound-constrained QP ``min 1/2 d'J'Jd + (J'r)'d`` solved by CasADi's
``conic`` (``qrqp`` by default; the gaps are in the cost, so no equality constraints).
The shooting stage function ``(x_k, x_{k+1}, u_k, p) -> (gap, dgap/dx_k)`` is SX; with
``compile=True`` it is built with gcc (cached on disk, see :func:`estimators.ekf.compile_cached`)
and loaded with ``casadi.external``, then mapped over the window inside one MX Function.

Arrival cost: EKF-style.  When the window slides, ``xbar`` becomes the previous
solution's ``x_1`` and ``Pbar`` follows the EKF Riccati recursion (correct with the
measurement leaving the window, predict through ``F``), so it is not a fixed weight.

Warm start: the previous solution shifted by one node, the new last node predicted.

Robustness: an EKF runs alongside every step.  Until the window is full, and whenever
the QP fails or returns non-finite numbers, the estimate is the EKF's (``success=False``
and counted as a failure/fallback after the window is full).  The reported covariance
is the marginal of the last node from the inverse Gauss-Newton Hessian.

Speed: the step is dominated by the dense Cholesky of the ``nx (N+1)`` square GN
Hessian (210 x 210 for N = 20).  Run with ``OPENBLAS_NUM_THREADS=1``: on a loaded
2-core machine, threaded BLAS made the median 2-5x and the p95 100x worse.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Mapping

import casadi as ca
import numpy as np
import scipy.linalg

from estimators.base import Estimate, StateEstimator
from estimators.ekf import (ALL_CHANNELS, EKF, EKFOptions, _check_common, build_estimation_model, compile_cached,
                            options_from_mapping)
from models.errors import ConfigError
from models.params import Rig3Params
from models.sensors import SensorOptions

__all__ = ["MHEOptions", "MHE", "make_mhe"]

_QP = ("cholesky", "qrqp", "osqp")
_QFLOOR = 1e-10   # [state unit^2] floor of the gap weights: keeps J'J well conditioned


@dataclass(frozen=True, kw_only=True)
class MHEOptions(EKFOptions):
    """Options of the MHE (``[estimator]`` with ``kind = "mhe"``); shares the EKF's model/noise options.

    Parameters
    ----------
    window : samples in the horizon N (nodes N+1), >= 2
    max_iter : Gauss-Newton iterations per sample (1 = real-time iteration), >= 1
    qpsol : "cholesky" (default: unconstrained GN step by dense Cholesky, then projected onto
        the bounds) or a CasADi QP solver for the bound-constrained step ("qrqp", "osqp")
    channels, angles, augment, eps, nsub, q_*, p0_*, compile : as :class:`estimators.ekf.EKFOptions`
    """

    window: int = 20
    max_iter: int = 1
    qpsol: str = "cholesky"

    def __post_init__(self):
        super().__post_init__()
        if isinstance(self.window, bool) or not isinstance(self.window, int) or self.window < 2:
            raise ConfigError(f"estimator.window must be an integer >= 2 samples, got {self.window!r}")
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, int) or self.max_iter < 1:
            raise ConfigError(f"estimator.max_iter must be an integer >= 1, got {self.max_iter!r}")
        if self.qpsol not in _QP:
            raise ConfigError(f"estimator.qpsol must be one of {', '.join(_QP)}, got {self.qpsol!r}")

    def ekf_options(self) -> EKFOptions:
        keep = {f for f in EKFOptions.__dataclass_fields__}
        return EKFOptions(**{k: getattr(self, k) for k in keep})


MHEOptions.kind_name = "mhe"


class MHE(StateEstimator):
    """Moving-horizon estimator for rig3 (see module docstring).

    Parameters
    ----------
    params : Rig3Params the estimator believes
    sensors : SensorOptions
    dt : DAQ period [s]
    options : MHEOptions
    x0 : initial guess (7 rig3 states or the full augmented state)
    """

    def __init__(self, params: Rig3Params, sensors: SensorOptions = SensorOptions(), dt: float = 0.01,
                 options: MHEOptions = MHEOptions(), x0=None):
        super().__init__()
        self.options = options
        self.ekf = EKF(params, sensors, dt, options.ekf_options(), x0)
        em = self.em = self.ekf.em
        self.names, self.channels = em.names, em.channels
        nx, ny, N = em.nx, em.ny, options.window
        self.N = N
        self._p = np.asarray(params.vector(), dtype=float)
        xs = ca.SX.sym("x", nx)
        C = np.array(ca.Function("C", [xs], [ca.jacobian(em.h(xs, self._p), xs)])(np.zeros(nx)))
        self.C = C
        self._sr = np.sqrt(em.r)
        self._iq = 1.0 / np.sqrt(np.maximum(em.q, _QFLOOR))

        # shooting stage: gap and its Jacobian w.r.t. x_k (weighted)
        xk, xk1 = ca.SX.sym("xk", nx), ca.SX.sym("xk1", nx)
        uk, p, iq = ca.SX.sym("u", 3), ca.SX.sym("p", len(self._p)), ca.SX.sym("iq", nx)
        Fk = em.F(xk, uk, p)
        gap = iq * (xk1 - Fk)
        Ja = -ca.mtimes(ca.diag(iq), ca.jacobian(Fk, xk))
        stage = ca.Function("mhe_stage", [xk, xk1, uk, p, iq], [gap, Ja],
                            ["x", "x_next", "u", "p", "iq"], ["gap", "J"])
        self.compile_status = "not requested"
        if options.compile:
            try:
                so = compile_cached(stage)
                stage = ca.external("mhe_stage", str(so))
                self.compile_status = f"compiled ({so.name})"
            except Exception as exc:
                self.compile_status = f"compile failed, using SX: {exc}"
        self.stage = stage

        # one MX Function: w, parameters -> GN Hessian J'J, gradient J'r, cost
        w = ca.MX.sym("w", nx * (N + 1))
        xbar, W0 = ca.MX.sym("xbar", nx), ca.MX.sym("W0", nx, nx)
        Um = ca.MX.sym("U", 3, N)
        Ym, Wm = ca.MX.sym("Y", ny, N + 1), ca.MX.sym("Wm", ny, N + 1)   # Wm = mask / sqrt(r)
        pm, iqm = ca.MX.sym("p", len(self._p)), ca.MX.sym("iq", nx)
        X = ca.reshape(w, nx, N + 1)
        gaps, Jas = stage.map(N)(X[:, :N], X[:, 1:], Um, ca.repmat(pm, 1, N), ca.repmat(iqm, 1, N))
        Cm = ca.DM(C)
        r_arr = ca.mtimes(W0, X[:, 0] - xbar)
        r_dyn = ca.vec(gaps)
        r_meas = ca.vec(Wm * (Ym - ca.mtimes(Cm, X)))
        J_arr = ca.horzcat(W0, ca.MX(nx, nx * N))
        Jblocks = ca.horzsplit(Jas, nx)
        J_dyn = ca.horzcat(ca.diagcat(*Jblocks), ca.MX(nx * N, nx)) + \
            ca.horzcat(ca.MX(nx * N, nx), ca.diagcat(*[ca.diag(iqm)] * N))
        J_meas = ca.diagcat(*[ca.mtimes(ca.diag(Wm[:, k]), Cm) for k in range(N + 1)])
        J = ca.vertcat(J_arr, J_dyn, -J_meas)
        r = ca.vertcat(r_arr, r_dyn, r_meas)
        H = ca.mtimes(J.T, J)
        g = ca.mtimes(J.T, r)
        self.gn = ca.Function("mhe_gn", [w, xbar, W0, Um, Ym, Wm, pm, iqm], [H, g, 0.5 * ca.sumsqr(r)],
                              ["w", "xbar", "W0", "U", "Y", "Wm", "p", "iq"], ["H", "g", "cost"])
        qp_opts = {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False} \
            if options.qpsol == "qrqp" else {"error_on_fail": False, "osqp": {"verbose": False}}
        self.qp = None if options.qpsol == "cholesky" else ca.conic("mhe_qp", options.qpsol, {"h": H.sparsity(), "a": ca.Sparsity(0, nx * (N + 1))}, qp_opts)
        # zero-copy calls: numpy arrays bound once to the Functions' argument/result buffers
        self._gn_in = [np.zeros(self.gn.nnz_in(i)) for i in range(self.gn.n_in())]
        self._gn_out = [np.zeros(self.gn.nnz_out(i)) for i in range(self.gn.n_out())]
        self._gn_buf, self._gn_eval = self.gn.buffer()
        for i, a in enumerate(self._gn_in):
            self._gn_buf.set_arg(i, memoryview(a))
        for i, a in enumerate(self._gn_out):
            self._gn_buf.set_res(i, memoryview(a))
        self._gn_in[6][:] = self._p
        self._gn_in[7][:] = self._iq
        hs = H.sparsity()
        self._H_rows, self._H_cols = (np.array(v, dtype=np.intp) for v in hs.get_triplet())
        self._Hd = np.zeros((nx * (N + 1), nx * (N + 1)))
        self._lbw = np.tile(em.lb, N + 1)
        self._ubw = np.tile(em.ub, N + 1)

        # arrival-cost covariance: EKF Riccati step (correct with the leaving sample, then predict)
        xa, Pa, ua, ma = ca.SX.sym("x", nx), ca.SX.sym("P", nx, nx), ca.SX.sym("u", 3), ca.SX.sym("m", ny)
        pa = ca.SX.sym("p", len(self._p))
        Pc = Pa
        for j in range(ny):
            cj = ca.DM(C[j:j + 1, :])
            Ph = ca.mtimes(Pc, cj.T)
            s = ca.mtimes(cj, Ph) + em.r[j]
            Pc = Pc - ma[j] * ca.mtimes(Ph, Ph.T) / s
        A = ca.jacobian(em.F(xa, ua, pa), xa)
        Pn = ca.mtimes([A, Pc, A.T]) + ca.diag(ca.DM(em.q))
        self.arrival = ca.Function("mhe_arrival", [xa, Pa, ua, ma, pa], [0.5 * (Pn + Pn.T)],
                                   ["x", "P", "u", "m", "p"], ["P_next"])

        self._ar_in = [np.zeros(self.arrival.nnz_in(i)) for i in range(self.arrival.n_in())]
        self._ar_out = np.zeros(self.arrival.nnz_out(0))
        self._ar_buf, self._ar_eval = self.arrival.buffer()
        for i, a in enumerate(self._ar_in):
            self._ar_buf.set_arg(i, memoryview(a))
        self._ar_buf.set_res(0, memoryview(self._ar_out))
        self._ar_in[4][:] = self._p
        # measurement channels -> internal measurements, in numpy (linear map and mask products)
        yr, mr = ca.SX.sym("y", len(self.channels)), ca.SX.sym("m", len(self.channels))
        yi_, mi_ = em.to_internal(yr, mr)
        self._T = np.array(ca.evalf(ca.jacobian(yi_, yr)))
        self._mask_idx = [np.array([i for i in range(len(self.channels)) if ca.depends_on(mi_[j], mr[i])])
                          for j in range(ny)]

        # buffers (the last N+1 samples)
        self._Y = deque(maxlen=N + 1)     # internal measurements (NaN-free)
        self._M = deque(maxlen=N + 1)     # internal masks
        self._U = deque(maxlen=N)         # input over the sample ending at each node > 0
        self._XE = deque(maxlen=N + 1)    # EKF estimates (initial guess for the first window)
        self._w = None
        self._xbar = None
        self._Pbar = None
        self.iterations = 0
        self.qp_failures = 0

    def _internal(self, y, mask):
        yi = self._T @ np.where(mask, y, 0.0)
        mi = np.array([float(mask[ix].all()) for ix in self._mask_idx])
        return yi, mi

    def _update_impl(self, y, mask, u, t):
        e_ekf = self.ekf.update(dict(zip(self.channels, y)), u, t)   # the fallback runs every step
        yi, mi = self._internal(y, mask)
        if self._XE:
            self._U.append(np.asarray(u, dtype=float).copy())
        else:
            self._P_first = e_ekf.P.copy()
        self._Y.append(yi)
        self._M.append(mi)
        self._XE.append(e_ekf.x)
        nx, N = self.em.nx, self.N
        if len(self._Y) < N + 1:
            return Estimate(t, e_ekf.x, e_ekf.P, self.names, f"window filling ({len(self._Y)}/{N + 1}): EKF",
                            True, e_ekf.corrected)
        if self._w is None:
            self._w = np.concatenate(list(self._XE))
            self._xbar = self._XE[0].copy()
            self._Pbar = self._P_first
        else:
            # slide: arrival prior from the previous solution's node 1 and an EKF Riccati step
            w_old = self._w
            x0_old = w_old[:nx]
            a = self._ar_in
            a[0][:] = x0_old
            a[1][:] = self._Pbar.ravel(order="F")
            a[2][:] = self._u_leaving
            a[3][:] = self._m_leaving
            self._ar_eval()
            self._Pbar = self._ar_out.reshape(nx, nx, order="F").copy()
            self._xbar = w_old[nx:2 * nx].copy()
            # warm start: shifted solution; the new node from the EKF (already one predict+correct ahead)
            self._w = np.concatenate([w_old[nx:], e_ekf.x])
        self._u_leaving = self._U[0].copy()
        self._m_leaving = self._M[0].copy()
        try:
            W0 = np.linalg.cholesky(np.linalg.inv(self._Pbar)).T
        except np.linalg.LinAlgError:
            raise RuntimeError("arrival covariance not positive definite") from None
        Um = np.array(self._U).T
        Ym = np.array(self._Y).T
        Wm = (np.array(self._M) / self._sr).T
        w = self._w
        for _ in range(self.options.max_iter):
            gi = self._gn_in
            gi[0][:] = w
            gi[1][:] = self._xbar
            gi[2][:] = W0.ravel(order="F")
            gi[3][:] = Um.ravel(order="F")
            gi[4][:] = Ym.ravel(order="F")
            gi[5][:] = Wm.ravel(order="F")
            self._gn_eval()
            Hd = self._Hd
            Hd[self._H_rows, self._H_cols] = self._gn_out[0]
            g = self._gn_out[1]
            self.iterations += 1
            if self.qp is None:
                cf = scipy.linalg.cho_factor(Hd, check_finite=False)
                d = -scipy.linalg.cho_solve(cf, g, check_finite=False)
            else:
                H = ca.DM(self.gn.sparsity_out(0), self._gn_out[0])
                sol = self.qp(h=H, g=g, lbx=self._lbw - w, ubx=self._ubw - w)
                if not self.qp.stats()["success"]:
                    self.qp_failures += 1
                    raise RuntimeError(f"QP ({self.options.qpsol}) failed: "
                                       f"{self.qp.stats().get('return_status', '?')}")
                d = np.array(sol["x"]).ravel()
                cf = None
            if not np.all(np.isfinite(d)):
                raise FloatingPointError("non-finite QP step")
            w = np.clip(w + d, self._lbw, self._ubw)
        self._w = w
        E = np.zeros((Hd.shape[0], nx))
        E[-nx:, :] = np.eye(nx)
        P = (scipy.linalg.cho_solve(cf, E, check_finite=False) if cf is not None else np.linalg.solve(Hd, E))[-nx:, :]
        P = 0.5 * (P + P.T)
        x = w[-nx:].copy()
        status = "ok" if mask.all() else "partial: missing " + ",".join(
            c for c, m in zip(self.channels, mask) if not m)
        return Estimate(t, x, P, self.names, status, True, bool(mask.any()))

    def _fallback(self, y, mask, u, t, status):
        """The EKF's estimate of this step (it was updated before the MHE solve)."""
        e = self.ekf.last
        if e is None or e.t != t:
            e = self.ekf.update(dict(zip(self.channels, y)), u, t)
        # restart the window from the EKF next time it is needed
        if self._w is not None:
            self._w[-self.em.nx:] = e.x
        return Estimate(t, e.x, e.P, self.names, status + " (EKF estimate)", False, e.corrected)


def make_mhe(opts: Mapping[str, Any], model_params: Rig3Params, sensors: SensorOptions, dt: float,
             x0=None, where: str = "estimator") -> MHE:
    """Factory hook: validate ``opts`` (an ``[estimator]`` table without ``kind``) and build an MHE."""
    o = options_from_mapping(MHEOptions, opts, where)
    return MHE(model_params, sensors, dt, o, x0)
