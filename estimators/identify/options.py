"""What to fit and how: :class:`IdentifyOptions` and :class:`LinearConstraint`.

Both are frozen and check themselves when built (:class:`IdentifyOptions` declares its checks with
:func:`models.checks.option`); every error is one line naming the field,
``"options.eps must be a finite number > 0 rad/s, got -1"``.  Names of parameters and channels
are checked against the rig and the logs later, by :class:`~estimators.identify.problem.IdentificationProblem`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Mapping

from models.checks import check_options, number, option, prefix
from models.discretise import METHODS
from models.errors import ConfigError
from models.sensors import SensorOptions

__all__ = ["IdentifyOptions", "LinearConstraint", "SOLVERS", "ENCODER_ZERO", "GLOBALISE", "INPUT_ROWS", "EPS_RIG3",
           "default_eps"]

SOLVERS = ("gn", "ipopt")
GLOBALISE = ("auto", "always", "off")
#: "free": each log's encoders were zeroed at an unknown twist (one unknown per angle difference
#: and log); "untwisted": the rig was untwisted when the encoders were zeroed
ENCODER_ZERO = ("free", "untwisted")
#: "end": row k+1 holds the input held over [t_k, t_k+1) (the plant's logs); "start": row k holds it
INPUT_ROWS = ("end", "start")

#: the identification's friction regularisation on rig3 [rad/s] (0.16 % of its 30 rpm); another rig's
#: default is this carried by its nominal speed (:func:`default_eps`)
EPS_RIG3 = 0.005


def default_eps(model) -> float:
    """The default friction regularisation [rad/s] of a fit of ``model``: rig3's :data:`EPS_RIG3` times
    the rig's nominal speed over rig3's (:func:`estimators.online.options.by_speed`, the rule the EKF's
    eps and the NMPC's follow: a field string turning at 0.5 rad/s gets 0.0008 rad/s, not rig3's
    number, whose creep would be a quarter of its stick-slip's low speeds)."""
    from estimators.online.options import by_speed
    return by_speed(EPS_RIG3, model)


_TERM = re.compile(r"\s*([+-]?)\s*((?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)?\s*\*?\s*([A-Za-z_][A-Za-z0-9_]*)\s*")
_NUM = re.compile(r"^\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?\s*$")


@dataclass(frozen=True)
class LinearConstraint:
    """A linear inequality on parameters, ``sum_i c_i p_i <= upper`` (SI units).

    Parameters
    ----------
    terms : ``((name, coefficient), ...)``
    upper : the right-hand side
    text : how it reads (for messages)

    Notes
    -----
    Build one from text with :meth:`parse`, e.g. ``LinearConstraint.parse("mu_k - mu_s <= 0")``
    or ``"k1 + 2.5 k2 >= 1"``.
    """

    terms: tuple[tuple[str, float], ...]
    upper: float
    text: str = ""

    def __post_init__(self):
        if not self.terms:
            raise ConfigError(f"constraint {self.text or ''!r} must involve at least one parameter")
        for name, c in self.terms:
            if not isinstance(name, str) or isinstance(c, bool) or not isinstance(c, (int, float)) \
                    or not math.isfinite(c):
                raise ConfigError(f"constraint term must be (name, finite coefficient), got {(name, c)!r}")
        number(self.upper, "constraint right-hand side")
        if not self.text:
            object.__setattr__(self, "text", self.describe())

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.terms)

    def describe(self) -> str:
        parts = []
        for i, (n, c) in enumerate(self.terms):
            sign = "-" if c < 0 else ("+" if i else "")
            mag = abs(c)
            coef = "" if mag == 1 else f"{mag:g} "
            parts.append(f"{sign} {coef}{n}".strip() if i else f"{'-' if c < 0 else ''}{coef}{n}")
        return " ".join(parts) + f" <= {self.upper:g}"

    @classmethod
    def parse(cls, text: str, where: str = "options.constraints") -> "LinearConstraint":
        """``"a x + b y <= c"`` (or ``>=``) with numeric coefficients and parameter names."""
        if not isinstance(text, str):
            raise ConfigError(f"{where} must be text such as 'mu_k - mu_s <= 0', got {text!r}")
        for op, sign in (("<=", 1.0), (">=", -1.0)):
            if op in text:
                lhs, _, rhs = text.partition(op)
                break
        else:
            raise ConfigError(f"{where} must read 'EXPRESSION <= NUMBER' or 'EXPRESSION >= NUMBER', got {text!r}")
        if not _NUM.match(rhs):
            raise ConfigError(f"{where}: the right-hand side must be a number, got {rhs.strip()!r} in {text!r}")
        terms: dict[str, float] = {}
        pos, s = 0, lhs.strip()
        if not s:
            raise ConfigError(f"{where}: no parameter on the left-hand side of {text!r}")
        while pos < len(s):
            m = _TERM.match(s, pos)
            if not m or m.end() == pos:
                raise ConfigError(f"{where}: cannot read {s[pos:]!r} in {text!r} (expected e.g. '2.5 k1 - k2')")
            if pos > 0 and not m.group(1):
                raise ConfigError(f"{where}: missing + or - before {m.group(3)!r} in {text!r}")
            c = float(m.group(2)) if m.group(2) else 1.0
            c = -c if m.group(1) == "-" else c
            terms[m.group(3)] = terms.get(m.group(3), 0.0) + c
            pos = m.end()
        terms = {n: c for n, c in terms.items() if c != 0.0}
        return cls(tuple((n, sign * c) for n, c in terms.items()), sign * float(rhs), text.strip())


