"""Writing files safely: atomically (temp file + rename), never replacing a user's file unasked.

The one home of this mechanism: parameter sets, logs, reports, plots and sweep chunks all
write through :func:`atomic_write_text`, :func:`atomic_write_bytes` or :func:`atomic_path`.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from models.errors import ConfigError

__all__ = ["atomic_write_text", "atomic_write_bytes", "atomic_path", "refuse_overwrite"]


def refuse_overwrite(path: str | os.PathLike, overwrite: bool, arg: str = "overwrite") -> Path:
    """``Path(path)``; a ConfigError if it exists and ``overwrite`` is False (the message names
    the caller's argument ``arg``; the CLI translates it to its ``--force`` flag)."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise ConfigError(f"{path}: file exists; refusing to overwrite (pass {arg}=True)")
    return path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = False):
    """Yield a temporary path next to ``path``; on success rename it onto ``path``, on error
    delete it.  Writers that need a file name (matplotlib, numpy) write to the yielded path."""
    path = refuse_overwrite(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False, durable: bool = False) -> Path:
    """Write ``text`` to ``path`` atomically; refuse to replace a file unless ``overwrite``.

    ``durable``: flush the data to disk before the rename (a file that survives a crash or a
    ``kill -9`` whole or not at all, e.g. a sweep's chunks)."""
    with atomic_path(path, overwrite=overwrite) as tmp:
        with open(tmp, "w", newline="") as fh:
            fh.write(text)
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
    return Path(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically; refuse to replace a file unless ``overwrite``."""
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return Path(path)
