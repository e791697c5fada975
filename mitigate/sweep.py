"""Parameter sweeps: maps of where stick-slip appears and how large it is (seed 002, Figs. 9.31-9.33).

A sweep runs one open-loop simulation of a scenario per point of a grid over some of
its numeric fields and reduces each run, after a settling time, to stick-slip
metrics (:mod:`mitigate.metrics`).  Axes are written ``name=start:stop:count``
(``count`` points from ``start`` to ``stop`` inclusive, linear), where ``name`` is

- a model input (``n1``, ``omega_ref``, ``axial_force``, ``omega_drive``, ...): the
  scenario's profile for it is replaced by a constant [SI units];
- a plant parameter (``k1``, ``d1``, ``c``, ``K``, ...): the plant value is replaced;
- ``<param>_scale`` (e.g. ``K_scale``): the scenario's plant value is multiplied;
- ``mismatch.<param>``: the mismatch factor on the nominal value is replaced.

With a controller (``--controller NAME``, rig3 only) each point is instead one closed-loop run
of :func:`mitigate.closedloop.run_closed_loop` (estimator and controller keep the NOMINAL
model: a swept plant parameter is a plant/model mismatch for them).

Every point is run from rest and/or from steady sliding at its input
(``start = "rest" | "sliding" | "both"``); where the two differ, stick-slip exists
next to a stable steady sliding (bistability: it is triggered by disturbances).

Speed: the plant is the exact stick/slip step :func:`models.hybrid.hybrid_step_function`,
compiled once to C (gcc, on-disk cache keyed by the source hash; falls back to the
CasADi VM without a compiler), accumulated over blocks of time steps
(``mapaccum``) and mapped over the points of a chunk (``map``).  Chunks run in
worker processes, or on a Dask cluster (``scheduler``); CasADi's ``map(n, "thread", 2)``
gave no speed-up over the serial map here (benchmarks/results/sweep.md), processes do.  Results are written per
chunk by :class:`mitigate.sweepstore.SweepStore`, so an interrupted sweep resumes.  The
store's hash covers the axes, the options and the scenario file's content: editing the
scenario makes a rerun into the same folder a different sweep (refused without ``--force``).

The ``[sweep]`` table of a scenario sets defaults::

    [sweep]
    vary = ["n1=5:40:50", "omega_ref=1:8:50"]   # default axes (command-line --vary replaces them)
    start = "both"            # rest | sliding | both
    settle = 15.0             # [s] discarded before the metrics (default: half the duration)
    speed = "omega1"          # state whose speed gives severity, stuck fraction, frequency
    amplitude_of = "omega1"   # state whose half peak-to-peak is the amplitude (unit of that state)
    threshold = 0.05          # amplitude above which a point counts as a limit cycle (if also sustained:
                              # the late half of the window swings >= 80 % of the early half)
    perturbation = 0.01       # [rad/s] added to the contact speeds of a steady-sliding start
    stuck_threshold = 1e-6    # [rad/s] |speed| at or below which the body counts as stuck
    chunk = 50                # points per chunk (unit of parallelism and of resuming)
    block = 200               # time steps per compiled call
    duration = 30.0           # [s] overrides scenario.duration for the sweep
    dt = 0.01                 # [s] overrides scenario.dt
    nsub = 10                 # substeps per dt (overrides plant.nsub)
    stability_points = 20     # linear stability of steady sliding on a sub-grid of at most this many
                              # values per axis (models.modal.sliding_stability; ~60 ms per point)
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import casadi as ca

from models.codegen import load_compiled
import numpy as np

from models.errors import ConfigError
from models.plant.hybrid import hybrid_step_function
from models.rigs import get_model
from mitigate import metrics as mx
from mitigate.scenario import Scenario
from mitigate.sweepstore import SweepStore

__all__ = ["Axis", "parse_axis", "SweepOptions", "SweepPlan", "ChunkTask", "SweepResult", "plan_sweep",
           "run_chunk", "run_sweep", "batched_step", "METRICS", "options_from_scenario", "make_tasks",
           "stability_indices", "stability_subgrid", "assemble", "connect_scheduler"]

#: per-point outputs of a sweep (besides the axis values)
METRICS = ("amplitude", "severity", "stuck_fraction", "frequency", "mean_speed", "growth", "limit_cycle", "ok")

_SWEEP_KEYS = {"vary", "start", "settle", "speed", "amplitude_of", "threshold", "stuck_threshold", "chunk", "block",
               "duration", "dt", "nsub", "stability_points", "perturbation"}


# ----------------------------------------------------------------------------- axes
@dataclass(frozen=True)
class Axis:
    """One sweep axis: ``count`` linearly spaced values of ``name`` from ``start`` to ``stop``."""

    name: str
    start: float
    stop: float
    count: int

    @property
    def values(self) -> np.ndarray:
        return np.linspace(self.start, self.stop, self.count)

    def spec(self) -> str:
        return f"{self.name}={self.start:g}:{self.stop:g}:{self.count}"


def parse_axis(text: str) -> Axis:
    """Parse ``name=start:stop:count`` (e.g. ``n1=5:40:50``)."""
    if not isinstance(text, str) or "=" not in text:
        raise ConfigError(f"--vary must be name=start:stop:count (e.g. n1=5:40:50), got {text!r}")
    name, rng = text.split("=", 1)
    name = name.strip()
    parts = rng.split(":")
    if not name or len(parts) != 3:
        raise ConfigError(f"--vary must be name=start:stop:count (e.g. n1=5:40:50), got {text!r}")
    try:
        start, stop = float(parts[0]), float(parts[1])
    except ValueError:
        raise ConfigError(f"--vary {name}: start and stop must be numbers, got {parts[0]!r}, {parts[1]!r}") from None
    try:
        count = int(parts[2])
    except ValueError:
        raise ConfigError(f"--vary {name}: count must be an integer >= 1, got {parts[2]!r}") from None
    if not (math.isfinite(start) and math.isfinite(stop)):
        raise ConfigError(f"--vary {name}: start and stop must be finite, got {start}, {stop}")
    if count < 1 or (count == 1 and start != stop):
        raise ConfigError(f"--vary {name}: count must be >= 2 (or 1 with start == stop), got {count}")
    return Axis(name, start, stop, count)


# ----------------------------------------------------------------------------- options
@dataclass(frozen=True, kw_only=True)
class SweepOptions:
    """How each point is simulated and reduced (see module docstring for the meaning)."""

    start: str = "rest"
    duration: float = 30.0
    dt: float = 0.01
    nsub: int = 10
    settle: float | None = None
    speed: str = ""
    amplitude_of: str = ""
    threshold: float = 0.05
    stuck_threshold: float = 1e-6
    chunk: int = 50
    block: int = 200
    stability_points: int = 20
    perturbation: float = 0.01
    backend: str = "compiled"

    def __post_init__(self):
        if self.start not in ("rest", "sliding", "both"):
            raise ConfigError(f"sweep.start must be rest, sliding or both, got {self.start!r}")
        for n in ("duration", "dt"):
            v = getattr(self, n)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise ConfigError(f"sweep.{n} must be a finite number > 0 s, got {v!r}")
        for n in ("nsub", "chunk", "block", "stability_points"):
            v = getattr(self, n)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"sweep.{n} must be an integer >= 1, got {v!r}")
        if self.settle is not None and not (isinstance(self.settle, (int, float)) and 0 <= self.settle < self.duration):
            raise ConfigError(f"sweep.settle must be in [0, duration={self.duration}) s, got {self.settle!r}")
        for n in ("threshold", "stuck_threshold", "perturbation"):
            v = getattr(self, n)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"sweep.{n} must be a finite number >= 0, got {v!r}")
        if self.backend not in ("compiled", "vm"):
            raise ConfigError(f"sweep backend must be 'compiled' or 'vm', got {self.backend!r}")
        if int(round(self.duration / self.dt)) < 4:
            raise ConfigError(f"sweep.duration must span at least 4 samples of dt={self.dt} s, got {self.duration}")

    @property
    def n_steps(self) -> int:
        return int(round(self.duration / self.dt))

    @property
    def settle_steps(self) -> int:
        s = 0.5 * self.duration if self.settle is None else self.settle
        return min(int(round(s / self.dt)), self.n_steps - 3)

    @property
    def starts(self) -> tuple[str, ...]:
        return ("rest", "sliding") if self.start == "both" else (self.start,)


_DEFAULT_CHANNELS = {"rig3": ("omega1", "omega1"), "disc": ("omega1", "omega1"), "rig2": ("omega_d", "omega_d"),
                     "leadscrew": ("omega", "phi")}


def options_from_scenario(sc: Scenario, **overrides) -> SweepOptions:
    """Sweep options from a scenario's ``[sweep]`` table, scenario timing and keyword overrides."""
    tab = dict(sc.sweep)
    for k in tab:
        if k not in _SWEEP_KEYS:
            raise ConfigError(f"{Path(sc.path).name}: sweep.{k}: unknown key; expected one of {', '.join(sorted(_SWEEP_KEYS))}")
    speed, amp = _DEFAULT_CHANNELS[sc.model]
    kw = dict(start=tab.get("start", "rest"), duration=tab.get("duration", sc.duration), dt=tab.get("dt", sc.dt),
              nsub=tab.get("nsub", sc.sim.nsub), settle=tab.get("settle"), speed=tab.get("speed", speed),
              amplitude_of=tab.get("amplitude_of", amp), threshold=tab.get("threshold", 0.05),
              stuck_threshold=tab.get("stuck_threshold", 1e-6), chunk=tab.get("chunk", 50), block=tab.get("block", 200),
              stability_points=tab.get("stability_points", 20), perturbation=tab.get("perturbation", 0.01))
    if overrides.get("duration") is not None and overrides.get("settle") is None:
        kw["settle"] = None   # a new duration without a new settle time: discard its first half
    kw.update({k: v for k, v in overrides.items() if v is not None})
    try:
        opts = SweepOptions(**kw)
    except ConfigError as exc:
        raise ConfigError(f"{Path(sc.path).name}: {exc}") from None
    model = get_model(sc.model)
    for n in ("speed", "amplitude_of"):
        if getattr(opts, n) not in model.states:
            raise ConfigError(f"sweep.{n} must be a state of {sc.model} ({', '.join(model.states)}), "
                              f"got {getattr(opts, n)!r}")
    return opts


