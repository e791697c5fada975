"""The results store of a parameter sweep: a manifest plus atomically written chunk files.

Layout of a sweep folder::

    DIR/manifest.json            grid definition, options and their hash
    DIR/chunks/rest_00012.csv    one finished chunk of points (written to a temp file, then renamed):
                                 ``index,status,message,<metric>...`` (one row per point's record)
    DIR/results.csv              all points (written at the end): the axes, ``<metric>_<start>`` and
                                 ``status_<start>`` per start mode, ``sliding_max_real``

A chunk written before the points had records (an ``ok`` column of 1.0 / 0.0 instead of ``status``
and ``message``) is still read: ``ok`` 1 is Status.OK, anything else Status.FAILED.

A chunk file exists only when all of its points are finished (``os.replace`` is atomic
on POSIX), so a sweep killed at any moment (Ctrl-C, ``kill -9``) loses at most the
chunks in flight.  A rerun with the same definition (same hash) skips the chunks
already on disk; a rerun with a different definition into the same folder is refused
unless ``force`` is given, which deletes the old chunks first.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import shutil
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from models.errors import ConfigError, DataError
from models.files import atomic_write_text
from models.status import Status

__all__ = ["SweepStore", "definition_hash", "manifest_hash"]


def definition_hash(definition: Mapping[str, Any]) -> str:
    """SHA-256 (first 16 hex digits) of the canonical JSON of a sweep definition."""
    text = json.dumps(definition, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def manifest_hash(root: Path, what: str, force: str) -> str | None:
    """The definition hash in ``root/manifest.json`` of a resumable store (a sweep's, a benchmark's),
    None when there is none yet.

    Raises
    ------
    DataError : ``"<root>/manifest.json: unreadable <what> manifest (...); use <force> to start over"``
    """
    man = Path(root) / "manifest.json"
    if not man.exists():
        return None
    try:
        return json.loads(man.read_text()).get("hash")
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError) as exc:
        raise DataError(f"{man}: unreadable {what} manifest ({exc}); use {force} to start over") from None


class SweepStore:
    """Folder holding one sweep's manifest and finished chunks.

    Parameters
    ----------
    root : folder of the sweep
    definition : JSON-serialisable grid definition (axes, options, scenario digest)
    force : discard an existing store with a different definition (and its chunks)
    """

    def __init__(self, root: os.PathLike | str, definition: Mapping[str, Any], *, force: bool = False):
        self.root = Path(root)
        self.chunk_dir = self.root / "chunks"
        self.definition = dict(definition)
        self.hash = definition_hash(self.definition)
        self.resumed = False
        man = self.root / "manifest.json"
        old = manifest_hash(self.root, "sweep", "--force")
        if old is not None:
            if old == self.hash:
                self.resumed = True
            elif not force:
                raise ConfigError(f"{self.root} holds a different sweep (hash {old}, this one {self.hash}); "
                                  f"refusing to mix results (use --force to discard it, or another --out)")
            else:
                shutil.rmtree(self.chunk_dir, ignore_errors=True)
                for f in ("results.csv",):
                    (self.root / f).unlink(missing_ok=True)
        elif force:
            shutil.rmtree(self.chunk_dir, ignore_errors=True)
        self.chunk_dir.mkdir(parents=True, exist_ok=True)
        if not self.resumed:
            atomic_write_text(man, json.dumps({"hash": self.hash, "definition": self.definition}, indent=2, default=str),
                              overwrite=True, durable=True)

    def chunk_path(self, key: str) -> Path:
        return self.chunk_dir / f"{key}.csv"

    def done(self) -> set[str]:
        """Keys of the chunks already on disk."""
        return {p.stem for p in self.chunk_dir.glob("*.csv") if not p.name.startswith(".")}   # (not a cut write's temp)

    def write_records(self, key: str, records) -> Path:
        """Write one finished chunk of points atomically: a row per :class:`mitigate.record.RunRecord`
        (its point index, status, message and metrics)."""
        from mitigate.metrics import in_order
        names = in_order({k for r in records for k in r.metrics})
        cols: dict[str, list] = {"index": [float(r.run.index) for r in records],
                                 "status": [r.status.value for r in records],
                                 "message": [r.message for r in records]}
        cols.update({n: [r.metrics.get(n, float("nan")) for r in records] for n in names})
        return self.write_chunk(key, cols)

    def write_chunk(self, key: str, columns: Mapping[str, Any]) -> Path:
        """Write one finished chunk atomically (columns of equal length; numbers or text)."""
        path = self.chunk_path(key)
        atomic_write_text(path, _csv(columns), overwrite=True, durable=True)
        return path

    def read_chunk(self, key: str) -> dict[str, np.ndarray]:
        """The columns of a chunk: numbers as float arrays, ``status`` as an array of Status and
        ``message`` as strings (a chunk with the old ``ok`` column: see the module docstring)."""
        path = self.chunk_path(key)
        with open(path, newline="") as fh:
            reader = csv.reader(fh)
            try:
                header = next(reader)
            except StopIteration:
                raise DataError(f"{path}: empty chunk file") from None
            rows = [r for r in reader if r]
        if any(len(r) != len(header) for r in rows):
            raise DataError(f"{path}: a row has not {len(header)} fields; delete the chunk to recompute it")
        text = {"status", "message"}
        out: dict[str, np.ndarray] = {}
        try:
            for j, h in enumerate(header):
                col = [r[j] for r in rows]
                out[h] = np.array(col, dtype=object if h in text else float)
            if "status" in out:
                out["status"] = np.array([Status(v) for v in out["status"]], dtype=object)
        except ValueError as exc:
            raise DataError(f"{path}: unreadable chunk ({exc}); delete it to recompute it") from None
        if "ok" in out and "status" not in out:          # written before the points had records
            ok = out.pop("ok") == 1
            out["status"] = np.array([Status.OK if k else Status.FAILED for k in ok], dtype=object)
            out["message"] = np.array(["ok" if k else "failed (no reason recorded)" for k in ok], dtype=object)
        return out

    def write_results(self, columns: Mapping[str, Any]) -> Path:
        """All points in one CSV (``results.csv``), written atomically."""
        path = self.root / "results.csv"
        atomic_write_text(path, _csv(columns), overwrite=True, durable=True)
        return path


def _csv(columns: Mapping[str, Any]) -> str:
    """CSV text of equal-length columns: numbers as ``repr(float)`` (exact round trip), text as is."""
    names = list(columns)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for r in zip(*[list(columns[n]) for n in names]):
        w.writerow([v.value if isinstance(v, Status) else v if isinstance(v, str) else repr(float(v)) for v in r])
    return buf.getvalue()
