"""The worker processes of ``mitigate run``, ``sweep`` and ``benchmark``: one pool, in one place.

:class:`WorkerPool` runs independent tasks (``fn(*args)``, picklable) in at most ``jobs``
spawned processes (``jobs = 1``: in this process, the same API) and yields each task's
:class:`Finished` as it finishes.  What it guarantees:

- **A failing task fails alone.**  An exception in a task, a task whose worker dies (``os._exit``,
  a crash, a kill) or stalls (no message for ``stall_timeout`` seconds: a call stuck in C code that
  the per-call timeout of :mod:`models.plugins` cannot interrupt; the worker is killed) gives that
  task a :class:`Finished` with ``ok = False`` and the reason; the other tasks go on (a new worker
  replaces a lost one).
- **No worker outlives the command.**  Each worker asks the kernel to kill it when its parent
  dies (Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)``, set in the worker before anything else, and a
  check that the parent is still the one that started it), and exits when its pipe to the parent
  closes; no ``multiprocessing.Manager`` (a server process of its own) is used.  So a
  ``kill -9`` of the command leaves no process behind (the resource tracker exits once its last
  holder is gone).  Ctrl-C reaches only the parent (the workers ignore SIGINT); the pool then
  kills its workers and the command ends with "interrupted".
- **Clean output.**  A worker's stdout is its stderr: a plug-in that prints cannot corrupt
  ``--json`` on the parent's stdout.

A program read from stdin (``python - < script.py``) cannot be imported again by a spawned worker,
and a script file whose top level calls ``run()``/``benchmark()``/``sweep()`` outside an
``if __name__ == "__main__":`` block would be run again by each spawned worker (multiprocessing's
spawn rule): in both cases the tasks run in the program's own process (the same results, one
core).  A guarded script, a module run with ``-m`` from its guard, and the CLI get the workers.

Each worker talks to the parent over its own pipe (a killed worker cannot corrupt a shared
queue).  Inside a task, :func:`report` sends a progress count to the parent (a no-op outside a
pool), which calls ``on_progress(index, count)``.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing as mp
from multiprocessing import resource_tracker
import os
import signal
import sys
import time
from dataclasses import dataclass
from multiprocessing.connection import wait
from typing import Any, Callable, Iterator, Sequence

from models.errors import ConfigError
from models.plugins import describe
from models.portable import pin as pin_blas

__all__ = ["WorkerPool", "Finished", "report", "die_with_parent"]

PR_SET_PDEATHSIG = 1
_reporter: Callable[[int], None] | None = None


@dataclass(frozen=True)
class Finished:
    """A task that finished: ``value`` if ``ok``, else ``error`` (one line: why).  (Not a result with a
    :class:`models.status.Status`: a task's own value carries that.)"""

    index: int
    ok: bool
    value: Any = None
    error: str = ""


#: a worker sends progress at most this often [s] (each message wakes the parent: fewer switches)
REPORT_EVERY = 0.25
_last_report = [0.0]


def report(count: int) -> None:
    """Tell the parent how far the current task is (e.g. samples done); a no-op outside a pool.
    In a worker at most every :data:`REPORT_EVERY` seconds (a heartbeat for the stall watchdog)."""
    if _reporter is not None:
        now = time.monotonic()
        if now - _last_report[0] >= REPORT_EVERY:
            _last_report[0] = now
            _reporter(int(count))


def die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux); exit now if the
    parent is already gone (it died before the request was made)."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:
        os._exit(1)


def _worker_main(conn, parent_pid: int) -> None:
    """A worker: run tasks received on ``conn`` until told to stop or the parent is gone."""
    global _reporter
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)        # Ctrl-C is the parent's to handle
    if hasattr(signal, "pthread_sigmask"):               # born with it blocked (WorkerPool._spawn)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:                                               # the parent's stdout is for its --json only
        sys.stdout.flush()
        os.dup2(2, 1)
    except OSError:
        pass
    sys.stdout = sys.stderr
    try:
        conn.send(("ready", None, None))               # the stall clock starts now, not at the spawn
    except OSError:
        return
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        index, fn, args = msg
        conn.send(("start", index, None))
        _reporter = lambda k, i=index: conn.send(("progress", i, k))  # noqa: E731
        try:
            value = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - a task's failure is its outcome, never the pool's
            # (also KeyboardInterrupt: a worker ignores SIGINT, so only the task's own code can raise it)
            out = ("error", index, describe(exc))
        else:
            out = ("done", index, value)
        _reporter = None
        try:
            conn.send(out)
        except (BrokenPipeError, EOFError, OSError):
            return
        except Exception as exc:  # noqa: BLE001 - an unpicklable result
            conn.send(("error", index, f"the result could not be sent back: {describe(exc)}"))