# ----------------------------------------------------------------------------- plan
@dataclass(frozen=True)
class SweepPlan:
    """The grid of a sweep resolved to per-point plant inputs and parameters.

    Attributes
    ----------
    axes : the axes (the grid is their Cartesian product, first axis slowest)
    grid : (n_points, n_axes) axis values per point
    U : (n_steps, nu) programmed input of the scenario (time on axis 0)
    u_cols : indices of the inputs set by axes; u_vals : (n_points, len(u_cols)) their constants
    P : (n_points, n_p) plant parameter vectors
    """

    scenario: Scenario
    options: SweepOptions
    axes: tuple[Axis, ...]
    grid: np.ndarray
    U: np.ndarray
    u_cols: tuple[int, ...]
    u_vals: np.ndarray
    P: np.ndarray

    @property
    def n_points(self) -> int:
        return self.grid.shape[0]

    def point_input(self, j: int, k: int = 0) -> np.ndarray:
        """Input of point ``j`` at step ``k``."""
        u = self.U[k].copy()
        u[list(self.u_cols)] = self.u_vals[j]
        return u

    def point_params(self, j: int):
        base = self.scenario.plant_params
        return base.with_vector(base.names(), self.P[j])

    def definition(self, controller: str | None = None) -> dict[str, Any]:
        """JSON-able definition used for the store's hash (resume only with the same one)."""
        sc = self.scenario
        return {"scenario": sc.name, "model": sc.model, "scenario_file": sc.path,
                "scenario_digest": hashlib.sha256(Path(sc.path).read_bytes()).hexdigest()[:16]
                if sc.path and Path(sc.path).is_file() else "",
                "axes": [a.spec() for a in self.axes],
                "options": {k: getattr(self.options, k) for k in self.options.__dataclass_fields__ if k != "backend"},
                "controller": controller}


