"""Validation of user input (numbers, TOML files): one place for the one-line error messages.

One vocabulary for every option dataclass, scenario field and profile, so that a bad value
always reads ``"<where> must be ..., got <value>"``:

- :func:`number` (a finite real, optionally in a range, with a unit), :func:`integer`,
  :func:`flag` (true or false), :func:`choice` (one of a few words), :func:`names` (a list of
  names), each taking ``where`` -- the field's full name as the user wrote it
  (``"scenario.toml: sweep.duration"``);
- :func:`option` declares a field's check beside its default (``gain: float = option(0.0, lo=0.0,
  unit="N s/rad")``) and :func:`check_options` runs every declared check of an option dataclass
  in its ``__post_init__``;
- :func:`options_from_mapping` builds a frozen option dataclass from a TOML table: an unknown
  key is refused naming it, and the dataclass's own checks name their fields under the
  table's ``where`` (:func:`prefix` inside ``__post_init__``), so no caller re-prefixes
  messages afterwards.

:func:`finite_number` is :func:`number` with the sign constraints most fields need.
"""

from __future__ import annotations

import contextvars
import math
import os
import tomllib
from dataclasses import field, fields, is_dataclass
from pathlib import Path
from typing import Any, Mapping

from models.errors import ConfigError, quote
from models.plugins import describe

__all__ = ["number", "integer", "flag", "choice", "names", "option", "check_options", "options_from_mapping",
           "prefix", "field_where", "finite_number", "read_toml"]

#: the ``where`` of the table :func:`options_from_mapping` is reading (None: not reading one)
_READING: contextvars.ContextVar[str | None] = contextvars.ContextVar("stickslip_options_where", default=None)


def _is_real(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float))


def _range_text(lo, hi, lo_open: bool, hi_open: bool) -> str:
    if lo is not None and hi is not None:
        return f" in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if lo is not None:
        return f" {'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f" {'<' if hi_open else '<='} {hi:g}"
    return ""


def number(v: Any, where: str, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           hi_open: bool = False, unit: str = "", none: bool = False) -> float | None:
    """``float(v)`` if ``v`` is a finite real number (not a bool) in the range.

    Parameters
    ----------
    v : the value
    where : the field's full name in messages
    lo, hi : bounds (None: none); lo_open, hi_open : exclude the bound itself
    unit : the field's SI unit, for messages
    none : None is allowed (and returned)

    Raises
    ------
    ConfigError : ``"<where> must be a finite number > 0 rad/s, got 'x'"`` (not a number), or
        ``"<where> must be > 0 rad/s, got -1"`` (out of range)
    """
    if v is None and none:
        return None
    rng, u = _range_text(lo, hi, lo_open, hi_open), f" {unit}" if unit else ""
    if not _is_real(v) or not math.isfinite(v):
        raise ConfigError(f"{where} must be a finite number{rng}{u}, got {quote(v)}")
    if (lo is not None and (v <= lo if lo_open else v < lo)) or (hi is not None and (v >= hi if hi_open else v > hi)):
        raise ConfigError(f"{where} must be{rng}{u}, got {quote(v)}")
    return float(v)


