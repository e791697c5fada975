"""Sweep plans: axes, options and the grid resolved to per-point inputs and parameters.

See :mod:`mitigate.sweep` for what a sweep is and the names an axis may have.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from models.checks import check_options, number, option, options_from_mapping, prefix
from models.errors import ConfigError
from models.units import convert, parse_quantity

__all__ = ["Axis", "parse_axis", "SweepOptions", "options_from_scenario", "SweepPlan", "plan_sweep", "MAX_POINTS",
           "rig_defaults", "REFERENCE_DEFAULTS"]

#: the most points a sweep may have (all axes multiplied; a 1000 x 1000 map), checked before anything
#: is allocated; and the plan must fit in memory at BYTES_PER_POINT per point
MAX_POINTS = 1_000_000
BYTES_PER_POINT = 64

_SWEEP_KEYS = {"vary", "start", "settle", "speed", "amplitude_of", "threshold", "stuck_threshold", "chunk", "block",
               "duration", "dt", "nsub", "stability_points", "perturbation"}


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


def parse_axis(text: str, units: Mapping[str, str] | None = None) -> Axis:
    """Parse ``name=start:stop:count`` (e.g. ``n1=5:40:50``, ``omega_ref=10 rpm:60 rpm:6``).

    ``start`` and ``stop`` are numbers in the axis's SI unit, or values with a unit as rig and
    scenario files write them, converted to ``units[name]`` (its SI unit: :func:`mitigate.sweep.axis_units`;
    an axis whose unit is not known there takes numbers only)."""
    if not isinstance(text, str) or "=" not in text:
        raise ConfigError(f"axis must be name=start:stop:count (e.g. n1=5:40:50), got {text!r}")
    name, rng = text.split("=", 1)
    name = name.strip()
    parts = rng.split(":")
    if not name or len(parts) != 3:
        raise ConfigError(f"axis must be name=start:stop:count (e.g. n1=5:40:50), got {text!r}")
    start, stop = (_axis_value(p, name, units) for p in parts[:2])
    try:
        count = int(parts[2])
    except ValueError:
        raise ConfigError(f"axis {name}: count must be an integer >= 1, got {parts[2]!r}") from None
    if not (math.isfinite(start) and math.isfinite(stop)):
        raise ConfigError(f"axis {name}: start and stop must be finite, got {start}, {stop}")
    if count < 1 or (count == 1 and start != stop):
        raise ConfigError(f"axis {name}: count must be >= 2 (or 1 with start == stop), got {count}")
    if count > MAX_POINTS:
        raise ConfigError(f"axis {name}: count must be <= {MAX_POINTS:,} (the most points a sweep may have), "
                          f"got {count:,}")
    return Axis(name, start, stop, count)


def _axis_value(text: str, name: str, units: Mapping[str, str] | None) -> float:
    """One end of an axis: a number [SI], or a value with its unit converted to the axis's SI unit."""
    q = parse_quantity(text)
    if q is None:
        try:
            return float(text)          # inf, nan: refused as not finite below
        except ValueError:
            pass
        raise ConfigError(f"axis {name}: start and stop must be numbers (or values with a unit, e.g. \"30 rpm\"), "
                          f"got {text.strip()!r}")
    if not q[1]:
        return q[0]
    si = (units or {}).get(name)
    if si is None:
        raise ConfigError(f"axis {name}: {text.strip()!r} has a unit, but {name!r} is not an input or parameter "
                          f"whose unit is known here; give a number in SI")
    return convert(q[0], q[1], si, f"axis {name}")


# ----------------------------------------------------------------------------- options
def _settles_within(o: "SweepOptions", name) -> None:
    """The settling time lies inside the run, and the run spans a few samples."""
    number(o.settle, name("settle"), lo=0.0, hi=o.duration, hi_open=True, unit="s", none=True)
    if int(round(o.duration / o.dt)) < 4:
        raise ConfigError(f"{name('duration')} must span at least 4 samples of dt={o.dt} s, got {o.duration}")