def plan_sweep(sc: Scenario, axes: list[Axis] | tuple[Axis, ...], options: SweepOptions) -> SweepPlan:
    """Resolve axes against a scenario (see module docstring for the names)."""
    if not axes:
        raise ConfigError("a sweep needs at least one --vary axis (or sweep.vary in the scenario)")
    names = [a.name for a in axes]
    if len(set(names)) != len(names):
        raise ConfigError(f"--vary: each name at most once, got {names}")
    model = get_model(sc.model)
    pnames = sc.plant_params.names()
    for a in axes:
        n = a.name
        ok = (n in model.inputs or n in pnames or (n.endswith("_scale") and n[:-6] in pnames)
              or (n.startswith("mismatch.") and n[9:] in pnames))
        if not ok:
            raise ConfigError(f"--vary {n}: unknown name for model {sc.model}; expected an input "
                              f"({', '.join(model.inputs)}), a parameter ({', '.join(pnames)}), <param>_scale "
                              f"or mismatch.<param>")
    mesh = np.meshgrid(*[a.values for a in axes], indexing="ij")
    grid = np.stack([m.ravel() for m in mesh], axis=1)
    n = options.n_steps
    U = np.array([sc.input_vector(k * options.dt) for k in range(n)], dtype=float).reshape(n, model.nu)
    u_cols = tuple(model.inputs.index(a.name) for a in axes if a.name in model.inputs)
    u_axes = [i for i, a in enumerate(axes) if a.name in model.inputs]
    u_vals = grid[:, u_axes]
    base = sc.plant_params
    nominal = sc.model_params
    P = np.empty((grid.shape[0], len(pnames)))
    for j in range(grid.shape[0]):
        ch = {}
        for i, a in enumerate(axes):
            v = float(grid[j, i])
            if a.name in pnames:
                ch[a.name] = v
            elif a.name.endswith("_scale") and a.name[:-6] in pnames:
                ch[a.name[:-6]] = getattr(base, a.name[:-6]) * v
            elif a.name.startswith("mismatch."):
                ch[a.name[9:]] = getattr(nominal, a.name[9:]) * v
        try:
            P[j] = base.replace(**ch).vector() if ch else base.vector()
        except (ConfigError, TypeError, ValueError) as exc:
            raise ConfigError(f"--vary: point {dict(zip(names, grid[j]))} gives invalid parameters ({exc})") from None
    for i, a in enumerate(axes):
        if a.name in ("n1", "n2", "axial_force") and np.any(grid[:, i] < 0):
            raise ConfigError(f"--vary {a.name}: a normal/axial force must be >= 0 N, got start {a.start}, stop {a.stop}")
    return SweepPlan(sc, options, tuple(axes), grid, U, u_cols, u_vals, P)


