"""Globalisation of a fit: Gauss-Newton first, then a continuation in the friction regularisation.

The constrained Gauss-Newton solver (:func:`~estimators.identify.gauss_newton.solve_gn`) is
globalised by Levenberg-Marquardt damping, a trust radius on the parameters and an l1 merit line
search; on logs of a plant its model can follow, that is enough.  A model structurally simpler
than the rig cannot follow every stick and slip of the log, and each one it misses folds the cost
surface of the regularised model (width ``eps``): the direct fit may stop at a poor point (a
degenerate corner where a friction parameter lost its effect) or not converge at all.

:func:`solve_globalised` then solves the same problem again along a path in ``eps``, from
``10 eps`` (a smooth friction law, a nearly convex problem) down to ``eps`` in half-decades, each
stage warm-started from the last, and keeps whichever of the two final fits, both at the target
``eps``, is better: converged before unconverged, then the lower cost.  The continuation runs
when the direct fit did not converge (at its iteration limit: only if it stalled, the cost falling
by less than 0.1 % over five iterations), or when it converged but its residual shows that the
structure misses (:func:`~estimators.identify.diagnostics.diagnose`; cold starts only: a refit
warm-started from a solution keeps its direct fit); ``strategy = "always"``
runs it every time, ``"off"`` never.  Every stage uses the same substeps (chosen for the target
``eps``, the stiffest) and the same compiled function: ``eps`` is one of its inputs.

Measured on the synthetic lab string of ``tests/lab_drillstring.py`` fitted with a user's 1-DOF
rig (``benchmarks/bench_identify.py labstring``): freeing k, d, mu_s, mu_k the direct fit
converges; freeing the Stribeck speed as well, the direct fit stopped at v_s = 0, mu_s = mu_k (cost
8.8e7) or at its iteration limit (cost 6.7e6), the continuation converged at cost 3.5e6.  IPOPT
(``solver = "ipopt"``) on that problem stopped after 241 s on a non-finite Hessian (cost 2.4e8):
no automatic switch to it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from estimators.identify.diagnostics import diagnose
from estimators.identify.gauss_newton import GAP_OK, GNResult, solve_gn

__all__ = ["Attempt", "solve_globalised", "solve_continuation", "EPS_FACTORS", "STRATEGIES", "GN_METHOD"]

#: the continuation's path: eps times these factors, the last one the target
EPS_FACTORS = (10.0, math.sqrt(10.0), 1.0)
STRATEGIES = ("auto", "always", "off")
GN_METHOD = "Gauss-Newton (Levenberg-Marquardt damping, trust region, l1 merit line search)"


@dataclass(frozen=True)
class Attempt:
    """One solve of a fit: how it was done and how it ended (cost ``0.5 |r|^2`` at the target eps)."""

    method: str
    reason: str
    success: bool
    cost: float
    max_gap: float
    iterations: int
    wall_time: float

    def as_dict(self) -> dict:
        return {"method": self.method, "reason": self.reason, "success": self.success, "cost": self.cost,
                "max_gap": self.max_gap, "iterations": self.iterations, "wall_time": self.wall_time}


def _cost(res: GNResult) -> float:
    return float(res.costs[-1]) if res.costs else float("inf")


def _stalled(res: GNResult) -> bool:
    """At its iteration limit, the cost fell by less than 0.1 % over the last five iterations (an
    iteration limit that cut a progressing fit short is the user's budget, not a failure)."""
    c = np.asarray(res.costs, float)
    return c.size >= 7 and bool(np.all(np.isfinite(c[-6:]))) and c[-6] - c[-1] < 1e-3 * abs(c[-1])


def _better(a: GNResult, b: GNResult) -> bool:
    """``a`` is a better end of the fit than ``b``: converged first, then gaps closed, then the lower cost."""
    if a.success != b.success:
        return a.success
    fa, fb = a.max_gap < GAP_OK, b.max_gap < GAP_OK
    if fa != fb:
        return fa
    return _cost(a) < _cost(b)


def solve_continuation(prob, w0, G, h, eps: float, factors=EPS_FACTORS, **gn) -> tuple[GNResult, list]:
    """Gauss-Newton at ``eps * f`` for ``f`` in ``factors`` (the last should be 1), each stage
    warm-started from the previous one; returns the last stage's result and every stage's
    ``(eps, GNResult)``.  ``prob.eps`` is restored."""
    stages = []
    w = np.asarray(w0, float)
    old = prob.eps
    try:
        for f in factors:
            prob.eps = eps * f
            res = solve_gn(prob, w, G, h, **gn)
            stages.append((prob.eps, res))
            if np.all(np.isfinite(res.w)):
                w = res.w
    finally:
        prob.eps = old
    total = sum(r.iterations for _, r in stages)
    last = stages[-1][1]
    return GNResult(last.w, total, last.reason, last.success, last.costs, last.max_gap, last.active, last.radius,
                    last.lm, last.history), stages


def structure_misses(prob, w, dt: float) -> bool:
    """Does the residual at ``w`` show that the structure misses (the quick check behind "auto")?"""
    r, g, _, _, _ = prob.evaluate(w, jac=False)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(g))):
        return False
    n = prob.Nint * prob.M * prob.ny
    res = r[:n].reshape(-1, prob.ny)
    meas = prob.Ymeas.reshape(-1, prob.ny)
    dof = max(r.size - prob.nw + g.size, 1)
    d = diagnose([{j: res[:, j] for j in range(prob.ny)}], [{j: meas[:, j] for j in range(prob.ny)}], dt,
                 sigma2=float(r @ r) / dof, gaps=g)
    return not d.structure_ok


