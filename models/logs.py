"""The one log format: CSV with ``name [unit]`` headers.

Everything a rig records, the simulator writes and the estimators read uses this format.
The header row holds ``name [unit]`` columns from the vocabulary below (disc side of the
gearbox); any subset a model needs may be present::

    t [s], theta1 [rad], theta2 [rad], theta3 [rad], omega1 [rad/s], omega2 [rad/s],
    omega3 [rad/s], motor_torque [N m], n1 [N], n2 [N], omega_ref [rad/s],
    theta_drive [rad], omega_drive [rad/s], axial_force [N]         (lead screw)
    twist12 [rad], twist23 [rad], twist [rad]                       (truth / estimates)

Units other than the canonical ones are converted where the conversion is unambiguous
(``deg``, ``rev``, ``rpm``, ``deg/s``, ``ms``, ``kN``, ``N mm`` ...) and rejected
otherwise.  Validation: time strictly increasing, no NaN or inf, no gap (a step longer
than 1.5 times the median step), known names and units; each error is one line naming
the column and the row (data rows count from 1; the header is line 1 of the file).
Nothing is silently dropped.  Where only angles are given, speeds are derived by
central differences.
"""

from __future__ import annotations

import csv
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from models.errors import ConfigError, DataError

__all__ = ["CANONICAL_UNITS", "UNIT_FACTORS", "Log", "read_csv", "parse_header", "convert_unit", "atomic_write_text"]

CANONICAL_UNITS: dict[str, str] = {
    "t": "s",
    "theta1": "rad", "theta2": "rad", "theta3": "rad",
    "omega1": "rad/s", "omega2": "rad/s", "omega3": "rad/s",
    "motor_torque": "N m",
    "n1": "N", "n2": "N",
    "omega_ref": "rad/s",
    "theta_drive": "rad", "omega_drive": "rad/s", "axial_force": "N",
    "twist12": "rad", "twist23": "rad", "twist": "rad",
}

#: unit -> (canonical unit, factor to SI)
UNIT_FACTORS: dict[str, tuple[str, float]] = {
    "s": ("s", 1.0), "ms": ("s", 1e-3), "min": ("s", 60.0),
    "rad": ("rad", 1.0), "deg": ("rad", math.pi / 180), "rev": ("rad", 2 * math.pi), "mrad": ("rad", 1e-3),
    "rad/s": ("rad/s", 1.0), "rpm": ("rad/s", 2 * math.pi / 60), "deg/s": ("rad/s", math.pi / 180),
    "rev/s": ("rad/s", 2 * math.pi), "hz": ("rad/s", 2 * math.pi),
    "n m": ("N m", 1.0), "nm": ("N m", 1.0), "n*m": ("N m", 1.0), "n.m": ("N m", 1.0),
    "n mm": ("N m", 1e-3), "nmm": ("N m", 1e-3), "mn m": ("N m", 1e-3), "kn m": ("N m", 1e3),
    "n": ("N", 1.0), "kn": ("N", 1e3), "mn": ("N", 1e-3), "kgf": ("N", 9.80665), "lbf": ("N", 4.4482216152605),
}
# ambiguous spellings that are refused even though they look like units
_AMBIGUOUS = {"mn m": "mN m or MN m", "mn": "mN or MN"}
# the exact-case spellings that resolve an ambiguous lower-case key (milli-newton)
_EXACT_CASE = {"mN m", "mN", "mN*m", "mN.m"}

_HEADER = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*\[([^\]]*)\]\s*$")


def convert_unit(name: str, unit: str, where: str) -> float:
    """Factor that converts ``unit`` to the canonical unit of channel ``name``."""
    canon = CANONICAL_UNITS[name]
    key = " ".join(unit.strip().lower().replace("·", " ").split())
    raw = " ".join(unit.strip().replace("·", " ").split())
    if key in _AMBIGUOUS and raw not in _EXACT_CASE:
        raise DataError(f"{where}: unit [{unit}] is ambiguous ({_AMBIGUOUS[key]}); "
                        f"write it exactly as 'mN m' / 'mN' or convert to [{canon}]")
    if key in UNIT_FACTORS:
        target, factor = UNIT_FACTORS[key]
        if target == canon:
            return factor
    raise DataError(f"{where}: unit [{unit}] cannot be converted to [{canon}] for column {name!r}")


def parse_header(cells: list[str], source: str) -> list[tuple[str, float]]:
    """Header cells -> [(name, factor to SI)]; raises DataError on unknown names/units."""
    out, seen = [], set()
    for j, cell in enumerate(cells, start=1):
        m = _HEADER.match(cell)
        if not m:
            raise DataError(f"{source}: header column {j} must look like 'name [unit]', got {cell!r}")
        name, unit = m.group(1), m.group(2)
        if name not in CANONICAL_UNITS:
            raise DataError(f"{source}: header column {j}: unknown channel {name!r}; "
                            f"expected one of {', '.join(CANONICAL_UNITS)}")
        if name in seen:
            raise DataError(f"{source}: header column {j}: channel {name!r} appears twice")
        seen.add(name)
        out.append((name, convert_unit(name, unit, f"{source}: column {name!r}")))
    if "t" not in seen:
        raise DataError(f"{source}: missing required column 't [s]'")
    return out


