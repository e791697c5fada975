"""Validation of user input (numbers, TOML files): one place for the one-line error messages.

One vocabulary for every option dataclass, scenario field and profile, so that a bad value
always reads ``"<where> must be ..., got <value>"``:

- :func:`number` (a finite real, optionally in a range, with a unit), :func:`integer`,
  :func:`flag` (true or false), :func:`choice` (one of a few words), :func:`names` (a list of
  names), each taking ``where`` -- the field's full name as the user wrote it
  (``"scenario.toml: sweep.duration"``);
- :func:`option` declares a field's check beside its default (``gain: float = option(0.0, lo=0.0,
  unit="N s/rad")``): a number, an integer, a flag, one of a few words, a name, a list of names,
  a fixed-length tuple of numbers (a band), a nested option table, a table of any of these by
  name, and a small per-field hook for what no keyword says; :func:`check_options` runs every
  declared check of an option dataclass in its ``__post_init__`` (plus, at most, one declared
  check across fields); :func:`where_field` declares a field that remembers the table's name;
- :func:`options_from_mapping` builds a frozen option dataclass from a TOML table: an unknown
  key is refused naming it, and the dataclass's own checks name their fields under the
  table's ``where`` (:func:`prefix` inside ``__post_init__``), so no caller re-prefixes
  messages afterwards.

:func:`finite_number` is :func:`number` with the sign constraints most fields need.
"""

from __future__ import annotations

import contextvars
import difflib
import math
import os
import tomllib
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from models.errors import ConfigError, quote
from models.plugins import describe

__all__ = ["number", "integer", "flag", "choice", "names", "option", "Check", "check_options", "where_field",
           "options_from_mapping", "prefix", "field_where", "finite_number", "read_toml"]

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
           hi_open: bool = False, unit: str = "", none: bool = False, why: str = "",
           finite: bool = True) -> float | None:
    """``float(v)`` if ``v`` is a finite real number (not a bool) in the range.

    Parameters
    ----------
    v : the value
    where : the field's full name in messages
    lo, hi : bounds (None: none); lo_open, hi_open : exclude the bound itself
    unit : the field's SI unit, for messages
    none : None is allowed (and returned)
    why : the reason for the range, said in brackets after it (``"it keeps the QP positive definite"``)
    finite : False: +-inf is allowed too (a bound); NaN never is

    Raises
    ------
    ConfigError : ``"<where> must be a finite number > 0 rad/s, got 'x'"`` (not a number), or
        ``"<where> must be > 0 rad/s, got -1"`` (out of range)
    """
    if v is None and none:
        return None
    rng, u = _range_text(lo, hi, lo_open, hi_open), f" {unit}" if unit else ""
    u += f" ({why})" if why else ""
    if not _is_real(v) or math.isnan(v) or (finite and not math.isfinite(v)):
        raise ConfigError(f"{where} must be a {'finite ' if finite else ''}number{rng}{u}, got {quote(v)}")
    if (lo is not None and (v <= lo if lo_open else v < lo)) or (hi is not None and (v >= hi if hi_open else v > hi)):
        raise ConfigError(f"{where} must be{rng}{u}, got {quote(v)}")
    return float(v)


def integer(v: Any, where: str, *, lo: int | None = None, hi: int | None = None, unit: str = "",
            none: bool = False, why: str = "") -> int | None:
    """``v`` if it is an integer (not a bool) in ``[lo, hi]`` (``why``: as :func:`number`).

    Raises
    ------
    ConfigError : ``"<where> must be an integer >= 1, got 0"``
    """
    if v is None and none:
        return None
    rng, u = _range_text(lo, hi, False, False), f" {unit}" if unit else ""
    u += f" ({why})" if why else ""
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


def _in_unit(v: str, unit: str, where: str) -> Any:
    """A quantity ``"<number> <unit>"`` (``"500 ms"``, ``"0.5 rpm"``) given for a number option whose
    SI unit is ``unit``, converted to it, as rig and scenario files take quantities; ``v`` unchanged
    when it is no quantity or ``unit`` is no unit (:func:`number` then refuses it)."""
    from models.units import convert, parse_quantity, parse_unit
    try:
        parse_unit(unit)
    except ConfigError:
        return v
    q = parse_quantity(v)
    if q is None:
        return v
    value, given = q
    if not given:
        return value
    try:
        return convert(value, given, unit, where)
    except ConfigError:
        raise ConfigError(f"{where} must be a number in {unit} or a quantity that converts to {unit}, "
                          f"got {quote(v)}") from None


