"""Benchmarks that cannot rot: every script in ``benchmarks/`` has argparse, a ``--help`` that only
prints (with an example), and a ``--quick`` smoke run that finishes and writes nothing into
``benchmarks/results/`` (issue 18, item 9).  Each script runs in its own interpreter, from a
scratch folder, as CI runs it."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted(p for p in (ROOT / "benchmarks").glob("*.py") if not p.name.startswith("_"))


def _results_state() -> dict:
    return {p: p.stat().st_mtime_ns for p in (ROOT / "benchmarks" / "results").rglob("*") if p.is_file()}


def _run(script: Path, *args, cwd, timeout):
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    return subprocess.run([sys.executable, str(script), *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def test_there_are_benchmark_scripts():
    assert len(SCRIPTS) >= 10


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_help_only_prints_and_offers_quick(script, tmp_path):
    before = _results_state()
    r = _run(script, "--help", cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr[-1500:]
    assert r.stdout.lstrip().startswith("usage:"), r.stdout[:300]
    assert "--quick" in r.stdout
    assert "example" in r.stdout.lower() or "python benchmarks/" in r.stdout, "no example in --help"
    assert list(tmp_path.iterdir()) == [] and _results_state() == before


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_quick_runs_and_writes_no_result(script, tmp_path):
    before = _results_state()
    r = _run(script, "--quick", cwd=tmp_path, timeout=600)
    assert r.returncode == 0, (r.stdout[-800:], r.stderr[-1500:])
    assert r.stdout.strip()
    assert _results_state() == before, "a --quick run changed benchmarks/results/"