@dataclass(frozen=True, kw_only=True)
class SweepOptions:
    """How each point is simulated and reduced (see module docstring for the meaning).

    ``threshold``, ``stuck_threshold`` and ``perturbation`` carry units: None (their default) is
    resolved by :func:`options_from_scenario` from the rig (:func:`rig_defaults`)."""

    start: str = option("rest", choices=("rest", "sliding", "both"))
    duration: float = option(30.0, lo=0.0, lo_open=True, unit="s")
    dt: float = option(0.01, lo=0.0, lo_open=True, unit="s")
    nsub: int = option(10, lo=1)
    settle: float | None = option(None, lo=0.0, unit="s", none=True)
    speed: str = option("", what="a state name")
    amplitude_of: str = option("", what="a state name")
    threshold: float | None = option(None, lo=0.0, none=True)
    stuck_threshold: float | None = option(None, lo=0.0, none=True)
    chunk: int = option(50, lo=1)
    block: int = option(200, lo=1)
    stability_points: int = option(20, lo=1)
    perturbation: float | None = option(None, lo=0.0, none=True)
    backend: str = option("compiled", choices=("compiled", "vm"))

    def __post_init__(self):
        check_options(self, prefix("sweep"), cross=_settles_within)

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


def options_from_scenario(sc: Scenario, **overrides) -> SweepOptions:
    """Sweep options from a scenario's ``[sweep]`` table, scenario timing and keyword overrides."""
    tab = dict(sc.sweep)
    for k in tab:
        if k not in _SWEEP_KEYS:
            raise ConfigError(f"{sc.where}: sweep.{k}: unknown key; expected one of {', '.join(sorted(_SWEEP_KEYS))}")
    # the amplitude defaults to the objective body's speed; a scenario may name another state
    # (sweep_leadscrew.toml: the twist, as seed 002 Figs. 9.31-9.33 plot the angle's amplitude)
    speed = amp = f"omega_{sc.plant_model.objective_body}"
    kw = dict(start=tab.get("start", "rest"), duration=tab.get("duration", sc.duration), dt=tab.get("dt", sc.dt),
              nsub=tab.get("nsub", sc.sim.nsub), settle=tab.get("settle"), speed=tab.get("speed", speed),
              amplitude_of=tab.get("amplitude_of", amp), threshold=tab.get("threshold"),
              stuck_threshold=tab.get("stuck_threshold"), chunk=tab.get("chunk", 50), block=tab.get("block", 200),
              stability_points=tab.get("stability_points", 20), perturbation=tab.get("perturbation"))
    if overrides.get("duration") is not None and overrides.get("settle") is None:
        kw["settle"] = None   # a new duration without a new settle time: discard its first half
    kw.update({k: v for k, v in overrides.items() if v is not None})
    opts = options_from_mapping(SweepOptions, kw, f"{sc.where}: sweep")
    model = sc.plant_model
    for n in ("speed", "amplitude_of"):
        if getattr(opts, n) not in model.states:
            raise ConfigError(f"{sc.where}: sweep.{n} must be a state of {model.name} ({', '.join(model.states)}), "
                              f"got {getattr(opts, n)!r}")
    unset = {n: None for n in ("threshold", "stuck_threshold", "perturbation") if getattr(opts, n) is None}
    if unset:
        d = rig_defaults(model, sc.plant_params, opts.amplitude_of)
        opts = replace(opts, **{n: d[n] for n in unset})
    return opts


#: rig3's values (30 rpm, twist 0.81 rad at N1 = 20 N), carried to any rig by its scales
#: (:func:`estimators.online.options.rig_scales`): a limit cycle's amplitude above 1.6 % of the
#: nominal speed (of the steady twist, for a twist), a stuck body at or below 3e-7 of it (the exact
#: plant holds a stuck body at exactly 0; this is a numerical zero), a sliding start kicked by 0.3 %
REFERENCE_DEFAULTS = {"threshold": 0.05, "stuck_threshold": 1e-6, "perturbation": 0.01}


