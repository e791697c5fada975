"""A benchmark's results as one submittable entry: ``results.json``.

The entry holds everything a leaderboard needs to compare it with any other entry of the same suite
version, metrics version and compute model: which suite and code scored it, how the controllers were
tuned, the uncontrolled references, every entry's medians and intervals, and EVERY run's record.  It
is checked against the results' JSON Schema (:func:`schema`; ``mitigate/benchmark/results.schema.json``).

Two of its fields depend on where and when it was made, and only those:

- ``timing``: the wall time, how many runs were computed now, every run's wall-clock timings and
  the entries and records of the suite's TIMING scenarios (a measured latency or a deadline);
- ``provenance``: the commit, the package versions, the machine, the command.

Everything else is the same, bit for bit, for the same command on any machine and at any load (the
suite's compute model: :mod:`mitigate.benchmark.suite`).
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any, Mapping

from mitigate.benchmark.freeze import check, lock_path, schema
from mitigate.cliutil import to_jsonable
from models.errors import DataError

__all__ = ["entry_document", "provenance", "schema", "validate", "read_entry", "finite", "ENTRY_FORMAT",
           "VARYING"]

#: the entry's format (the schema's ``format_version``)
ENTRY_FORMAT = 1
#: the top-level fields that depend on the machine, the load or the time (module docstring)
VARYING = ("timing", "provenance")
_PACKAGES = ("stickslip-workbench", "numpy", "scipy", "casadi", "control", "optuna")


def provenance(command: str = "") -> dict[str, Any]:
    """Where an entry was made: the git commit of this package's source (``"unknown"`` outside a git
    checkout) and whether it had uncommitted changes, the versions of Python and the packages that
    compute a run, the machine, and the command."""
    root = Path(__file__).resolve().parents[2]
    commit, dirty = "unknown", None
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip() or "unknown"
        dirty = bool(subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                                    capture_output=True, text=True, timeout=10, check=True).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        pass
    versions = {"python": platform.python_version()}
    for p in _PACKAGES:
        try:
            versions[p] = metadata.version(p)
        except metadata.PackageNotFoundError:
            versions[p] = None
    from models.portable import blas_core
    machine = {"system": platform.system(), "release": platform.release(), "machine": platform.machine(),
               "processor": platform.processor() or "", "cpus": os.cpu_count() or 0, "node": platform.node(),
               # the OpenBLAS kernels of this process and the pin its workers inherit (models/portable.py)
               "blas_core": blas_core(), "blas_pin": os.environ.get("OPENBLAS_CORETYPE")}
    return {"commit": commit, "dirty": dirty, "packages": versions, "machine": machine, "command": command}


def _record(r) -> dict:
    d = r.to_json()
    d.pop("timings", None)
    return d


def _frozen(suite) -> bool:
    """The suite's files, rigs, metric code and schema are what its lock says (:mod:`.freeze`)."""
    if not suite.path or not lock_path(suite.path).is_file():
        return False
    try:
        return not check(suite.path)
    except (DataError, OSError):
        return False


def entry_document(res, prov: Mapping | None = None) -> dict[str, Any]:
    """The entry of a :class:`mitigate.benchmark.BenchmarkResult` (module docstring)."""
    su = res.suite
    timing_sc = set(su.timing)
    ranked_recs = [r for r in res.records if r.run.scenario not in timing_sc]
    timing_recs = [r for r in res.records if r.run.scenario in timing_sc]
    ctrl_class = {}
    for e in res.entries.values():
        if e.klass:
            ctrl_class.setdefault(e.controller, e.klass)
    doc = {
        "format": "stickslip-benchmark-entry", "format_version": ENTRY_FORMAT,
        "suite": {"name": su.name, "version": su.version, "frozen": _frozen(su), "description": su.description,
                  "scenarios": [sc.name for sc in su.scenarios if sc.name not in timing_sc],
                  "timing_scenarios": list(su.timing), "compute": su.compute, "compute_model": su.compute_text,
                  "phases": res.phases, "seeds": res.seeds},
        "metrics_version": res.metrics_version, "mode": res.mode,
        "controllers": [{"name": c.name, "kind": c.kind, "options": dict(c.options),
                         "class": ctrl_class.get(c.name, "")} for c in su.controllers],
        "tuning": dict(res.tuning) if res.tuned else None,
        "tuned": [{"scenario": s, "controller": c, "options": o} for (s, c), o in res.tuned.items()],
        "status": res.status.value, "message": res.message,
        "references": {k: v.as_dict() for k, v in res.references.items()},
        "entries": [e.as_dict() for (s, _c), e in res.entries.items() if s not in timing_sc],
        "tables": res.tables,
        "records": [_record(r) for r in ranked_recs],
        "timing": {"elapsed_s": res.elapsed, "computed": res.computed, "runs": len(res.records),
                   "timings": {r.run.key: r.timings for r in res.records},
                   "entries": [e.as_dict() | {"timings": e.timings} for (s, _c), e in res.entries.items()
                               if s in timing_sc],
                   "entry_timings": {f"{s}/{c}": e.timings for (s, c), e in res.entries.items()},
                   "records": [_record(r) for r in timing_recs]},
        "provenance": dict(prov) if prov is not None else provenance(),
    }
    return to_jsonable(doc, nonfinite="text")


def validate(doc: Mapping, where: str = "results.json") -> None:
    """Check an entry against :func:`schema` (with the ``jsonschema`` package, ``pip install jsonschema``).

    Raises
    ------
    DataError : the first place the entry breaks the schema, in one line.
    """
    try:
        import jsonschema
    except ImportError:
        raise DataError("validating an entry needs the jsonschema package (pip install jsonschema)") from None
    v = jsonschema.Draft202012Validator(schema())
    err = next(iter(sorted(v.iter_errors(doc), key=lambda e: list(e.absolute_path))), None)
    if err is not None:
        at = "/".join(str(p) for p in err.absolute_path) or "(top)"
        raise DataError(f"{where}: {at}: {err.message[:300]}")


def read_entry(path) -> dict:
    """An entry from ``results.json`` (or ``.json.gz``), checked for its format.

    Raises
    ------
    DataError : unreadable, not JSON, or not an entry of this format.
    """
    import gzip
    p = Path(path)
    try:
        raw = gzip.decompress(p.read_bytes()) if p.suffix == ".gz" else p.read_bytes()
        doc = json.loads(raw)
    except (OSError, ValueError) as exc:
        raise DataError(f"{p}: unreadable entry ({type(exc).__name__}: {exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != "stickslip-benchmark-entry":
        raise DataError(f"{p}: not a benchmark entry (its format is not \"stickslip-benchmark-entry\")")
    if doc.get("format_version") != ENTRY_FORMAT:
        raise DataError(f"{p}: entry format {doc.get('format_version')!r} is not {ENTRY_FORMAT}")
    return doc


def finite(v) -> float:
    """A JSON number of an entry as a float (the strings "inf", "-inf", "nan" too)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan
