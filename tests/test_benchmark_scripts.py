"""Benchmarks that cannot rot: every script in ``benchmarks/`` has argparse, a ``--help`` that only
prints (with an example), and a ``--quick`` smoke run that finishes and writes nothing into
``benchmarks/results/`` (issue 18, item 9).  Each script runs in its own interpreter, from a
scratch folder, as CI runs it.

The two scripts that read a benchmark (:data:`READERS`) have a ``--quick`` that is
``benchmarks/_results.quick_benchmark`` (a one-scenario benchmark, about 40 s on 2 cores) and then
their reading of it: that benchmark runs once here and both read it, through the same call and the
same reading (the same 40 s twice otherwise)."""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted(p for p in (ROOT / "benchmarks").glob("*.py") if not p.name.startswith("_"))
#: the scripts whose --quick reads the one quick benchmark (:func:`quick_store`)
READERS = ("benchmark_compare", "benchmark_partial")
_spec = importlib.util.spec_from_file_location("bench_results", ROOT / "benchmarks" / "_results.py")
RESULTS = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(RESULTS)


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
@pytest.mark.parametrize("script", [p for p in SCRIPTS if p.stem not in READERS], ids=lambda p: p.stem)
def test_quick_runs_and_writes_no_result(script, tmp_path):
    before = _results_state()
    r = _run(script, "--quick", cwd=tmp_path, timeout=600)
    assert r.returncode == 0, (r.stdout[-800:], r.stderr[-1500:])
    assert r.stdout.strip()
    assert _results_state() == before, "a --quick run changed benchmarks/results/"


@pytest.fixture(scope="session")
def quick_store(tmp_path_factory):
    """The readers' quick benchmark (``_results.quick_benchmark``, what their ``--quick`` runs), once
    (a session fixture: a module one is built again when the worker ran another file's test between
    the two readers, as it did in a suite run: 80 s and 92 s)."""
    out = tmp_path_factory.mktemp("quick_benchmark") / "b"
    r = RESULTS.quick_benchmark(out)
    assert r.returncode in (0, 1), r.stderr[-1500:]
    return out


@pytest.mark.slow
@pytest.mark.xdist_group("quick_benchmark")
@pytest.mark.parametrize("script", READERS)
def test_the_readers_quick_reads_the_quick_benchmark(script, quick_store, tmp_path):
    """What ``--quick`` does after the benchmark, on the one quick benchmark: the comparison prints
    the three actuator classes' verdicts; the partial results hold the one scenario and write the
    benchmark's output set."""
    before = _results_state()
    if script == "benchmark_compare":
        args = [str(quick_store / "results.json")]
    else:
        args = [str(ROOT / "scenarios/benchmark/suite.toml"), str(quick_store), "--out", str(tmp_path / "p"),
                "--phases", "1", "--seeds", "1", "--only", RESULTS.QUICK_ONLY]
    r = _run(ROOT / "benchmarks" / f"{script}.py", *args, cwd=tmp_path, timeout=600)
    assert r.returncode == 0, (r.stdout[-800:], r.stderr[-1500:])
    if script == "benchmark_compare":
        for cls in ("### drive set-point only", "### normal force only", "### both"):
            assert cls in r.stdout, r.stdout[:1500]
        assert f"| {RESULTS.QUICK_ONLY} |" in r.stdout
    else:
        assert "all 1 scenarios" in r.stdout, r.stdout[:800]
        assert {p.name for p in (tmp_path / "p").iterdir()} >= {"ranking.md", "results.csv", "results.json",
                                                                "benchmark.png"}
    assert _results_state() == before, "a reader changed benchmarks/results/"