# ----------------------------------------------------------------------------- batched plant
_FN_CACHE: dict = {}


def _compiled(F: ca.Function) -> ca.Function | None:
    """``F`` compiled to a shared library (cached on disk, :mod:`models.codegen`); None without gcc."""
    try:
        return load_compiled(F)[F.name()]
    except RuntimeError:
        return None


def batched_step(model_name: str, dt: float, nsub: int, block: int, n_points: int, backend: str = "compiled"):
    """``G(x0, theta0, U, P) -> (X, Theta)``: ``block`` hybrid plant steps for ``n_points`` points.

    Shapes: x0 (nx, n), U (nu, block*n) (point-major), P (n_p, n); X (nx, block*n),
    column ``j*block + k`` is point ``j`` after step ``k+1``.
    """
    key = (model_name, float(dt), int(nsub), backend)
    F = _FN_CACHE.get(key)
    if F is None:
        model = get_model(model_name)
        F = hybrid_step_function(model, dt, nsub)
        if backend == "compiled":
            F = _compiled(F) or F
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


# ----------------------------------------------------------------------------- chunks
@dataclass(frozen=True)
class ChunkTask:
    """Everything a worker needs to run one chunk of points (picklable, no CasADi objects)."""

    key: str
    indices: np.ndarray          # (m,) point indices into the plan
    model: str
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
    controller: Any = None       # (scenario path, controller name, duration [s]) for closed-loop sweeps
    kind: str = "simulate"       # simulate | stability (linear stability of steady sliding)
    params: Any = None           # the scenario's plant ParameterSet (for kind="stability")