#: what :func:`option` can check; inferred from the keywords and the default when ``kind`` is not given
KINDS = ("number", "integer", "flag", "choice", "text", "names", "numbers", "table", "any")


@dataclass(frozen=True, kw_only=True)
class Check:
    """How :func:`check_options` checks one option field; built by :func:`option` (see there).

    Calling it, ``check(value, where)``, returns the value to store (numbers as floats, lists as
    tuples, a nested table as its option dataclass) or raises the field's one-line ConfigError.
    """

    kind: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    unit: str = ""
    why: str = ""
    none: bool = False
    choices: tuple = ()
    words: tuple = ()
    what: str = ""
    nonempty: bool = False
    unique: bool = False
    split: bool = False
    items: int | None = None
    increasing: bool = False
    finite: bool = True
    table: type | None = None
    by_name: bool = False
    check: Callable[[Any, str], Any] | None = None

    def __call__(self, v: Any, where: str) -> Any:
        if v is None and self.none:
            return None
        if self.words and isinstance(v, str) and v in self.words:
            return v
        if self.by_name:
            if not isinstance(v, Mapping):
                raise ConfigError(f"{where} must be {self._words()}a table of {self.what or 'numbers'}, got {quote(v)}")
            v = {k: self._one(x, f"{where}.{k}") for k, x in v.items()}
        else:
            v = self._one(v, where)
        if self.check is not None:
            out = self.check(v, where)
            v = v if out is None else out
        return v

    def _words(self) -> str:
        return f"one of {', '.join(self.words)} or " if self.words else ""

    def _one(self, v: Any, where: str) -> Any:
        k = self.kind
        rng = dict(lo=self.lo, hi=self.hi, unit=self.unit, why=self.why)
        if k == "number":
            if isinstance(v, str) and self.unit:
                v = _in_unit(v, self.unit, where)
            return number(v, where, lo_open=self.lo_open, hi_open=self.hi_open, finite=self.finite, **rng)
        if k == "integer":
            return integer(v, where, **rng)
        if k == "flag":
            return flag(v, where, none=self.none)
        if k == "choice":
            return choice(v, where, self.choices)
        if k == "text":
            if not isinstance(v, str) or (self.nonempty and not v):
                raise ConfigError(f"{where} must be {self.what or 'text'}, got {quote(v)}")
            return v
        if k == "names":
            if self.words and not isinstance(v, (list, tuple)):
                raise ConfigError(f"{where} must be {self._words()}a list of {self.what or 'names'}, got {quote(v)}")
            return names(v, where, what=self.what or "names", nonempty=self.nonempty, unique=self.unique,
                         split=self.split)
        if k == "numbers":
            what = self.what or f"{self.items} numbers"
            if not isinstance(v, (list, tuple)) or len(v) != self.items:
                raise ConfigError(f"{where} must be {what}, got {quote(v)}")
            try:
                out = tuple(number(x, where, lo_open=self.lo_open, hi_open=self.hi_open, finite=self.finite, **rng)
                            for x in v)
            except ConfigError:
                raise ConfigError(f"{where} must be {what}, got {quote(v)}") from None
            if self.increasing and not all(a < b for a, b in zip(out, out[1:])):
                raise ConfigError(f"{where} must be {what}, got {quote(v)}")
            return out
        if k == "table":
            if isinstance(v, self.table):
                return v
            if isinstance(v, Mapping):
                return options_from_mapping(self.table, v, where)
            raise ConfigError(f"{where} must be {self.what or 'a table'}, got {type(v).__name__}")
        return v                                              # "any": the hook alone checks it


