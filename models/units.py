"""Units: parse a unit string, check its dimension, convert to SI.

One small parser serves the rig files, the parameter files and the logs.  A unit is a
product of factors separated by spaces, ``*`` or ``·``, with ``^`` or ``**`` exponents, one
``/`` (everything after it is in the denominator; parentheses group a denominator such as
``V/(rad/s)``).  The radian is kept as a dimension of its own, so that a stiffness
[N m/rad] is not mistaken for a torque [N m] and a speed [rad/s] not for a rate [1/s].
Dimensionless quantities are written ``-``, ``1`` or left empty.

Examples
--------
>>> to_si(1.0, "g cm^2", "inertia")
1e-07
>>> factor("rpm", "speed")   # 2 pi / 60
0.10471975511965977
"""

from __future__ import annotations

import math
import re

from models.errors import ConfigError

__all__ = ["Unit", "parse_unit", "parse_quantity", "factor", "to_si", "convert", "DIMENSIONS", "dimension_of"]

_QTY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*)$")

# base dimensions: kg, m, s, A, rad, K (exponent vector)
_BASE = ("kg", "m", "s", "A", "rad")


def _dim(kg=0, m=0, s=0, A=0, rad=0):
    return (kg, m, s, A, rad)


# symbol -> (SI factor, dimension); case-sensitive (mN is milli-newton, MN mega-newton)
_SYMBOLS: dict[str, tuple[float, tuple]] = {
    "kg": (1.0, _dim(kg=1)), "g": (1e-3, _dim(kg=1)), "t": (1e3, _dim(kg=1)),
    "m": (1.0, _dim(m=1)), "mm": (1e-3, _dim(m=1)), "cm": (1e-2, _dim(m=1)), "um": (1e-6, _dim(m=1)),
    "km": (1e3, _dim(m=1)), "in": (0.0254, _dim(m=1)), "ft": (0.3048, _dim(m=1)),
    "s": (1.0, _dim(s=1)), "ms": (1e-3, _dim(s=1)), "us": (1e-6, _dim(s=1)), "min": (60.0, _dim(s=1)),
    "h": (3600.0, _dim(s=1)),
    "A": (1.0, _dim(A=1)), "mA": (1e-3, _dim(A=1)),
    "rad": (1.0, _dim(rad=1)), "mrad": (1e-3, _dim(rad=1)), "deg": (math.pi / 180, _dim(rad=1)),
    "rev": (2 * math.pi, _dim(rad=1)), "turn": (2 * math.pi, _dim(rad=1)),
    "N": (1.0, _dim(kg=1, m=1, s=-2)), "kN": (1e3, _dim(kg=1, m=1, s=-2)), "mN": (1e-3, _dim(kg=1, m=1, s=-2)),
    "MN": (1e6, _dim(kg=1, m=1, s=-2)), "kgf": (9.80665, _dim(kg=1, m=1, s=-2)),
    "lbf": (4.4482216152605, _dim(kg=1, m=1, s=-2)),
    "V": (1.0, _dim(kg=1, m=2, s=-3, A=-1)), "mV": (1e-3, _dim(kg=1, m=2, s=-3, A=-1)),
    "ohm": (1.0, _dim(kg=1, m=2, s=-3, A=-2)), "Ohm": (1.0, _dim(kg=1, m=2, s=-3, A=-2)),
    "Ω": (1.0, _dim(kg=1, m=2, s=-3, A=-2)), "mohm": (1e-3, _dim(kg=1, m=2, s=-3, A=-2)),
    "H": (1.0, _dim(kg=1, m=2, s=-2, A=-2)), "mH": (1e-3, _dim(kg=1, m=2, s=-2, A=-2)),
    "uH": (1e-6, _dim(kg=1, m=2, s=-2, A=-2)),
    "W": (1.0, _dim(kg=1, m=2, s=-3)), "J": (1.0, _dim(kg=1, m=2, s=-2)),
    # speeds written as one symbol
    "rpm": (2 * math.pi / 60, _dim(rad=1, s=-1)), "krpm": (2 * math.pi * 1000 / 60, _dim(rad=1, s=-1)),
    "Hz": (1.0, _dim(s=-1)), "hz": (1.0, _dim(s=-1)),
    "Nm": (1.0, _dim(kg=1, m=2, s=-2)), "Nmm": (1e-3, _dim(kg=1, m=2, s=-2)),
}