def _x0(model, start, u, pvec, param_cls, perturbation=0.0):
    if start == "rest":
        return np.zeros(model.nx), True
    try:
        params = model.published().with_vector(param_cls.names(), pvec)
        x = model.steady_sliding(u, params)
        # a small kick so that a linearly unstable sliding state does leave (the exact plant would sit on it)
        x[list(model.contacts)] += perturbation
        return x, bool(np.all(np.isfinite(x)))
    except Exception:  # noqa: BLE001 - a failed equilibrium search marks the point, it does not stop the sweep
        return np.zeros(model.nx), False


def _reduce(speed: np.ndarray, amp: np.ndarray, dt: float, task: ChunkTask) -> dict[str, float]:
    if not (np.all(np.isfinite(speed)) and np.all(np.isfinite(amp))):
        return {k: float("nan") for k in METRICS[:-2]} | {"limit_cycle": float("nan"), "ok": 0.0}
    a = mx.amplitude(amp)
    # sustained, not a decaying transient: the late half of the window swings at least 80 % of the early half
    h = len(amp) // 2
    a_early, a_late = mx.amplitude(amp[:h]), mx.amplitude(amp[h:])
    growth = a_late / a_early if a_early > 0 else (1.0 if a_late == 0 else float("inf"))
    cycle = bool(a > task.threshold and growth >= 0.8)
    # a frequency is only meaningful for a limit cycle (else it is the spectrum of rounding noise)
    return {"amplitude": a, "severity": mx.severity(speed),
            "stuck_fraction": mx.stuck_fraction(speed, task.stuck_threshold),
            "frequency": mx.dominant_frequency(speed, dt) if cycle else float("nan"),
            "mean_speed": float(np.mean(speed)), "growth": float(growth), "limit_cycle": float(cycle), "ok": 1.0}


def run_chunk(task: ChunkTask) -> dict[str, np.ndarray]:
    """Simulate one chunk of points and reduce each to :data:`METRICS` (plus ``index``)."""
    if task.kind == "stability":
        return _run_chunk_stability(task)
    if task.controller is not None:
        return _run_chunk_closed_loop(task)
    model = get_model(task.model)
    m = len(task.indices)
    n_steps = task.U.shape[0]
    Uall = np.repeat(task.U[None, :, :], m, axis=0)           # (m, n_steps, nu)
    if task.u_cols:
        Uall[:, :, list(task.u_cols)] = task.u_vals[:, None, :]
    x = np.empty((model.nx, m))
    started = np.ones(m, dtype=bool)
    for j in range(m):
        x[:, j], started[j] = _x0(model, task.start, Uall[j, 0], task.P[j], model.param_cls, task.perturbation)
    th = np.zeros((1, m))
    Pt = task.P.T.copy()
    keep = n_steps - task.settle_steps
    spd = np.empty((m, keep))
    amp = np.empty((m, keep))
    k = 0
    while k < n_steps:
        b = min(task.block, n_steps - k)
        G = batched_step(task.model, task.dt, task.nsub, b, m, task.backend)
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
    rows = [_reduce(spd[j], amp[j], task.dt, task) for j in range(m)]
    out = {"index": np.asarray(task.indices, dtype=float)}
    for name in METRICS:
        out[name] = np.array([r[name] for r in rows])
    out["ok"] = out["ok"] * started
    return out


def _run_chunk_stability(task: ChunkTask) -> dict[str, np.ndarray]:
    from models.modal import sliding_stability
    model = get_model(task.model)
    out = np.full(len(task.indices), np.nan)
    for j in range(len(task.indices)):
        u = task.U[0].copy()
        u[list(task.u_cols)] = task.u_vals[j]
        try:
            out[j] = sliding_stability(model, task.params.with_vector(task.params.names(), task.P[j]), u)[1]
        except Exception:  # noqa: BLE001 - no steady sliding (e.g. zero speed): leave NaN
            pass
    return {"index": np.asarray(task.indices, dtype=float), "max_real": out}