def _main_importable() -> bool:
    """Whether a spawned worker can import this program's ``__main__`` as it must (a module run with
    ``-m``, a script file, or an interactive session) without running the call that starts the pool
    again; not a script read from stdin, nor a call from a script's unguarded top level: then the
    tasks run in this process."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None:
        return True                                   # interactive: nothing to import again
    if not os.path.isfile(path):
        return False                                  # python - < script.py
    return _called_from_main_guard(main, path)


def _called_from_main_guard(main, path: str) -> bool:
    """Whether ``__main__``'s top-level code is not running, or runs this call from inside an
    ``if __name__ == "__main__":`` block (what a spawned worker, importing the file as
    ``__mp_main__``, skips)."""
    import ast

    f = sys._getframe()
    while f is not None and not (f.f_code.co_name == "<module>" and f.f_globals is vars(main)):
        f = f.f_back
    if f is None:
        return True                                   # the script's top level has finished (or is not ours)
    try:
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
    except (OSError, SyntaxError, ValueError):
        return False

    def is_main_test(t) -> bool:
        return (isinstance(t, ast.Compare) and len(t.ops) == 1 and isinstance(t.ops[0], ast.Eq)
                and {ast.dump(t.left), ast.dump(t.comparators[0])}
                == {ast.dump(ast.Name("__name__", ast.Load())), ast.dump(ast.Constant("__main__"))})

    line = f.f_lineno
    return any(isinstance(n, ast.If) and is_main_test(n.test) and n.lineno <= line <= (n.end_lineno or n.lineno)
               for n in tree.body)


def _exit_reason(code: int | None) -> str:
    if code is None:
        return "did not exit"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class WorkerPool:
    """Run tasks in ``jobs`` worker processes (module docstring).

    Parameters
    ----------
    jobs : number of worker processes; 1 runs every task in this process
    stall_timeout : kill a worker that sent nothing for this long while on a task [s]
        (None: never); the task's outcome says so

    Use as a context manager; :meth:`map` yields outcomes as tasks finish::

        with WorkerPool(2) as pool:
            for out in pool.map(run_one, [(sc, 0), (sc, 1)]):
                ...
    """

    def __init__(self, jobs: int, *, stall_timeout: float | None = None):
        if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
            raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
        if stall_timeout is not None and not stall_timeout > 0:
            raise ConfigError(f"stall_timeout must be > 0 s or None, got {stall_timeout!r}")
        self.jobs = jobs
        self.stall_timeout = stall_timeout
        self._ctx = mp.get_context("spawn")
        self._workers: list[dict] = []

    # ------------------------------------------------------------------ processes
    def _spawn(self) -> dict:
        parent, child = self._ctx.Pipe(duplex=True)
        p = self._ctx.Process(target=_worker_main, args=(child, os.getpid()), daemon=True,
                              name="stickslip-worker")
        # The worker starts with SIGINT blocked (the signal mask is inherited through fork and exec), so a
        # Ctrl-C while it is still importing does not print a traceback from it; its first act is to
        # ignore SIGINT and unblock it (_worker_main).  The parent only blocks SIGINT in this thread
        # meanwhile and keeps its handler: a Ctrl-C in that window reaches the handler (through another
        # thread, or here when unblocked).  Ignoring it in the parent instead, as before, lost a Ctrl-C
        # that fell in the window (tests/test_faults_processes.py sends one there).  The spawn context's
        # resource tracker, started with the first process, unblocks SIGINT when it is up: started first.
        resource_tracker.ensure_running()
        pin_blas()                      # the worker loads OpenBLAS with the portable kernels (models/portable.py)
        sigmask = getattr(signal, "pthread_sigmask", None)
        mask = sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if sigmask is not None else None
        try:
            p.start()
        except BaseException:           # (a Ctrl-C inside start: no worker left behind)
            if p.pid is not None:
                p.kill()
                p.join(timeout=5.0)
            raise
        finally:
            if mask is not None:
                sigmask(signal.SIG_SETMASK, mask)
        child.close()
        w = {"proc": p, "conn": parent, "task": None, "last": time.monotonic(), "ready": False}
        self._workers.append(w)
        return w

    def _retire(self, w: dict, kill: bool) -> None:
        p = w["proc"]
        if kill and p.is_alive():
            p.kill()
        try:
            w["conn"].close()
        except OSError:
            pass
        p.join(timeout=5.0)
        if w in self._workers:
            self._workers.remove(w)

    def close(self) -> None:
        """Stop every worker (asked first, then killed); idempotent."""
        for w in list(self._workers):
            if w["task"] is None and w["proc"].is_alive():
                try:
                    w["conn"].send(None)
                except OSError:
                    pass
        deadline = time.monotonic() + 2.0
        for w in list(self._workers):
            w["proc"].join(timeout=max(0.0, deadline - time.monotonic()))
            self._retire(w, kill=True)

    def __enter__(self) -> "WorkerPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ tasks
    def map(self, fn: Callable, tasks: Sequence[tuple], *,
            on_progress: Callable[[int, int], None] | None = None) -> Iterator[Finished]:
        """Run ``fn(*args)`` for every ``args`` of ``tasks``; yield a :class:`Finished` per task
        as it finishes (``Finished.index``: its position in ``tasks``)."""
        global _reporter
        tasks = list(tasks)
        if self.jobs == 1 or len(tasks) <= 1 and self.stall_timeout is None or not _main_importable():
            for i, args in enumerate(tasks):
                _reporter = (lambda k, i=i: on_progress(i, k)) if on_progress is not None else None
                try:
                    with contextlib.redirect_stdout(sys.stderr):     # as as in a worker: stdout is for --json
                        value = fn(*args)
                except KeyboardInterrupt:
                    raise
                except Exception as exc:  # noqa: BLE001 - a task's failure is its outcome
                    yield Finished(i, False, error=describe(exc))
                else:
                    yield Finished(i, True, value)
                finally:
                    _reporter = None
            return
        todo = list(range(len(tasks)))[::-1]
        left = len(tasks)
        try:
            while left:
                while todo and sum(w["task"] is None for w in self._workers) < len(todo) \
                        and len(self._workers) < min(self.jobs, left):
                    self._spawn()                    # every worker needed, at once
                for w in list(self._workers):
                    if w["task"] is None and todo:
                        i = todo.pop()
                        try:
                            w["conn"].send((i, fn, tasks[i]))
                        except (BrokenPipeError, EOFError, ConnectionError):   # an idle worker that died
                            todo.append(i)
                            self._retire(w, kill=True)
                            continue
                        w["task"], w["last"] = i, time.monotonic()
                for w in [w for w in self._workers if w["task"] is None]:
                    if not todo:                     # nothing left for it
                        try:
                            w["conn"].send(None)
                        except OSError:
                            pass
                        self._retire(w, kill=False)
                busy = [w for w in self._workers if w["task"] is not None]
                ready = wait([w["conn"] for w in busy] + [w["proc"].sentinel for w in busy], timeout=0.5)
                for w in busy:
                    i = w["task"]
                    if w["conn"] in ready:
                        try:
                            kind, idx, payload = w["conn"].recv()
                        except (EOFError, OSError):
                            kind = None
                        if kind in ("progress", "ready", "start"):
                            w["last"], w["ready"] = time.monotonic(), True
                            if kind == "progress" and on_progress is not None:
                                on_progress(idx, payload)
                            continue
                        if kind in ("done", "error"):
                            w["task"] = None
                            left -= 1
                            yield Finished(i, kind == "done", payload if kind == "done" else None,
                                          payload if kind == "error" else "")
                            continue
                    if w["proc"].sentinel in ready or w["conn"] in ready:     # died, or closed its pipe
                        w["proc"].join(timeout=1.0)
                        why = f"its worker process died ({_exit_reason(w['proc'].exitcode)})"
                        self._retire(w, kill=True)
                        left -= 1
                        yield Finished(i, False, error=why)
                    elif self.stall_timeout is not None and w["ready"] \
                            and time.monotonic() - w["last"] > self.stall_timeout:
                        self._retire(w, kill=True)
                        left -= 1
                        yield Finished(i, False, error=f"its worker sent nothing for {self.stall_timeout:g} s "
                                                      f"(stuck); killed")
        finally:
            if left:
                self.close()
