"""Running the benchmark's runs: resumable, in local worker processes or on a Dask cluster.

Each finished run is one JSON record on disk (:class:`RunStore`, written by :meth:`RunStore.write`,
the one place that writes): a benchmark killed at any moment (Ctrl-C, ``kill -9``) and started again
with the same definition redoes only the runs that had not finished.  The runs go to the worker
processes of :class:`mitigate.workers.WorkerPool` (through :func:`pool`, the one place that makes
one: workers that die with the command, a run whose worker dies or stalls fails alone and is not
stored, so a rerun retries it) or to a Dask scheduler
(``scheduler="tcp://host:port"``, the same option as ``mitigate sweep``; the workers need this
package, and the scheduler is trusted: Dask sends pickled tasks).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from models.errors import ConfigError, DataError
from models.files import atomic_write_text
from models.status import Status
from mitigate.benchmark.plan import RunTask, task_scenario
from mitigate.record import RunRecord

__all__ = ["run_task", "RunStore", "execute", "pool", "failed_record", "commanded_inputs"]

#: environment of every worker process: one BLAS/OpenMP thread (the matrices are tiny; threads only
#: add contention), set before the workers import numpy
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def run_task(task: RunTask) -> RunRecord:
    """Run one task; its :class:`mitigate.record.RunRecord`.  A controller the rig cannot host is not
    applicable (``applicable = False``, the reason in ``message``); a controller that raises, or a run
    that diverges, is FAILED with the reason; so is a controller that commands an input it does not
    declare in ``actuated_inputs()`` (its class would not be like for like).  The actuator class is that
    of the declared inputs (:func:`actuator_class`), or, for a controller that keeps the base class's
    ``actuated_inputs`` (every input), that of the inputs its actions set."""
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.base import Controller
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.metrics import closed_loop_metrics
    from mitigate.tunables import actuator_class

    t0 = time.perf_counter()
    run = task.identity()
    sc = task_scenario(task)
    try:
        ctrl = make_controller(sc.controllers[0], context_for(sc, 0))
    except ConfigError as exc:     # the rig lacks what the controller needs: not applicable here
        return RunRecord.measured(run, Status.FAILED, str(exc), {}, elapsed=time.perf_counter() - t0,
                                  applicable=False)
    except Exception as exc:  # noqa: BLE001 - a user's controller may fail in any way: its run fails
        return RunRecord.measured(run, Status.FAILED, _one_line(exc), {}, elapsed=time.perf_counter() - t0)
    declares = type(ctrl).actuated_inputs is not Controller.actuated_inputs
    declared: tuple = ()
    try:
        declared = tuple(ctrl.actuated_inputs()) if declares else ()
        res = run_closed_loop(sc, ctrl)
        met = closed_loop_metrics(res, sc, task.metrics, task.uncontrolled)
    except Exception as exc:  # noqa: BLE001 - a controller or estimator that raises fails its run
        klass = actuator_class(sc.model, declared) if declares else ""
        return RunRecord.measured(run, Status.FAILED, _one_line(exc), {}, elapsed=time.perf_counter() - t0,
                                  actuator_class=klass)
    used = commanded_inputs(res, sc)
    klass = actuator_class(sc.model, declared if declares else used)
    extra = [n for n in used if declares and n not in declared]
    if extra:
        return RunRecord.measured(run, Status.FAILED, f"the controller commanded {', '.join(extra)}, which its "
                                  f"actuated_inputs() does not declare ({', '.join(declared) or 'none'})", met,
                                  elapsed=time.perf_counter() - t0, actuator_class=klass)
    return RunRecord.measured(run, res.status, res.message, met, elapsed=time.perf_counter() - t0,
                              actuator_class=klass)


def commanded_inputs(result, scenario) -> tuple[str, ...]:
    """The inputs a run's controller set away from the programme while it was in charge."""
    import numpy as np
    on = np.asarray(result.controller_active, bool)
    if not on.any():
        return ()
    prog = np.array([scenario.programme(t) for t in result.t[on]]).reshape(int(on.sum()), -1)
    out = []
    for name, cmd in result.commands.items():
        c = np.asarray(cmd, float)[on]
        p = prog[:, scenario.model.inputs.index(name)]
        if np.any(np.isfinite(c) & (c != p)):
            out.append(name)
    return tuple(out)


def failed_record(task: RunTask, why: str) -> RunRecord:
    """The record of a run that could not finish in its worker (the worker died or stalled): FAILED
    with the reason (:func:`execute` does not store it: a rerun retries it)."""
    return RunRecord.measured(task.identity(), Status.FAILED, " ".join(str(why).split())[:300], {}, elapsed=0.0)


def _one_line(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())[:300]


