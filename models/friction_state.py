"""The friction laws with state of the registry (:mod:`models.friction`): LuGre and rate-and-state.

Each is one function of the signed sliding speed and the law's states returning the friction that
resists the speed and the states' derivatives, its steady-sliding curve (the memoryless view every
other consumer uses), the states at steady sliding (starting values of steady solves) and one
registry line (:class:`models.friction.FrictionLaw` with ``states`` and ``dynamics``).  The rig
model carries the states (``<state>_<contact>``), the plant, the estimators, identification and
the NMPC integrate them (``docs/friction-with-state.md``).

``lugre``        Canudas de Wit, Olsson, Astrom & Lischinsky, IEEE TAC 40(3) 1995
``rate_state``   Dieterich-Ruina with the ageing law (Ruina, JGR 88, 1983), arcsinh-regularised at
                 rest (Rice, Lapusta & Ranjith, JMPS 49, 2001)
"""

from __future__ import annotations

import casadi as ca

from models.friction import (FrictionLaw, LawState, Param, fabs, fasinh, fexp, flog, fsign, is_symbolic, register,
                             smooth_abs)

__all__ = ["LUGRE_ABS", "lugre", "lugre_steady", "lugre_states", "rate_state", "rate_state_steady",
           "rate_state_states"]

#: the width [rad/s] below which LuGre's |v| is rounded (its kink at 0 would stall Newton's method in the
#: implicit integrators; 1e-9 rad/s is far below any speed a log resolves)
LUGRE_ABS = 1e-9


def lugre_steady(v_abs, scale, *, sigma0, sigma1, sigma2, mu_c, mu_s, v_s):
    """LuGre at steady sliding: ``N r [mu_c + (mu_s - mu_c) exp(-(|w|/v_s)^2)] + sigma2 |w|`` [N m]
    (Canudas de Wit et al. 1995, eq. 3 with ``dz/dt = 0``)."""
    return scale * (mu_c + (mu_s - mu_c) * fexp(-(v_abs / v_s) ** 2)) + sigma2 * v_abs


def lugre(v, z, scale, *, sigma0, sigma1, sigma2, mu_c, mu_s, v_s):
    """LuGre (Canudas de Wit, Olsson, Astrom, Lischinsky, IEEE TAC 40(3) 1995, eqs. 1-4).

    ``dz/dt = w - sigma0 |w| z / g(w)``, ``g(w) = mu_c + (mu_s - mu_c) exp(-(w/v_s)^2)``, friction
    ``N r (sigma0 z + sigma1 dz/dt) + sigma2 w`` resisting ``w``.  ``z`` is the bristles' mean
    deflection [rad] (at the contact's radius ``r``: ``r z`` metres); the levels ``mu_c``, ``mu_s``
    and the bristle stiffness and damping ``sigma0`` [1/rad], ``sigma1`` [s/rad] are scaled by
    ``N r`` as every level of the registry, the viscous ``sigma2`` [N m s/rad] is not.  With
    ``N r = 1 N m`` and ``r = 1 m`` the paper's numbers apply as printed (``sigma0 = 1e5 N/m``,
    ``F_c = 1 N``, ...).  ``|w|`` is rounded below :data:`LUGRE_ABS`.
    """
    g = mu_c + (mu_s - mu_c) * fexp(-(v / v_s) ** 2)
    zdot = v - sigma0 * smooth_abs(v, LUGRE_ABS) * z[0] / g
    return scale * (sigma0 * z[0] + sigma1 * zdot) + sigma2 * v, [zdot]


def lugre_states(v, scale, *, sigma0, sigma1, sigma2, mu_c, mu_s, v_s):
    """LuGre's bristle deflection at steady sliding, ``sign(w) g(w) / sigma0`` [rad]."""
    return [fsign(v) * (mu_c + (mu_s - mu_c) * fexp(-(v / v_s) ** 2)) / sigma0]


