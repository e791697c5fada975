"""Where a benchmark script's results go: printed, and written to the markdown file ``--out`` names.

Imported by the scripts beside it (``python benchmarks/<script>.py`` puts this folder first on the
path), like ``_zoo_rigs.py``.
"""

from __future__ import annotations

import os
from pathlib import Path

from models.files import atomic_write_text

__all__ = ["publish"]


def publish(text: str, out: str | os.PathLike | None, *, append: bool = False) -> None:
    """Print ``text`` and, when ``out`` is given, write it there atomically (its folder made).

    Parameters
    ----------
    text : the results (markdown)
    out : the results file, or None (print only)
    append : add ``text`` after what the file holds (a blank line between); else replace the file
    """
    print(text)
    if not out:
        return
    path = Path(out)
    if append and path.exists():
        text = path.read_text().rstrip("\n") + "\n\n" + text
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text, overwrite=True)
