"""The worker pool (mitigate/workers.py), a sweep whose chunk fails, and the trust of compiled code
(models/codegen.py): issue 20, "Kills and processes" and "Trust"."""

import os
import signal
import stat
import sys
import time

import casadi as ca
import numpy as np
import pytest

from mitigate.workers import WorkerPool
from models import codegen
from models.errors import ConfigError
from models.status import Status


def _square(x):
    return x * x


def _boom(x):
    if x == 2:
        raise ValueError("two is bad")
    return x


def _exit_hard(x):
    if x == 1:
        os._exit(9)
    return x


def _stuck(x):
    if x == 1:
        time.sleep(60)
    return x


def _outcomes(pool, fn, n):
    return {o.index: o for o in pool.map(fn, [(i,) for i in range(n)])}


@pytest.mark.slow
def test_a_task_that_raises_fails_alone_in_workers_and_in_process():
    for jobs in (1, 2):
        with WorkerPool(jobs) as pool:
            out = _outcomes(pool, _boom, 4)
        assert [out[i].ok for i in range(4)] == [True, True, False, True]
        assert out[2].error == "ValueError: two is bad" and out[3].value == 3


@pytest.mark.slow
def test_a_worker_that_dies_fails_its_task_and_is_replaced():
    with WorkerPool(2) as pool:
        out = _outcomes(pool, _exit_hard, 5)
    assert out[1].ok is False and out[1].error == "its worker process died (exit code 9)"
    assert [out[i].value for i in (0, 2, 3, 4)] == [0, 2, 3, 4]


@pytest.mark.slow
def test_a_stuck_worker_is_killed_after_the_stall_timeout():
    t0 = time.perf_counter()
    with WorkerPool(2, stall_timeout=1.0) as pool:
        out = _outcomes(pool, _stuck, 3)
    assert time.perf_counter() - t0 < 30
    assert out[1].ok is False and "sent nothing for 1 s (stuck); killed" in out[1].error
    assert out[0].value == 0 and out[2].value == 2


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_a_ctrl_c_while_a_worker_starts_is_not_lost(monkeypatch):
    """A Ctrl-C that falls inside the start of a worker reaches the parent as KeyboardInterrupt (the
    parent ignored SIGINT there before and the Ctrl-C was lost: the command ran on), and the worker
    started is not left behind.  (Python's own SIGINT handler, as in a
    command run from a terminal: a pytest-xdist worker ignores SIGINT.)"""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with WorkerPool(1) as pool:
            start = pool._ctx.Process.start

            def interrupted_start(proc):
                os.kill(os.getpid(), signal.SIGINT)          # what a terminal sends, inside the window
                return start(proc)

            with monkeypatch.context() as m:
                m.setattr(pool._ctx.Process, "start", interrupted_start)
                with pytest.raises(KeyboardInterrupt):
                    pool._spawn()
                    time.sleep(2.0)                          # (delivered at the latest when unblocked)
            procs = [w["proc"] for w in pool._workers]
    finally:
        signal.signal(signal.SIGINT, previous)
    assert all(not p.is_alive() for p in procs)


def test_bad_pool_arguments_are_config_errors():
    with pytest.raises(ConfigError, match=r"jobs must be an integer >= 1, got 0"):
        WorkerPool(0)
    with pytest.raises(ConfigError, match=r"stall_timeout must be > 0 s or None"):
        WorkerPool(2, stall_timeout=-1)


def test_a_sweep_chunk_that_fails_is_counted_not_written_and_retried_by_the_rerun(tmp_path, monkeypatch):
    import importlib

    from mitigate.sweep import sweep
    ex = importlib.import_module("mitigate.sweep.execute")     # (mitigate.sweep is also the function)

    sc_path = tmp_path / "s.toml"
    sc_path.write_text('[scenario]\nname = "s"\nduration = 1.0\n[inputs]\nomega_ref = "30 rpm"\nn1 = 20.0\n')
    real = ex.run_chunk

    def flaky(task):
        if task.key == "rest_00001":
            raise RuntimeError("chunk exploded")
        return real(task)

    monkeypatch.setattr(ex, "run_chunk", flaky)
    kw = dict(out=tmp_path / "o", workers=1, stability=False, maps=False, duration=1.0, chunk=2)
    res = sweep(sc_path, ["n1=5:40:4"], **kw)
    assert res.status is Status.FAILED and res.computed == 1
    assert res.message.startswith("1 chunk(s) failed and were not written (the first: rest_00001: RuntimeError: "
                                  "chunk exploded); rerun the same command to retry them")
    assert np.isnan(res.maps["rest"]["amplitude"][2:]).all() and np.isfinite(res.maps["rest"]["amplitude"][:2]).all()
    monkeypatch.setattr(ex, "run_chunk", real)
    res = sweep(sc_path, ["n1=5:40:4"], **kw)
    assert res.computed == 1 and res.reused == 1 and res.status is not Status.FAILED


# ----------------------------------------------------------------------------- trust of compiled code
@pytest.fixture
def cache(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv("STICKSLIP_CACHE", str(d))
    return d


def _fn():
    x = ca.SX.sym("x")
    return ca.Function("faults_trust", [x], [2 * ca.sin(x)])


needs_cc = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler")


@needs_cc
def test_the_cache_is_created_0700_and_each_library_has_a_matching_sidecar(cache):
    so = codegen.compile_cached(_fn())
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700
    side = so.with_name(so.name + ".sha256")
    assert side.is_file() and codegen.verify_library(so)
    assert float(codegen.load_compiled(_fn())["faults_trust"](0.5)) == pytest.approx(2 * np.sin(0.5))


@needs_cc
def test_a_tampered_library_is_rebuilt_never_loaded(cache):
    so = codegen.compile_cached(_fn())
    good = so.read_bytes()
    so.write_bytes(good[:-16] + b"\0" * 16)                 # someone changed the code
    assert not codegen.verify_library(so)
    again = codegen.compile_cached(_fn())
    assert again == so and so.read_bytes() == good          # rebuilt (builds are byte-for-byte the same)
    so.with_name(so.name + ".sha256").unlink()              # a library without its sidecar: not trusted
    assert not codegen.verify_library(so)
    codegen.compile_cached(_fn())
    assert codegen.verify_library(so)


@needs_cc
@pytest.mark.parametrize("mode", [0o777, 0o770])
def test_a_cache_others_can_write_is_refused(cache, mode):
    cache.mkdir(mode=0o700)
    os.chmod(cache, mode)
    with pytest.raises(RuntimeError, match=r"is writable by (others|its group) .*refusing to load code from it"):
        codegen.compile_cached(_fn())
    assert codegen.compiled_or_none(_fn()) is None           # callers keep the uncompiled Function
    assert not list(cache.glob("*.so"))


@needs_cc
def test_a_cache_of_another_user_is_refused(cache, monkeypatch):
    cache.mkdir(mode=0o700)
    monkeypatch.setattr(os, "getuid", lambda: os.stat(cache).st_uid + 1)
    with pytest.raises(RuntimeError, match=r"belongs to user id .*refusing to load code from it"):
        codegen.compile_cached(_fn())