class RunStore:
    """The folder of finished runs: ``manifest.json`` (the definition and its hash) and
    ``runs/<scenario>/<controller>/p<k>_s<j>.json``, each written atomically and durably.

    Parameters
    ----------
    root : folder
    definition : JSON-serialisable definition of the benchmark (suite file contents, phases,
        seeds, options); a folder holding a different definition is refused unless ``force``
    force : discard a different definition's runs
    """

    def __init__(self, root, definition: Mapping[str, Any], *, force: bool = False):
        from mitigate.sweep.store import definition_hash, manifest_hash
        self.root = Path(root)
        self.run_dir = self.root / "runs"
        self.hash = definition_hash(definition)
        man = self.root / "manifest.json"
        old = manifest_hash(self.root, "benchmark", "force")
        if old is not None and old != self.hash:
            if not force:
                raise ConfigError(f"{self.root} holds the runs of a different benchmark (hash {old}, "
                                  f"this one {self.hash}); refusing to mix them (pass force=True)")
            shutil.rmtree(self.run_dir, ignore_errors=True)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(man, json.dumps({"hash": self.hash, "definition": definition}, indent=2, default=str) + "\n",
                          overwrite=True, durable=True)

    def path(self, key: str) -> Path:
        return self.run_dir / f"{key}.json"

    def done(self) -> set[str]:
        """Keys of the runs on disk (not the hidden ``.<run>.json.tmp<pid>.json`` of a write a
        ``kill -9`` cut short: :func:`models.files.atomic_path`)."""
        return {str(p.relative_to(self.run_dir).with_suffix("")) for p in self.run_dir.rglob("*.json")
                if not p.name.startswith(".")}

    def write(self, record: RunRecord) -> Path:
        """Write one finished run (the only function that writes a run's result)."""
        p = self.path(record.run.key)
        p.parent.mkdir(parents=True, exist_ok=True)
        return atomic_write_text(p, json.dumps(record.to_json()) + "\n", overwrite=True, durable=True)

    def read(self, key: str) -> RunRecord:
        """The record of run ``key`` (written by :meth:`write`, or by a version before the records
        were typed: :meth:`mitigate.record.RunRecord.from_json`)."""
        p = self.path(key)
        try:
            data = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise DataError(f"{p}: unreadable run record ({exc}); delete it to rerun that run") from None
        try:
            return RunRecord.from_json(data, str(p))
        except DataError as exc:
            raise DataError(f"{exc}; delete it to rerun that run") from None


def pool(workers: int):
    """The benchmark's local pool (runs, reference runs, tuning workers): a
    :class:`mitigate.workers.WorkerPool` of ``workers`` processes with one BLAS thread each."""
    from mitigate.runner import STALL_TIMEOUT
    from mitigate.workers import WorkerPool
    for k, v in WORKER_ENV.items():      # inherited by the spawned workers, before they import numpy
        os.environ.setdefault(k, v)
    return WorkerPool(workers, stall_timeout=STALL_TIMEOUT)


def execute(tasks: Iterable[RunTask], *, store: RunStore | None = None, jobs: int = 1, scheduler: str | None = None,
            client=None, progress: bool = False, desc: str = "benchmark",
            on_record: Callable[[RunRecord], None] | None = None) -> dict[str, RunRecord]:
    """Run ``tasks`` (skipping those ``store`` has) and return ``{key: record}`` for all of them.

    Parameters
    ----------
    store : a :class:`RunStore` to resume from and write to (None: keep the records in memory)
    jobs : local worker processes (1: in this process)
    scheduler, client : a Dask scheduler address or an existing ``distributed.Client`` (overrides jobs)
    progress : a tqdm bar (on stderr)
    """
    from tqdm import tqdm

    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    tasks = list(tasks)
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        raise ConfigError("two benchmark runs share a key (controller or scenario names that differ only in "
                          "punctuation or case)")
    done = store.done() if store is not None else set()
    out = {k: store.read(k) for k in keys if k in done} if store is not None else {}
    pending = [t for t in tasks if t.key not in out]
    bar = tqdm(total=len(tasks), initial=len(tasks) - len(pending), desc=desc, unit="run",
               disable=not progress)

    def finish(rec: RunRecord, keep: bool = True):
        if store is not None and keep:          # a run whose worker was lost is not kept: a rerun retries it
            store.write(rec)
        out[rec.run.key] = rec
        bar.update()
        if on_record is not None:
            on_record(rec)

    try:
        if not pending:
            pass
        elif client is not None or scheduler:
            from mitigate.sweep import connect_scheduler
            own = client is None
            client = client or connect_scheduler(scheduler)
            try:
                from distributed import as_completed
                futs = [client.submit(run_task, t, pure=False, key=f"bench-{t.run_seed}-{t.key}") for t in pending]
                for fut in as_completed(futs):
                    finish(fut.result())
            finally:
                if own:
                    client.close()
        elif jobs == 1 or len(pending) == 1:
            for t in pending:
                finish(run_task(t))
        else:
            with pool(min(jobs, len(pending))) as p:
                for res in p.map(run_task, [(t,) for t in pending]):
                    finish(res.value if res.ok else failed_record(pending[res.index], res.error), res.ok)
    finally:
        bar.close()
    return {k: out[k] for k in keys}
