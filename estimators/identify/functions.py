"""The numerical pieces an identification problem is built from, cached on the rig model.

- :func:`shooting_functions`: the per-sample sensitivity and value Functions of a problem
  (:func:`~estimators.identify.shooting.sample_function`), compiled where asked;
- :class:`StiffRate`: the regularised model's stiffest rate as a function of the parameters,
  which sets RK4's substeps and guards the fit's trial steps.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from estimators.identify.outputs import output_function
from estimators.identify.shooting import compiled_or_none, sample_function
from models.discretise import rate_jacobian
from models.params import ParameterSet

__all__ = ["shooting_functions", "StiffRate"]


def shooting_functions(model, integ, channels, avg, free_idx, input_jac: bool, compile_: bool):
    """(sensitivity function to run, values function to run, values function uncompiled, compiled?), cached on
    the model object (never by ``id``: a freed rig's id is reused by the next one)."""
    key = ("identify", integ.key, tuple((c.name, c.kind) for c in channels), tuple(avg), tuple(free_idx),
           input_jac, compile_)
    cache = model._fcache
    if key not in cache:
        h = output_function(model, channels)
        S = sample_function(model, integ, h, avg, free_idx, input_jac=input_jac)
        Sv = sample_function(model, integ, h, avg, free_idx, values_only=True)
        S_run, Sv_run = S, Sv
        if compile_:
            S_run = compiled_or_none(S) or S
            if S_run is not S:
                Sv_run = compiled_or_none(Sv) or Sv
        cache[key] = (S_run, Sv_run, Sv, S_run is not S)
    return cache[key]


class StiffRate:
    """The largest eigenvalue magnitude [1/s] of the regularised model's Jacobian at zero contact
    speed (its stiffest point), as a function of the parameter vector, for inputs ``u`` (with a
    quasi-static current when the integration treats it so); :meth:`growth`: the largest positive
    rate with the contacts sliding just beyond the regularisation band (10 eps), where a friction
    that falls with speed falls fastest (what the implicit step must resolve)."""

    def __init__(self, model, params: ParameterSet, u, eps: float, reduced: bool = False):
        J = rate_jacobian(model, eps, reduced)
        self._J = lambda x, p: J(x, ca.DM(u), p)
        try:
            x0 = np.asarray(model.sliding_guess(u, params), dtype=float)
        except Exception:  # noqa: BLE001 - any finite point will do
            x0 = np.zeros(model.nx)
        x0 = np.where(np.isfinite(x0), x0, 0.0)
        x1 = x0.copy()
        for idx in model.contacts:
            x0[idx] = 0.0
            x1[idx] = 10.0 * eps
        self.x0, self.x1 = x0, x1

    def _eig(self, x, p):
        J = np.array(self._J(x, np.asarray(p, float)))
        if not np.all(np.isfinite(J)):
            return None
        return np.linalg.eigvals(J)

    def __call__(self, p) -> float:
        lam = self._eig(self.x0, p)
        if lam is None:
            return float("inf")
        return float(np.max(np.abs(lam))) if lam.size else 0.0

    def growth(self, p) -> float:
        """The largest positive real eigenvalue [1/s] at the contacts sliding at 10 eps (0 if none)."""
        lam = self._eig(self.x1, p)
        if lam is None:
            return float("inf")
        return max(float(np.max(lam.real)), 0.0) if lam.size else 0.0
