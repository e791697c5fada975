"""Globalisation of a fit: Gauss-Newton first, then a continuation in the friction regularisation.

The constrained Gauss-Newton solver (:func:`~estimators.identify.gauss_newton.solve_gn`) is
globalised by Levenberg-Marquardt damping, a trust radius on the parameters and an l1 merit line
search; on logs of a plant its model can follow, that is enough.  A model structurally simpler
than the rig cannot follow every stick and slip of the log, and each one it misses folds the cost
surface of the regularised model (width ``eps``): the direct fit may stop at a poor point (a
degenerate corner where a friction parameter lost its effect) or not converge at all.

The problem then solves itself again (cold, from the same start, with the substeps the direct
fit ended with) along a path in ``eps``: :func:`solve_continuation` runs Gauss-Newton at ``10 eps``
(a smooth friction law, a nearly convex problem), then down to ``eps`` in half-decades, each stage
warm-started from the last (the stages before the last at most :data:`STAGE_ITER` iterations), all
with the same compiled function (``eps`` is one of its inputs).
:func:`choose` keeps whichever of the two fits, both at the target ``eps`` and the same substeps,
ends at the lower cost on a consistent trajectory: a fit whose gaps stayed open is first continued
by single shooting (:mod:`~estimators.identify.single`); of two ends at the same cost the converged one.
:func:`wants_continuation` says when: the direct fit did not converge (at its iteration limit:
only if it stalled, the cost falling by less than 0.1 % over five iterations; a budget that cut a
progressing fit short is the user's), or it converged against a bound or a constraint (a degenerate
corner: the lab string's v_s = 0 with mu_s = mu_k) and its residual shows that the structure misses
(:mod:`~estimators.identify.diagnostics`) by more than the sensors' noise: a residual variance per
degree of freedom of at least :data:`CORNER_SIGMA2` noise variances.  A degenerate corner leaves orders
of magnitude (the lab string's: 4.6e4); a fit at the sensors' noise has little to gain, and its bound is
where the log leaves a parameter undetermined: the field-scale zoo rig (a torque drive at 1 rad/s) put
mu_k and c0 at 0 with a residual variance of 0.31 noise variances (from the true set as well), and the
continuation spent 26 iterations to end at twice the cost.  A converged fit inside its bounds whose residual misses
is not repeated: on the zoo's logs of the exact plant (whose regularised model misses the exact
stick) the continuation spent 20-38 iterations to end at the direct fit's cost (median 22, worst 51
iterations a fit; benchmarks/results/identify.md, zoo).  Never after a warm start (a refit from a
solution, a bootstrap replicate stays cheap); ``globalise = "always"`` every time, ``"off"`` never.

Measured on the synthetic lab string of ``tests/lab_drillstring.py`` fitted with the user's 1-DOF
rig ``tests/data/lab_string_1dof.toml`` (``benchmarks/bench_identify.py labstring``): freeing k, d,
mu_s, mu_k the direct fit converges (the continuation ends at the same cost); freeing the Stribeck
speed as well, the direct fit stopped at v_s = 0, mu_s = mu_k (cost 8.8e7, a degenerate corner) or
at its iteration limit (cost 6.7e6), the continuation converged at cost 2.6e6 / 3.5e6.  IPOPT
(``solver = "ipopt"``) on that problem stopped after 241 s on a non-finite Hessian (cost 2.4e8):
no automatic switch to it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from estimators.identify.gauss_newton import CONVERGED, GAP_OK, GNResult, solve_gn

__all__ = ["Attempt", "attempt", "solve_continuation", "continuation_method", "wants_continuation", "choose",
           "closed", "EPS_FACTORS", "STAGE_ITER", "CORNER_SIGMA2", "STRATEGIES", "GN_METHOD"]

#: the continuation's path: eps times these factors, the last one the target
EPS_FACTORS = (10.0, math.sqrt(10.0), 1.0)
#: iteration limit of the continuation's stages before the last (a 1-body DC-motor zoo rig spent 8 + 17
#: iterations on them, the last stage 22, to end where the direct fit had)
STAGE_ITER = 10
#: a converged fit against a bound is repeated along the continuation only if its residual variance per
#: degree of freedom is at least this many noise variances (module docstring)
CORNER_SIGMA2 = 2.0
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
    stalled: bool = False

    def as_dict(self) -> dict:
        return {"method": self.method, "reason": self.reason, "success": self.success, "cost": self.cost,
                "max_gap": self.max_gap, "iterations": self.iterations, "wall_time": self.wall_time,
                "stalled": self.stalled}


def continuation_method(eps: float, factors=EPS_FACTORS) -> str:
    path = " -> ".join(f"{eps * f:.3g}" for f in factors)
    return f"{GN_METHOD} along a continuation in eps {path} rad/s"


def solve_continuation(prob, w0, G, h, eps: float, factors=EPS_FACTORS, **gn) -> tuple[GNResult, list]:
    """Gauss-Newton at ``eps * f`` for ``f`` in ``factors`` (the last should be 1), each stage
    warm-started from the previous one; returns the last stage's result (its iterations: all
    stages') and every stage's ``(eps, GNResult)``.  ``prob.eps`` is restored."""
    stages = []
    w = np.asarray(w0, float)
    old = prob.eps
    try:
        for i, f in enumerate(factors):
            prob.eps = eps * f
            last = i == len(factors) - 1
            # the smoother stages only lead the way: at most STAGE_ITER iterations each
            res = solve_gn(prob, w, G, h, **(gn if last else {**gn, "max_iter": min(gn.get("max_iter", 100), STAGE_ITER)}))
            stages.append((prob.eps, res))
            if np.all(np.isfinite(res.w)):
                w = res.w
    finally:
        prob.eps = old
    last = stages[-1][1]
    return replace(last, iterations=sum(r.iterations for _, r in stages)), stages


def _stalled(costs) -> bool:
    c = np.asarray(costs, float)
    return bool(c.size >= 7 and np.all(np.isfinite(c[-6:])) and c[-6] - c[-1] < 1e-3 * abs(c[-1]))


def wants_continuation(fit, strategy: str, warm: bool) -> str | None:
    """Why ``fit`` (a direct fit) should be repeated along the continuation, or None (see the module
    docstring)."""
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy must be one of {', '.join(STRATEGIES)}, got {strategy!r}")
    if strategy == "off" or warm:
        return None
    if strategy == "always":
        return "always"
    if fit.reason not in CONVERGED:
        if fit.reason != "max_iter" or (fit.attempts and fit.attempts[-1].stalled):
            return f"the direct fit did not converge ({fit.reason})"
        return None
    if (fit.structure is not None and fit.structure.misses and (fit.at_bound or fit.active_constraints)
            and not fit.sigma2 < CORNER_SIGMA2):          # (NaN: not known, repeated)
        held = ", ".join(tuple(fit.at_bound) + tuple(fit.active_constraints))
        return f"the direct fit's residual shows that the structure misses, and it ended against {held}"
    return None


def _cost(fit) -> float:
    return fit.cost if np.isfinite(fit.cost) else math.inf


def closed(fit) -> bool:
    """The fit's continuity gaps are closed (below :data:`~estimators.identify.gauss_newton.GAP_OK`):
    its parameters belong to one trajectory of the model."""
    return fit.structure is None or fit.structure.max_gap < GAP_OK


def choose(direct, cont, why: str, consistent=None):
    """The better of two fits of one problem (direct, continuation): the lower cost of two consistent
    ends, with ``method`` and ``attempts`` telling every solve; iterations and wall time add up.

    A fit whose gaps stayed open has no consistent cost (its parameters belong to no trajectory):
    ``consistent(fit)`` (the single-shooting refinement; None: none) continues it first, unless its
    multiple-shooting cost already exceeds a consistent candidate's (the refinement can only close
    its gaps at a cost).  Never is a result of higher cost kept over a consistent one of lower cost
    (a converged continuation at 2.989e4 had been kept over a direct fit at 2.369e4)."""
    ends = []
    for label, f in sorted((("the direct fit", direct), ("the continuation", cont)),
                           key=lambda x: (not closed(x[1]), _cost(x[1]))):
        end = f
        if not closed(f) and consistent is not None:
            best = min((_cost(e) for _, _, e in ends if closed(e)), default=math.inf)
            if _cost(f) < best:
                end = consistent(f)
        ends.append((label, f, end))
    label, _, pick = min(ends, key=lambda e: (not closed(e[2]), _cost(e[2])))
    if not pick.success:
        # a converged end at the same cost (within a hundredth of a noise level squared, or 1e-6 of
        # it) is the same answer, certified: a continuation that stalled 0.004 below a converged
        # direct fit had made the fit "not converged"
        tie = [e for e in ends if e[2] is not pick and e[2].success and closed(e[2])
               and _cost(e[2]) <= _cost(pick) + max(1e-2, 1e-6 * abs(_cost(pick)))]
        if tie:
            label, _, pick = tie[0]
    parts = []
    for lab, f, end in sorted(ends, key=lambda e: e[0] != "the direct fit"):
        part = f"{lab[4:]} stopped ({f.reason}) at cost {f.cost:.4g}"
        if end is not f:
            part += f", refined by single shooting to {end.cost:.4g} ({end.reason})"
        parts.append(part)
    method = f"{pick.method} ({why}; kept {label}: " + ", ".join(parts) + ")"
    attempts, seen = [], set()
    for _, f, end in sorted(ends, key=lambda e: e[0] != "the direct fit"):        # in the order they ran
        for a in end.attempts:
            if id(a) not in seen:
                seen.add(id(a))
                attempts.append(a)
    other = [f for _, f, _ in ends if f is not pick]
    notes = pick.guess_notes or (other[0].guess_notes if other else ())
    return replace(pick, method=method, attempts=tuple(attempts),
                   iterations=sum(e.iterations for _, _, e in ends), wall_time=sum(e.wall_time for _, _, e in ends),
                   guess_notes=notes)


def attempt(method: str, res: GNResult, t_start: float) -> Attempt:
    costs = getattr(res, "costs", ())
    return Attempt(method, res.reason, res.success, float(costs[-1]) if costs else float("nan"),
                   float(res.max_gap), int(res.iterations), time.perf_counter() - t_start, _stalled(costs))