def integer(v: Any, where: str, *, lo: int | None = None, hi: int | None = None, unit: str = "",
            none: bool = False) -> int | None:
    """``v`` if it is an integer (not a bool) in ``[lo, hi]``.

    Raises
    ------
    ConfigError : ``"<where> must be an integer >= 1, got 0"``
    """
    if v is None and none:
        return None
    rng, u = _range_text(lo, hi, False, False), f" {unit}" if unit else ""
    if isinstance(v, bool) or not isinstance(v, int) or (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ConfigError(f"{where} must be an integer{rng}{u}, got {quote(v)}")
    return int(v)


def flag(v: Any, where: str, *, none: bool = False) -> bool | None:
    """``v`` if it is True or False.

    Raises
    ------
    ConfigError : ``"<where> must be true or false, got 'yes'"`` (``"..., or unset"`` with ``none``)
    """
    if v is None and none:
        return None
    if not isinstance(v, bool):
        raise ConfigError(f"{where} must be true or false{', or unset' if none else ''}, got {quote(v)}")
    return v


def choice(v: Any, where: str, options, *, none: bool = False):
    """``v`` if it is one of ``options``.

    Raises
    ------
    ConfigError : ``"<where> must be one of gn, ipopt, got 'lm'"``
    """
    if v is None and none:
        return None
    if not isinstance(v, (str, int, float)) or isinstance(v, bool) or v not in options:
        raise ConfigError(f"{where} must be one of {', '.join(map(str, options))}, got {quote(v)}")
    return v


def names(v: Any, where: str, *, what: str = "names", nonempty: bool = False, unique: bool = False,
          split: bool = False) -> tuple[str, ...]:
    """A tuple of non-empty strings from a list (or, with ``split``, a comma-separated string).

    Raises
    ------
    ConfigError : ``"<where> must be a list of names, got 3"``, ``"... must be a non-empty list of
        names, got []"``, ``"<where> lists 'k1' twice, got [...]"``
    """
    if isinstance(v, str):
        if not split:
            raise ConfigError(f"{where} must be a list of {what}, got {quote(v)}")
        v = [s.strip() for s in v.split(",") if s.strip()]
    try:
        out = tuple(v)
    except TypeError:
        raise ConfigError(f"{where} must be a list of {what}, got {quote(v)}") from None
    for n in out:
        if not isinstance(n, str) or not n:
            raise ConfigError(f"{where} must be a list of {what}, got {list(out)!r}")
    if nonempty and not out:
        raise ConfigError(f"{where} must be a non-empty list of {what}, got []")
    if unique:
        dup = [n for i, n in enumerate(out) if n in out[:i]]
        if dup:
            raise ConfigError(f"{where} lists {dup[0]!r} twice, got {list(out)!r}")
    return out


def option(default: Any, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           hi_open: bool = False, unit: str = "", choices=None, none: bool = False):
    """A dataclass field with its default and the check :func:`check_options` runs on it.

    A bool default is checked with :func:`flag`, an int default with :func:`integer`, ``choices``
    with :func:`choice`, anything else with :func:`number` (range ``lo``/``hi``, ``unit`` for
    messages; a number is stored back as a float); ``none``: None is allowed (unset).
    """
    if choices is not None:
        check = ("choice", {"options": tuple(choices), "none": none})
    elif isinstance(default, bool):
        check = ("flag", {"none": none})
    elif isinstance(default, int):
        check = ("integer", {"lo": lo, "hi": hi, "unit": unit, "none": none})
    else:
        check = ("number", {"lo": lo, "hi": hi, "lo_open": lo_open, "hi_open": hi_open, "unit": unit, "none": none})
    return field(default=default, metadata={"check": check})


def check_options(obj, where: str | None = None) -> None:
    """Run the check of every field of the option dataclass ``obj`` declared with :func:`option`,
    in field order, naming ``<where>.<field>`` (``where`` default: the table being read,
    :func:`prefix`; outside one, the bare field name); numbers are stored back as floats.

    Raises
    ------
    ConfigError : the first failing field's message, e.g. ``"sc.toml: controller 1 'B'.n_max must be
        >= 0 N, got -1.0"``
    """
    for f in fields(obj):
        kind, kw = f.metadata.get("check", (None, None))
        if kind is None:
            continue
        v, name = getattr(obj, f.name), field_where(f.name, where)
        if kind == "number":
            # a whole number from TOML is quoted as the float it becomes (``got -1.0``)
            v = number(float(v) if _is_real(v) else v, name, **kw)
        elif kind == "integer":
            v = integer(v, name, **kw)
        elif kind == "flag":
            v = flag(v, name, **kw)
        else:
            v = choice(v, name, **kw)
        object.__setattr__(obj, f.name, v)


def prefix(default: str) -> str:
    """The ``where`` of the table being read by :func:`options_from_mapping`, else ``default``:
    what an option dataclass's ``__post_init__`` names its fields under."""
    return _READING.get() or default


def field_where(name: str, where: str | None = None) -> str:
    """How a message names the option field ``name``: ``<where>.<name>``, ``where`` by default the
    table being read (:func:`prefix`); the bare name outside one."""
    where = prefix("") if where is None else where
    return f"{where}.{name}" if where else name


def options_from_mapping(cls, table: Mapping[str, Any], where: str, *, kind: str | None = None):
    """``cls(**table)`` for a (frozen, keyword-only) option dataclass, its errors naming ``where``.

    Parameters
    ----------
    cls : the option dataclass; its checks use :func:`prefix` for their field names
    table : the TOML table (keys: the dataclass's fields)
    where : the table's full name in messages (``"scenario.toml: sweep"``)
    kind : the plug-in kind the options belong to, for the unknown-key message

    Raises
    ------
    ConfigError : ``"<where>.<key>: unknown key; expected one of ..."``, or the dataclass's own
        message naming ``<where>.<field>`` (a class that does not use :func:`prefix`: its message
        under ``"<where>."`` when it opens with one of its fields, else ``"<where>: <its message>"``); anything else a (plug-in's) class raises, as
        ``"<where>: <type>: <first line of its message>"``
    """
    if not is_dataclass(cls):
        raise ConfigError(f"{where}: options class {getattr(cls, '__name__', cls)!r} is not a dataclass")
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where} must be a table, got {table!r}")
    allowed = [f.name for f in fields(cls) if f.init]
    for k in table:
        if k not in allowed:
            what = f" for kind {kind!r}" if kind else ""
            raise ConfigError(f"{where}.{k}: unknown key{what}; expected one of {', '.join(sorted(allowed))}")
    token = _READING.set(where)
    try:
        return cls(**dict(table))
    except ConfigError as exc:
        msg = str(exc)
        if msg.startswith((f"{where}.", f"{where}:", f"{where} ")):    # named under the table already
            raise
        # a class that does not name its fields under prefix() (a plug-in's): a message opening
        # with one of its fields names it under the table, any other says at least which table
        head = msg.split(" ", 1)[0].split(":", 1)[0]
        raise ConfigError(f"{where}.{msg}" if head in allowed else f"{where}: {msg}") from None
    except Exception as exc:  # noqa: BLE001 - a plug-in's options class may check with anything: still bad input
        raise ConfigError(f"{where}: {describe(exc)}") from None
    finally:
        _READING.reset(token)


def finite_number(v: Any, where: str, *, positive: bool = False, nonneg: bool = False, unit: str = "") -> float:
    """:func:`number` ``> 0`` (``positive``) or ``>= 0`` (``nonneg``) or any finite real.

    Raises
    ------
    ConfigError : ``"<where> must be a finite number [> 0] [unit], got <v>"`` or ``"<where> must be > 0 ..."``.
    """
    return number(v, where, lo=0.0 if positive or nonneg else None, lo_open=positive, unit=unit)


def read_toml(path: str | os.PathLike, what: str) -> dict:
    """Parse a TOML file; a missing, unreadable or malformed file is one ConfigError naming it.

    ``what`` names the kind of file in the message ("parameter file", "scenario", ...).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read {what} ({exc})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
