"""Friction laws and their registry.

A friction *contact* of a rig file (``[contacts.<name>]``) names a law from :data:`LAWS`
and gives its parameters.  A law is one Python function of the sliding speed
``v_abs >= 0`` [rad/s] that returns the *magnitude* of the friction torque [N m]; it must
work on floats, numpy arrays and CasADi ``SX``/``MX`` alike (use the helpers ``fexp``, ``flog``,
``fasinh``, ``fabs``, ``fsign``, :func:`smooth_abs`, :func:`smooth_sign`).  Its argument ``scale`` is the contact's
normal force times its radius, ``N r`` [N m] (1 when the contact gives neither, in which
case the law's "level" parameters are torques in N m instead of coefficients).

Adding a law is one function and one registry line::

    def my_law(v_abs, scale, *, mu_k, c_v):
        '''mu_k N r + c_v |w|: Coulomb plus viscous.'''
        return scale * mu_k + c_v * v_abs

    register(FrictionLaw("my_law", my_law, (Param("mu_k", "level", role="kinetic"),
                                            Param("c_v", "damping", role="viscous")),
                         doc="Coulomb plus viscous", reference="textbook"))

The *roles* (:data:`ROLES`: static and kinetic level, viscous coefficient, decay speed, ...)
are how the rest of the workbench understands a law without knowing its name:
identification's starting guess regresses a torque balance on the parameters the torque is
linear in, its ``kinetic <= static`` constraint pairs the two levels, and D-OSKIL scales its
gain by the kinetic level.

after which a rig file may say ``law = "my_law"`` with ``mu_k`` and ``c_v`` in the contact.

**Laws with state.**  A law may carry internal states (LuGre's bristle deflection, rate-and-state's
contact age): it declares them (:class:`LawState`: name, quantity kind, description) and gives one
function of the SIGNED sliding speed ``v`` [rad/s] and its states ``z`` (a list) that returns the
friction torque resisting ``v`` [N m] and the states' derivatives::

    def my_dynamic_law(v, z, scale, *, sigma0, mu_c):
        zdot = v - sigma0 * smooth_abs(v, 1e-9) * z[0] / mu_c
        return scale * sigma0 * z[0], [zdot]

    register(FrictionLaw("my_dynamic_law", my_steady_law, params,
                         states=(LawState("z", "angle", "bristle deflection"),), dynamics=my_dynamic_law))

``magnitude`` is then the law at steady sliding (the states settled), which every memoryless view
uses (static limits, steady sliding guesses, data-derived starting values, D-OSKIL's level).  The
rig model appends each contact's states to its state vector (``<state>_<contact>``, after the body
speeds), and the plant, the estimators, identification and the NMPC integrate them with the rest.

The exact stick/slip plant (:mod:`models.plant`) uses the law as it is: a body at rest
stays stuck while the torque on it lies within the law's value at zero speed.  Optimisers
use a regularised version (:meth:`FrictionLaw.smooth`): ``tanh(v/eps)`` times the law at
``|v|`` (seed 001 eq. 4), or the law's own regularisation when it has one (seed 002
eq. 9.33).

Laws shipped
------------
``coulomb``      seed 001 eq. (3)-(4): ``mu_k N r``
``stribeck``     thesis eq. (3-13): ``N r [mu_k + (mu_s - mu_k) exp(-|w|/v_s)]``
``vahid_araghi`` seed 002 eqs. (9.8), (9.33): ``N r s_m (mu1 + mu2 exp(-r0|w|) + mu3 |w|)``
``bit_rock``     drill-string bit-rock interaction, velocity weakening then strengthening
                 (Navarro-Lopez and Cortes, J. Sound Vib. 307, 2007; Navarro-Lopez and
                 Suarez, IEEE CCA 2004): ``c_b |w| + W R_b [mu_cb + (mu_sb - mu_cb) exp(-|w|/v_b)]``
``leadscrew``    seed 002 eqs. (9.7), (9.31), (9.33): the lead-screw thread friction with
                 the lead angle, which is not symmetric in the sliding direction and changes
                 the effective inertia
``lugre``        Canudas de Wit, Olsson, Astrom & Lischinsky, IEEE TAC 40(3) 1995: bristle
                 deflection ``z``, presliding hysteresis, a smooth model of stick (state)
``rate_state``   Dieterich-Ruina with the ageing law (Ruina 1983; the arcsinh form of Rice,
                 Lapusta & Ranjith 2001), the state as ``psi = ln(v0 theta / Dc)`` (state)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import casadi as ca
import numpy as np

from models.errors import ConfigError

__all__ = [
    "Param",
    "LawState",
    "level_kind",
    "ROLES",
    "LINEAR_ROLES",
    "FrictionLaw",
    "LAWS",
    "register",
    "get_law",
    "coulomb",
    "stribeck",
    "vahid_araghi",
    "bit_rock",
    "smooth_sign",
    "smooth_abs",
    "is_symbolic",
    "fexp",
    "flog",
    "fasinh",
    "fabs",
    "fsign",
]


# ----------------------------------------------------------------------------- math helpers
def is_symbolic(x) -> bool:
    """True for a CasADi expression (SX, MX, DM)."""
    return isinstance(x, (ca.SX, ca.MX, ca.DM))


def fexp(x):
    """``exp`` of a float, a numpy array or a CasADi expression (law functions take all three)."""
    return ca.exp(x) if is_symbolic(x) else np.exp(x)


def flog(x):
    """``log`` of a float, a numpy array or a CasADi expression."""
    return ca.log(x) if is_symbolic(x) else np.log(x)


def fasinh(x):
    """``asinh`` of a float, a numpy array or a CasADi expression."""
    return ca.asinh(x) if is_symbolic(x) else np.arcsinh(x)


def fabs(x):
    """``|x|`` of a float, a numpy array or a CasADi expression."""
    return ca.fabs(x) if is_symbolic(x) else np.abs(x)


def fsign(x):
    """``sign`` of a float, a numpy array or a CasADi expression."""
    return ca.sign(x) if is_symbolic(x) else np.sign(x)


_sym, _exp, _abs, _sign = is_symbolic, fexp, fabs, fsign


def _tanh(x):
    return ca.tanh(x) if _sym(x) else np.tanh(x)


def _sqrt(x):
    return ca.sqrt(x) if _sym(x) else np.sqrt(x)


def smooth_sign(v, eps):
    """``tanh(v/eps)``: the regularised sign of seed 001 eq. (4); ``eps`` [rad/s] > 0."""
    return _tanh(v / eps)


def smooth_abs(v, eps):
    """``sqrt(v^2 + eps^2) - eps``: |v| smoothed at zero, exact far from it."""
    return _sqrt(v * v + eps * eps) - eps


# ----------------------------------------------------------------------------- the laws
def coulomb(v_abs, scale, *, mu_k):
    """Coulomb friction, seed 001 eq. (3): ``mu_k N r`` at any sliding speed [N m]."""
    return scale * mu_k + 0 * v_abs


def stribeck(v_abs, scale, *, mu_s, mu_k, v_s):
    """Exponential Stribeck law, thesis eq. (3-13): ``N r [mu_k + (mu_s - mu_k) e^{-|w|/v_s}]``.

    ``v_s`` [rad/s] is the decay speed; the thesis' ``e^{-|w|}`` means ``v_s = 1 rad/s``.
    """
    return scale * (mu_k + (mu_s - mu_k) * _exp(-v_abs / v_s))


def vahid_araghi(v_abs, scale, *, mu1, mu2, mu3, r0, sm):
    """Velocity-dependent coefficient of seed 002 eq. (9.8), scaled by ``sm`` as in (9.33).

    The zero-speed factor ``1 - exp(-r1|w|)`` of (9.33) is the law's regularisation and is
    applied by :meth:`FrictionLaw.smooth` (``smoothing="vahid"``), not here.
    """
    return scale * sm * (mu1 + mu2 * _exp(-r0 * v_abs) + mu3 * v_abs)


def bit_rock(v_abs, scale, *, mu_sb, mu_cb, v_b, c_b):
    """Bit-rock torque of the drill-string literature: weakening, then strengthening.

    ``T = c_b |w| + W R_b [mu_cb + (mu_sb - mu_cb) exp(-|w|/v_b)]`` (Navarro-Lopez and
    Cortes 2007, with ``v_b = nu_f/gamma_b``): the Stribeck part falls from ``mu_sb`` to
    ``mu_cb`` over the speed ``v_b`` [rad/s], and the viscous part ``c_b`` [N m s/rad] makes
    the torque rise again at higher speed.  ``scale`` is the weight on bit times the bit
    radius.
    """
    return c_b * v_abs + scale * (mu_cb + (mu_sb - mu_cb) * _exp(-v_abs / v_b))


def _leadscrew_xi(mu_signed, lam):
    t = ca.tan(lam) if _sym(lam) else np.tan(lam)
    return (mu_signed - t) / (1 + mu_signed * t), t


def leadscrew_torque(v_abs, s, N, r, *, mu1, mu2, mu3, r0, sm, lam, m, F0, T0, r1):
    """Signed thread torque of seed 002 eq. (9.31) on the screw sliding in direction ``s``.

    ``-r_m xi(s mu) (R - F0 s) - T0 s`` with ``xi`` of eq. (9.7) and ``mu`` of (9.8)/(9.33);
    ``N`` is the axial force R [N] and ``r`` the pitch radius r_m [m].
    """
    mu = sm * (mu1 + mu2 * _exp(-r0 * v_abs) + mu3 * v_abs)
    xi, _ = _leadscrew_xi(s * mu, lam)
    return -r * xi * (N - F0 * s) - T0 * s


def leadscrew_inertia(v_abs, s, N, r, *, mu1, mu2, mu3, r0, sm, lam, m, F0, T0, r1):
    """Inertia the translating mass adds, ``-tan(lam) xi m r_m^2`` (seed 002 eq. 9.31)."""
    mu = sm * (mu1 + mu2 * _exp(-r0 * v_abs) + mu3 * v_abs)
    xi, t = _leadscrew_xi(s * mu, lam)
    return -t * xi * m * r ** 2


def leadscrew_smooth(v, N, r, eps, *, mu1, mu2, mu3, r0, sm, lam, m, F0, T0, r1):
    """Seed 002's own regularisation (9.33): ``mu`` and the direction are multiplied by
    ``sign(v)(1 - exp(-r1|v|))``; ``eps`` is not used."""
    av = _abs(v)
    soft = _sign(v) * (1 - _exp(-r1 * av))
    mu_signed = soft * sm * (mu1 + mu2 * _exp(-r0 * av) + mu3 * av)
    xi, _ = _leadscrew_xi(mu_signed, lam)
    return -r * xi * (N - F0 * soft) - T0 * soft


# ----------------------------------------------------------------------------- registry
#: parameter roles a law may declare (:attr:`Param.role`); identification's starting guess, its
#: ``kinetic <= static`` constraint and D-OSKIL's gain ask a law for these instead of its names
ROLES = {
    "static": "friction level at zero sliding speed (a coefficient with a normal force, else a torque)",
    "kinetic": "friction level once sliding (Coulomb / kinetic level)",
    "excess": "static level minus kinetic level (a Stribeck part added to the kinetic level)",
    "viscous": "viscous coefficient: friction grows in proportion to the sliding speed",
    "decay_speed": "characteristic speed of the fall from static to kinetic level [rad/s]",
    "decay_rate": "inverse characteristic speed of that fall [s/rad]",
    "scale": "a factor on the whole law",
    "smoothing": "the law's own regularisation at zero speed",
    "geometry": "a dimension or mass of the contact's mechanism",
}
#: roles in which the friction torque is linear (so a torque balance gives them by least squares)
LINEAR_ROLES = ("static", "kinetic", "excess", "viscous")


@dataclass(frozen=True)
class Param:
    """A parameter of a law: its name, quantity kind (:data:`models.units.DIMENSIONS`, or
    ``"level"``: dimensionless when the contact has a normal force and a radius, a torque
    [N m] when it has neither; ``"level_slowness"``: a level per rad/s), a description, physical
    bounds, and its role (one of :data:`ROLES`, or ``""``).

    ``linear`` says the law's torque is linear in this parameter (with the others fixed); it
    defaults to True for the roles of :data:`LINEAR_ROLES`.
    """

    name: str
    kind: str
    doc: str = ""
    lower: float = float("-inf")
    upper: float = float("inf")
    role: str = ""
    linear: bool | None = None

    def __post_init__(self):
        if self.role and self.role not in ROLES:
            raise ConfigError(f"friction law parameter {self.name!r}: role must be one of {', '.join(ROLES)} or "
                              f"empty, got {self.role!r}")
        if self.linear is None:
            object.__setattr__(self, "linear", self.role in LINEAR_ROLES)


@dataclass(frozen=True)
class LawState:
    """An internal state of a friction law: its name (the rig names it ``<name>_<contact>``), its
    quantity kind (:data:`models.units.DIMENSIONS`) and a description."""

    name: str
    kind: str
    doc: str = ""


#: parameter kinds whose unit depends on whether the contact has a normal force and a radius: a
#: level is a coefficient with them and a torque without (and likewise per speed, per angle)
_LEVEL_KINDS = {"level": ("dimensionless", "torque"), "level_slowness": ("slowness", "damping"),
                "level_per_angle": ("per_angle", "stiffness")}


def level_kind(kind: str, has_normal: bool) -> str:
    """The quantity kind of a law parameter of ``kind`` in a contact with (or without) a normal force
    and radius: ``"level"`` is dimensionless with them and a torque without, ``"level_slowness"`` s/rad
    or N m s/rad, ``"level_per_angle"`` 1/rad or N m/rad; other kinds are themselves."""
    pair = _LEVEL_KINDS.get(kind)
    return kind if pair is None else pair[0 if has_normal else 1]


@dataclass(frozen=True)
class FrictionLaw:
    """One registered law.

    Parameters
    ----------
    name : the name a rig file uses (``law = "..."``)
    magnitude : ``f(v_abs, scale, **params) -> torque magnitude [N m]`` (symmetric laws)
    params : the law's parameters, in the order they are listed
    doc, reference : one line each, shown by ``mitigate modal --model ... --json`` and the README
    directional : ``g(v_abs, s, N, r, **params) -> signed torque`` for laws that are not
        symmetric in the sliding direction ``s`` = +1/-1 (then ``magnitude`` is unused)
    inertia : optional ``h(v_abs, s, N, r, **params)``: inertia the contact adds [kg m^2]
    smooth_fn : optional own regularisation ``(v, N, r, eps, **params) -> signed torque``
    smoothing_param : the parameter that sets the law's own regularisation (shown to users)
    states : the law's internal states (:class:`LawState`), empty for a memoryless law
    dynamics : with ``states``: ``d(v, z, scale, **params) -> (friction, zdot)``, the friction torque
        [N m] resisting the SIGNED speed ``v`` [rad/s] and the states' derivatives (a list), ``z`` the
        states (a list); ``magnitude`` is then the law at steady sliding
    rest_free : with ``states``: the friction vanishes at zero speed whatever the states (rate-and-state's
        arcsinh form), so an implicit step may bracket the speed by rest and the friction-free speed
    steady : with ``states``: optional ``s(v, scale, **params) -> z`` (a list), the states at steady
        sliding at the signed speed ``v`` (starting values of steady-sliding solves; else zeros)
    """

    name: str
    magnitude: Callable[..., Any] | None
    params: tuple[Param, ...]
    doc: str = ""
    reference: str = ""
    directional: Callable[..., Any] | None = None
    inertia: Callable[..., Any] | None = None
    smooth_fn: Callable[..., Any] | None = None
    smoothing_param: str = ""
    extras: dict = field(default_factory=dict, compare=False)
    states: tuple[LawState, ...] = ()
    dynamics: Callable[..., Any] | None = None
    rest_free: bool = False
    steady: Callable[..., Any] | None = None

    @property
    def stateful(self) -> bool:
        """True when the law has internal states (its friction depends on their history)."""
        return bool(self.states)

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(q.name for q in self.states)

    def dynamic_torque(self, v, z, N, r, P: dict):
        """``(torque, zdot)``: the signed friction torque ON the body at signed speed ``v`` with states
        ``z`` (it resists ``v``), and the states' derivatives (a list)."""
        F, zdot = self.dynamics(v, list(z), N * r, **P)
        return -F, list(zdot)

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def with_role(self, role: str) -> str | None:
        """The name of the parameter that plays ``role`` (:data:`ROLES`), or None."""
        if role not in ROLES:
            raise ConfigError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
        return next((p.name for p in self.params if p.role == role), None)

    @property
    def linear_params(self) -> tuple[str, ...]:
        """Parameters the torque is linear in (least-squares regressors of a torque balance)."""
        return tuple(p.name for p in self.params if p.linear)

    @property
    def level_order(self) -> tuple[str, str] | None:
        """``(kinetic, static)`` names when the law has both levels (then ``kinetic <= static``
        is a physical constraint), else None."""
        k, s = self.with_role("kinetic"), self.with_role("static")
        return (k, s) if k and s else None

    def magnitude_at(self, v_abs, N, r, P: dict):
        """Friction torque magnitude opposing motion in the + direction at speed ``v_abs >= 0``
        [N m] (for a symmetric law, the law itself)."""
        return -self.torque(v_abs, 1.0, N, r, P)

    def torque(self, v_abs, s, N, r, P: dict):
        """Signed friction torque on the body sliding in direction ``s`` (+1/-1) at speed
        ``v_abs >= 0``: it opposes the motion for symmetric laws (``-s`` times the magnitude)."""
        if self.directional is not None:
            return self.directional(v_abs, s, N, r, **P)
        return -s * self.magnitude(v_abs, N * r, **P)

    def static_limits(self, N, r, P: dict):
        """``(T_plus, T_minus)``: the torques that oppose motion starting in the + and -
        directions at zero speed (``T_plus <= 0 <= T_minus`` for a dissipative law)."""
        return self.torque(0 * N, 1.0, N, r, P), self.torque(0 * N, -1.0, N, r, P)

    def added_inertia(self, v_abs, s, N, r, P: dict):
        if self.inertia is None:
            return 0.0
        return self.inertia(v_abs, s, N, r, **P)

    def smooth(self, v, N, r, P: dict, eps: float):
        """Regularised signed torque at signed speed ``v``.

        Default: blend the two sliding branches with ``sigma = tanh(v/eps)``,
        ``(1+sigma)/2 T(|v|, +1) + (1-sigma)/2 T(|v|, -1)``; for a symmetric law this is
        ``-tanh(v/eps) T(|v|)`` (seed 001 eq. 4).  ``|v|`` is itself smoothed at 1e-3 eps.
        """
        if self.smooth_fn is not None:
            return self.smooth_fn(v, N, r, eps, **P)
        sig = smooth_sign(v, eps)
        va = smooth_abs(v, 1e-3 * eps)
        if self.directional is None:
            return -sig * self.magnitude(va, N * r, **P)
        return 0.5 * (1 + sig) * self.torque(va, 1.0, N, r, P) + 0.5 * (1 - sig) * self.torque(va, -1.0, N, r, P)