def rate_state_states(v, scale, *, mu0, a, b, v0, d_c):
    """Rate-and-state's state at steady sliding, ``psi = ln(v0 / |w|)`` (the contact's age ``d_c/|w|``);
    at rest (no steady state: the contact ages for ever) that of ``|w| = v0``."""
    av = fabs(v)
    return [flog(v0 / (av + 1e-300)) * (av > 0) if not is_symbolic(v) else ca.if_else(av > 0, ca.log(v0 / av), 0)]


def rate_state_steady(v_abs, scale, *, mu0, a, b, v0, d_c):
    """Rate-and-state at steady sliding: ``N r [mu0 + (a - b) ln(1 + |w|/v0)]`` [N m].

    The exact steady state is ``mu0 + (a - b) ln(|w|/v0)`` (Ruina 1983), which has no limit at rest;
    this memoryless view (static limits, starting values) uses ``ln(1 + |w|/v0)``, equal to it
    within ``v0/|w|`` above the reference speed and ``mu0`` at rest.  The dynamic law
    (:func:`rate_state`) is exact.
    """
    return scale * (mu0 + (a - b) * flog(1 + v_abs / v0))


def rate_state(v, z, scale, *, mu0, a, b, v0, d_c):
    """Dieterich-Ruina rate-and-state friction with the ageing law, regularised at rest.

    ``mu = a asinh(w/(2 v0) exp((mu0 + b psi)/a))`` (Rice, Lapusta & Ranjith, JMPS 49, 2001, eq. 9:
    equal to ``mu0 + a ln(w/v0) + b psi`` once ``w >> v0 exp(-(mu0 + b psi)/a)``, and odd in ``w``),
    ``psi = ln(v0 theta / d_c)`` the state in log form (``theta`` the contact's age [s]),
    ``dtheta/dt = 1 - |w| theta / d_c`` (ageing law, Ruina 1983), i.e.
    ``dpsi/dt = (v0 exp(-psi) - |w|) / d_c`` (``|w|`` rounded below ``1e-6 v0``).  Friction ``N r mu`` resisting ``w``; ``v0`` [rad/s] the
    reference speed, ``d_c`` [rad] the characteristic slip (a distance ``r d_c`` at the contact).
    """
    psi = z[0]
    mu = a * fasinh(v / (2 * v0) * fexp((mu0 + b * psi) / a))
    return scale * mu, [(v0 * fexp(-psi) - smooth_abs(v, 1e-6 * v0)) / d_c]


register(FrictionLaw("lugre", lugre_steady,
                     (Param("sigma0", "level_per_angle", "bristle stiffness", 0.0),
                      Param("sigma1", "level_slowness", "bristle damping", 0.0),
                      Param("sigma2", "damping", "viscous coefficient [N m s/rad]", 0.0, role="viscous"),
                      Param("mu_c", "level", "Coulomb level", 0.0, role="kinetic"),
                      Param("mu_s", "level", "static level", 0.0, role="static"),
                      Param("v_s", "speed", "Stribeck speed", 0.0, role="decay_speed")),
                     doc="LuGre: bristle deflection with presliding hysteresis and a Stribeck curve",
                     reference="Canudas de Wit, Olsson, Astrom & Lischinsky, IEEE TAC 40(3) 1995",
                     states=(LawState("z", "angle", "mean bristle deflection"),), dynamics=lugre,
                     steady=lugre_states))
register(FrictionLaw("rate_state", rate_state_steady,
                     (Param("mu0", "level", "friction level at the reference speed", 0.0, role="kinetic"),
                      Param("a", "level", "direct effect", 0.0), Param("b", "level", "evolution effect", 0.0),
                      Param("v0", "speed", "reference speed", 0.0), Param("d_c", "angle", "characteristic slip", 0.0)),
                     doc="Dieterich-Ruina rate-and-state friction, ageing law (arcsinh-regularised at rest)",
                     reference="Ruina, JGR 88 (1983); Rice, Lapusta & Ranjith, JMPS 49 (2001)",
                     states=(LawState("psi", "dimensionless", "log contact age, ln(v0 theta / d_c)"),),
                     dynamics=rate_state, rest_free=True, steady=rate_state_states))
