"""Friction laws, as separate composable pieces.

Each law gives the *magnitude* of the friction force/torque coefficient as a function of
the sliding speed ``v_abs >= 0`` (so that the exact, event-capturing plant can use it with
an explicit sliding direction), and a *regularised* signed version with an explicit
smoothing parameter (for optimisers, which need smooth models).

All functions work on floats, numpy arrays and CasADi ``SX``/``MX`` alike.

References
----------
- thesis eq. (3-13): exponential Stribeck law ``mu_k + (mu_s - mu_k) exp(-|w|/v_s)``
- seed 001 eq. (4): regularised Coulomb ``F_C tanh(v / v_t)``
- seed 002 eqs. (9.8)/(9.33): ``s_m (mu1 + mu2 exp(-r0|w|) + mu3 |w|) (1 - exp(-r1|w|))``
"""

from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = [
    "stribeck_exp",
    "coulomb",
    "vahid_araghi",
    "smooth_sign",
    "smooth_abs",
    "regularised",
]


def _is_symbolic(x) -> bool:
    return isinstance(x, (ca.SX, ca.MX, ca.DM))


def _exp(x):
    return ca.exp(x) if _is_symbolic(x) else np.exp(x)


def _tanh(x):
    return ca.tanh(x) if _is_symbolic(x) else np.tanh(x)


def _sqrt(x):
    return ca.sqrt(x) if _is_symbolic(x) else np.sqrt(x)


def stribeck_exp(v_abs, mu_s, mu_k, v_s):
    """Exponential Stribeck coefficient, thesis eq. (3-13).

    Parameters
    ----------
    v_abs : sliding speed magnitude [rad/s], >= 0
    mu_s, mu_k : static and kinetic coefficients [-] (or torques [N m])
    v_s : Stribeck decay speed [rad/s]; the thesis' ``e^{-|w|}`` means ``v_s = 1 rad/s``

    Returns
    -------
    coefficient at that speed; equals ``mu_s`` at zero speed and tends to ``mu_k``.
    """
    return mu_k + (mu_s - mu_k) * _exp(-v_abs / v_s)


def coulomb(v_abs, level):
    """Coulomb friction magnitude: constant ``level`` at any sliding speed (seed 001 eq. 3)."""
    return level + 0 * v_abs


def vahid_araghi(v_abs, mu1, mu2, mu3, r0, sm=1.0):
    """Velocity-dependent coefficient of seed 002 eq. (9.8), scaled by ``sm`` as in (9.33).

    The zero-speed smoothing factor ``(1 - exp(-r1|w|))`` of (9.33) is *not* included:
    it is the law's regularisation and is applied by :func:`regularised` with
    ``kind="vahid"``.
    """
    return sm * (mu1 + mu2 * _exp(-r0 * v_abs) + mu3 * v_abs)


def smooth_sign(v, eps):
    """``tanh(v/eps)``: the regularised sign used by seed 001 eq. (4); ``eps`` [rad/s] > 0."""
    return _tanh(v / eps)


def smooth_abs(v, eps):
    """``sqrt(v^2 + eps^2) - eps``: |v| smoothed at zero, exact far from it."""
    return _sqrt(v * v + eps * eps) - eps


def regularised(magnitude, v, eps, kind: str = "tanh"):
    """Signed, regularised friction from a magnitude law.

    Parameters
    ----------
    magnitude : callable ``v_abs -> magnitude``
    v : sliding speed [rad/s]
    eps : smoothing parameter. For ``kind="tanh"`` the transition speed [rad/s]
        (seed 001's ``v_t``); for ``kind="vahid"`` the rate ``r1`` [s/rad] of
        seed 002 eq. (9.33), ``sign(v) (1 - exp(-r1|v|))``.
    kind : "tanh" or "vahid"

    Returns
    -------
    friction with the sign of ``v`` (it opposes the caller's sign convention: the
    caller subtracts it).
    """
    if kind == "tanh":
        return smooth_sign(v, eps) * magnitude(smooth_abs(v, 1e-3 * eps))
    if kind == "vahid":
        av = ca.fabs(v) if _is_symbolic(v) else np.abs(v)
        sgn = ca.sign(v) if _is_symbolic(v) else np.sign(v)
        return sgn * (1 - _exp(-eps * av)) * magnitude(av)
    raise ValueError(f"kind must be 'tanh' or 'vahid', got {kind!r}")
