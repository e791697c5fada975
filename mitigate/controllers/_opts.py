"""Validation helpers shared by the controller option dataclasses."""

from __future__ import annotations


from models.checks import finite_number
from models.errors import ConfigError, quote

__all__ = ["check_number", "check_bool"]


def check_number(obj, name: str, *, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False, unit: str = "") -> None:
    """Raise ConfigError naming ``name`` unless ``getattr(obj, name)`` is a finite number in range."""
    v = finite_number(getattr(obj, name), name, unit=unit)
    u = f" {unit}" if unit else ""
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise ConfigError(f"{name} must be {'>' if lo_open else '>='} {lo}{u}, got {quote(v)}")
    if hi is not None and v > hi:
        raise ConfigError(f"{name} must be <= {hi}{u}, got {quote(v)}")
    object.__setattr__(obj, name, float(v))


def check_bool(obj, name: str) -> None:
    v = getattr(obj, name)
    if not isinstance(v, bool):
        raise ConfigError(f"{name} must be true or false, got {quote(v)}")