def _run_chunk_closed_loop(task: ChunkTask) -> dict[str, np.ndarray]:
    """Closed loop per point (``mitigate.closedloop``): the scenario with the point's constant inputs and
    plant parameters, its estimator and the named controller (which keeps the NOMINAL model)."""
    import dataclasses

    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import make_controller
    from mitigate.profiles import Profile
    from mitigate.scenario import load_scenario
    from models.plant import Plant

    path, name, duration = task.controller
    sc0 = load_scenario(path)
    index = [c.name for c in sc0.controllers].index(name)
    model = get_model(task.model)
    m = len(task.indices)
    rows, started = [], np.ones(m, dtype=bool)
    for j in range(m):
        inputs = dict(sc0.inputs)
        for c, v in zip(task.u_cols, task.u_vals[j]):
            inputs[model.inputs[c]] = Profile("constant", (0.0,), (float(v),))
        params = sc0.plant_params.with_vector(sc0.plant_params.names(), task.P[j])
        sim = dataclasses.replace(sc0.sim, dt=task.dt, nsub=task.nsub, start=task.start)
        sc = sc0.replace(inputs=inputs, plant_params=params, sim=sim, dt=task.dt, duration=duration)
        u0 = np.asarray(sc.input_vector(0.0), dtype=float)
        x0, started[j] = _x0(model, task.start, u0, task.P[j], model.param_cls, task.perturbation)
        plant = Plant(model, params, sim, sensors=sc.sensors, servo=sc.servo, x0=x0, u0=u0)
        res = run_closed_loop(sc, make_controller(sc.controllers[index], sc, index), plant=plant)
        X = np.asarray(res.x)
        if not res.success or X.shape[0] < task.settle_steps + 4:
            rows.append({k: float("nan") for k in METRICS[:-2]} | {"limit_cycle": float("nan"), "ok": 0.0})
            continue
        rows.append(_reduce(X[task.settle_steps + 1:, task.speed_index], X[task.settle_steps + 1:, task.amp_index],
                            task.dt, task))
    out = {"index": np.asarray(task.indices, dtype=float)}
    for k in METRICS:
        out[k] = np.array([r[k] for r in rows])
    out["ok"] = out["ok"] * started
    return out