#: the dimension every quantity kind of the workbench must have
DIMENSIONS: dict[str, tuple] = {
    "inertia": _dim(kg=1, m=2, rad=0),
    "stiffness": _dim(kg=1, m=2, s=-2, rad=-1),
    "damping": _dim(kg=1, m=2, s=-1, rad=-1),
    "torque": _dim(kg=1, m=2, s=-2),
    "force": _dim(kg=1, m=1, s=-2),
    "length": _dim(m=1),
    "mass": _dim(kg=1),
    "angle": _dim(rad=1),
    "speed": _dim(rad=1, s=-1),
    "acceleration": _dim(rad=1, s=-2),
    "time": _dim(s=1),
    "rate": _dim(s=-1),
    "slowness": _dim(s=1, rad=-1),          # s/rad (Stribeck decay rates, viscous friction coefficients)
    "current": _dim(A=1),
    "voltage": _dim(kg=1, m=2, s=-3, A=-1),
    "resistance": _dim(kg=1, m=2, s=-3, A=-2),
    "inductance": _dim(kg=1, m=2, s=-2, A=-2),
    "torque_constant": _dim(kg=1, m=2, s=-2, A=-1),
    "voltage_constant": _dim(kg=1, m=2, s=-2, A=-1, rad=-1),   # V s/rad
    "pi_kp": _dim(kg=1, m=2, s=-2, A=-1, rad=-1),              # V per rad/s
    "pi_ki": _dim(kg=1, m=2, s=-3, A=-1, rad=-1),              # V per rad
    "force_rate": _dim(kg=1, m=1, s=-3),
    "torque_rate": _dim(kg=1, m=2, s=-3),
    "viscous_torque": _dim(kg=1, m=2, s=-1, rad=-1),           # = damping
    "dimensionless": _dim(),
    "per_angle": _dim(rad=-1),                                 # 1/rad (a friction level per bristle deflection)
}


class Unit:
    """A parsed unit: SI ``factor`` and dimension exponents over (kg, m, s, A, rad)."""

    __slots__ = ("text", "factor", "dim")

    def __init__(self, text: str, factor: float, dim: tuple):
        self.text, self.factor, self.dim = text, factor, dim

    def __repr__(self) -> str:
        return f"Unit({self.text!r}, factor={self.factor:g}, dim={self.dim})"


_TOKEN = re.compile(r"^([A-Za-zΩ]+)(?:(?:\^|\*\*)?(-?\d+))?$")
_CACHE: dict[str, Unit] = {}


def _suggest(tok: str) -> str:
    """`` (did you mean 'rpm'?)`` for a symbol that differs from a known one only in case (symbols
    are case-sensitive: mN is milli-, MN mega-newton), else ""."""
    m = _TOKEN.match(tok)
    sym = m.group(1) if m else tok
    near = sorted(s for s in _SYMBOLS if s.lower() == sym.lower() and s != sym)
    if not near:
        return ""
    rest = tok[len(sym):]
    return f" (did you mean {' or '.join(repr(s + rest) for s in near)}?)"


def _parse_product(text: str, where: str, full: str) -> tuple[float, list[int]]:
    f, d = 1.0, [0] * len(_BASE)
    for tok in re.split(r"[\s*·.]+", text.strip()):
        if not tok or tok == "1":
            continue
        m = _TOKEN.match(tok)
        if not m or m.group(1) not in _SYMBOLS:
            raise ConfigError(f"{where}: unit [{full}] does not convert: unknown symbol {tok!r}{_suggest(tok)}")
        sf, sd = _SYMBOLS[m.group(1)]
        e = int(m.group(2)) if m.group(2) else 1
        f *= sf ** e
        for i in range(len(d)):
            d[i] += e * sd[i]
    return f, d


