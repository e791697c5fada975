"""Validation of user input (numbers, TOML files): one place for the one-line error messages.

Every option dataclass, scenario field and profile uses :func:`finite_number`, so that a
bad value always reads ``"<where> must be ..., got <value>"``.
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import Any

from models.errors import ConfigError, quote

__all__ = ["finite_number", "read_toml"]


def finite_number(v: Any, where: str, *, positive: bool = False, nonneg: bool = False, unit: str = "") -> float:
    """``float(v)`` if ``v`` is a finite real number (not a bool) within the sign constraint.

    Raises
    ------
    ConfigError : ``"<where> must be a finite number [unit], got <v>"`` (or ``> 0`` / ``>= 0``).
    """
    u = f" {unit}" if unit else ""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(f"{where} must be a finite number{u}, got {quote(v)}")
    if positive and not v > 0:
        raise ConfigError(f"{where} must be > 0{u}, got {quote(v)}")
    if nonneg and v < 0:
        raise ConfigError(f"{where} must be >= 0{u}, got {quote(v)}")
    return float(v)


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
