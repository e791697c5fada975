"""The one log format: CSV with ``name [unit]`` headers.

Everything a rig records, the simulator writes and the estimators read uses this format.
The first row holds ``name [unit]`` columns; ``t [s]`` is required, the other names are the
channels of the rig file's sensors and inputs (the reference rig: ``theta1..3 [rad]``,
``omega1..3 [rad/s]``, ``motor_torque [N m]``, ``n1``, ``n2 [N]``, ``omega_ref [rad/s]``), and
true states written by the simulator and the closed loop (``true_twist_<connection> [rad]``,
``true_omega_<body> [rad/s]``: the prefix :data:`TRUTH_PREFIX` keeps a true state apart from a
sensor channel of the same name, e.g. an encoder's default speed channel ``omega_<body>``)::

    t [s], theta1 [rad], omega1 [rpm], n1 [kN], motor_torque [N mm], ...

Units are converted to SI by :mod:`models.units` (``deg``, ``rev``, ``rpm``, ``ms``, ``kN``,
``N mm``, ``mN m``, ... case-sensitive: ``mN`` is milli-, ``MN`` mega-newton).  A channel whose
name follows the vocabulary (``theta*``/``twist*`` angles, ``omega*`` speeds, ``*torque*``
torques, ``n<k>``/``normal_*``/``*_force`` forces, ``current``, ``voltage``) must have a unit
of that quantity; any other name takes the quantity of its unit.  Validation: time strictly
increasing, no NaN or inf, no gap (a step longer than 1.5 times the median step), one
``name [unit]`` per column; each error is one line naming the column and the row (data rows
count from 1; the header is line 1 of the file).  A UTF-8 byte-order mark (Excel's CSV) is
accepted.  Nothing is silently dropped.  Where only angles are given, speeds are derived by
central differences: on reading, ``omega<X>`` from ``theta<X>``; once the rig is known
(:meth:`Log.with_speeds` with the rig: identification does so), each encoder's speed channel from
its angle channel, whatever they are named.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from models.errors import ConfigError, DataError
from models.files import atomic_write_text
from models.rig.spec import SI_UNITS, TRUTH_PREFIX
from models.units import DIMENSIONS, parse_unit

__all__ = ["TRUTH_PREFIX", "Log", "read_csv", "parse_header", "channel_kind", "convert_unit", "atomic_write_text"]

_HEADER = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*\[([^\]]*)\]\s*$")

# name pattern -> quantity kind (the log vocabulary)
_VOCAB = (
    (re.compile(r"^t$"), "time"),
    (re.compile(r"^(theta|twist)"), "angle"),
    (re.compile(r"^omega"), "speed"),
    (re.compile(r"torque"), "torque"),
    (re.compile(r"^(n\d+|normal_.*|.*_force|weight_on_bit|wob)$"), "force"),
    (re.compile(r"^current$"), "current"),
    (re.compile(r"^voltage$"), "voltage"),
)
# kinds a free-named channel may take from its unit, in order of preference
_BY_DIM = ("angle", "speed", "torque", "force", "time", "current", "voltage", "acceleration", "length",
           "dimensionless")


def channel_kind(name: str) -> str | None:
    """The quantity kind the vocabulary gives a channel name, or None for a free name
    (a true-state column ``true_<state>`` takes its state's kind)."""
    if name.startswith(TRUTH_PREFIX):
        name = name[len(TRUTH_PREFIX):]
    for pat, kind in _VOCAB:
        if pat.search(name):
            return kind
    return None


def _unit_of(name: str, unit: str | None, where: str) -> tuple[str, float]:
    """(SI unit, factor) of a channel given in ``unit`` (None: its vocabulary unit, already SI)."""
    kind = channel_kind(name)
    if unit is None:
        if kind is None:
            raise DataError(f"{where}: unknown channel {name!r}: give its unit (free-named channels need one)")
        return SI_UNITS[kind], 1.0
    try:
        u = parse_unit(unit, where)
    except ConfigError:
        want = f" to [{SI_UNITS[kind]}]" if kind else ""
        raise DataError(f"{where}: unit [{unit}] cannot be converted{want} for column {name!r}") from None
    if kind is not None:
        if u.dim != DIMENSIONS[kind]:
            if kind == "speed" and unit.strip().lower() == "hz":
                return SI_UNITS[kind], 2 * np.pi
            raise DataError(f"{where}: unit [{unit}] cannot be converted to [{SI_UNITS[kind]}] for column {name!r}")
        return SI_UNITS[kind], u.factor
    for k in _BY_DIM:
        if DIMENSIONS[k] == u.dim:
            return SI_UNITS[k], u.factor
    raise DataError(f"{where}: unit [{unit}] of column {name!r} is not a quantity a log holds "
                    f"({', '.join(_BY_DIM)})")


def convert_unit(name: str, unit: str, where: str) -> tuple[str, float]:
    """``(SI unit, factor)`` of channel ``name`` logged in ``unit``; DataError if it does not convert."""
    return _unit_of(name, unit, where)


_SHOWABLE = re.compile(r"^[\w .()\[\]/^*+-]{0,40}$")


def _shown(cell: str) -> str:
    """A cell of a file for an error message: quoted if it is short and looks like a log's header or
    number, else only described -- an error never echoes the content of a file that is not a log
    (``file = "/etc/passwd"`` in a scenario)."""
    if _SHOWABLE.match(cell):
        return repr(cell)
    return f"a {len(cell)}-character text (not shown: is this a CSV log of the workbench?)"


def parse_header(cells: list[str], source: str) -> list[tuple[str, str, float]]:
    """Header cells -> [(name, SI unit, factor to SI)]; raises DataError on bad names/units."""
    out, seen = [], set()
    for j, cell in enumerate(cells, start=1):
        m = _HEADER.match(cell)
        if not m:
            raise DataError(f"{source}: header column {j} must look like 'name [unit]', got {_shown(cell)}")
        name, unit = m.group(1), m.group(2)
        if name in seen:
            raise DataError(f"{source}: header column {j}: channel {name!r} appears twice")
        seen.add(name)
        si, f = _unit_of(name, unit, f"{source}: column {name!r}")
        out.append((name, si, f))
    if "t" not in seen:
        raise DataError(f"{source}: missing required column 't [s]'")
    return out


@dataclass(frozen=True)
class Log:
    """A validated log: time [s] and channels in SI units.

    Attributes
    ----------
    t : (n,) sample times [s], strictly increasing
    channels : name -> (n,) values in SI units
    source : where it came from (file name or "simulation")
    derived : channels computed from others (speeds from angles)
    units : name -> SI unit (from the vocabulary unless given)
    """

    t: np.ndarray
    channels: Mapping[str, np.ndarray]
    source: str = "memory"
    derived: tuple[str, ...] = field(default=())
    units: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self):
        t = np.asarray(self.t, dtype=float)
        object.__setattr__(self, "t", t)
        chans = {k: np.asarray(v, dtype=float) for k, v in self.channels.items()}
        object.__setattr__(self, "channels", chans)
        units = {}
        for k in chans:
            if not isinstance(k, str) or not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", k):
                raise DataError(f"{self.source}: channel name {k!r} must be an identifier")
            units[k] = self.units.get(k) or _unit_of(k, None, self.source)[0]
        object.__setattr__(self, "units", units)
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

    def require_kind(self, name: str, kind: str) -> np.ndarray:
        """``self[name]``, checking that it holds a quantity of ``kind`` (e.g. a force)."""
        col = self[name]
        if self.units.get(name) != SI_UNITS[kind]:
            raise DataError(f"{self.source}: column {name!r} holds [{self.units.get(name)}], expected a "
                            f"{kind} [{SI_UNITS[kind]}]")
        return col

    def with_speeds(self, rig=None) -> "Log":
        """Derive missing speeds from angles (central differences).

        Parameters
        ----------
        rig : the rig the log belongs to (:class:`models.rig.RigModel`), or None.  With it, the sensor's
            kind decides: each encoder's speed channel is derived from that encoder's angle channel,
            whatever the two are named (an encoder on a body gives that body's angle: ``q`` -> ``qd``),
            and a speed derived earlier by name that no encoder of the rig writes is dropped.  Without
            it (a log read before its rig is known), ``omega<X>`` from ``theta<X>``, by the log vocabulary.

        Returns
        -------
        Log : the derived channels listed in ``derived``
        """
        chans = {k: v for k, v in self.channels.items() if rig is None or k not in self.derived}
        units = {k: u for k, u in self.units.items() if k in chans}
        derived = [d for d in self.derived if d in chans]
        if rig is None:
            pairs = [(a, "omega" + a[len("theta"):]) for a in chans if a.startswith("theta")]
        else:
            pairs = [(s.channels[0], s.channels[1]) for s in rig.sensors if s.kind == "encoder"]
        for ang, spd in pairs:
            if ang in chans and spd not in chans:
                chans[spd] = np.gradient(chans[ang], self.t)
                units[spd] = "rad/s"
                derived.append(spd)
        return Log(self.t, chans, self.source, tuple(derived), units)

    def slice(self, t0: float, t1: float) -> "Log":
        """The samples with ``t0 <= t < t1``."""
        m = (self.t >= t0) & (self.t < t1)
        if m.sum() < 2:
            raise DataError(f"{self.source}: window [{t0}, {t1}) s holds fewer than 2 samples")
        return Log(self.t[m], {k: v[m] for k, v in self.channels.items()}, self.source, self.derived, self.units)

    def with_channels(self, **channels) -> "Log":
        """A copy with channels added (vocabulary units) or replaced (keeping their units)."""
        ch = dict(self.channels)
        ch.update(channels)
        return Log(self.t, ch, self.source, self.derived, dict(self.units))

    def to_csv_text(self, precision: int = 9) -> str:
        names = [n for n in self.channels if n != "t"]
        cols = [self.t] + [self.channels[n] for n in names]
        lines = [",".join(["t [s]"] + [f"{n} [{self.units[n]}]" for n in names])]
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
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise DataError(f"{src}: log file not found") from None
    except IsADirectoryError:
        raise DataError(f"{src}: is a folder, expected a CSV log file") from None
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
                                f"expected a number, got {_shown(cell)}") from None
    cols = {name: data[:, j] * f for j, (name, _u, f) in enumerate(header)}
    units = {name: u for name, u, _f in header}
    t = cols.pop("t")
    units.pop("t")
    log = Log(t, cols, src, (), units).with_speeds()
    log.require(required)
    return log
