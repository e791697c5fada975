"""Running a sweep: chunks in local processes or on a Dask cluster, resumable, assembled into maps."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from models.errors import ConfigError
from models.plant import SimOptions, plant_integration
from models.plugins import describe
from models.status import Outcome, Status
from mitigate.sweep.chunks import ChunkTask, run_chunk, sweep_metrics
from mitigate.sweep.plan import Axis, SweepPlan
from mitigate.sweep.store import SweepStore

__all__ = ["make_tasks", "closed_loop_controller", "run_sweep", "assemble", "SweepResult", "connect_scheduler", "stability_subgrid",
           "stability_indices"]


def closed_loop_controller(plan: SweepPlan, name: str | None):
    """``(scenario, controller index, run duration [s])`` of a closed-loop sweep's ``[[controllers]]``
    entry ``name`` (None for an open-loop sweep): checked before anything is written.

    Raises
    ------
    ConfigError : no entry of that name, or runs that end before the controller switches on
        (``control.start`` at or after ``sweep.duration``: it would never act)
    """
    if name is None:
        return None
    sc, o = plan.scenario, plan.options
    names = [c.name for c in sc.controllers]
    if name not in names:
        raise ConfigError(f"controller must be one of the scenario's [[controllers]] names {names}, got {name!r}")
    if sc.control.start >= o.duration:
        raise ConfigError(f"{sc.where}: sweep.duration must be > control.start = {sc.control.start:g} s for a "
                          f"closed-loop sweep (the controller would never act), got {o.duration:g} s")
    return sc, names.index(name), o.duration


def make_tasks(plan: SweepPlan, controller: str | None = None) -> list[ChunkTask]:
    """All chunks of a plan, for each start mode; keys like ``rest_00003``.

    ``controller``: name of a ``[[controllers]]`` entry for closed-loop points (:func:`closed_loop_controller`).
    """
    o = plan.options
    controller = closed_loop_controller(plan, controller)
    model = plan.scenario.plant_model
    # the integration rule at the scenario's plant parameters (one decision for the whole grid)
    qs = plant_integration(model, plan.scenario.plant_params, SimOptions(dt=o.dt, nsub=o.nsub)).quasi_static
    tasks = []
    for start in o.starts:
        for c, lo in enumerate(range(0, plan.n_points, o.chunk)):
            idx = np.arange(lo, min(lo + o.chunk, plan.n_points))
            tasks.append(ChunkTask(key=f"{start}_{c:05d}", indices=idx, model=model, start=start,
                                   dt=o.dt, nsub=o.nsub, block=o.block, settle_steps=o.settle_steps, U=plan.U,
                                   u_cols=plan.u_cols, u_vals=plan.u_vals[idx], P=plan.P[idx],
                                   speed_index=model.states.index(o.speed),
                                   amp_index=model.states.index(o.amplitude_of), threshold=o.threshold,
                                   stuck_threshold=o.stuck_threshold, backend=o.backend, controller=controller,
                                   perturbation=o.perturbation, quasi_static=qs, scenario=plan.scenario.name))
    if model.drive.sets_speed and "force" in model.input_kinds:
        idx = stability_indices(plan)
        for c, lo in enumerate(range(0, len(idx), o.chunk)):
            ii = idx[lo:lo + o.chunk]
            tasks.append(ChunkTask(key=f"stability_{c:05d}", indices=ii, model=model, start="sliding",
                                   dt=o.dt, nsub=o.nsub, block=o.block, settle_steps=o.settle_steps, U=plan.U[:1],
                                   u_cols=plan.u_cols, u_vals=plan.u_vals[ii], P=plan.P[ii], speed_index=0,
                                   amp_index=0, threshold=o.threshold, stuck_threshold=o.stuck_threshold,
                                   kind="stability", params=plan.scenario.plant_params))
    return tasks


def connect_scheduler(address: str, timeout: float = 10.0):
    """A ``distributed.Client`` for the Dask scheduler at ``address`` (imports Dask only here)."""
    try:
        from distributed import Client
    except ImportError:
        raise ConfigError("a Dask scheduler needs dask.distributed (pip install 'stickslip-workbench[dask]')") from None
    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ConfigError(f"scheduler {address}: cannot connect ({type(exc).__name__}: {exc})") from None


def stability_subgrid(plan: SweepPlan) -> tuple[np.ndarray, ...]:
    """Per axis, the indices of the values at which the sliding stability is computed."""
    S = plan.options.stability_points
    return tuple(np.unique(np.round(np.linspace(0, a.count - 1, min(a.count, S))).astype(int)) for a in plan.axes)


def stability_indices(plan: SweepPlan) -> np.ndarray:
    """Flat point indices of the stability sub-grid."""
    shape = tuple(a.count for a in plan.axes)
    sub = stability_subgrid(plan)
    mesh = np.meshgrid(*sub, indexing="ij")
    return np.ravel_multi_index(tuple(m.ravel() for m in mesh), shape)


@dataclass(frozen=True)
class SweepResult(Outcome):
    """All points of a sweep.

    Attributes
    ----------
    axes : the axes; grid : (n_points, n_axes)
    maps : {start: {metric: (count_1, ..., count_k) array}} (axis order as given) of every
        :func:`mitigate.sweep.chunks.sweep_metrics`
    statuses : {start: (count_1, ..., count_k) array of Status}: each point run's (FAILED where it
        failed, found no steady sliding to start from, or its chunk was not written)
    stability : max real part [1/s] of the sliding linearisation per point (n_points,; NaN off the
        stability sub-grid :func:`stability_subgrid`), or None
    computed, reused : numbers of chunks computed now and found on disk
    status : :meth:`Status.worst` of the point runs and chunks: Status.FAILED when some point runs
        failed or chunks were not written (``message`` says how many), else Status.OK
    """

    axes: tuple[Axis, ...]
    grid: np.ndarray
    maps: dict
    stability: np.ndarray | None
    computed: int
    reused: int
    elapsed: float
    status: Status = Status.OK
    message: str = "ok"
    files: dict = field(default_factory=dict)
    stability_subgrid: tuple = ()
    statuses: dict = field(default_factory=dict)


def run_sweep(plan: SweepPlan, store: SweepStore, *, workers: int | None = None, scheduler: str | None = None,
              client=None, controller=None, progress: bool = True, on_chunk: Callable[[str], None] | None = None,
              stability: bool = True) -> SweepResult:
    """Run the pending chunks of ``plan`` into ``store`` and assemble the maps.

    Parameters
    ----------
    workers : local worker processes (default: CPU count); 1 runs in this process
    scheduler : address of a Dask scheduler (``tcp://host:port``); chunks are sent there
    client : an existing ``distributed.Client`` (tests); overrides ``scheduler``
    stability : also compute the linear stability of steady sliding per point (``models.modal``)
    """
    t0 = time.perf_counter()
    tasks = make_tasks(plan, controller)
    if not stability:
        tasks = [t for t in tasks if t.kind != "stability"]
    done = store.done()
    pending = [t for t in tasks if t.key not in done]
    reused = len(tasks) - len(pending)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=sum(len(t.indices) for t in tasks), unit="pt", desc=f"sweep {plan.scenario.name}",
                   initial=sum(len(t.indices) for t in tasks if t.key in done))

    def finish(task, res):
        if task.kind == "simulate":
            store.write_records(task.key, res)
        else:
            store.write_chunk(task.key, res)
        if bar is not None:
            bar.update(len(task.indices))
        if on_chunk is not None:
            on_chunk(task.key)

    failed: list[str] = []
    if pending:
        if client is not None or scheduler:
            own = client is None
            if own:
                client = connect_scheduler(scheduler)
            try:
                from distributed import as_completed
                futs = {client.submit(run_chunk, t, pure=False, key=f"sweep-{store.hash}-{t.key}"): t for t in pending}
                for fut in as_completed(futs):
                    try:
                        value = fut.result()
                    except Exception as exc:  # noqa: BLE001 - a chunk's failure is counted, the others go on
                        failed.append(f"{futs[fut].key}: {describe(exc)}")
                    else:
                        finish(futs[fut], value)
            finally:
                if own:
                    client.close()
        else:
            from mitigate.workers import WorkerPool

            workers = workers or os.cpu_count() or 1
            jobs = 1 if workers <= 1 or len(pending) == 1 else min(workers, len(pending))
            with WorkerPool(jobs) as pool:
                for out in pool.map(run_chunk, [(t,) for t in pending]):
                    if out.ok:
                        finish(pending[out.index], out.value)
                    else:
                        failed.append(f"{pending[out.index].key}: {out.error}")
    if bar is not None:
        bar.close()
    result = assemble(plan, store, tasks)
    status, message = result[2], result[3]
    if failed:
        status = Status.FAILED
        message = (f"{len(failed)} chunk(s) failed and were not written (the first: {failed[0]}); rerun the same "
                   f"command to retry them; {message}")
    return SweepResult(plan.axes, plan.grid, result[0], result[1], len(pending) - len(failed), reused,
                       time.perf_counter() - t0, status, message, stability_subgrid=stability_subgrid(plan),
                       statuses=result[4])


def assemble(plan: SweepPlan, store: SweepStore, tasks):
    """Read all chunks of a finished sweep into maps and write ``results.csv``: ``(maps, stability,
    status, message, statuses)`` (:class:`SweepResult`).  A metric a chunk has no column for (declared
    after it was written) is NaN at its points."""
    shape = tuple(a.count for a in plan.axes)
    names = sweep_metrics()
    maps, statuses = {}, {}
    cols: dict[str, np.ndarray] = {a.name: plan.grid[:, i] for i, a in enumerate(plan.axes)}
    reasons: list[str] = []
    for start in plan.options.starts:
        arr = {m: np.full(plan.n_points, np.nan) for m in names}
        st = np.full(plan.n_points, Status.FAILED, dtype=object)   # a chunk that failed: its points stay FAILED
        for t in tasks:
            if t.start != start or t.kind != "simulate" or not store.chunk_path(t.key).exists():
                continue
            d = store.read_chunk(t.key)
            idx = d["index"].astype(int)
            for m in names:
                if m in d:
                    arr[m][idx] = d[m]
            st[idx] = d["status"]
            reasons += [msg for s, msg in zip(d["status"], d["message"]) if not s.success]
        maps[start] = {m: v.reshape(shape) for m, v in arr.items()}
        statuses[start] = st.reshape(shape)
        for m in names:
            cols[f"{m}_{start}"] = arr[m]
        cols[f"status_{start}"] = st
    stab = None
    stab_tasks = [t for t in tasks if t.kind == "stability"]
    if stab_tasks:
        stab = np.full(plan.n_points, np.nan)
        for t in stab_tasks:
            if not store.chunk_path(t.key).exists():
                continue
            d = store.read_chunk(t.key)
            stab[d["index"].astype(int)] = d["max_real"]
    if stab is not None:
        cols["sliding_max_real"] = stab
    points = [s for v in statuses.values() for s in v.ravel()]
    bad = sum(not s.success for s in points)
    store.write_results(cols)
    message = "ok" if bad == 0 else f"{bad} point run(s) failed (the first: {reasons[0] if reasons else 'chunk lost'})"
    # a point whose run did not succeed is a failed part of the sweep (as a failed run is of ``run()``)
    return maps, stab, Status.worst(points), message, statuses