def make_tasks(plan: SweepPlan, controller: str | None = None) -> list[ChunkTask]:
    """All chunks of a plan, for each start mode; keys like ``rest_00003``.

    ``controller``: name of a ``[[controllers]]`` entry for closed-loop points (rig3 only).
    """
    o = plan.options
    if controller is not None:
        sc = plan.scenario
        if sc.model != "rig3":
            raise ConfigError(f"--controller: closed-loop sweeps need a rig3 scenario, got model {sc.model!r}")
        if controller not in [c.name for c in sc.controllers]:
            raise ConfigError(f"--controller must be one of the scenario's [[controllers]] names "
                              f"{[c.name for c in sc.controllers]}, got {controller!r}")
        if not sc.path:
            raise ConfigError("--controller: the scenario must come from a file (workers reload it)")
        controller = (str(Path(sc.path).resolve()), controller, o.duration)
    model = get_model(plan.scenario.model)
    tasks = []
    for start in o.starts:
        for c, lo in enumerate(range(0, plan.n_points, o.chunk)):
            idx = np.arange(lo, min(lo + o.chunk, plan.n_points))
            tasks.append(ChunkTask(key=f"{start}_{c:05d}", indices=idx, model=plan.scenario.model, start=start,
                                   dt=o.dt, nsub=o.nsub, block=o.block, settle_steps=o.settle_steps, U=plan.U,
                                   u_cols=plan.u_cols, u_vals=plan.u_vals[idx], P=plan.P[idx],
                                   speed_index=model.states.index(o.speed),
                                   amp_index=model.states.index(o.amplitude_of), threshold=o.threshold,
                                   stuck_threshold=o.stuck_threshold, backend=o.backend, controller=controller,
                                   perturbation=o.perturbation))
    if stability_available():
        idx = stability_indices(plan)
        for c, lo in enumerate(range(0, len(idx), o.chunk)):
            ii = idx[lo:lo + o.chunk]
            tasks.append(ChunkTask(key=f"stability_{c:05d}", indices=ii, model=plan.scenario.model, start="sliding",
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
        raise ConfigError("--scheduler needs dask.distributed (pip install 'stickslip-workbench[dask]')") from None
    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ConfigError(f"--scheduler {address}: cannot connect ({type(exc).__name__}: {exc})") from None


def stability_available() -> bool:
    """Whether ``models.modal.sliding_stability`` (helper H1) is importable."""
    try:
        from models.modal import sliding_stability  # noqa: F401
    except ImportError:
        return False
    return True


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


# ----------------------------------------------------------------------------- running
@dataclass(frozen=True)
class SweepResult:
    """All points of a sweep.

    Attributes
    ----------
    axes : the axes; grid : (n_points, n_axes)
    maps : {start: {metric: (count_1, ..., count_k) array}} (axis order as given)
    stability : max real part [1/s] of the sliding linearisation per point (n_points,; NaN off the
        stability sub-grid :func:`stability_subgrid`), or None
    computed, reused : numbers of chunks computed now and found on disk
    """

    axes: tuple[Axis, ...]
    grid: np.ndarray
    maps: dict
    stability: np.ndarray | None
    computed: int
    reused: int
    elapsed: float
    status: str = "ok"
    success: bool = True
    files: dict = field(default_factory=dict)
    stability_subgrid: tuple = ()


def _init_worker():
    # one CasADi thread per process; the process pool is the parallelism
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def _local_executor(workers: int):
    import concurrent.futures as cf
    import multiprocessing as mp
    return cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_init_worker)


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
        store.write_chunk(task.key, res)
        if bar is not None:
            bar.update(len(task.indices))
        if on_chunk is not None:
            on_chunk(task.key)

    if pending:
        if client is not None or scheduler:
            own = client is None
            if own:
                client = connect_scheduler(scheduler)
            try:
                from distributed import as_completed
                futs = {client.submit(run_chunk, t, pure=False, key=f"sweep-{store.hash}-{t.key}"): t for t in pending}
                for fut in as_completed(futs):
                    finish(futs[fut], fut.result())
            finally:
                if own:
                    client.close()
        else:
            workers = workers or os.cpu_count() or 1
            if workers <= 1 or len(pending) == 1:
                for t in pending:
                    finish(t, run_chunk(t))
            else:
                import concurrent.futures as cf
                with _local_executor(min(workers, len(pending))) as ex:
                    futs = {ex.submit(run_chunk, t): t for t in pending}
                    try:
                        for fut in cf.as_completed(futs):
                            finish(futs[fut], fut.result())
                    except BaseException:
                        for f in futs:
                            f.cancel()
                        raise
    if bar is not None:
        bar.close()
    result = assemble(plan, store, tasks)
    return SweepResult(plan.axes, plan.grid, result[0], result[1], len(pending), reused,
                       time.perf_counter() - t0, result[2], result[3], stability_subgrid=stability_subgrid(plan))


def assemble(plan: SweepPlan, store: SweepStore, tasks):
    """Read all chunks of a finished sweep into maps and write ``results.csv``."""
    shape = tuple(a.count for a in plan.axes)
    maps = {}
    cols: dict[str, np.ndarray] = {a.name: plan.grid[:, i] for i, a in enumerate(plan.axes)}
    for start in plan.options.starts:
        arr = {m: np.full(plan.n_points, np.nan) for m in METRICS}
        for t in tasks:
            if t.start != start or t.kind != "simulate":
                continue
            d = store.read_chunk(t.key)
            idx = d["index"].astype(int)
            for m in METRICS:
                arr[m][idx] = d[m]
        maps[start] = {m: v.reshape(shape) for m, v in arr.items()}
        for m in METRICS:
            cols[f"{m}_{start}"] = arr[m]
    stab = None
    stab_tasks = [t for t in tasks if t.kind == "stability"]
    if stab_tasks:
        stab = np.full(plan.n_points, np.nan)
        for t in stab_tasks:
            d = store.read_chunk(t.key)
            stab[d["index"].astype(int)] = d["max_real"]
    if stab is not None:
        cols["sliding_max_real"] = stab
    bad = int(sum(np.sum(maps[s]["ok"] == 0) for s in maps))
    store.write_results(cols)
    status = "ok" if bad == 0 else f"{bad} point run(s) failed (non-finite state or no steady sliding)"
    return maps, stab, status, bad == 0