LAWS: dict[str, FrictionLaw] = {}


def register(law: FrictionLaw) -> FrictionLaw:
    """Add ``law`` to :data:`LAWS` (its name must be new)."""
    if not isinstance(law, FrictionLaw):
        raise TypeError(f"register expects a FrictionLaw, got {type(law).__name__}")
    if law.name in LAWS:
        raise ConfigError(f"friction law {law.name!r} is already registered")
    if law.magnitude is None and law.directional is None:
        raise ConfigError(f"friction law {law.name!r} needs a magnitude or a directional function")
    if bool(law.states) != (law.dynamics is not None):
        raise ConfigError(f"friction law {law.name!r}: states and dynamics go together (a law with states "
                          f"gives dynamics(v, z, scale, **params) -> (friction, zdot))")
    if law.states and law.directional is not None:
        raise ConfigError(f"friction law {law.name!r}: a law with states must be symmetric (no directional function)")
    LAWS[law.name] = law
    return law


def get_law(name: str, where: str = "law") -> FrictionLaw:
    """The registered law ``name``; a one-line ConfigError lists the known ones."""
    try:
        return LAWS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"{where} must be one of {', '.join(sorted(LAWS))}, got {name!r}") from None


_LS_PARAMS = (
    Param("mu1", "dimensionless", "Coulomb part of the thread friction (seed 002 Table 9.5)", role="kinetic", linear=False),
    Param("mu2", "dimensionless", "Stribeck part", role="excess", linear=False),
    Param("mu3", "slowness", "viscous part [s/rad]", role="viscous", linear=False),
    Param("r0", "slowness", "Stribeck decay rate [s/rad]", 0.0, role="decay_rate"),
    Param("sm", "dimensionless", "friction scaling of eq. (9.33)", 0.0, role="scale"),
    Param("lam", "angle", "lead angle", 0.0, 1.5, role="geometry"),
    Param("m", "mass", "mass of the translating parts", 0.0, role="geometry"),
    Param("F0", "force", "slider resistance", 0.0),
    Param("T0", "torque", "support friction torque", 0.0),
    Param("r1", "slowness", "zero-speed smoothing rate of eq. (9.33) [s/rad]", 0.0, role="smoothing"),
)

