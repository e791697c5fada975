"""Options of the online estimators: frozen keyword-only dataclasses that check themselves.

A scenario's ``[estimator]`` table (``kind = "ekf" | "mhe" | "fd"`` and the fields below) is
turned into one of these by :func:`models.checks.options_from_mapping`; every bad value is one
:class:`models.errors.ConfigError` line ``"<where>.<field> must be ..., got <value>"`` (built
directly, ``<where>`` is ``estimator``).
Checks that need the rig (is ``omega4`` one of its channels? is ``pin3`` a contact?) are
made when the estimation model is built (:mod:`estimators.online.model`).

The defaults, and why, are in :mod:`estimators.online.model`'s docstring.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from models.checks import check_options, option, prefix
from models.errors import ConfigError
# the speed scale and the rule that carries a speed-like default from rig3 are the model's
# (models.rig.steady): the model's own eps follows it too
from models.rig.steady import RIG3_SPEED, by_speed, speed_scale

__all__ = ["EKFOptions", "MHEOptions", "FDOptions", "ANGLES", "QP_SOLVERS", "RigScales",
           "rig_scales", "for_rig", "REFERENCE", "SCALED", "speed_scale", "by_speed"]

ANGLES = ("zeroed", "absolute")
QP_SOLVERS = ("ldl", "osqp")
#: how messages name the table when the options are built directly (not from a scenario's table)
WHERE = "estimator"


def _augment_entries(augment: tuple[str, ...], where: str) -> None:
    """Each extra state names its kind and its target: ``load:<contact>``, ``offset:<channel>``, ``gain:<channel>``."""
    for a in augment:
        kind, _, target = a.partition(":")
        if kind not in ("load", "offset", "gain") or not target:
            raise ConfigError(f"{where} entries must be 'load:<contact>', 'offset:<channel>' or 'gain:<channel>', "
                              f"got {a!r}")


@dataclass(frozen=True, kw_only=True)
class EKFOptions:
    """Options of the EKF (``[estimator]`` with ``kind = "ekf"``); the MHE shares them.

    Parameters
    ----------
    channels : log channels measured (None: the rig's encoder angles and speeds, speed
        sensors and torque sensors; load cells are inputs, never measurements)
    angles : "zeroed" (incremental encoders read 0 at power-on: the twists at power-on are
        estimated as states ``zero:<twist>``) or "absolute" (encoders referenced to the
        untwisted shaft)
    augment : extra random-walk states, each ``"load:<contact>"`` (a factor on that
        contact's friction torque), ``"offset:<channel>"`` or ``"gain:<channel>"`` (a
        torque sensor's, speed sensor's or load cell's offset [channel unit] or gain [-]);
        None: the rig's default (see :mod:`estimators.online.model`); ``[]``: none
    eps : friction regularisation of the estimator's model [rad/s]
    nsub : RK4 substeps per DAQ sample, at least (the regularised friction is stiff, ~400 1/s on
        rig3); the integration rule (:func:`models.discretise.integration`) raises them for a
        stiffer rig and treats a fast DC motor's current quasi-statically
    q_torque : unmodelled torque on each body, standard deviation [N m] (white over a sample)
    q_current : unmodelled armature current per sample, standard deviation [A]
    q_twist : unmodelled twist per sample, standard deviation [rad]
    q_load : random-walk intensity of the load factors [1/sqrt(s)]
    q_offset : random-walk intensity of the sensor offsets [channel unit/sqrt(s)]
    q_gain : random-walk intensity of the sensor gains [1/sqrt(s)]
    q_stick : unknown friction torque on a body at (near) rest, standard deviation as a
        multiple of its contacts' static friction torque [-] (weighted by
        ``1 - tanh^2(omega/eps)``): in stick the friction is a constraint force, not the
        regularised law's creep; 0 trusts the regularised model in stick
    p0_twist, p0_speed, p0_current, p0_pi, p0_load, p0_offset, p0_gain : initial standard
        deviations [rad], [rad/s], [A], [rad], [-], [channel unit], [-]
    compile : build the step Functions in C (gcc, cached on disk); False or a failed build
        calls CasADi
    check_observability : run the observability checks at construction (a start-up of the
        estimator's own model at the rig's operating point, and steady sliding there;
        :class:`estimators.online.ekf.ObservabilityMixin`)
    observability_window : length of the start-up trajectory [s]

    Notes
    -----
    The defaults are rig3's measured choices (:mod:`estimators.online.model`, "Defaults, and
    why").  Those that carry a unit (:data:`SCALED`) default to None: :func:`for_rig` carries
    rig3's value to the rig at hand by the ratio of the rig's scale to rig3's (:class:`RigScales`:
    nominal speed, load torque, twist, current, stick-slip period), so a field string 1e4 times
    heavier gets noise levels 1e4 times larger, not rig3's grams.
    """


    channels: tuple | None = option(None, kind="names", what="log channels of the rig", nonempty=True, unique=True,
                                    none=True)
    angles: str = option("zeroed", choices=ANGLES)
    augment: tuple | None = option(None, kind="names", what="'load:<contact>', 'offset:<channel>' or 'gain:<channel>'",
                                   unique=True, none=True, check=_augment_entries)
    eps: float | None = option(None, lo=0.0, lo_open=True, none=True)
    nsub: int = option(4, lo=1)
    q_torque: float | None = option(None, lo=0.0, none=True)
    q_current: float | None = option(None, lo=0.0, none=True)
    q_twist: float | None = option(None, lo=0.0, none=True)
    q_load: float = option(0.02, lo=0.0)
    q_offset: float | None = option(None, lo=0.0, none=True)
    q_gain: float = option(0.002, lo=0.0)
    q_stick: float = option(2.0, lo=0.0)
    p0_twist: float | None = option(None, lo=0.0, none=True)
    p0_speed: float | None = option(None, lo=0.0, none=True)
    p0_current: float | None = option(None, lo=0.0, none=True)
    p0_pi: float | None = option(None, lo=0.0, none=True)
    p0_load: float = option(0.3, lo=0.0)
    p0_offset: float | None = option(None, lo=0.0, none=True)
    p0_gain: float = option(0.05, lo=0.0)
    compile: bool = option(True)
    check_observability: bool = option(True)
    observability_window: float | None = option(None, lo=0.0, lo_open=True, none=True)

    def __post_init__(self):
        check_options(self, prefix(WHERE))


@dataclass(frozen=True, kw_only=True)
class MHEOptions(EKFOptions):
    """Options of the MHE (``[estimator]`` with ``kind = "mhe"``): the EKF's, and

    Parameters
    ----------
    window : samples in the horizon N (nodes N + 1), >= 2
    max_iter : Gauss-Newton iterations per sample (1: real-time iteration), >= 1
    qpsol : "ldl" (the unconstrained Gauss-Newton step by CasADi's sparse LDL, projected on the
        bounds; 0.6 ms at N = 20) or "osqp" (the bound-constrained step; ~10 ms).  qrqp is not
        offered: it failed ("search direction") on every rig3 window, whose Hessian carries the
        weights of exact constraints (power-on twists, lagged states)
    """


    window: int = option(20, lo=2)
    max_iter: int = option(1, lo=1)
    qpsol: str = option("ldl", choices=QP_SOLVERS)

    def ekf_options(self) -> EKFOptions:
        """The options of the EKF that runs alongside (its fallback and arrival cost)."""
        return EKFOptions(**{f.name: getattr(self, f.name) for f in fields(EKFOptions)})


@dataclass(frozen=True, kw_only=True)
class FDOptions:
    """Options of the finite-difference baseline (``[estimator]`` with ``kind = "fd"``).

    Parameters
    ----------
    angles : "zeroed" (differences of encoders that read 0 at power-on, plus the initial
        twist of the context's ``x0``) or "absolute" (the differences are the twists)
    """


    angles: str = option("zeroed", choices=ANGLES)

    def __post_init__(self):
        check_options(self, prefix(WHERE))


@dataclass(frozen=True)
class RigScales:
    """The scales a rig's estimator defaults are carried by (:func:`rig_scales`).

    speed : nominal speed [rad/s]; torque : largest steady shaft torque at the operating point
    [N m]; twist : largest steady twist [rad]; current : a DC motor's current limit [A] (nan:
    none); period : the rig's stick-slip period [s] (:func:`models.modal.stick_slip_period`)
    """

    speed: float
    torque: float
    twist: float
    current: float
    period: float


#: rig3's scales (30 rpm, N1 = 20 N): the defaults were measured there
REFERENCE = RigScales(speed=RIG3_SPEED, torque=0.29552088, twist=0.80765478, current=10.0, period=1.0 / 0.42854708)

#: option -> (rig3's value, the scale that carries it)
SCALED = {
    "eps": (0.05, "speed"), "p0_speed": (1.0, "speed"),
    "q_torque": (0.02, "torque"), "q_offset": (0.002, "torque"), "p0_offset": (0.05, "torque"),
    "q_twist": (1e-4, "twist"), "p0_twist": (0.5, "twist"), "p0_pi": (1.0, "twist"),
    "q_current": (0.05, "current"), "p0_current": (2.0, "current"),
    "observability_window": (4.0, "period"),
}


def rig_scales(model, params) -> RigScales:
    """The :class:`RigScales` of a rig at its nominal operating point (steady sliding)."""
    from models.modal import operating_point, stick_slip_period
    P = params.as_dict()
    u, x = operating_point(model, params)
    if x is None:
        x = model.steady_sliding(u, params)
    springs = [c for c in model.spec.connections if c.stiffness is not None]
    torque = max((abs(float(x[j]) * c.stiffness.value(P)) for j, c in enumerate(springs)), default=0.0)
    twist = max((abs(float(x[j])) for j in range(len(springs))), default=0.0)
    speed = speed_scale(model)
    current = model.drive.current_limit(P)
    try:
        period = stick_slip_period(model, params)
    except ConfigError:
        period = REFERENCE.period
    ref = REFERENCE
    return RigScales(speed or ref.speed, torque or ref.torque, twist or ref.twist,
                     current if current > 0 else ref.current, period)


def for_rig(options, model, params):
    """``options`` with every unset (None) option of :data:`SCALED` derived from the rig: rig3's
    value times the rig's scale over rig3's (``q_torque = 0.02 N m x T / 0.2955 N m``, ...)."""
    from dataclasses import replace
    unset = [n for n in SCALED if hasattr(options, n) and getattr(options, n) is None]
    if not unset:
        return options
    sc = rig_scales(model, params)
    return replace(options, **{n: SCALED[n][0] * getattr(sc, SCALED[n][1]) / getattr(REFERENCE, SCALED[n][1])
                               for n in unset})