def solve_globalised(prob, w0, G=None, h=None, *, strategy: str = "auto", dt: float = 1.0, on_misses: bool = True,
                     **gn):
    """Fit ``prob`` from ``w0`` (see the module docstring).

    Parameters
    ----------
    prob : :class:`~estimators.identify.shooting.ShootingProblem` (its ``eps`` is the target)
    w0, G, h : start and linear inequalities, as for :func:`~estimators.identify.gauss_newton.solve_gn`
    strategy : "auto", "always" or "off"
    dt : sample period [s] (the structure check's spectra)
    on_misses : "auto" also runs the continuation after a converged direct fit whose structure
        misses (False for warm starts: a refit from a solution, a bootstrap replicate, stays cheap)
    gn : keyword arguments of :func:`~estimators.identify.gauss_newton.solve_gn`

    Returns
    -------
    ``(GNResult, method, attempts)``: the chosen end, how it was reached (text), and every
    :class:`Attempt` in order.
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy must be one of {', '.join(STRATEGIES)}, got {strategy!r}")
    eps = prob.eps
    t0 = time.perf_counter()
    direct = solve_gn(prob, w0, G, h, **gn)
    attempts = [Attempt(GN_METHOD, direct.reason, direct.success, _cost(direct), direct.max_gap, direct.iterations,
                        time.perf_counter() - t0)]
    if strategy == "off":
        return direct, GN_METHOD, tuple(attempts)
    why = None
    if strategy == "always":
        why = "always"
    elif not direct.success and (direct.reason != "max_iter" or _stalled(direct)):
        why = f"the direct fit ended: {direct.reason}"
    elif on_misses and direct.success and structure_misses(prob, direct.w, dt):
        why = "the direct fit's residual shows that the structure misses"
    if why is None:
        return direct, GN_METHOD, tuple(attempts)
    t1 = time.perf_counter()
    cont, stages = solve_continuation(prob, w0, G, h, eps, **gn)
    path = " -> ".join(f"{e:.3g}" for e, _ in stages)
    cmethod = f"{GN_METHOD} along a continuation in eps {path} rad/s"
    attempts.append(Attempt(cmethod, cont.reason, cont.success, _cost(cont), cont.max_gap, cont.iterations,
                            time.perf_counter() - t1))
    iters = direct.iterations + cont.iterations
    if _better(cont, direct):
        chosen = cont
        method = (f"{cmethod} ({why}; the direct fit stopped ({direct.reason}) at cost {_cost(direct):.4g}, the "
                  f"continuation ({cont.reason}) at cost {_cost(cont):.4g})")
    else:
        chosen = direct
        method = (f"{GN_METHOD} ({why}; a continuation in eps {path} rad/s stopped ({cont.reason}) at cost "
                  f"{_cost(cont):.4g}, the direct fit ({direct.reason}) at cost {_cost(direct):.4g})")
    out = GNResult(chosen.w, iters, chosen.reason, chosen.success, chosen.costs, chosen.max_gap, chosen.active,
                   chosen.radius, chosen.lm, chosen.history)
    return out, method, tuple(attempts)
