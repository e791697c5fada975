"""Sweep chunks: the exact plant batched over points and time, and the reduction of each run.

The plant step :func:`models.plant.hybrid_step_function` is compiled once to C (gcc, on-disk cache
keyed by the source hash; the CasADi VM without a compiler), accumulated over blocks of time
steps (``mapaccum``) and mapped over the points of a chunk (``map``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from models.codegen import compiled_or_none
from models.plant.hybrid import hybrid_step_function
from models.status import Status
from mitigate.metrics import SweepWindow, columns, evaluate
from mitigate.record import RunRecord, SweepPoint

__all__ = ["batched_step", "ChunkTask", "run_chunk", "sweep_metrics"]


def sweep_metrics() -> tuple[str, ...]:
    """The metrics of a sweep point: the registry's columns of a sweep
    (:func:`mitigate.metrics.columns` ``("sweep")``)."""
    return tuple(m.name for m in columns("sweep"))


_FN_CACHE: dict = {}


def _model_key(model) -> str:
    return hashlib.sha256(repr(model.spec).encode()).hexdigest()[:16]


def batched_step(model, dt: float, nsub: int, block: int, n_points: int, backend: str = "compiled",
                 quasi_static: bool = False):
    """``G(x0, theta0, U, P) -> (X, Theta)``: ``block`` hybrid plant steps for ``n_points`` points.

    Shapes: x0 (nx, n), U (nu, block*n) (point-major), P (n_p, n); X (nx, block*n),
    column ``j*block + k`` is point ``j`` after step ``k+1``.
    """
    key = (_model_key(model), float(dt), int(nsub), backend, bool(quasi_static))
    F = _FN_CACHE.get(key)
    if F is None:
        F = hybrid_step_function(model, dt, nsub, quasi_static=quasi_static)
        if backend == "compiled":
            F = compiled_or_none(F) or F
        _FN_CACHE[key] = F
    gkey = key + (int(block), int(n_points))
    G = _FN_CACHE.get(gkey)
    if G is None:
        acc = F.mapaccum("acc", int(block), [0, 1], [0, 1])
        # the parameters are constant over the block: one column per point, repeated by map's broadcasting
        xs = ca.MX.sym("x", F.size1_in(0), 1)
        th = ca.MX.sym("th", 1, 1)
        us = ca.MX.sym("u", F.size1_in(2), int(block))
        ps = ca.MX.sym("p", F.size1_in(3), 1)
        X, T = acc(xs, th, us, ca.repmat(ps, 1, int(block)))
        one = ca.Function("block", [xs, th, us, ps], [X, T], ["x", "theta_ref", "u", "p"], ["X", "Theta"])
        G = one.map(int(n_points))
        _FN_CACHE[gkey] = G
    return G


@dataclass(frozen=True)
class ChunkTask:
    """Everything a worker needs to run one chunk of points (picklable, no CasADi objects)."""

    key: str
    indices: np.ndarray          # (m,) point indices into the plan
    model: Any                   # the plant's RigModel (pickles as its spec)
    start: str                   # rest | sliding
    dt: float
    nsub: int
    block: int
    settle_steps: int
    U: np.ndarray                # (n_steps, nu) programmed input
    u_cols: tuple[int, ...]
    u_vals: np.ndarray           # (m, len(u_cols))
    P: np.ndarray                # (m, n_p)
    speed_index: int
    amp_index: int
    threshold: float
    stuck_threshold: float
    backend: str = "compiled"
    perturbation: float = 0.0    # [rad/s] added to the contact speeds of a sliding start
    controller: Any = None       # (scenario, controller index, duration [s]) for closed-loop sweeps
    kind: str = "simulate"       # simulate | stability (linear stability of steady sliding)
    params: Any = None           # the scenario's plant ParameterSet (for kind="stability")
    quasi_static: bool = False   # a DC motor's current quasi-static (models.discretise.integration)
    scenario: str = ""           # the scenario's name (the points' records)

    def point(self, j: int) -> SweepPoint:
        """Which run point ``j`` of the chunk is."""
        ctrl = self.controller[0].controllers[self.controller[1]].name if self.controller is not None else ""
        return SweepPoint(self.scenario, ctrl, self.start, int(self.indices[j]))


def _x0(model, start, u, pvec, perturbation=0.0):
    if start == "rest":
        return np.zeros(model.nx), True
    try:
        params = model.published().with_vector(model.param_names, pvec)
        x = model.steady_sliding(u, params)
        # a small kick so that a linearly unstable sliding state does leave (the exact plant would sit on it)
        x[list(model.contacts)] += perturbation
        return x, bool(np.all(np.isfinite(x)))
    except Exception:  # noqa: BLE001 - a failed equilibrium search marks the point, it does not stop the sweep
        return np.zeros(model.nx), False


def _record(task: ChunkTask, j: int, speed: np.ndarray, amp: np.ndarray, started: bool,
            failed: str = "") -> RunRecord:
    """The record of point ``j``: the registry's sweep metrics over its window after the settling time
    (NaN when the run failed or left the finite numbers)."""
    if not failed and not (np.all(np.isfinite(speed)) and np.all(np.isfinite(amp))):
        failed = "non-finite state"
    if failed:
        return RunRecord(task.point(j), Status.FAILED, failed, {k: float("nan") for k in sweep_metrics()})
    values = evaluate(SweepWindow(speed, amp, task.dt, task.threshold, task.stuck_threshold))
    if not started:          # it ran from rest instead: its numbers are kept, the point is not what was asked
        return RunRecord(task.point(j), Status.FAILED, "no steady sliding to start from (ran from rest)", values)
    return RunRecord(task.point(j), Status.OK, "ok", values)


def run_chunk(task: ChunkTask) -> list[RunRecord] | dict[str, np.ndarray]:
    """Simulate one chunk of points: a :class:`mitigate.record.RunRecord` per point (its
    :func:`sweep_metrics`); a stability chunk gives the columns ``index`` and ``max_real``."""
    if task.kind == "stability":
        return _run_chunk_stability(task)
    if task.controller is not None:
        return _run_chunk_closed_loop(task)
    model = task.model
    m = len(task.indices)
    n_steps = task.U.shape[0]
    Uall = np.repeat(task.U[None, :, :], m, axis=0)           # (m, n_steps, nu)
    if task.u_cols:
        Uall[:, :, list(task.u_cols)] = task.u_vals[:, None, :]
    x = np.empty((model.nx, m))
    started = np.ones(m, dtype=bool)
    for j in range(m):
        x[:, j], started[j] = _x0(model, task.start, Uall[j, 0], task.P[j], task.perturbation)
    th = np.zeros((1, m))
    Pt = task.P.T.copy()
    keep = n_steps - task.settle_steps
    spd = np.empty((m, keep))
    amp = np.empty((m, keep))
    k = 0
    while k < n_steps:
        b = min(task.block, n_steps - k)
        G = batched_step(task.model, task.dt, task.nsub, b, m, task.backend, task.quasi_static)
        Ub = Uall[:, k:k + b, :].transpose(2, 0, 1).reshape(model.nu, m * b)
        X, T = G(x, th, Ub, Pt)
        X = np.asarray(X).reshape(model.nx, m, b)
        # record steps k+1 .. k+b whose sample index is >= settle_steps + 1
        lo = max(task.settle_steps + 1 - (k + 1), 0)
        if lo < b:
            dst = k + 1 + lo - (task.settle_steps + 1)
            spd[:, dst:dst + b - lo] = X[task.speed_index, :, lo:]
            amp[:, dst:dst + b - lo] = X[task.amp_index, :, lo:]
        x = X[:, :, -1]
        th = np.asarray(T).reshape(1, m, b)[:, :, -1]
        k += b
    return [_record(task, j, spd[j], amp[j], bool(started[j])) for j in range(m)]


def _run_chunk_stability(task: ChunkTask) -> dict[str, np.ndarray]:
    from models.stability import sliding_stability
    model = task.model
    out = np.full(len(task.indices), np.nan)
    for j in range(len(task.indices)):
        u = task.U[0].copy()
        u[list(task.u_cols)] = task.u_vals[j]
        try:
            out[j] = sliding_stability(model, task.params.with_vector(task.params.names(), task.P[j]), u)[1]
        except Exception:  # noqa: BLE001 - no steady sliding (e.g. zero speed): leave NaN
            pass
    return {"index": np.asarray(task.indices, dtype=float), "max_real": out}


def _run_chunk_closed_loop(task: ChunkTask) -> list[RunRecord]:
    """Closed loop per point (``mitigate.closedloop``): the scenario with the point's constant inputs and
    plant parameters, its estimator and the named controller (which keeps the NOMINAL model)."""
    import dataclasses

    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.profiles import Profile
    from models.plant import Plant

    sc0, index, duration = task.controller
    model = task.model
    out = []
    for j in range(len(task.indices)):
        inputs = dict(sc0.inputs)
        for c, v in zip(task.u_cols, task.u_vals[j]):
            inputs[model.inputs[c]] = Profile("constant", (0.0,), (float(v),))
        params = sc0.plant_params.with_vector(sc0.plant_params.names(), task.P[j])
        sim = dataclasses.replace(sc0.sim, dt=task.dt, nsub=task.nsub, start=task.start)
        sc = sc0.replace(inputs=inputs, plant_params=params, sim=sim, dt=task.dt, duration=duration)
        u0 = sc.programme(0.0)
        x0, started = _x0(model, task.start, u0, task.P[j], task.perturbation)
        plant = Plant(model, params, sim, sensors=sc.sensors, x0=x0, u0=u0, drift=sc.drift)
        res = run_closed_loop(sc, make_controller(sc.controllers[index], context_for(sc, index)), plant=plant)
        X = np.asarray(res.x)
        if not res.success or X.shape[0] < task.settle_steps + 4:
            why = res.message if not res.success else "the run ended before the settling time"
            out.append(_record(task, j, X[:0, 0], X[:0, 0], started, failed=why or "failed"))
            continue
        out.append(_record(task, j, X[task.settle_steps + 1:, task.speed_index],
                           X[task.settle_steps + 1:, task.amp_index], started))
    return out