def option(default: Any = MISSING, *, kind: str | None = None, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False, hi_open: bool = False, unit: str = "", why: str = "", none: bool = False,
           choices=None, words=(), what: str = "", nonempty: bool = False, unique: bool = False, split: bool = False,
           items: int | None = None, increasing: bool = False, finite: bool = True, table: type | None = None,
           by_name: bool = False, check: Callable[[Any, str], Any] | None = None):
    """A keyword-only dataclass field with its default and the check :func:`check_options` runs on it.

    What is checked (``kind``; inferred when not given):

    - ``"number"`` (a float default, or None): :func:`number` in ``lo``/``hi`` (``lo_open``,
      ``hi_open``), ``unit`` and ``why`` for messages, ``finite=False`` to allow +-inf;
    - ``"integer"`` (an int default): :func:`integer`; ``"flag"`` (a bool default): :func:`flag`;
    - ``"choice"`` (``choices`` given): :func:`choice`;
    - ``"text"`` (a str default): a string (``nonempty``), ``what`` it is for messages ("a body name");
    - ``"names"``: a list of names, :func:`names` (``what``, ``nonempty``, ``unique``, ``split``);
    - ``"numbers"`` (``items`` given): a tuple of ``items`` numbers each in the range, strictly
      ``increasing`` if asked (a band); any fault reads ``"<where> must be <what>, got ..."``;
    - ``"table"`` (``table`` given: an option dataclass): an instance of it, or a table read with
      :func:`options_from_mapping` under ``<where>.<field>`` (NMPC's ``weights``);
    - ``"any"``: only ``check`` checks it.

    ``by_name``: a table ``{name: value}`` whose every value is checked as above (named
    ``<where>.<field>.<name>``).  ``words``: a word from these is accepted instead of the list or
    table (``inputs = "both"``, ``input_noise = "auto"``).  ``none``: None is allowed (unset).
    ``check(value, where)``: a per-field hook run after the declared check, for a rule no keyword
    says (``horizon <= MAX_HORIZON`` with its reason); it raises a one-line ConfigError naming
    ``where``, or returns the value to store (None: keep it).  No ``default``: a required field.
    """
    if kind is None:
        kind = ("table" if table is not None else "numbers" if items is not None else "choice" if choices is not None
                else "number" if by_name else "flag" if isinstance(default, bool)
                else "integer" if isinstance(default, int) else "text" if isinstance(default, str) else "number")
    if kind not in KINDS:
        raise TypeError(f"option kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if (kind == "table") != (table is not None) or (kind == "numbers") != (items is not None):
        raise TypeError("option: a 'table' needs table=<option dataclass>, 'numbers' needs items=<count>")
    spec = Check(kind=kind, lo=lo, hi=hi, lo_open=lo_open, hi_open=hi_open, unit=unit, why=why, none=none,
                 choices=tuple(choices or ()), words=tuple(words), what=what, nonempty=nonempty, unique=unique,
                 split=split, items=items, increasing=increasing, finite=finite, table=table, by_name=by_name,
                 check=check)
    return field(default=default, kw_only=True, metadata={"check": spec})


def where_field(default: str):
    """A field that remembers the name of the table the options were read from (None: the table
    :func:`options_from_mapping` is reading, else ``default``): what :func:`check_options` names
    the other fields under, and what a consumer that checks them against the rig later names its
    messages with (``options.where``).  It is not a key of the table."""
    return field(default=None, kw_only=True, metadata={"where": default})


def _where_of(obj, where: str | None) -> str:
    for f in fields(obj):
        if "where" in f.metadata:
            w = getattr(obj, f.name)
            if w is None:
                w = prefix(f.metadata["where"])
                object.__setattr__(obj, f.name, w)
            elif not isinstance(w, str):
                raise ConfigError(f"{f.metadata['where']}.{f.name} must be the table's name, got {quote(w)}")
            return w if where is None else where
    return prefix("") if where is None else where


def check_options(obj, where: str | None = None, *, cross: Callable[[Any, Callable[[str], str]], None] | None = None
                  ) -> None:
    """Run the check of every field of the option dataclass ``obj`` declared with :func:`option`,
    in field order, naming ``<where>.<field>``, and store what each returns (floats, tuples, a
    nested option table); then ``cross(obj, name)``, the class's declared check across fields
    (``off < on``), where ``name(field)`` is how a message names a field.

    ``where`` defaults to the class's :func:`where_field`, else the table being read
    (:func:`prefix`), else the bare field name; a class names its own default with
    ``check_options(self, prefix("sim"))``.

    Raises
    ------
    ConfigError : the first failing field's message, e.g. ``"sc.toml: controller 1 'B'.n_max must be
        >= 0 N, got -1"``
    """
    where = _where_of(obj, where)
    for f in fields(obj):
        spec = f.metadata.get("check")
        if spec is not None:
            object.__setattr__(obj, f.name, spec(getattr(obj, f.name), field_where(f.name, where)))
    if cross is not None:
        cross(obj, lambda name: field_where(name, where))


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
    allowed = [f.name for f in fields(cls) if f.init and "where" not in f.metadata]
    for k in table:
        if k not in allowed:
            what = f" for kind {kind!r}" if kind else ""
            near = difflib.get_close_matches(str(k), allowed, n=1)
            what += f" (did you mean {near[0]!r}?)" if near else ""
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
