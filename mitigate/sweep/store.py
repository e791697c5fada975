"""The results store of a parameter sweep: a manifest plus atomically written chunk files.

Layout of a sweep folder::

    DIR/manifest.json            grid definition, options and their hash
    DIR/chunks/rest_00012.csv    one finished chunk of points (written to a temp file, then renamed)
    DIR/results.csv              all points (written at the end)

A chunk file exists only when all of its points are finished (``os.replace`` is atomic
on POSIX), so a sweep killed at any moment (Ctrl-C, ``kill -9``) loses at most the
chunks in flight.  A rerun with the same definition (same hash) skips the chunks
already on disk; a rerun with a different definition into the same folder is refused
unless ``force`` is given, which deletes the old chunks first.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from models.errors import ConfigError, DataError
from models.files import atomic_write_text

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
        return {p.stem for p in self.chunk_dir.glob("*.csv")}

    def write_chunk(self, key: str, columns: Mapping[str, np.ndarray]) -> Path:
        """Write one finished chunk atomically (columns of equal length)."""
        names = list(columns)
        rows = zip(*[np.asarray(columns[n]).tolist() for n in names])
        lines = [",".join(names)]
        for r in rows:
            lines.append(",".join(repr(float(v)) if not isinstance(v, str) else v for v in r))
        path = self.chunk_path(key)
        atomic_write_text(path, "\n".join(lines) + "\n", overwrite=True, durable=True)
        return path

    def read_chunk(self, key: str) -> dict[str, np.ndarray]:
        path = self.chunk_path(key)
        with open(path, newline="") as fh:
            reader = csv.reader(fh)
            try:
                header = next(reader)
            except StopIteration:
                raise DataError(f"{path}: empty chunk file") from None
            data = [list(map(float, r)) for r in reader if r]
        arr = np.array(data, dtype=float).reshape(len(data), len(header))
        return {h: arr[:, j] for j, h in enumerate(header)}

    def write_results(self, columns: Mapping[str, np.ndarray]) -> Path:
        """All points in one CSV (``results.csv``), written atomically."""
        names = list(columns)
        lines = [",".join(names)]
        for r in zip(*[np.asarray(columns[n]).tolist() for n in names]):
            lines.append(",".join(repr(float(v)) for v in r))
        path = self.root / "results.csv"
        atomic_write_text(path, "\n".join(lines) + "\n", overwrite=True, durable=True)
        return path