def rig_defaults(model, params, amplitude_of: str) -> dict:
    """``threshold`` [unit of ``amplitude_of``], ``stuck_threshold`` and ``perturbation`` [rad/s]
    from the rig's scales: rig3's values (:data:`REFERENCE_DEFAULTS`) times the rig's nominal speed
    (or, for an amplitude of a twist or a current, its steady twist or current limit) over rig3's."""
    from estimators.online.options import REFERENCE, rig_scales
    sc = rig_scales(model, params)
    unit = dict(zip(model.states, model.state_units)).get(amplitude_of, "rad/s")
    kind = {"rad": "twist", "A": "current"}.get(unit, "speed")
    speed = sc.speed / REFERENCE.speed
    return {"threshold": REFERENCE_DEFAULTS["threshold"] * getattr(sc, kind) / getattr(REFERENCE, kind),
            "stuck_threshold": REFERENCE_DEFAULTS["stuck_threshold"] * speed,
            "perturbation": REFERENCE_DEFAULTS["perturbation"] * speed}


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
        return {"scenario": sc.name, "model": sc.model.name, "rig": sc.model.key, "scenario_file": sc.path,
                "scenario_digest": hashlib.sha256(Path(sc.path).read_bytes()).hexdigest()[:16]
                if sc.path and Path(sc.path).is_file() else "",
                "axes": [a.spec() for a in self.axes],
                "options": {k: getattr(self.options, k) for k in self.options.__dataclass_fields__ if k != "backend"},
                "controller": controller}


def _check_size(sc: Scenario, axes, options: SweepOptions) -> None:
    """One-line ConfigError before anything is allocated: too many points (all axes multiplied),
    too many time steps per point, or a plan that does not fit in this machine's memory."""
    from mitigate.scenario_fields import MAX_SAMPLES, memory_bytes

    points = math.prod(int(a.count) for a in axes)           # exact, however large
    counts = " x ".join(f"{a.count:,}" for a in axes)
    if points > MAX_POINTS:
        raise ConfigError(f"axes: {counts} = {points:,} points; the limit is {MAX_POINTS:,} (fewer values per axis)")
    steps = options.duration / options.dt
    if steps > MAX_SAMPLES:
        raise ConfigError(f"sweep.duration / sweep.dt = {options.duration:g} s / {options.dt:g} s = {steps:.3g} steps "
                          f"per point; the limit is {MAX_SAMPLES:,}")
    per_point = BYTES_PER_POINT + 8 * (len(axes) + len(sc.plant_params.names()) + sc.plant_model.nu)
    need, have = points * per_point + steps * 8 * sc.plant_model.nu, memory_bytes()
    if have is not None and need > have:
        raise ConfigError(f"axes: {counts} = {points:,} points need about {need / 2**30:.1f} GiB for the plan; this "
                          f"machine has {have / 2**30:.1f} GiB of memory (fewer values per axis)")


def plan_sweep(sc: Scenario, axes: list[Axis] | tuple[Axis, ...], options: SweepOptions) -> SweepPlan:
    """Resolve axes against a scenario (see module docstring for the names)."""
    if not axes:
        raise ConfigError("a sweep needs at least one axis (sweep.vary in the scenario, or axes)")
    names = [a.name for a in axes]
    if len(set(names)) != len(names):
        raise ConfigError(f"axes: each name at most once, got {names}")
    model = sc.plant_model
    pnames = sc.plant_params.names()
    for a in axes:
        n = a.name
        ok = (n in model.inputs or n in pnames or (n.endswith("_scale") and n[:-6] in pnames)
              or (n.startswith("mismatch.") and n[9:] in pnames))
        if not ok:
            raise ConfigError(f"axis {n}: unknown name for rig {model.name}; expected an input "
                              f"({', '.join(model.inputs)}), a parameter ({', '.join(pnames)}), <param>_scale "
                              f"or mismatch.<param>")
    _check_size(sc, axes, options)
    mesh = np.meshgrid(*[a.values for a in axes], indexing="ij")
    grid = np.stack([m.ravel() for m in mesh], axis=1)
    n = options.n_steps
    U = np.array([sc.programme(k * options.dt) for k in range(n)], dtype=float).reshape(n, model.nu)
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
                ch[a.name[:-6]] = base[a.name[:-6]] * v
            elif a.name.startswith("mismatch."):
                ch[a.name[9:]] = nominal[a.name[9:]] * v
        try:
            P[j] = base.replace(**ch).vector() if ch else base.vector()
        except (ConfigError, TypeError, ValueError) as exc:
            raise ConfigError(f"axes: point {dict(zip(names, grid[j]))} gives invalid parameters ({exc})") from None
    for i, a in enumerate(axes):
        if a.name in model.inputs and model.input_kinds[model.inputs.index(a.name)] == "force" and np.any(grid[:, i] < 0):
            raise ConfigError(f"axis {a.name}: a normal force must be >= 0 N, got start {a.start}, stop {a.stop}")
    return SweepPlan(sc, options, tuple(axes), grid, U, u_cols, u_vals, P)


