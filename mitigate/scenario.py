"""Scenario files: declarative TOML describing a plant, its inputs and the controllers to compare.

Schema (all sections but ``[scenario]`` and ``[inputs]`` optional)::

    [scenario]
    name = "stick-slip-30rpm"        # used for output names
    description = "..."
    model = "rig3"                   # rig3 | rig2 | leadscrew | disc ("run" needs rig3)
    duration = 60.0                  # [s]
    dt = 0.01                        # [s] DAQ period
    seed = 1                         # sensor noise and random profiles

    [plant]
    params = "published"             # or a parameter TOML path (relative to this file)
    method = "hybrid"                # hybrid (exact stick) | smooth | cvodes
    nsub = 10                        # substeps per sample
    start = "rest"                   # rest | sliding

    [mismatch]                       # plant = model x factor (the controller keeps the nominal)
    k1 = 1.2

    [sensors]                        # models.sensors.SensorOptions fields
    noise_scale = 1.0

    [servo]                          # models.actuators.ServoOptions fields
    n_max = 40.0

    [inputs]                         # one profile per model input (mitigate.profiles)
    omega_ref = { kind = "constant", value = 30, unit = "rpm" }
    n1 = { kind = "constant", value = 20 }
    n2 = 0.0

    [control]
    start = 20.0                     # [s] controllers act from here; before, baseline (a)
    every = 1                        # controller runs every k DAQ samples

    [estimator]
    kind = "ekf"                     # ekf | mhe | fd; other keys are the estimator's options

    [[controllers]]                  # compared one by one; other keys are the controller's options
    name = "PI only"
    kind = "pi"

Unknown keys, missing fields, non-finite numbers and wrong types are reported as one
line naming the field.  So is a run too long to hold: at most :data:`MAX_SAMPLES` samples
(``duration / dt``), and no more than fit in this machine's memory at about
:data:`BYTES_PER_SAMPLE` per sample and controller.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

from models.actuators import ServoOptions
from models.errors import ConfigError
from models.checks import finite_number as _num, read_toml
from models.params import ParameterSet, load_params, published
from models.rigs import MODEL_NAMES, get_model
from models.sensors import SensorOptions
from models.plant import SimOptions
from mitigate.profiles import Profile, parse_profile

__all__ = ["Scenario", "ControllerSpec", "load_scenario", "parse_scenario"]

# A run keeps every sample in memory (states, measurements, estimates, actions: about 0.7 kB
# per sample and controller while it runs, measured on rig3 with the EKF), then hands it back
# for the logs and plots.  Both limits are checked before anything is allocated or run.
MAX_SAMPLES = 10_000_000
BYTES_PER_SAMPLE = 2048     # per sample and controller run, with room for the logs and plots

_SECTIONS = {"scenario", "plant", "mismatch", "sensors", "servo", "inputs", "control", "estimator", "controllers",
             "sweep"}


@dataclass(frozen=True)
class ControllerSpec:
    """One ``[[controllers]]`` entry: a display name, a kind and its raw options."""

    name: str
    kind: str
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Scenario:
    """A validated scenario (see module docstring)."""

    name: str
    description: str
    model: str
    duration: float
    dt: float
    seed: int
    plant_params: ParameterSet          # the true plant (mismatch applied)
    model_params: ParameterSet          # what controllers and estimators believe
    mismatch: Mapping[str, float]
    sim: SimOptions
    sensors: SensorOptions
    servo: ServoOptions
    inputs: Mapping[str, Profile]
    control_start: float = 0.0
    control_every: int = 1
    estimator: Mapping[str, Any] = field(default_factory=lambda: {"kind": "ekf"})
    controllers: tuple[ControllerSpec, ...] = ()
    sweep: Mapping[str, Any] = field(default_factory=dict)
    path: str = ""

    def input_vector(self, t: float):
        """Programmed input at time ``t`` in model input order."""
        return [self.inputs[n](t) for n in get_model(self.model).inputs]

    def replace(self, **changes) -> "Scenario":
        import dataclasses
        return dataclasses.replace(self, **changes)


def _table(data: Mapping, key: str, where: str) -> Mapping:
    v = data.get(key, {})
    if not isinstance(v, Mapping):
        raise ConfigError(f"{where}.{key} must be a table, got {type(v).__name__}")
    return v


def _check_keys(tab: Mapping, allowed, where: str):
    for k in tab:
        if k not in allowed:
            raise ConfigError(f"{where}.{k}: unknown key; expected one of {', '.join(sorted(allowed))}")


def _options(cls, tab: Mapping, where: str, extra: Mapping | None = None):
    names = {f.name for f in fields(cls)}
    _check_keys(tab, names, where)
    kw = dict(extra or {})
    kw.update(tab)
    try:
        return cls(**kw)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _memory_bytes() -> int | None:
    """This machine's physical memory, or its cgroup's limit if lower (None: unknown)."""
    total = None
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        pass
    for f in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            limit = int(Path(f).read_text().split()[0])
        except (OSError, ValueError, IndexError):   # absent, or "max" (no limit)
            continue
        if limit > 0:
            total = limit if total is None else min(total, limit)
    return total if total and total > 0 else None


def _check_size(duration: float, dt: float, runs: int, where: str) -> None:
    """One-line ConfigError if ``duration / dt`` samples cannot be run (count, then memory)."""
    samples = duration / dt
    shown = f"{samples:,.0f}" if samples < 1e15 else f"{samples:.3g}"
    head = f"{where}: scenario.duration / scenario.dt = {duration:g} s / {dt:g} s = {shown} samples"
    if samples > MAX_SAMPLES:
        raise ConfigError(f"{head}; the limit is {MAX_SAMPLES:,} samples (shorten the duration or raise dt)")
    need, have = samples * runs * BYTES_PER_SAMPLE, _memory_bytes()
    if have is not None and need > have:
        fit = int(have // (runs * BYTES_PER_SAMPLE))
        raise ConfigError(f"{head}; the limit is {fit:,} samples here: {runs} controller run(s) need about "
                          f"{need / 2**30:.1f} GiB ({BYTES_PER_SAMPLE} bytes per sample each), this machine has "
                          f"{have / 2**30:.1f} GiB of memory")


def parse_scenario(data: Mapping[str, Any], path: str = "<scenario>") -> Scenario:
    """Validate a scenario mapping (as read from TOML)."""
    where = Path(path).name if path else "scenario"
    _check_keys(data, _SECTIONS, where)
    sc = _table(data, "scenario", where)
    _check_keys(sc, {"name", "description", "model", "duration", "dt", "seed"}, f"{where}: scenario")
    for req in ("name", "duration"):
        if req not in sc:
            raise ConfigError(f"{where}: scenario.{req}: missing field")
    name = sc["name"]
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"{where}: scenario.name must be a non-empty string, got {name!r}")
    model_name = sc.get("model", "rig3")
    if model_name not in MODEL_NAMES:
        raise ConfigError(f"{where}: scenario.model must be one of {', '.join(MODEL_NAMES)}, got {model_name!r}")
    model = get_model(model_name)
    duration = _num(sc["duration"], f"{where}: scenario.duration", positive=True)
    dt = _num(sc.get("dt", 0.01), f"{where}: scenario.dt", positive=True)
    ctrls_raw = data.get("controllers", [])
    _check_size(duration, dt, max(1, len(ctrls_raw) if isinstance(ctrls_raw, list) else 1), where)
    seed = sc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ConfigError(f"{where}: scenario.seed must be an integer, got {seed!r}")

    plant = _table(data, "plant", where)
    _check_keys(plant, {"params", "method", "nsub", "start"}, f"{where}: plant")
    ptxt = plant.get("params", "published")
    if not isinstance(ptxt, str):
        raise ConfigError(f"{where}: plant.params must be \"published\" or a file path, got {ptxt!r}")
    if ptxt == "published":
        nominal = published(model_name)
    else:
        ppath = Path(ptxt)
        if not ppath.is_absolute() and path and path != "<scenario>":
            ppath = Path(path).parent / ppath
        nominal = load_params(ppath, model_name)
    mism = _table(data, "mismatch", where)
    factors = {}
    for k, v in mism.items():
        if k not in nominal.names():
            raise ConfigError(f"{where}: mismatch.{k}: unknown parameter for model {model_name!r}")
        factors[k] = _num(v, f"{where}: mismatch.{k}", positive=True)
    try:
        plant_params = nominal.replace(**{k: getattr(nominal, k) * f for k, f in factors.items()})
    except ConfigError as exc:
        raise ConfigError(f"{where}: mismatch: {exc}") from None
    sim = _options(SimOptions, {k: v for k, v in plant.items() if k != "params"}, f"{where}: plant",
                   {"dt": dt, "seed": seed})
    sensors = _options(SensorOptions, _table(data, "sensors", where), f"{where}: sensors",
                       {"motor_ratio": getattr(nominal, "eta", 8.0)})
    servo = _options(ServoOptions, _table(data, "servo", where), f"{where}: servo")

    inp = _table(data, "inputs", where)
    _check_keys(inp, set(model.inputs), f"{where}: inputs")
    inputs = {}
    for n in model.inputs:
        if n not in inp:
            if n == "n2":
                inputs[n] = Profile("constant", (0.0,), (0.0,))
                continue
            raise ConfigError(f"{where}: inputs.{n}: missing field (inputs of {model_name}: {', '.join(model.inputs)})")
        inputs[n] = parse_profile(inp[n], f"{where}: inputs.{n}", duration,
                                  nonnegative=n in ("n1", "n2", "axial_force"))

    ctl = _table(data, "control", where)
    _check_keys(ctl, {"start", "every"}, f"{where}: control")
    cstart = _num(ctl.get("start", 0.0), f"{where}: control.start", nonneg=True)
    every = ctl.get("every", 1)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError(f"{where}: control.every must be an integer >= 1, got {every!r}")

    est = dict(_table(data, "estimator", where)) or {"kind": "ekf"}
    if not isinstance(est.get("kind", "ekf"), str):
        raise ConfigError(f"{where}: estimator.kind must be a string, got {est.get('kind')!r}")
    est.setdefault("kind", "ekf")

    if not isinstance(ctrls_raw, list):
        raise ConfigError(f"{where}: controllers must be an array of tables ([[controllers]]), got {type(ctrls_raw).__name__}")
    ctrls = []
    seen = set()
    for i, c in enumerate(ctrls_raw):
        cw = f"{where}: controllers[{i}]"
        if not isinstance(c, Mapping):
            raise ConfigError(f"{cw} must be a table, got {c!r}")
        for req in ("name", "kind"):
            if not isinstance(c.get(req), str) or not c.get(req):
                raise ConfigError(f"{cw}.{req}: missing field or not a string (got {c.get(req)!r})")
        if c["name"] in seen:
            raise ConfigError(f"{cw}.name: duplicate controller name {c['name']!r}")
        seen.add(c["name"])
        ctrls.append(ControllerSpec(c["name"], c["kind"], {k: v for k, v in c.items() if k not in ("name", "kind")}))
    sweep = dict(_table(data, "sweep", where))
    return Scenario(name=name.strip(), description=str(sc.get("description", "")), model=model_name,
                    duration=duration, dt=dt, seed=seed, plant_params=plant_params, model_params=nominal,
                    mismatch=factors, sim=sim, sensors=sensors, servo=servo, inputs=inputs,
                    control_start=cstart, control_every=every, estimator=est, controllers=tuple(ctrls),
                    sweep=sweep, path=str(path))


def load_scenario(path) -> Scenario:
    """Read and validate a scenario TOML file."""
    return parse_scenario(read_toml(path, "scenario file"), str(path))
