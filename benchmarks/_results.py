"""Where a benchmark script's results go: printed, and written to the markdown file ``--out`` names;
and the one-scenario benchmark that the ``--quick`` modes of the scripts reading a benchmark share.

Imported by the scripts beside it (``python benchmarks/<script>.py`` puts this folder first on the
path), like ``_zoo_rigs.py``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from models.files import atomic_write_text

__all__ = ["publish", "quick_benchmark", "QUICK_ONLY"]

ROOT = Path(__file__).resolve().parents[1]
#: the scenario of :func:`quick_benchmark`
QUICK_ONLY = "drillstring"


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


def quick_benchmark(out: str | os.PathLike) -> subprocess.CompletedProcess:
    """Run ``mitigate benchmark scenarios/benchmark/suite.toml --quick --only drillstring --json --out OUT``
    (one scenario, one phase, one seed; about 40 s on 2 cores) in a subprocess: the benchmark whose
    ``results.json`` and run store the ``--quick`` modes of ``benchmark_compare.py`` and
    ``benchmark_partial.py`` read (``tests/test_benchmark_scripts.py`` runs it once for both).
    Exit code 1 is a benchmark with a failed run: still a benchmark to read."""
    cmd = [sys.executable, "-m", "mitigate.cli", "benchmark", str(ROOT / "scenarios/benchmark/suite.toml"), "--quick",
           "--only", QUICK_ONLY, "--json", "--out", str(out)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
