"""The controllers' option checks, in the one vocabulary of :mod:`models.checks`.

Kept as a thin adapter while the controllers' option classes move to calling
:func:`models.checks.number` / :func:`models.checks.flag` with ``where`` directly (their
modules are being edited elsewhere); the messages are the vocabulary's, naming the field under
the table being read (:func:`models.checks.prefix`).
"""

from __future__ import annotations

from models.checks import flag, number, prefix

__all__ = ["check_number", "check_bool"]


def _where(name: str) -> str:
    p = prefix("")
    return f"{p}.{name}" if p else name


def check_number(obj, name: str, *, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False, unit: str = "") -> None:
    """:func:`models.checks.number` on ``getattr(obj, name)``, stored back as a float."""
    v = getattr(obj, name)
    # a whole number from TOML is quoted as the float it becomes (``got -1.0``)
    v = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v
    object.__setattr__(obj, name, number(v, _where(name), lo=lo, hi=hi, lo_open=lo_open, unit=unit))


def check_bool(obj, name: str) -> None:
    """:func:`models.checks.flag` on ``getattr(obj, name)``."""
    flag(getattr(obj, name), _where(name))
