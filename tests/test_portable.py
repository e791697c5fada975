"""The same bits on any machine (models/portable.py): OpenBLAS's kernels are pinned before numpy loads
them, in this process and in every worker.  The cross-host evidence (the reference made on another
host reproduced bit for bit here once pinned) is in BENCHMARKS.md; these tests check the mechanism."""

from __future__ import annotations

import subprocess
import sys

import pytest

from models.portable import CORE, NATIVE_ENV, blas_core, pin, portable_core
from mitigate.workers import WorkerPool

PINNED = portable_core() is not None


def _where() -> tuple[int, str | None]:
    return __import__("os").getpid(), blas_core()


def test_pin_sets_the_core_unless_the_environment_chose():
    env = {}
    assert pin(env) == (CORE if PINNED else None) and env.get("OPENBLAS_CORETYPE") == (CORE if PINNED else None)
    assert pin({"OPENBLAS_CORETYPE": "Zen"}) == "Zen"                  # a user's choice stands
    assert pin({NATIVE_ENV: "1"}) is None                              # the CPU's own kernels, asked for


@pytest.mark.skipif(not PINNED, reason="not an x86_64 CPU with AVX2 and FMA: OpenBLAS picks")
def test_a_process_that_imports_the_workbench_first_and_its_workers_run_the_pinned_kernels():
    code = ("import mitigate, numpy\nfrom models.portable import blas_core\nprint(blas_core())\n")
    env = {k: v for k, v in __import__("os").environ.items() if k not in ("OPENBLAS_CORETYPE", NATIVE_ENV)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == CORE, out.stderr[-500:]
    native = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                            env={**env, NATIVE_ENV: "1"})
    assert native.returncode == 0 and native.stdout.strip(), native.stderr[-500:]     # whatever this CPU picks
    with WorkerPool(2) as pool:
        got = [f.value for f in pool.map(_where, [(), ()])]
    assert all(pid != __import__("os").getpid() for pid, _ in got)      # spawned workers, not this process
    assert [core for _, core in got] == [CORE, CORE]
