"""Small helpers shared by the CLI commands: output folders, JSON, tables."""

from __future__ import annotations

import argparse
import enum
import json
import math
import os
import sys
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from models.errors import ConfigError

__all__ = ["add_command", "add_common", "check_outputs", "emit_json", "format_table", "to_jsonable", "savefig_atomic",
           "finish_figure", "quantity"]

#: an example of each quantity a flag takes, for its error message
_EXAMPLES = {"speed": "30 rpm", "force": "0.8 kN", "torque": "2 kN m", "time": "250 ms", "rate": "0.5 Hz",
             "angle": "5 deg", "length": "10 mm", "current": "500 mA", "voltage": "24 V"}


def quantity(kind: str, *, lo: float | None = None, lo_open: bool = False) -> Callable[[str], float]:
    """An argparse ``type=`` for a flag that takes a physical quantity of ``kind`` (a key of
    :data:`models.units.DIMENSIONS`: ``"speed"``, ``"force"``, ``"time"``, ...): a number, taken in the
    kind's SI unit, or a number with its unit as rig and scenario files write it (``"5 rpm"``,
    ``"0.8 kN"``, ``"250 ms"``), converted to SI by :mod:`models.units`.

    Parameters
    ----------
    kind : the quantity kind; lo : the smallest value allowed [SI] (None: any finite value);
        lo_open : ``lo`` itself excluded

    Returns
    -------
    ``parse(text) -> float`` [SI]. A value that does not parse, carries the unit of another quantity,
    is not finite or lies below ``lo`` raises :class:`argparse.ArgumentTypeError`, which argparse
    prints as one line naming the flag (exit 2): ``argument --omega: expected a speed (a number in
    rad/s, or with its unit, e.g. "30 rpm"), got '5 kN' (unit [kN] does not convert to a speed ...)``.
    Called directly (the value part of ``CHANNEL=VALUE``), the caller names its flag.
    """
    from models.rig.spec import SI_UNITS
    from models.units import factor, parse_quantity

    si = SI_UNITS[kind]
    bound = "" if lo is None else f" {'>' if lo_open else '>='} {lo:g} {si}"
    expected = (f"expected a {kind.replace('_', ' ')}{bound} (a number in {si}, or with its unit, e.g. "
                f"\"{_EXAMPLES.get(kind, '1 ' + si)}\")")

    def parse(text: str) -> float:
        q = parse_quantity(text) if isinstance(text, str) else None
        if q is None:
            raise argparse.ArgumentTypeError(f"{expected}, got {text!r}")
        try:
            v = q[0] * factor(q[1], kind, "value") if q[1] else q[0]
        except ConfigError as exc:
            why = str(exc).removeprefix("value: ")
            raise argparse.ArgumentTypeError(f"{expected}, got {text!r} ({why})") from None
        if not math.isfinite(v) or (lo is not None and (v <= lo if lo_open else v < lo)):
            raise argparse.ArgumentTypeError(f"{expected}, got {text!r}" + (f" ({v:g} {si})" if q[1] else ""))
        return float(v)

    parse.__name__ = kind          # what argparse calls the type in its own messages
    return parse


def add_command(subparsers, name: str, *, help: str, description: str, epilog: str) -> argparse.ArgumentParser:
    """A ``mitigate <name>`` sub-command whose ``--help`` shows ``description`` and the ``epilog``
    (its examples) as written."""
    return subparsers.add_parser(name, help=help, description=description, epilog=epilog,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)


def add_common(p: argparse.ArgumentParser, *, out: bool = True, default_out: str = "out") -> None:
    """``--json`` and (optionally) ``--out DIR`` / ``--force``."""
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON document on stdout")
    if out:
        p.add_argument("--out", default=default_out, metavar="DIR", help=f"output folder (default: {default_out})")
        p.add_argument("--force", action="store_true", help="overwrite existing output files")


def check_outputs(paths: Iterable[os.PathLike | str], force: bool) -> None:
    """Refuse (ConfigError) if an output file cannot be written (a folder of that name, a parent
    that is a file or not writable) or exists and ``force`` is not set.  Call before any work."""
    from models.files import check_output_file

    paths = [Path(p) for p in paths]
    for p in paths:
        check_output_file(p, True)
    existing = [str(p) for p in paths if p.exists()]
    if existing and not force:
        raise ConfigError(f"output file {existing[0]} exists"
                          f"{f' (and {len(existing) - 1} more)' if len(existing) > 1 else ''}; "
                          f"refusing to overwrite (use --force or another --out)")


def to_jsonable(obj: Any, *, nonfinite: str = "null") -> Any:
    """JSON data of ``obj``: mappings, sequences and arrays as dicts and lists, numpy scalars as
    Python numbers, enums as their values, paths as strings.

    Parameters
    ----------
    obj : the data
    nonfinite : how an infinite or NaN number is written: ``"null"`` (JSON's null), or ``"text"``
        (the strings "inf", "-inf" and "nan", as in a run's record,
        :meth:`mitigate.record.RunRecord.to_json`, so that "never suppressed" survives a round trip)
    """
    if nonfinite not in ("null", "text"):
        raise ValueError(f"nonfinite must be 'null' or 'text', got {nonfinite!r}")
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v, nonfinite=nonfinite) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, nonfinite=nonfinite) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist(), nonfinite=nonfinite)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        if math.isfinite(v):
            return v
        if nonfinite == "text":
            return "inf" if v > 0 else "-inf" if v < 0 else "nan"
        return None
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, enum.Enum):
        return obj.value
    return obj


def emit_json(payload: Any) -> None:
    json.dump(to_jsonable(payload), sys.stdout, indent=2)
    sys.stdout.write("\n")


def format_table(headers: list[str], rows: list[list[Any]], floatfmt: str = "{:.4g}") -> str:
    """A plain fixed-width text table."""
    def cell(v):
        if isinstance(v, (float, np.floating)):
            return floatfmt.format(v) if math.isfinite(v) else "-"
        return str(v)
    cells = [[cell(v) for v in r] for r in rows]
    widths = [max(len(h), *(len(r[j]) for r in cells)) if cells else len(h) for j, h in enumerate(headers)]
    line = "  ".join(h.ljust(w) for h, w in zip(headers, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in cells]
    return "\n".join([line, sep, *body])


def savefig_atomic(fig, path: os.PathLike | str, **kw) -> Path:
    """Save a matplotlib figure as PNG atomically (:func:`models.files.atomic_path`)."""
    from models.files import atomic_path

    with atomic_path(path, overwrite=True) as tmp:
        fig.savefig(tmp, dpi=kw.pop("dpi", 110), format="png", **kw)
    return Path(path)


def finish_figure(fig, path: os.PathLike | str, title: str | None = None, dpi: int = 110) -> Path:
    """Title, tight layout, atomic PNG save, and close (always, even on failure)."""
    import matplotlib.pyplot as plt

    if title:
        fig.suptitle(title)
    fig.tight_layout()
    try:
        return savefig_atomic(fig, path, dpi=dpi)
    finally:
        plt.close(fig)
