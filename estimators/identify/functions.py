"""The numerical pieces an identification problem is built from, cached on the rig model.

- :func:`shooting_functions`: the per-sample sensitivity and value Functions of a problem
  (:func:`~estimators.identify.shooting.sample_function`), compiled where asked; beyond
  :data:`FOLD_ABOVE` substeps as a loop over one substep (:func:`folded_sample_function`);
- :class:`StiffRate`: the regularised model's stiffest rate as a function of the parameters,
  which sets RK4's substeps and guards the fit's trial steps.
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np

from estimators.identify.outputs import output_function
from estimators.identify.shooting import compiled_or_none, sample_function
from models.discretise import FOLD_ABOVE, Integration
from models.rates import rate_jacobian
from models.params import ParameterSet

__all__ = ["shooting_functions", "folded_sample_function", "StiffRate", "FOLD_ABOVE"]



def shooting_functions(model, integ, channels, avg, free_idx, input_jac: bool, compile_: bool):
    """(sensitivity function to run, values function to run, values function uncompiled, compiled?), cached on
    the model object (never by ``id``: a freed rig's id is reused by the next one)."""
    key = ("identify", integ.key, tuple((c.name, c.kind) for c in channels), tuple(avg), tuple(free_idx),
           input_jac, compile_)
    cache = model._fcache
    if key not in cache:
        h = output_function(model, channels)
        if integ.nsub > FOLD_ABOVE:
            S = folded_sample_function(model, integ, h, avg, free_idx, input_jac=input_jac)
            Sv = folded_sample_function(model, integ, h, avg, free_idx, values_only=True)
        else:
            S = sample_function(model, integ, h, avg, free_idx, input_jac=input_jac)
            Sv = sample_function(model, integ, h, avg, free_idx, values_only=True)
        S_run, Sv_run = S, Sv
        if compile_:
            S_run = compiled_or_none(S) or S
            if S_run is not S:
                Sv_run = compiled_or_none(Sv) or Sv
        cache[key] = (S_run, Sv_run, Sv, S_run is not S)
    return cache[key]


def folded_sample_function(model, integ, h: ca.Function, avg, free_idx, *, values_only: bool = False,
                           input_jac: bool = False) -> ca.Function:
    """:func:`~estimators.identify.shooting.sample_function` with ``integ.nsub`` substeps (RK4 or the
    implicit step: ``integ``, a :class:`models.discretise.Integration` or an int, RK4 substeps), built as a loop
    (``Function.fold``) over ONE substep's sample function and its sensitivities, chained by the
    chain rule: the same numbers, C code that does not grow with the substeps.

    One substep (``sample_function(model, 1, ...)`` over ``dt / nsub``) returns its end state, its
    outputs (averaged ones as the mean over the substep, the others at its end) and their Jacobians
    with respect to its start state (``A1``, ``C1``), the free parameters (``B1``, ``D1``) and the
    inputs (``E1``, ``F1``).  Over the substeps ``j``, with ``X_j = dx_j / dx_0`` (``B_j``, ``E_j``
    likewise for the parameters and inputs)::

        X_{j+1} = A1 X_j,   B_{j+1} = A1 B_j + B1,   E_{j+1} = A1 E_j + E1
        C_j = C1 X_j,       D_j = C1 B_j + D1,       F_j = C1 E_j + F1

    and an averaged output, its C, D and F are the means over the substeps, the others the last.
    Same signature and outputs as the unrolled function.
    """
    if isinstance(integ, int):
        integ = Integration(1.0, integ)
    nsub = integ.nsub
    S1 = sample_function(model, dataclasses.replace(integ, nsub=1), h, avg, free_idx, values_only=values_only,
                         input_jac=input_jac)
    nx, nu, nt, ny = model.nx, model.nu, len(free_idx), len(avg)
    mask = ca.DM([1.0 if a else 0.0 for a in avg])
    blocks = [("x", nx, 1), ("ys", ny, 1), ("yl", ny, 1)]
    if not values_only:
        blocks += [("X", nx, nx), ("B", nx, nt), ("Cs", ny, nx), ("Cl", ny, nx), ("Ds", ny, nt), ("Dl", ny, nt)]
        if input_jac:
            blocks += [("E", nx, nu), ("Fs", ny, nu), ("Fl", ny, nu)]
    sizes = [r * c for _, r, c in blocks]
    z = ca.SX.sym("z", sum(sizes))
    u, th, p = ca.SX.sym("u", nu), ca.SX.sym("th", nt), ca.SX.sym("p", model.n_p)
    hs, eps = ca.SX.sym("h"), ca.SX.sym("eps")
    parts, k = {}, 0
    for (name, r, c), n in zip(blocks, sizes):
        parts[name] = ca.reshape(z[k:k + n], r, c)
        k += n
    out = S1(parts["x"], u, th, p, hs, eps)
    nxt = dict(x=out[0], ys=parts["ys"] + out[1], yl=out[1])
    if not values_only:
        A1, B1, C1, D1 = out[2:6]
        Cj, Dj = ca.mtimes(C1, parts["X"]), ca.mtimes(C1, parts["B"]) + D1
        nxt.update(X=ca.mtimes(A1, parts["X"]), B=ca.mtimes(A1, parts["B"]) + B1, Cs=parts["Cs"] + Cj, Cl=Cj,
                   Ds=parts["Ds"] + Dj, Dl=Dj)
        if input_jac:
            E1, F1 = out[6:8]
            Fj = ca.mtimes(C1, parts["E"]) + F1
            nxt.update(E=ca.mtimes(A1, parts["E"]) + E1, Fs=parts["Fs"] + Fj, Fl=Fj)
    G = ca.Function(f"{S1.name()}_step", [z, u, th, p, hs, eps],
                    [ca.vertcat(*[ca.vec(nxt[name]) for name, _, _ in blocks])])
    Gf = G.fold(nsub)
    xs, us, ths, ps = ca.MX.sym("x", nx), ca.MX.sym("u", nu), ca.MX.sym("th", nt), ca.MX.sym("p", model.n_p)
    dt, es = ca.MX.sym("dt"), ca.MX.sym("eps")
    init = {"x": xs, "X": ca.MX.eye(nx)}
    z0 = ca.vertcat(*[ca.vec(init[name]) if name in init else ca.MX.zeros(r * c, 1) for name, r, c in blocks])
    zN = Gf(z0, ca.repmat(us, 1, nsub), ca.repmat(ths, 1, nsub), ca.repmat(ps, 1, nsub),
            ca.repmat(dt / nsub, 1, nsub), ca.repmat(es, 1, nsub))
    res, k = {}, 0
    for (name, r, c), n in zip(blocks, sizes):
        res[name] = ca.reshape(zN[k:k + n], r, c)
        k += n

    def mean_or_last(s, l_):
        return ca.mtimes(ca.diag(mask), s) / nsub + ca.mtimes(ca.diag(1 - mask), l_)

    outs = [res["x"], mean_or_last(res["ys"], res["yl"])]
    names = ["x_next", "y"]
    if not values_only:
        outs += [res["X"], res["B"], mean_or_last(res["Cs"], res["Cl"]), mean_or_last(res["Ds"], res["Dl"])]
        names += ["A", "B", "C", "D"]
        if input_jac:
            outs += [res["E"], mean_or_last(res["Fs"], res["Fl"])]
            names += ["E", "F"]
    name = S1.name().replace("_n1", f"_n{nsub}fold", 1).replace("_i1", f"_i{nsub}fold", 1)
    return ca.Function(name, [xs, us, ths, ps, dt, es], outs, ["x", "u", "th", "p", "dt", "eps"], names)


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