def atomic_write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False) -> Path:
    """Write a file atomically (temp file + rename); refuse to replace unless ``overwrite``."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise ConfigError(f"{path}: file exists; refusing to overwrite (use --force)")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


@dataclass(frozen=True)
class Log:
    """A validated log: time [s] and channels in canonical SI units.

    Attributes
    ----------
    t : (n,) sample times [s], strictly increasing
    channels : name -> (n,) values in the canonical unit of :data:`CANONICAL_UNITS`
    source : where it came from (file name or "simulation")
    """

    t: np.ndarray
    channels: Mapping[str, np.ndarray]
    source: str = "memory"
    derived: tuple[str, ...] = field(default=())

    def __post_init__(self):
        t = np.asarray(self.t, dtype=float)
        object.__setattr__(self, "t", t)
        chans = {k: np.asarray(v, dtype=float) for k, v in self.channels.items()}
        object.__setattr__(self, "channels", chans)
        validate(t, chans, self.source)

    def __contains__(self, name: str) -> bool:
        return name in self.channels

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.channels[name]
        except KeyError:
            raise DataError(f"{self.source}: missing required column {name!r} "
                            f"(present: {', '.join(self.channels) or 'none'})") from None

    @property
    def dt(self) -> float:
        """Median sample period [s]."""
        return float(np.median(np.diff(self.t)))

    def require(self, names: Iterable[str]) -> None:
        for n in names:
            self[n]

    def with_speeds(self) -> "Log":
        """Derive missing speeds from angles (central differences, one-sided at the ends)."""
        chans = dict(self.channels)
        derived = list(self.derived)
        for ang, spd in (("theta1", "omega1"), ("theta2", "omega2"), ("theta3", "omega3"),
                         ("theta_drive", "omega_drive")):
            if ang in chans and spd not in chans:
                chans[spd] = np.gradient(chans[ang], self.t)
                derived.append(spd)
        return Log(self.t, chans, self.source, tuple(derived))

    def slice(self, t0: float, t1: float) -> "Log":
        """The samples with ``t0 <= t < t1``."""
        m = (self.t >= t0) & (self.t < t1)
        if m.sum() < 2:
            raise DataError(f"{self.source}: window [{t0}, {t1}) s holds fewer than 2 samples")
        return Log(self.t[m], {k: v[m] for k, v in self.channels.items()}, self.source, self.derived)

    def to_csv_text(self, precision: int = 9) -> str:
        names = ["t"] + [n for n in CANONICAL_UNITS if n in self.channels and n != "t"]
        cols = [self.t] + [self.channels[n] for n in names[1:]]
        lines = [",".join(f"{n} [{CANONICAL_UNITS[n]}]" for n in names)]
        fmt = f"{{:.{precision}g}}"
        for row in zip(*cols):
            lines.append(",".join(fmt.format(v) for v in row))
        return "\n".join(lines) + "\n"

    def write_csv(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the log (atomically; refuses to replace a file unless ``overwrite``)."""
        return atomic_write_text(path, self.to_csv_text(), overwrite=overwrite)


def validate(t: np.ndarray, chans: Mapping[str, np.ndarray], source: str) -> None:
    """Raise DataError (column and row) on non-finite values, non-increasing time or gaps."""
    n = len(t)
    if n < 2:
        raise DataError(f"{source}: needs at least 2 samples, got {n}")
    for name, col in [("t", t)] + list(chans.items()):
        if name not in CANONICAL_UNITS:
            raise DataError(f"{source}: unknown channel {name!r}; expected one of {', '.join(CANONICAL_UNITS)}")
        if col.shape != (n,):
            raise DataError(f"{source}: column {name!r} has shape {col.shape}, expected ({n},)")
        bad = np.flatnonzero(~np.isfinite(col))
        if bad.size:
            r = int(bad[0])
            raise DataError(f"{source}: column {name!r} row {r + 1} (line {r + 2}): "
                            f"expected a finite number, got {col[r]}")
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        r = int(bad[0]) + 1
        raise DataError(f"{source}: column 't' row {r + 1} (line {r + 2}): time must be strictly increasing, "
                        f"got {t[r]:g} s after {t[r - 1]:g} s")
    med = float(np.median(dt))
    gap = np.flatnonzero(dt > 1.5 * med)
    if gap.size:
        r = int(gap[0]) + 1
        raise DataError(f"{source}: column 't' row {r + 1} (line {r + 2}): gap of {dt[r - 1]:g} s "
                        f"(median step {med:g} s); expected uniform sampling")


def read_csv(path: str | os.PathLike, required: Iterable[str] = ()) -> Log:
    """Read and validate a CSV log; convert units to SI; derive missing speeds.

    Raises
    ------
    DataError : one line naming the column and row of the first problem.
    """
    path = Path(path)
    src = str(path)
    try:
        # utf-8-sig: a CSV exported by Excel starts with a byte-order mark (dropped; plain UTF-8 reads as before)
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise DataError(f"{src}: log file not found") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f"{src}: not a readable CSV file ({exc})") from None
    rows = [r for r in rows if r and not (len(r) == 1 and not r[0].strip()) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise DataError(f"{src}: empty file; expected a header row of 'name [unit]' columns")
    header = parse_header(rows[0], src)
    data = np.empty((len(rows) - 1, len(header)))
    for i, row in enumerate(rows[1:], start=1):
        if len(row) != len(header):
            raise DataError(f"{src}: row {i} (line {i + 1}): expected {len(header)} values, got {len(row)}")
        for j, cell in enumerate(row):
            try:
                data[i - 1, j] = float(cell)
            except ValueError:
                raise DataError(f"{src}: column {header[j][0]!r} row {i} (line {i + 1}): "
                                f"expected a number, got {cell!r}") from None
    cols = {name: data[:, j] * f for j, (name, f) in enumerate(header)}
    t = cols.pop("t")
    log = Log(t, cols, src).with_speeds()
    log.require(required)
    return log
