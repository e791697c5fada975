"""Options of the online estimators: frozen keyword-only dataclasses that check themselves.

A scenario's ``[estimator]`` table (``kind = "ekf" | "mhe" | "fd"`` and the fields below) is
turned into one of these by :func:`options_from_mapping`; every bad value is one
:class:`models.errors.ConfigError` line ``"<where>.<field> must be ..., got <value>"``.
Checks that need the rig (is ``omega4`` one of its channels? is ``pin3`` a contact?) are
made when the estimation model is built (:mod:`estimators.online.model`).

The defaults, and why, are in :mod:`estimators.online.model`'s docstring.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

from models.errors import ConfigError

__all__ = ["EKFOptions", "MHEOptions", "FDOptions", "options_from_mapping", "ANGLES", "QP_SOLVERS"]

ANGLES = ("zeroed", "absolute")
QP_SOLVERS = ("ldl", "osqp")
_W = "estimator"     # prefix of the messages; options_from_mapping swaps in the caller's ``where``


def _number(o, name: str, *, positive: bool = False) -> None:
    v = getattr(o, name)
    rel = "> 0" if positive else ">= 0"
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 \
            or (positive and v == 0):
        raise ConfigError(f"{_W}.{name} must be a finite number {rel}, got {v!r}")


def _names(o, name: str, what: str, *, allow_none: bool = True, allow_empty: bool = True) -> None:
    """A list of distinct strings (stored as a tuple), or None."""
    v = getattr(o, name)
    if v is None and allow_none:
        return
    if isinstance(v, list):
        v = tuple(v)
        object.__setattr__(o, name, v)
    if not isinstance(v, tuple) or not all(isinstance(s, str) and s for s in v):
        raise ConfigError(f"{_W}.{name} must be a list of {what}, got {v!r}")
    if not v and not allow_empty:
        raise ConfigError(f"{_W}.{name} must be a non-empty list of {what}, got []")
    dup = [s for i, s in enumerate(v) if s in v[:i]]
    if dup:
        raise ConfigError(f"{_W}.{name} lists {dup[0]!r} twice, got {list(v)!r}")


def _int(o, name: str, lo: int) -> None:
    v = getattr(o, name)
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise ConfigError(f"{_W}.{name} must be an integer >= {lo}, got {v!r}")


def _bool(o, name: str) -> None:
    v = getattr(o, name)
    if not isinstance(v, bool):
        raise ConfigError(f"{_W}.{name} must be true or false, got {v!r}")


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

    The defaults are rig3's measured choices (:mod:`estimators.online.model`, "Defaults, and
    why"); the noise levels ``q_torque``, ``p0_*`` are in SI units and sized for it.
    """


    channels: tuple | None = None
    angles: str = "zeroed"
    augment: tuple | None = None
    eps: float = 0.05
    nsub: int = 4
    q_torque: float = 0.02
    q_current: float = 0.05
    q_twist: float = 1e-4
    q_load: float = 0.02
    q_offset: float = 0.002
    q_gain: float = 0.002
    q_stick: float = 2.0
    p0_twist: float = 0.5
    p0_speed: float = 1.0
    p0_current: float = 2.0
    p0_pi: float = 1.0
    p0_load: float = 0.3
    p0_offset: float = 0.05
    p0_gain: float = 0.05
    compile: bool = True
    check_observability: bool = True
    observability_window: float = 4.0

    def __post_init__(self):
        _names(self, "channels", "log channels of the rig", allow_empty=False)
        if self.angles not in ANGLES:
            raise ConfigError(f"{_W}.angles must be 'zeroed' or 'absolute', got {self.angles!r}")
        _names(self, "augment", "'load:<contact>', 'offset:<channel>' or 'gain:<channel>'")
        for a in self.augment or ():
            kind, _, target = a.partition(":")
            if kind not in ("load", "offset", "gain") or not target:
                raise ConfigError(f"{_W}.augment entries must be 'load:<contact>', 'offset:<channel>' or "
                                  f"'gain:<channel>', got {a!r}")
        _number(self, "eps", positive=True)
        _int(self, "nsub", 1)
        for name in ("q_torque", "q_current", "q_twist", "q_load", "q_offset", "q_gain", "q_stick", "p0_twist", "p0_speed",
                     "p0_current", "p0_pi", "p0_load", "p0_offset", "p0_gain"):
            _number(self, name)
        _bool(self, "compile")
        _bool(self, "check_observability")
        _number(self, "observability_window", positive=True)


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


    window: int = 20
    max_iter: int = 1
    qpsol: str = "ldl"

    def __post_init__(self):
        super().__post_init__()
        _int(self, "window", 2)
        _int(self, "max_iter", 1)
        if self.qpsol not in QP_SOLVERS:
            raise ConfigError(f"{_W}.qpsol must be one of {', '.join(QP_SOLVERS)}, got {self.qpsol!r}")

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


    angles: str = "zeroed"

    def __post_init__(self):
        if self.angles not in ANGLES:
            raise ConfigError(f"{_W}.angles must be 'zeroed' or 'absolute', got {self.angles!r}")


def options_from_mapping(cls, table: Mapping[str, Any], where: str = "estimator", kind: str = "?"):
    """Options of class ``cls`` (of the estimator kind ``kind``) from a TOML table (without ``kind``).

    Raises
    ------
    ConfigError : ``"<where>: unknown key 'q_nosie' for kind 'ekf'; expected ..."`` or the
        options' own one-line message with ``estimator.`` replaced by ``<where>.``.
    """
    allowed = [f.name for f in fields(cls)]
    unknown = [k for k in table if k not in allowed]
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} for kind {kind!r}; "
                          f"expected some of {', '.join(sorted(allowed))}")
    try:
        return cls(**dict(table))
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(where + msg[len(_W):] if msg.startswith(_W) else f"{where}: {msg}") from None
    except Exception as exc:  # noqa: BLE001 - a plug-in's options class may check with anything: still bad input
        raise ConfigError(f"{where}: {type(exc).__name__}: {exc}") from None
