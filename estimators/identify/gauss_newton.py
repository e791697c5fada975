"""Constrained Gauss-Newton / Levenberg-Marquardt for a :class:`~estimators.identify.shooting.ShootingProblem`.

Each iteration solves the sparse KKT system of the continuity-constrained least-squares
problem with the Gauss-Newton Hessian ``J^T J``::

    [ J^T J + mu I   A^T   G_a^T ] [dw ]   [ -J^T r  ]
    [ A              0     0     ] [lam] = [ -g      ]
    [ G_a            0     0     ] [nu ]   [ h_a - G_a w ]

(scipy SuperLU on a banded ordering with a border; the zero block is regularised to ``-1e-12 I`` so
that the factorisation may pivot in that order, and every solve is refined iteratively against the
exact matrix: the multipliers of stuck intervals reach 1e8, and the regularisation alone left their
``1e-12 lambda`` behind as continuity gaps no step could close), where ``A`` is the Jacobian of the
continuity gaps ``g`` and ``G_a w <= h_a`` the *active* linear inequalities on the border
variables (the parameters' bounds, ``mu_k <= mu_s``, user constraints).  The active set is
updated inside the iteration: a row whose multiplier has the wrong sign is released, the most
violated inactive row is added, until neither happens.

Robustness on real logs (Levenberg-Marquardt / trust region):

- ``mu`` (relative to the largest diagonal entry of ``J^T J``) and a trust radius on the scaled
  parameter step adapt to the ratio of the actual to the predicted decrease of the l1 merit
  function ``0.5 |r|^2 + nu |g|_1``;
- a step whose parameter part leaves the trust radius is first damped (``mu`` raised for that
  step, a decade at a time up to :data:`LM_RADIUS_MAX`, the search starting two decades below the
  last step's damping), and only then shortened to the radius: the undamped Gauss-Newton direction
  of a log that leaves states unmeasured is dominated by ill-conditioned node moves (steps of 70
  state ranges), and shortening it to the radius crawled (zoo example_3: 35 iterations, not
  converged);
- the step length comes from a backtracking line search on that merit, with one second-order
  correction (Nocedal & Wright 18.3) against the Maratos effect;
- when no step decreases the merit, ``mu`` is raised (shorter, more gradient-like steps) and the
  iteration is retried before the solver gives up;
- once the scaled gaps are below :data:`GAP_OK` (far below any sensor's noise), a step is judged
  by the cost alone: its actual change may not exceed the GN model's for that step length (closing
  the last gaps may cost a little), and the gaps must stay below GAP_OK; the l1 merit's gap
  multipliers, huge in stiff (stuck) intervals, would trade real cost for gap changes far below
  the noise; a problem without gaps (single shooting, :mod:`~estimators.identify.single`) has no
  gaps to close and takes a sufficient decrease of the cost (Armijo): asking it for the GN model's
  whole predicted decrease rejected every step of a simulation more curved than its model (the
  refinements ended on failed line searches with the cost still falling);
- the solver keeps the lowest-cost iterate whose scaled gaps are below GAP_OK, and counts a failed
  line search there as
  converged when the step would lower the cost by less than ``0.02 s^2`` (``s^2`` the residual
  variance per degree of freedom: the parameters would move by less than 0.2 standard errors),
  or when five feasible iterations together lowered it by less than ``1e-3 s^2`` (a stall).

The solver reports WHY it stopped (:class:`GNResult.reason`): ``"small_step"``,
``"no_predicted_decrease"``, ``"no_further_decrease"`` (all converged), ``"max_iter"``,
``"line_search"``, ``"stalled"`` (gaps open, cost and gaps no longer moving over five iterations),
``"diverging"`` (gaps open and not closing while the cost grew tenfold: :data:`DIVERGE_COST`)
or ``"singular"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from estimators.identify.shooting import KKTFactor

__all__ = ["GNResult", "solve_gn", "CONVERGED"]

CONVERGED = ("small_step", "no_predicted_decrease", "no_further_decrease")
#: scaled continuity gaps below this are far below any sensor's noise (the states are scaled by
#: their range): such an iterate counts as feasible
GAP_OK = 1e-4
#: the largest Levenberg-Marquardt parameter (relative to the largest diagonal entry of ``J^T J``) that a
#: step whose parameters leave the trust radius is damped to; beyond it the step is shortened to the
#: radius (zoo example_3, a lead screw read at the motor only: the shortened undamped steps crawled, 35
#: iterations and not converged; damped it converged in 22.  Damping up to 1e-2 sent zoo example_1,
#: one encoder on a bit, to a cost of 291 instead of 0.37: the steps then turn into gradient steps
#: in the scaled nodes and close the gaps in the first basin they meet)
LM_RADIUS_MAX = 1e-5
#: a fit is diverging when over its last DIVERGE_ITER iterations every cost exceeded DIVERGE_COST times its
#: first iteration's and every largest gap stayed above half the first's (and at least ten times GAP_OK):
#: the rig2 case of ``bench_identify.py accuracy`` (Stribeck friction at the rig's eps, 0.0016 rad/s, a
#: 60 s log) went from cost 1.8e4 to 1.1e6 over 100 iterations with its largest gap at 0.10-0.35, where
#: the continuation in eps converges in 21; the same rig on a 20 s log rose to 97 times its first cost
#: for four iterations and then converged (14 iterations): a shorter window would have cut it off; no
#: fit of the zoo (``bench_identify_zoo.py``) raises its cost above its first iteration's
DIVERGE_COST = 10.0
DIVERGE_ITER = 8


@dataclass(frozen=True)
class GNResult:
    """What :func:`solve_gn` returns.

    Attributes
    ----------
    w : the final scaled decision vector
    iterations : iterations done
    reason : why it stopped (see the module docstring)
    success : ``reason in CONVERGED``
    costs : ``0.5 |r|^2`` at the start of every iteration, then at the end
    max_gap : largest scaled continuity gap at the end
    active : indices of the inequality rows active at the end
    """

    w: np.ndarray
    iterations: int
    reason: str
    success: bool
    costs: tuple = ()
    max_gap: float = 0.0
    active: tuple = ()
    radius: float = float("nan")
    lm: float = float("nan")
    history: tuple = field(default=(), repr=False)


#: regularisation of the KKT matrix's constraint block (it makes the matrix quasi-definite, so the
#: factorisation may take its pivots in the banded order); every solve is refined against the exact
#: KKT matrix, because the multipliers of stiff (stuck) intervals reach 1e8 and ``delta * lambda``
#: would otherwise stay behind as a continuity gap of 1e-4 that no step closes
_DELTA = 1e-12


class _Refined:
    """Solves with the regularised factorisation ``fac``, refined iteratively against the exact KKT
    matrix ``K0`` (same unknowns, original order) until its residual stops falling."""

    def __init__(self, fac, K0):
        self.fac, self.K0 = fac, K0.tocsr()

    def solve(self, rhs):
        x = self.fac.solve(rhs)
        scale = float(np.max(np.abs(rhs))) + 1e-300
        res = rhs - self.K0 @ x
        err = float(np.max(np.abs(res)))
        for _ in range(8):
            if err <= 1e-14 * scale:
                break
            x_new = x + self.fac.solve(res)
            res_new = rhs - self.K0 @ x_new
            err_new = float(np.max(np.abs(res_new)))
            if not err_new < 0.5 * err:
                break
            x, res, err = x_new, res_new, err_new
        return x


def _kkt_solve(prob, H, mu, grad, A, g, G, h, w, active, ng):
    """Solve the KKT system for the step with the active-set update; returns (dw, lam, active, factor, Aall)."""
    nw, nb = prob.nw, prob.nb
    m = G.shape[0]
    active = [i for i in active if i < m]
    Hm = (H + mu * sp.identity(nw, format="csc")).tocsc()
    fac = Aall = None
    for _ in range(2 * m + 4):
        na = len(active)
        if na:
            Ga = np.zeros((na, nw))
            Ga[:, :nb] = G[active]
            Aall = sp.vstack([A, sp.csc_matrix(Ga)]).tocsc()
            rhs_c = np.r_[-g, h[active] - G[active] @ w[:nb]]
        else:
            Aall = A.tocsc()
            rhs_c = -g
        K = sp.bmat([[Hm, Aall.T], [Aall, -_DELTA * sp.identity(Aall.shape[0], format="csc")]], format="csc")
        fac = _Refined(KKTFactor(prob, K, na), sp.bmat([[Hm, Aall.T], [Aall, None]], format="csc"))
        sol = fac.solve(np.r_[-grad, rhs_c])
        if not np.all(np.isfinite(sol)):
            raise RuntimeError("non-finite KKT solution")
        dw = sol[:nw]
        lam = sol[nw:nw + ng]
        if na:
            nu = sol[nw + ng:]
            j = int(np.argmin(nu))
            if nu[j] < -1e-10 * max(1.0, float(np.max(np.abs(grad[:nb])))):
                active.pop(j)           # this row pulls the step inward: release it
                continue
        if m:
            slack = G @ (w[:nb] + dw[:nb]) - h
            slack[active] = -np.inf
            j = int(np.argmax(slack))
            if slack[j] > 1e-12 * max(1.0, abs(h[j])):
                active.append(j)
                continue
        break
    return dw, lam, active, fac, Aall


def solve_gn(prob, w0, G=None, h=None, *, max_iter: int = 100, tol: float = 1e-8, trust_radius: float = 1.0,
             callback=None, admissible=None) -> GNResult:
    """Constrained Gauss-Newton on ``prob`` from ``w0`` (see the module docstring).

    Parameters
    ----------
    prob : ShootingProblem
    w0 : (nw,) scaled start; it must satisfy ``G w0[:nb] <= h`` (up to round-off)
    G, h : linear inequalities ``G w[:nb] <= h`` on the scaled border variables (m, nb), (m,)
    max_iter : iteration limit
    tol : converged when the scaled step is below ``sqrt(tol)`` and the scaled gaps below ``100 tol``
    trust_radius : initial largest change of a scaled free parameter per step
    callback : ``callback(iteration, cost, max_gap, step)`` per iteration
    admissible : ``admissible(w) -> bool``: trial points where it is False are rejected by the line
        search (e.g. parameters for which the discretisation is unstable)
    """
    nf, nb, nw = prob.nf, prob.nb, prob.nw
    G = np.zeros((0, nb)) if G is None else np.asarray(G, float)
    h = np.zeros(0) if h is None else np.asarray(h, float)
    w = np.asarray(w0, float).copy()
    r, g, Jr, A, _ = prob.evaluate(w)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(g))):
        return GNResult(w, 0, "non_finite_start", False, (), float("inf"))
    nu_pen = 1.0
    lm = 1e-10
    lm_tr = 0.0         # the damping the last step needed to fit the trust radius
    radius = float(trust_radius)
    active = [i for i in range(G.shape[0]) if G[i] @ w[:nb] >= h[i] - 1e-10 * max(1.0, abs(h[i]))]
    reason = "max_iter"
    costs, gaps = [], []
    best = None         # (cost, w) of the lowest-cost iterate whose gaps are below GAP_OK
    diag = ()
    it = 0
    for it in range(1, max_iter + 1):
        f = 0.5 * float(r @ r)
        costs.append(f)
        gmax0 = float(np.max(np.abs(g))) if g.size else 0.0
        if gmax0 < GAP_OK and (best is None or f < best[0]):
            best = (f, w.copy())
        H = (Jr.T @ Jr).tocsc()
        grad = Jr.T @ r
        mu = lm * max(1.0, float(H.diagonal().max()))
        ng = A.shape[0]
        try:
            # a parameter step beyond the trust radius is damped (the Levenberg-Marquardt trust-region
            # step) rather than shortened along the Gauss-Newton direction, whose long part can be all
            # ill-conditioned node moves: the damping search starts two decades below the damping the
            # last step needed (lm itself follows the line search)
            lm_r = max(lm, min(lm_tr / 100, LM_RADIUS_MAX))
            mu = lm_r * max(1.0, float(H.diagonal().max()))
            dw, lam, active, fac, Aall = _kkt_solve(prob, H, mu, grad, A, g, G, h, w, active, ng)
            while nf and float(np.max(np.abs(dw[:nf]))) > radius and lm_r < LM_RADIUS_MAX:
                lm_r = min(lm_r * 10, LM_RADIUS_MAX)
                mu = lm_r * max(1.0, float(H.diagonal().max()))
                dw, lam, active, fac, Aall = _kkt_solve(prob, H, mu, grad, A, g, G, h, w, active, ng)
            damped = lm_r > lm
            lm_tr = lm_r if damped else 0.0
        except (RuntimeError, ValueError):
            reason = "singular"
            break
        gmax = float(np.max(np.abs(g))) if g.size else 0.0
        step_inf = float(np.max(np.abs(dw))) if nw else 0.0
        if callback is not None:
            callback(it, f, gmax, step_inf)
        if step_inf < math.sqrt(tol) and gmax < 100 * tol:
            reason = "small_step"
            break
        # predicted GN decrease negligible (in units of noise-normalised squares: 1e-4 moves the
        # parameters by ~0.01 standard errors) and the gaps small: converged
        Jdw = Jr @ dw
        pred_full = -float(grad @ dw) - 0.5 * float(Jdw @ Jdw)
        s2 = max(1.0, 2 * f / max(r.size - nw + g.size, 1))
        if 0 <= pred_full <= max(tol * f, 1e-4 * s2) and gmax < GAP_OK:
            reason = "no_predicted_decrease"
            break
        # stalled: feasible, and the last 5 iterations lowered the cost by less than 1e-3 s^2
        if gmax < GAP_OK and len(costs) > 5 and costs[-6] - f < 1e-3 * s2:
            reason = "no_further_decrease"
            break
        gaps.append(gmax)
        # diverging: the l1 merit falls only through the gaps' sum while the data misfit grows (the gap
        # multipliers of a stiff friction law's stuck intervals reach 1e8 and dominate the merit); a
        # smoother problem (the continuation in eps) is the caller's way out
        if (len(gaps) > DIVERGE_ITER and gmax >= 10 * GAP_OK and min(costs[-DIVERGE_ITER:]) > DIVERGE_COST * costs[0]
                and min(gaps[-DIVERGE_ITER:]) > 0.5 * gaps[0]):
            reason = "diverging"
            break
        # stalled with gaps open (ten times GAP_OK): over the last 5 iterations the cost moved by less than
        # 0.1 % and the largest gap shrank by less than a tenth (a gap across a kink of the model, a DC motor's
        # voltage limit, that no step closes): not converged; the caller may continue by single shooting
        if gmax >= 10 * GAP_OK and len(costs) > 5 and abs(costs[-6] - f) < 1e-3 * abs(f) and gmax > 0.9 * gaps[-6]:
            reason = "stalled"
            break
        # step length limits: the feasible region of the inequalities, the trust radius
        t_max = 1.0
        if G.shape[0]:
            Gd = G @ dw[:nb]
            slack = h - G @ w[:nb]
            for i in np.flatnonzero(Gd > 1e-15):
                if i in active:
                    continue
                t_max = min(t_max, max(slack[i], 0.0) / Gd[i])
        dth = float(np.max(np.abs(dw[:nf]))) if nf else 0.0
        capped = False
        if dth * t_max > radius:
            t_max, capped = radius / dth, True
        nu_pen = max(nu_pen, 1.5 * float(np.max(np.abs(lam))) if lam.size else 0.0)
        gl1 = float(np.sum(np.abs(g)))
        phi0 = f + nu_pen * gl1
        dphi = float(grad @ dw) - nu_pen * gl1
        alpha = t_max
        accepted = False
        # feasible phase (gaps far below the noise): judge a step by the cost alone and keep the
        # gaps below GAP_OK, instead of the l1 merit that the gap multipliers dominate
        feasible = gmax < GAP_OK
        gdw = float(grad @ dw)

        jdw2 = float(Jdw @ Jdw)

        def _ok(rt, gt, a):
            if not (np.all(np.isfinite(rt)) and np.all(np.isfinite(gt))):
                return False, np.inf
            ft = 0.5 * float(rt @ rt)
            if feasible and not ng:
                # no gaps at all (single shooting): sufficient decrease of the cost (Armijo)
                return ft <= f + 1e-4 * a * min(gdw, 0.0), ft
            if feasible:
                # the actual cost change may not exceed the GN model's for this step length (which
                # may be an increase: closing the last gaps can cost a little), plus a sufficient
                # decrease margin; and the gaps stay below GAP_OK
                model = a * gdw + 0.5 * a * a * jdw2
                return (ft - f <= model - 1e-4 * a * abs(gdw) + 1e-10 * f + 1e-12
                        and (float(np.max(np.abs(gt))) if gt.size else 0.0) < GAP_OK), ft
            pt = ft + nu_pen * float(np.sum(np.abs(gt)))
            return pt <= phi0 + 1e-4 * a * min(dphi, 0.0), pt

        wt, phit = w, np.inf
        for ls in range(12 if feasible else 30):
            wt = w + alpha * dw
            if admissible is not None and not admissible(wt):
                alpha *= 0.5
                continue
            rt, gt, _, _, _ = prob.evaluate(wt, jac=False)
            ok, phit = _ok(rt, gt, alpha)
            if ok:
                accepted = True
                break
            if ls == 0 and Aall is not None and np.all(np.isfinite(gt)):
                # second-order correction: the minimum-norm (GN metric) change that removes the
                # gaps the full step leaves, from the same factorisation
                corr = fac.solve(np.r_[np.zeros(nw), -gt, np.zeros(Aall.shape[0] - ng)])
                ws = wt + corr[:nw]
                if not G.shape[0] or np.all(G @ ws[:nb] - h <= 1e-10 * np.maximum(1.0, np.abs(h))):
                    rs, gs, _, _, _ = prob.evaluate(ws, jac=False)
                    ok, phis = _ok(rs, gs, alpha)
                    if ok:
                        wt, phit, accepted = ws, phis, True
                        break
            alpha *= 0.5
        if not accepted and lm < 1e-3:
            lm = max(lm * 100, 1e-8)          # shorter, more gradient-like steps; retry from w
            radius = max(radius * 0.25, 1e-3)
            continue
        if not accepted:
            # near a solution the gap multipliers of stiff (stuck) intervals make the l1 merit
            # reject every step: converged if the gaps are far below the noise and the step would
            # lower the cost by less than 0.02 s^2 (it would move the parameters by < 0.2 SE)
            if (gmax < 1e-6 and step_inf < 1e-3) or (gmax < GAP_OK and pred_full <= 0.02 * s2):
                reason = "no_further_decrease"
            else:
                reason = "line_search"
            diag = (("max_gap", gmax), ("predicted_decrease", pred_full), ("s2", s2), ("step", step_inf),
                    ("parameter_step", dw[:nf].copy()))
            break
        # trust-region bookkeeping: actual vs predicted merit decrease along the accepted step
        pred = -(alpha * gdw + 0.5 * alpha * alpha * jdw2) + (0.0 if feasible else alpha * nu_pen * gl1)
        rho = ((f if feasible else phi0) - phit) / pred if pred > 0 else 1.0
        if rho > 0.75 and (capped or damped) and alpha >= t_max:
            radius = min(2 * radius, 1e3)
        elif rho < 0.25:
            radius = max(0.25 * radius, 1e-3)
        lm = max(lm / 10, 1e-12) if alpha >= 0.5 * t_max else min(lm * 10, 1e-2)
        w = wt
        active = [i for i in active if G[i] @ w[:nb] >= h[i] - 1e-9 * max(1.0, abs(h[i]))]
        r, g, Jr, A, _ = prob.evaluate(w)
    f = 0.5 * float(r @ r)
    gmax = float(np.max(np.abs(g))) if g.size else 0.0
    if best is not None and (gmax >= GAP_OK or f > best[0]) and reason != "max_iter":
        w = best[1]
        r, g, _, _, _ = prob.evaluate(w, jac=False)
        f = 0.5 * float(r @ r)
        gmax = float(np.max(np.abs(g))) if g.size else 0.0
        active = [i for i in range(G.shape[0]) if G[i] @ w[:nb] >= h[i] - 1e-9 * max(1.0, abs(h[i]))]
    costs.append(f)
    return GNResult(w, it, reason, reason in CONVERGED, tuple(costs), gmax, tuple(sorted(active)), radius, lm, diag)