def parse_unit(text: str, where: str = "unit") -> Unit:
    """Parse ``text`` (see module docstring).

    Raises
    ------
    ConfigError : ``"<where>: unit [text] does not convert: ..."``.
    """
    if not isinstance(text, str):
        raise ConfigError(f"{where}: unit must be a string, got {text!r}")
    key = text.strip()
    if key in _CACHE:
        return _CACHE[key]
    if key in ("", "-", "1"):
        u = Unit(key, 1.0, _dim())
    else:
        s = key.replace("(", " ( ").replace(")", " ) ")
        if s.count("/") > 1 and "(" not in s:
            raise ConfigError(f"{where}: unit [{text}] does not convert: use one '/' (group a denominator in "
                              f"parentheses, e.g. V/(rad/s))")
        num, _, den = s.partition("/")
        den = den.strip()
        inner_div = False
        if den.startswith("(") and den.endswith(")"):
            den = den[1:-1]
            inner_div = "/" in den
        if "(" in num or "(" in den or ")" in num or ")" in den:
            raise ConfigError(f"{where}: unit [{text}] does not convert: unbalanced parentheses")
        fn, dn = _parse_product(num, where, text)
        if inner_div:   # a/(b/c) = a c / b
            b, _, c = den.partition("/")
            fb, db = _parse_product(b, where, text)
            fc, dc = _parse_product(c, where, text)
            fd, dd = fb / fc, [x - y for x, y in zip(db, dc)]
        else:
            fd, dd = _parse_product(den, where, text) if den else (1.0, [0] * len(_BASE))
        u = Unit(key, fn / fd, tuple(a - b for a, b in zip(dn, dd)))
    _CACHE[key] = u
    return u


def dimension_of(kind: str) -> tuple:
    try:
        return DIMENSIONS[kind]
    except KeyError:
        raise ConfigError(f"unknown quantity kind {kind!r}; expected one of {', '.join(DIMENSIONS)}") from None


def _dim_text(d: tuple) -> str:
    parts = [f"{b}^{e}" if e != 1 else b for b, e in zip(_BASE, d) if e]
    return " ".join(parts) or "dimensionless"


def factor(unit: str, kind: str, where: str = "unit") -> float:
    """SI factor of ``unit`` for a quantity of ``kind`` (a key of :data:`DIMENSIONS`).

    Raises
    ------
    ConfigError : the unit does not parse, or is not of that kind
        (``"<where>: unit [N m] does not convert to a stiffness (kg m^2 s^-2 rad^-1)"``).
    """
    u = parse_unit(unit, where)
    want = dimension_of(kind)
    if u.dim != want:
        # "Hz" on a speed is the one common unit whose dimension lacks the radian: rev/s
        if kind == "speed" and u.dim == _dim(s=-1) and unit.strip().lower() == "hz":
            return 2 * math.pi
        raise ConfigError(f"{where}: unit [{unit}] does not convert to a {kind.replace('_', ' ')} "
                          f"(expected {_dim_text(want)}, got {_dim_text(u.dim)})")
    return u.factor


def to_si(value: float, unit: str, kind: str, where: str = "unit") -> float:
    """``value`` in ``unit`` converted to SI for a quantity of ``kind``."""
    return float(value) * factor(unit, kind, where)


def convert(value: float, unit: str, to: str, where: str = "unit") -> float:
    """``value`` in ``unit`` expressed in the unit ``to`` (e.g. a value given in rpm, for an axis whose
    SI unit is rad/s): ``convert(30, "rpm", "rad/s") == pi``.

    Raises
    ------
    ConfigError : a unit that does not parse, or of another dimension than ``to``
        (``"<where>: unit [kN] does not convert to [rad/s] (expected rad s^-1, got kg m s^-2)"``).
    """
    u, t = parse_unit(unit, where), parse_unit(to, where)
    if u.dim != t.dim:
        if t.dim == DIMENSIONS["speed"] and u.dim == _dim(s=-1) and unit.strip().lower() == "hz":
            return float(value) * 2 * math.pi / t.factor
        raise ConfigError(f"{where}: unit [{unit}] does not convert to [{to}] (expected {_dim_text(t.dim)}, got "
                          f"{_dim_text(u.dim)})")
    return float(value) * u.factor / t.factor


def parse_quantity(text: str) -> tuple[float, str] | None:
    """``"<number> <unit>"`` -> ``(number, unit text)`` (unit ``""`` when absent), or None if
    ``text`` does not start with a number.  The unit is not checked here (:func:`factor`).

    >>> parse_quantity("30 rpm")
    (30.0, 'rpm')
    """
    m = _QTY.match(text)
    if not m:
        return None
    return float(m.group(1)), m.group(2).strip()