def _distinct(free: tuple[str, ...], where: str) -> None:
    """``free`` names at least one parameter, each once."""
    if not free:
        raise ConfigError(f"{where} must name at least one parameter, got none")
    dup = sorted({n for n in free if free.count(n) > 1})
    if dup:
        raise ConfigError(f"{where} must not repeat names, got {', '.join(dup)} twice")


def _constraints(v, where: str) -> tuple[LinearConstraint, ...]:
    """One constraint or a list of them, each a :class:`LinearConstraint` or its text."""
    out = []
    for c in (v if not isinstance(v, (str, LinearConstraint)) else (v,)):
        if isinstance(c, str):
            c = LinearConstraint.parse(c, where)
        if not isinstance(c, LinearConstraint):
            raise ConfigError(f"{where} must hold LinearConstraint or text, got {type(c).__name__}")
        out.append(c)
    return tuple(out)


def _noise_needs_gn(o: "IdentifyOptions", name) -> None:
    """Errors in the variables are a Gauss-Newton feature."""
    if isinstance(o.input_noise, Mapping) and o.input_noise and o.solver != "gn":
        raise ConfigError(f"{name('input_noise')} needs solver 'gn' (errors in the variables), got solver "
                          f"{o.solver!r}")


@dataclass(frozen=True, kw_only=True)
class IdentifyOptions:
    """What to fit and how.

    Parameters
    ----------
    free : names of the parameters to fit: physical ones and sensor offsets/gains alike
        (``("k1", "k2", "motor_torque_offset")``); a comma-separated string is accepted
    bounds : ``{name: (lower, upper)}`` [SI]; default the initial set's fitting bounds
        (its TOML ``[bounds]``, else the rig file's physical bounds)
    constraints : further linear inequalities on the free parameters, as
        :class:`LinearConstraint` or text (``"k1 - 3 k2 <= 0"``)
    order_friction : add ``mu_k <= mu_s`` for every Stribeck-type contact whose static and
        kinetic levels are both free (stribeck: mu_k <= mu_s; bit_rock: mu_cb <= mu_sb)
    outputs : compared channels; default every sensor channel of the rig found in the log
        (encoder speeds, speed, torque and load-cell channels that are not inputs) plus the
        encoder angle differences that measure twists (``"theta1-theta2"``, see ``use_twist``)
    exclude : channels left out of the default ``outputs`` (e.g. ``("torque_bit",)``)
    noise : ``{channel: standard deviation}`` [SI]; default from the rig's sensors
        (:func:`models.sensors.channel_std` with ``sensors``)
    sensors : the noise scale and quantisation the default noise levels assume
    eps : friction regularisation of the fitted model [rad/s]; None: from the rig,
        :func:`default_eps` (rig3's 0.005 rad/s at its 30 rpm, i.e. 0.16 % of the rig's nominal
        speed); the fit states the value used (``fit.eps``).  The regularised model creeps where
        the plant sticks; the bias this puts on friction and damping shrinks with eps (a small eps
        costs no refusal: where RK4 would need too many substeps the implicit step takes over)
    nsub : substeps per sample; None: from the integration rule
        (:func:`models.discretise.integration`: RK4 with ``h |lambda|max <= 2.5`` over the contacts at
        rest and sliding, a fast motor's current quasi-static, or the L-stable implicit step where RK4
        would need many more substeps than it, as at a small eps: never refused for stiffness).
        Given, it is RK4's (or, with ``integrator = "sdirk2"``, the implicit step's)
    integrator : "auto" (the rule's choice), "rk4" or "sdirk2" (:data:`models.discretise.METHODS`)
    shoot_every : samples per shooting interval
    speed_average : compare encoder speeds as means over the sample (the DAQ's backward
        differences of counted angles)
    use_twist : compare encoder angle differences with the twists they measure
    encoder_zero : "free" (default): incremental encoders read 0 at power-on, so an angle
        difference is the twist minus its unknown value then: one unknown per difference and
        log, fitted with the parameters; "untwisted": the logs started untwisted (the
        differences are the twists).  With "free" a constant friction level and a constant
        twist can only be told apart by a torque sensor, a varying normal force, or reversals
    input_row : "end" (row k+1 holds the input held over [t_k, t_k+1): the plant's logs) or
        "start" (row k holds it)
    extra_delay : whole samples added to every sensor channel's delay (the rig file's
        ``delay``); commands (set-points) are not delayed
    detect_delay : also fit with ``extra_delay`` = 0 .. detect_delay and keep the delay with
        the smallest cost per residual (reported in the result)
    max_iter : iteration limit; tol : convergence tolerance (GN: the scaled step below
        ``sqrt(tol)`` and the scaled gaps below ``100 tol``; IPOPT: its ``tol``)
    trust_radius : largest change of a scaled parameter (relative to its scale) in the first
        Gauss-Newton step; adapted from the ratio of actual to predicted decrease
    solver : "gn" (constrained Gauss-Newton / Levenberg-Marquardt on the sparse KKT system,
        compiled sensitivities) or "ipopt" (IPOPT with the Gauss-Newton Hessian, uncompiled;
        no errors in the variables)
    globalise : GN: "auto" (default): when the direct fit does not converge, or converges with a
        residual showing that the structure misses, solve again along a continuation in eps (10 eps
        down to eps) and keep the better end; "always"; "off" (the direct fit only).  See
        :mod:`~estimators.identify.continuation`
    compile : GN: build the per-sample sensitivity function with gcc (cached on disk); None:
        if gcc is available
    input_cutoff : ``{input channel: cutoff [Hz]}``: zero-phase low-pass of those logged inputs
    input_noise : errors in the variables: ``{input channel: noise std [SI]}``, "auto" (the
        force/torque inputs whose fast part is white noise, with the estimated std; GN only)
        or "off".  Every shooting interval gets a constant correction per such input, with the
        prior N(0, std^2 / shoot_every)
    corr_warn, rse_warn : identifiability thresholds (|correlation|, relative standard error,
        also along the weakest direction of the information matrix)
    systematic : also refit with the regularisation halved (eps/2; the lead screw's r1 doubled)
        and report ``|theta(eps) - theta(eps/2)|`` as a systematic error
    systematic_iter : iteration limit of that refit
    progress : one status line per iteration on stderr
    """

    free: tuple[str, ...] = option(kind="names", what="parameter names", split=True, check=_distinct)
    bounds: Mapping[str, tuple[float, float]] | None = option(None, items=2, finite=False, increasing=True,
                                                              by_name=True, none=True,
                                                              what="(lower, upper) with lower < upper")
    constraints: tuple = option((), kind="any", check=_constraints)
    order_friction: bool = option(True)
    outputs: tuple[str, ...] | None = option(None, kind="names", what="channel names", split=True, nonempty=True,
                                             none=True)
    exclude: tuple[str, ...] = option((), kind="names", what="channel names", split=True)
    noise: Mapping[str, float] | None = option(None, lo=0.0, lo_open=True, by_name=True, none=True)
    sensors: SensorOptions = option(SensorOptions(), table=SensorOptions, what="SensorOptions")
    eps: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s", none=True)
    nsub: int | None = option(None, kind="integer", lo=1, none=True)
    integrator: str = option("auto", choices=("auto",) + METHODS)
    shoot_every: int = option(10, lo=1)
    speed_average: bool = option(True)
    use_twist: bool = option(True)
    encoder_zero: str = option("free", choices=ENCODER_ZERO)
    input_row: str = option("end", choices=INPUT_ROWS)
    extra_delay: int = option(0, lo=0, hi=100, unit="samples")
    detect_delay: int = option(0, lo=0, hi=10, unit="samples")
    max_iter: int = option(100, lo=1)
    tol: float = option(1e-8, lo=0.0, lo_open=True)
    trust_radius: float = option(1.0, lo=0.0, lo_open=True)
    solver: str = option("gn", choices=SOLVERS)
    globalise: str = option("auto", choices=GLOBALISE)
    compile: bool | None = option(None, kind="flag", none=True)
    input_cutoff: Mapping[str, float] | None = option(None, lo=0.0, lo_open=True, unit="Hz", by_name=True, none=True)
    input_noise: Mapping[str, float] | str | None = option("auto", lo=0.0, lo_open=True, by_name=True, none=True,
                                                           words=("auto", "off"), what="standard deviations")
    corr_warn: float = option(0.95, lo=0.0, lo_open=True, hi=1.0)
    rse_warn: float = option(0.5, lo=0.0, lo_open=True)
    systematic: bool = option(False)
    systematic_iter: int = option(20, lo=1)
    progress: bool = option(False)

    def __post_init__(self):
        check_options(self, prefix("options"), cross=_noise_needs_gn)

    def replace(self, **changes) -> "IdentifyOptions":
        """A copy with some fields changed (validated again)."""
        import dataclasses

        for k in changes:
            if k not in self.__dataclass_fields__:
                raise ConfigError(f"options has no field {k!r}; fields: {', '.join(self.__dataclass_fields__)}")
        return dataclasses.replace(self, **changes)
