"""Uncertainty and conditioning of a fit: covariance, correlations, weakest directions.

The parameter covariance of the continuity-constrained least-squares problem is a sandwich: with
``K = [(J^T J, A^T), (A, 0)]`` (``J`` the Jacobian of the weighted residuals, ``A`` that of the gaps)
and ``Z = K^-1 E`` the solution's response to each border variable (parameters and encoder zeros),
``U = J Z`` says how each residual moves the estimates, and the covariance is ``sum_l w_l sum_t
g_t g_(t+l)^T`` (and its transpose) over the per-sample scores ``g_t = sum_channels U_t r_t``, with
Bartlett weights ``w_l = 1 - l / (L + 1)`` up to ``L`` lags (Newey-West).  For white residuals of the
stated noise this is ``(J^T J)^-1`` restricted to the border, as before; residuals that are larger
than the noise or correlated in time (an encoder's quantisation error is constant while its body is
stuck; a regularised model creeps through a stick) widen the errors of the parameters they move,
and only those.  An angle difference taken as the twist (``encoder_zero = "untwisted"``) enters
without the encoders' power-on phase, ``offset_error``'s: without its mean over each log and without
the rest of that constant's trace in the residual, the fit's reaction to it (the residual's component
along ``d r / d offset + J d w / d offset`` is taken out).  That reaction is slow and long-correlated,
and the lags counted it a second time: on the DC-motor zoo rig's logs the phase alone explained the
estimates' spread (c0: 14.6 % against 14.7 %, k0 1.37 against 1.36 %, 60 logs), yet the statistical SE
said 11.5 % (0.29 %) beside it; with the trace taken out 5.1 % (0.07 %), and over 200 logs a rig
(``benchmarks/identify_coverage.py``) the stated 95 % interval covers every parameter 90-98 % of the
time among the fits that converged.
The previous estimate, ``s^2 tau (J^T J)^-1`` with the residual variance ``s^2`` and
the largest integrated autocorrelation time ``tau`` over the channels, widened every parameter alike
(on 50 logs of a zoo rig, ``benchmarks/identify_coverage.py``, the RMS of error over stated error
was 0.5-0.9: too wide); ``s^2``
(over the degrees of freedom: residuals minus parameters, encoder zeros and nodes, plus the gap
equations) and ``tau`` are still reported.

Errors no statistical standard error covers, both from the implicit-function theorem on the KKT
conditions at the solution (one more solve with the factorised matrix, no refit):

- ``eps_bias``: the regularisation's first-order bias ``eps d theta / d eps``.  The regularised
  model creeps where the plant sticks; on a 1-body lab rig with the encoders' zero free the fit put
  mu_k at 0.265 +- 0.003 against 0.300, and ``eps d mu_k / d eps`` said -0.027 (refits at smaller
  eps: 0.291 at eps / 5, 0.297 at eps / 25).
- ``offset_error``: with ``encoder_zero = "untwisted"`` an angle difference is taken as the twist,
  yet each incremental encoder stood at an unknown phase within a tick at power-on and counts whole
  ticks from there: its reading is off by a constant in ``[-q/2, q/2)``, the difference by one of
  standard deviation ``sqrt(q_a^2 + q_b^2) / sqrt(12)`` (its own quantisation noise level), which
  no averaging removes.  ``offset_error`` is how far such a constant moves the estimates (the
  parameters' sensitivity to it times that deviation); two differences that share an encoder share its
  phase (``offset_corr``): counted as independent, a 3-body zoo rig's twists ``enc_0 - enc_c`` and
  ``enc_c - enc_d`` stated mu_k's total error at 4.9 % against a spread of 3.5 % over 50 logs (and a
  DC-motor rig's k0 and k1 at 1.2-1.3 % against 1.5 %).  On a twist of a few ticks it dominates (a
  micro lab rig's mu_k 0.278 +- 0.002 against 0.300: the simulated log's offset is 0.8 deviations).

Conditioning: the information matrix of the free parameters in *relative* units (each
parameter divided by its scale, the magnitude it started from), with the state nodes and
encoder zeros eliminated, is the inverse of their relative covariance.  Its condition number says how unevenly the data
determine the parameters; its weakest eigen-directions are named by their dominant
parameters, e.g. ``"k1 - 0.9 d1"``: a relative increase of k1 with 0.9 times that relative
decrease of d1 changes the fit least (:class:`WeakDirection`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.special import ndtri

from models.signals import autocorrelation_time
from estimators.identify.shooting import KKTFactor

__all__ = ["WeakDirection", "Uncertainty", "uncertainty", "direction_text", "sandwich", "interval_halfwidth"]


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

    ``zero_stderr`` holds the standard errors of the encoder zeros [rad], ``zero_corr`` (n_free,
    n_zeros) the correlations of the parameters with them; ``eps_bias`` (n_free,) the first-order
    bias of the regularisation, ``eps d theta / d eps`` [SI] (0 where the friction is not regularised
    by eps); ``offset_error`` (n_free,) the standard deviation the encoders' unknown power-on phase
    puts on the estimates [SI] (module docstring), ``phase_parts`` (n_free, n_encoders) each encoder's
    share of it (``offset_error`` is the root sum of squares of a row).
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
    zero_corr: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    eps_bias: np.ndarray = field(default_factory=lambda: np.zeros(0))
    offset_error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    phase_parts: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


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


def sandwich(prob, Jr, r, Z_b, tau: float, demean=()) -> np.ndarray:
    """Newey-West covariance (scaled units) of the border variables (module docstring).

    Parameters
    ----------
    prob : the shooting problem (residual order: interval, sample, channel, then the priors of the
        input corrections); Jr : (n_res, nw) residual Jacobian; r : (n_res,) weighted residuals
    Z_b : (nw, nb) the solution's response to each border variable, ``K^-1 E``
    tau : integrated autocorrelation time of the residuals: the lags run to ``L = max(10, 5 tau)``
        (at most a quarter of the samples)
    demean : channels whose residual's mean over each log is left out: angle differences taken as the
        twists, whose constant part is the encoders' phase at power-on, which ``offset_error`` counts
        (the coverage study: counted twice, the errors of the stiffnesses were twice too wide)
    """
    nb = Z_b.shape[1]
    U = np.asarray(Jr @ Z_b)                              # (n_res, nb)
    n_y = prob.Nint * prob.M * prob.ny
    if len(demean):
        r = r.copy()
        R = r[:n_y].reshape(prob.Nint, prob.M, prob.ny)
        cuts = np.r_[0, np.flatnonzero(np.diff(prob.starts) > 1) + 1, prob.Nint]      # logs' intervals
        for a, b in zip(cuts[:-1], cuts[1:]):
            for j in demean:
                R[a:b, :, j] -= R[a:b, :, j].mean()
        r[:n_y] = R.ravel()
    s = U * r[:, None]
    g = s[:n_y].reshape(prob.Nint * prob.M, prob.ny, nb).sum(axis=1)      # per sample, channels summed
    T = g.shape[0]
    L = int(min(max(10, math.ceil(5 * tau)), T // 4))
    S = g.T @ g + s[n_y:].T @ s[n_y:]
    for lag in range(1, L + 1):
        G = g[:-lag].T @ g[lag:]
        S += (1 - lag / (L + 1)) * (G + G.T)
    return S


def uncertainty(prob, w, r, Jr, A, names, *, rse_warn: float = 0.5, offsets=(), offset_phases=None) -> Uncertainty:
    """Covariance, correlations and conditioning at the solution ``w`` (see the module docstring).

    Parameters
    ----------
    prob : the ShootingProblem; w : the scaled solution; r, Jr, A : residuals and Jacobians there
    names : free parameter names
    rse_warn : directions whose relative standard error exceeds this are reported as weak
        (the weakest one always is)
    offsets : ``((channel index, sigma), ...)``: angle differences taken as the twists
        (``encoder_zero = "untwisted"``), each off by an unknown constant of standard deviation
        ``sigma`` [rad] (the encoders' phase within a tick at power-on)
    offset_phases : (len(offsets), n_encoders): each constant, in its own standard deviations, as a sum
        of the encoders' independent unit-variance phases (``a - b``: ``q_a / sqrt(12) / sigma`` times
        ``a``'s minus ``q_b / sqrt(12) / sigma`` times ``b``'s; two differences that share an encoder
        share its phase); None: each constant its own phase
    """
    nf, nb, nw = prob.nf, prob.nb, prob.nw
    n_res = r.size
    n_nodes_vars = prob.nx * prob.n_nodes
    ng = A.shape[0]
    # the gap equations fix all nodes but each log's first: they give the degrees of freedom back
    dof = max(n_res - (nb + n_nodes_vars) + ng, 1)
    sigma2 = float(r @ r / dof)
    H = (Jr.T @ Jr).tocsc()
    K = sp.bmat([[H + 1e-12 * max(1.0, float(H.diagonal().max())) * sp.identity(nw, format="csc"), A.T],
                 [A, -1e-12 * sp.identity(ng, format="csc")]], format="csc")
    C = np.full((nb, nb), np.nan)
    Z_b = Z = None
    dw_eps = np.full(nf, np.nan)
    # the regularisation's first-order bias: the solution's sensitivity to eps (implicit function
    # theorem on the KKT conditions, dr/deps and dg/deps by a forward difference), times eps
    d_eps = 1e-4 * prob.eps
    old_eps = prob.eps
    try:
        prob.eps = old_eps + d_eps
        r2, g2 = prob.evaluate(w, jac=False)[:2]
    finally:
        prob.eps = old_eps
    r0, g0 = prob.evaluate(w, jac=False)[:2]
    rhs_eps = np.r_[-(Jr.T @ ((r2 - r0) / d_eps)), -(g2 - g0) / d_eps]
    # an unknown constant offset of an angle difference: d r / d offset = -1 / noise on its rows
    rhs_off, dr_off = [], []
    for j, sig in offsets:
        d3 = np.zeros(prob.Ymeas.shape)
        d3[:, :, j] = -prob.wgt[:, :, j]
        dr = np.r_[d3.ravel(), np.zeros(n_res - d3.size)]
        dr_off.append(dr)
        rhs_off.append(np.r_[-(Jr.T @ dr), np.zeros(ng)] * sig)
    no = len(rhs_off)
    dth_off = np.zeros((nf, no))
    try:
        E = np.zeros((nw + ng, nb + 1 + no))
        E[np.arange(nb), np.arange(nb)] = 1.0
        E[:, nb] = rhs_eps if np.all(np.isfinite(rhs_eps)) else 0.0
        for k, col in enumerate(rhs_off):
            E[:, nb + 1 + k] = col
        Z = KKTFactor(prob, K, 0).solve(E)
        C = 0.5 * (Z[:nb, :nb] + Z[:nb, :nb].T)
        Z_b = Z[:nw, :nb]
        if np.all(np.isfinite(rhs_eps)):
            dw_eps = Z[:nf, nb]
        dth_off = Z[:nf, nb + 1:] * prob.th_scale[:, None]
    except RuntimeError:
        pass
    # residuals of quantised, slowly varying signals are correlated in time (reported: tau)
    res = ((prob.predict(w) - prob.Ymeas) * prob.wgt)
    tau = 1.0
    for j in range(prob.ny):
        tau = max(tau, autocorrelation_time(res[:, :, j].ravel()))
    scale_b = np.r_[prob.th_scale, prob.z_scale]
    r_s = r
    if no and Z_b is not None:
        # each offset's whole trace in the residual (the constant and the fit's reaction to it), taken out:
        # offset_error counts it (module docstring)
        D = np.column_stack([d * sig + Jr @ Z[:nw, nb + 1 + k] for k, (d, (_, sig)) in enumerate(zip(dr_off, offsets))])
        if np.all(np.isfinite(D)):
            r_s = r - D @ np.linalg.lstsq(D, r, rcond=None)[0]
    cov_b = sandwich(prob, Jr, r_s, Z_b, tau, demean=[j for j, _ in offsets]) if Z_b is not None \
        else sigma2 * tau * C
    cov_b = 0.5 * (cov_b + cov_b.T) * np.outer(scale_b, scale_b)
    cov = cov_b[:nf, :nf]
    var = np.diag(cov)
    se = np.sqrt(np.where(var > 0, var, np.nan))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    zvar = np.diag(cov_b)[nf:]
    zse = np.sqrt(np.where(zvar > 0, zvar, np.nan))
    with np.errstate(invalid="ignore", divide="ignore"):
        zcorr = cov_b[:nf, nf:] / np.outer(se, zse)
    eps_bias = old_eps * dw_eps * prob.th_scale
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
    M = np.eye(dth_off.shape[1]) if offset_phases is None else np.asarray(offset_phases, float)
    parts = dth_off @ M
    off_err = np.sqrt(np.sum(parts ** 2, axis=1))
    return Uncertainty(cov, se, corr, zse, sigma2, tau, dof, cond, tuple(weak), zcorr, eps_bias, off_err, parts)


def interval_halfwidth(sd: float, uniform_sds=(), level: float = 0.95) -> float:
    """Half-width ``h`` of the symmetric interval that holds ``level`` of ``e = n + sum_k u_k``: ``n``
    normal of standard deviation ``sd``, each ``u_k`` uniform (an encoder's phase within a tick) of
    standard deviation ``uniform_sds[k]``, all independent: their densities convolved on a grid.
    ``1.95996 sd`` without uniform parts; ``0.95 sqrt(3) s`` for one uniform part ``s`` alone (bounded,
    short-tailed: 1.96 standard deviations would hold all of it).

    Parameters
    ----------
    sd : the normal part's standard deviation [SI]; uniform_sds : the uniform parts' [SI]
    level : the interval's probability
    """
    halfs = [math.sqrt(3.0) * abs(float(u)) for u in uniform_sds if np.isfinite(u) and u != 0]
    sd = abs(float(sd)) if np.isfinite(sd) else 0.0
    if not halfs:
        return float(sd * ndtri(0.5 + 0.5 * level))
    span = 8.0 * sd + sum(halfs)
    x = np.linspace(-span, span, (1 << 15) + 1)          # odd: x = 0 is the middle cell
    dx = x[1] - x[0]
    # each uniform part a box of half-width a (its edge cells weighted by the share they hold), then the normal
    parts = [np.clip((a - np.abs(x)) / dx + 0.5, 0.0, 1.0) for a in halfs]
    if sd > 0:
        parts.append(np.exp(-0.5 * (x / sd) ** 2))
    from scipy.signal import fftconvolve    # imported here: scipy.signal takes 1-2 s to import

    dens = None
    for d in parts:
        d = d / d.sum()
        dens = d if dens is None else np.maximum(fftconvolve(dens, d, mode="same"), 0.0)
    cdf = np.cumsum(dens) - 0.5 * dens                    # F at the cells' centres
    cdf /= cdf[-1] + 0.5 * dens[-1]
    return float(np.interp(0.5 + 0.5 * level, cdf, x))
