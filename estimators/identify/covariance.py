"""Uncertainty and conditioning of a fit: covariance, correlations, weakest directions.

The parameter covariance of the continuity-constrained least-squares problem is
``s^2 tau [(J^T J, A^T), (A, 0)]^-1`` restricted to the border variables (parameters and
encoder zeros), with ``J`` the Jacobian of the weighted residuals, ``A`` that of the gaps,
``s^2`` the residual variance per degree of freedom and ``tau`` the integrated autocorrelation
time of the residuals (quantised, slowly varying signals and model error make them correlated).

Conditioning: the information matrix of the free parameters in *relative* units (each
parameter divided by its scale, the magnitude it started from), with the state nodes and
encoder zeros eliminated, is the inverse of their relative covariance.  Its condition number says how unevenly the data
determine the parameters; its weakest eigen-directions are named by their dominant
parameters, e.g. ``"k1 - 0.9 d1"``: a relative increase of k1 with 0.9 times that relative
decrease of d1 changes the fit least (:class:`WeakDirection`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from models.signals import autocorrelation_time
from estimators.identify.shooting import KKTFactor

__all__ = ["WeakDirection", "Uncertainty", "uncertainty", "direction_text"]


@dataclass(frozen=True)
class WeakDirection:
    """A poorly determined combination of parameters (relative units).

    Attributes
    ----------
    text : e.g. ``"k1 - 0.9 d1"`` (coefficients of relative changes, the dominant one 1)
    coefficients : ``{name: coefficient}`` of that combination
    rel_stderr : standard error of a unit relative move along the (normalised) direction
    """

    text: str
    coefficients: dict
    rel_stderr: float


@dataclass(frozen=True)
class Uncertainty:
    """Covariance and conditioning of the free parameters (SI units, ``names`` order).

    ``zero_stderr`` holds the standard errors of the encoder zeros [rad].
    """

    cov: np.ndarray
    stderr: np.ndarray
    corr: np.ndarray
    zero_stderr: np.ndarray
    sigma2: float
    tau: float
    dof: int
    condition: float
    weak: tuple[WeakDirection, ...]


def direction_text(names, v, floor: float = 0.1) -> tuple[str, dict]:
    """``"k1 - 0.9 d1"`` for the vector ``v`` (normalised so that its largest entry is +1)."""
    v = np.asarray(v, float)
    j = int(np.argmax(np.abs(v)))
    if v[j] == 0:
        return "0", {}
    v = v / v[j]
    order = [i for i in np.argsort(-np.abs(v)) if abs(v[i]) >= floor]
    parts = []
    for k, i in enumerate(order):
        c = v[i]
        mag = f"{abs(c):.2g} " if abs(abs(c) - 1) > 5e-3 else ""
        if k == 0:
            parts.append(f"{'-' if c < 0 else ''}{mag}{names[i]}")
        else:
            parts.append(f"{'-' if c < 0 else '+'} {mag}{names[i]}")
    return " ".join(parts), {names[i]: float(v[i]) for i in order}


def uncertainty(prob, w, r, Jr, A, names, *, rse_warn: float = 0.5) -> Uncertainty:
    """Covariance, correlations and conditioning at the solution ``w`` (see the module docstring).

    Parameters
    ----------
    prob : the ShootingProblem; w : the scaled solution; r, Jr, A : residuals and Jacobians there
    names : free parameter names
    rse_warn : directions whose relative standard error exceeds this are reported as weak
        (the weakest one always is)
    """
    nf, nb, nw = prob.nf, prob.nb, prob.nw
    n_res = r.size
    n_nodes_vars = prob.nx * prob.n_nodes
    dof = max(n_res - (nb + n_nodes_vars), 1)
    sigma2 = float(r @ r / dof)
    ng = A.shape[0]
    H = (Jr.T @ Jr).tocsc()
    K = sp.bmat([[H + 1e-12 * max(1.0, float(H.diagonal().max())) * sp.identity(nw, format="csc"), A.T],
                 [A, -1e-12 * sp.identity(ng, format="csc")]], format="csc")
    C = np.full((nb, nb), np.nan)
    try:
        E = np.zeros((nw + ng, nb))
        E[np.arange(nb), np.arange(nb)] = 1.0
        Z = KKTFactor(prob, K, 0).solve(E)
        C = 0.5 * (Z[:nb, :nb] + Z[:nb, :nb].T)
    except RuntimeError:
        pass
    # residuals of quantised, slowly varying signals are correlated in time: inflate the
    # covariance by the largest integrated autocorrelation time over the channels
    res = ((prob.predict(w) - prob.Ymeas) * prob.wgt)
    tau = 1.0
    for j in range(prob.ny):
        tau = max(tau, autocorrelation_time(res[:, :, j].ravel()))
    scale_b = np.r_[prob.th_scale, prob.z_scale]
    cov_b = sigma2 * tau * C * np.outer(scale_b, scale_b)
    cov = cov_b[:nf, :nf]
    var = np.diag(cov)
    se = np.sqrt(np.where(var > 0, var, np.nan))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    zvar = np.diag(cov_b)[nf:]
    zse = np.sqrt(np.where(zvar > 0, zvar, np.nan))
    # conditioning in relative units: each parameter divided by its scale (its starting magnitude;
    # an estimate that runs to 0 would make its own relative variance explode)
    cond, weak = float("inf"), []
    if np.all(np.isfinite(C[:nf, :nf])):
        Crel = C[:nf, :nf]
        mu, V = np.linalg.eigh(0.5 * (Crel + Crel.T))
        mu = np.maximum(mu, 0.0)
        cond = float(mu[-1] / mu[0]) if mu[0] > 0 else float("inf")
        for i in range(nf - 1, -1, -1):
            rse = float(np.sqrt(sigma2 * tau * mu[i]))
            if i < nf - 1 and rse <= rse_warn:
                break
            text, coefs = direction_text(names, V[:, i])
            weak.append(WeakDirection(text, coefs, rse))
    return Uncertainty(cov, se, corr, zse, sigma2, tau, dof, cond, tuple(weak))