register(FrictionLaw("coulomb", coulomb, (Param("mu_k", "level", "kinetic coefficient (or torque)", 0.0, role="kinetic"),),
                     doc="constant friction at any sliding speed", reference="seed 001 eqs. (3)-(4)"))
register(FrictionLaw("stribeck", stribeck,
                     (Param("mu_s", "level", "static coefficient (or torque)", 0.0, role="static"),
                      Param("mu_k", "level", "kinetic coefficient (or torque)", 0.0, role="kinetic"),
                      Param("v_s", "speed", "Stribeck decay speed", 0.0, role="decay_speed")),
                     doc="exponential decay from static to kinetic friction", reference="thesis eq. (3-13)"))
register(FrictionLaw("vahid_araghi", vahid_araghi,
                     (Param("mu1", "level", "Coulomb part", role="kinetic"), Param("mu2", "level", "Stribeck part", role="excess"),
                      Param("mu3", "level_slowness", "viscous part", role="viscous"),
                      Param("r0", "slowness", "Stribeck decay rate", 0.0, role="decay_rate"),
                      Param("sm", "dimensionless", "friction scaling", 0.0, role="scale")),
                     doc="Coulomb + exponential Stribeck + linear viscous coefficient", reference="seed 002 eqs. (9.8), (9.33)"))
register(FrictionLaw("bit_rock", bit_rock,
                     (Param("mu_sb", "level", "static bit-rock coefficient", 0.0, role="static"),
                      Param("mu_cb", "level", "Coulomb bit-rock coefficient", 0.0, role="kinetic"),
                      Param("v_b", "speed", "decay speed of the weakening branch", 0.0, role="decay_speed"),
                      Param("c_b", "damping", "viscous (strengthening) coefficient [N m s/rad]", 0.0, role="viscous")),
                     doc="velocity weakening followed by viscous strengthening (bit-rock interaction)",
                     reference="Navarro-Lopez & Cortes, J. Sound Vib. 307 (2007)"))
register(FrictionLaw("leadscrew", None, _LS_PARAMS, doc="lead-screw thread friction (direction-dependent)",
                     reference="seed 002 eqs. (9.7), (9.31), (9.33)", directional=leadscrew_torque,
                     inertia=leadscrew_inertia, smooth_fn=leadscrew_smooth, smoothing_param="r1"))

# the laws with state (LuGre, rate-and-state) live in models/friction_state.py and register themselves
# there; the package's __init__ imports it, so every use of the registry sees them
