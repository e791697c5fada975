"""Scenarios: a rig, its input programme, the plant it runs against, and the controllers to compare.

A scenario is a TOML file (``scenarios/*.toml``) or, from Python, :func:`make_scenario` with the
same fields as keyword arguments.  Schema (only ``[scenario]`` and ``[inputs]`` are required)::

    [scenario]
    name = "stick_slip_30rpm"        # output names
    description = "..."
    model = "rig3"                   # a shipped rig, or a rig file (relative to this file)
    duration = 60.0                  # [s]
    dt = 0.01                        # [s] DAQ period
    seed = 1                         # sensor noise and random profiles

    [plant]
    params = "published"             # or a parameter TOML (e.g. one written by `mitigate identify`)
    method = "hybrid"                # hybrid (exact stick) | smooth | cvodes
    nsub = 10                        # substeps per sample, at least (raised automatically for stiff plants)
    start = "rest"                   # rest | sliding
    max_speed = 100.0                # [rad/s] a body faster than this ends the run as diverged (default:
                                     # 100/pi = 32 times the largest programmed drive speed; rig3: 100)

    [mismatch]                       # plant parameter = model parameter x factor
    mu_k = 1.2

    [structure]                      # the plant differs from the model in structure (README)
    torque_definition = "electromagnetic"
    sensor_offsets = { motor_torque = 0.05 }
    sensor_gains = { n1 = 1.05 }
    pi_error = "motor"
    delay = 1                        # DAQ delay [samples]: every channel, or { omega1 = 1 }
    backlash = { gap = "0.5 deg", stiffness = "200 N m/rad", inertia = "1e-3 kg m^2" }
    shaft_elements = { count = 3, inertia = "2e-4 kg m^2" }
    friction = { law = "bit_rock", mu_sb = 0.5, mu_cb = 0.306, v_b = 1.0, c_b = 0.005 }
    drift = { mu_k = 0.002 }         # relative change per second (wear)

    [sensors]                        # noise_scale, quantise
    [actuators.servo2]               # override a servo of the rig: n_min, n_max, rate_max, tau

    [inputs]                         # one profile per model input (mitigate.profiles)
    omega_ref = "30 rpm"
    n1 = { kind = "steps", times = [0, 20, 40], values = [15, 25, 20] }

    [control]
    start = 20.0                     # [s] controllers act from here (< duration); before, the programme alone
    every = 1                        # a controller runs every k DAQ samples
    deadline = "5 ms"                # optional ("period": one control period; default off): a later answer
                                     # is a counted deadline miss and the fallback acts (on in the benchmark)
    timeout = "2 s"                  # a call not returned by then fails its run (default max(2 s, 100 periods))
    latency = "measured"             # optional: each answer applied after its measured time, or "3 ms" (fixed)
    speed = "60 rpm"                 # a torque drive only: the drive speed a speed-holding law (softspeed,
                                     # ztorque) aims at, a profile (default: the rig's operating_point.speed)

    [estimator]
    kind = "ekf"                     # ekf | mhe | fd, and their options

    [[controllers]]                  # compared side by side; the other keys are the controller's options
    name = "NMPC"
    kind = "nmpc"                    # pi | brake | supervisor | nmpc | softspeed | ztorque | doskil | module:Class

Every error is one line naming the field.  So is a run too long to hold: at most
:data:`MAX_SAMPLES` samples (``duration / dt``), and no more than fit in this machine's memory
at about :data:`BYTES_PER_SAMPLE` per sample and controller.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from models.checks import finite_number as _num, read_toml
from models.errors import ConfigError
from models.params import ParameterSet
from models.plant import SimOptions, plant_integration
from models.rig import RigModel, get_model, load_params
from models.sensors import SensorOptions
from mitigate.profiles import Profile, parse_profile
# limits and field converters live in mitigate.scenario_fields; their public names are also read from here
from mitigate.scenario_fields import (BYTES_PER_SAMPLE, DEFAULT_TIMEOUT, MAX_CALL_TIME, MAX_SAMPLES,
                                      MAX_SPEED_FACTOR, TIMEOUT_PERIODS, ControlSection, check_keys, check_size,
                                      default_max_speed, memory_bytes, parse_control, si_value, table)
from mitigate.scenario_structure import apply_structure

__all__ = ["Scenario", "ControllerSpec", "ControlSection", "load_scenario", "parse_scenario", "make_scenario", "controller_where",
           "MAX_SAMPLES", "BYTES_PER_SAMPLE", "DEFAULT_TIMEOUT", "TIMEOUT_PERIODS", "MAX_CALL_TIME",
           "MAX_SPEED_FACTOR", "memory_bytes", "default_max_speed"]

_SECTIONS = {"scenario", "plant", "mismatch", "structure", "sensors", "actuators", "inputs", "control", "estimator",
             "controllers", "sweep"}


def controller_where(where: str, index: int, name=None) -> str:
    """How messages name the ``index``-th (0-based) ``[[controllers]]`` table: counted from 1 as a
    reader of the file counts, with its name (``"sc.toml: controller 2 'SoftSpeed'"``)."""
    label = f" {name!r}" if isinstance(name, str) and name else ""
    return f"{where}: controller {index + 1}{label}"


@dataclass(frozen=True)
class ControllerSpec:
    """One ``[[controllers]]`` entry: a display name, a kind and its raw options."""

    name: str
    kind: str
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Scenario:
    """A validated scenario (see module docstring).

    Attributes
    ----------
    model, model_params : the rig and parameters the controllers and estimators believe
    plant_model, plant_params : the rig that is simulated (structurally different if
        ``[structure]`` says so) and its true parameters (mismatch and sensor calibration applied)
    inputs : ``{input: Profile}`` for every model input (SI units)
    sim, sensors : plant simulator and sensor settings
    drift : ``{parameter: relative rate [1/s]}`` of the plant (wear)
    messages : notes made while building it (e.g. substeps raised for a stiff plant)
    control : the ``[control]`` section (:class:`mitigate.scenario_fields.ControlSection`: start, every,
        deadline, timeout, latency, a torque drive's target speed)
    """

    name: str
    model: RigModel
    model_params: ParameterSet
    plant_model: RigModel
    plant_params: ParameterSet
    duration: float
    dt: float
    seed: int
    inputs: Mapping[str, Profile]
    sim: SimOptions
    sensors: SensorOptions = SensorOptions()
    description: str = ""
    control: ControlSection = ControlSection()
    estimator: Mapping[str, Any] = field(default_factory=lambda: {"kind": "ekf"})
    controllers: tuple[ControllerSpec, ...] = ()
    mismatch: Mapping[str, float] = field(default_factory=dict)
    structure: Mapping[str, Any] = field(default_factory=dict)
    drift: Mapping[str, float] = field(default_factory=dict)
    max_speed: float = 100.0
    sweep: Mapping[str, Any] = field(default_factory=dict)
    path: str = ""
    messages: tuple[str, ...] = ()

    @property
    def where(self) -> str:
        return Path(self.path).name if self.path else self.name

    @property
    def samples(self) -> int:
        return int(round(self.duration / self.dt))

    def programme(self, t: float) -> np.ndarray:
        """Scheduled inputs at ``t`` [s], in ``model.inputs`` order (SI)."""
        const = self._constant
        if const is not None:
            return const.copy()
        return np.array([f(t) for f in self._profiles], dtype=float)

    @functools.cached_property
    def _profiles(self) -> tuple[Profile, ...]:
        """The profiles in ``model.inputs`` order (the programme is asked on every control call)."""
        return tuple(self.inputs[n] for n in self.model.inputs)

    @functools.cached_property
    def _constant(self) -> np.ndarray | None:
        """The programme when every profile is a constant (computed once), else None."""
        if all(getattr(f, "kind", None) == "constant" for f in self._profiles):
            return np.array([f(0.0) for f in self._profiles], dtype=float)
        return None

    input_vector = programme

    def nominal_speed(self, t: float = 0.0) -> float:
        """The programmed drive input at ``t`` (a speed set-point or prescribed speed) [rad/s]."""
        return float(self.inputs[self.model.drive_input](t))

    def replace(self, **changes) -> "Scenario":
        return dataclasses.replace(self, **changes)


def _resolve_model(name: Any, path: str, where: str) -> RigModel:
    if not isinstance(name, str):
        raise ConfigError(f"{where}: scenario.model must be a rig name or a rig file path, got {name!r}")
    if name.endswith(".toml") and path and not Path(name).is_absolute():
        cand = Path(path).parent / name
        if cand.exists():
            name = str(cand)
    try:
        return get_model(name)
    except ConfigError as exc:
        raise ConfigError(f"{where}: scenario.model: {exc}") from None


# ----------------------------------------------------------------------------- parsing
def parse_scenario(data: Mapping[str, Any], path: str = "", *, model: RigModel | None = None) -> Scenario:
    """Validate a scenario mapping (as read from TOML) into a :class:`Scenario`.

    ``path`` is the file it came from (relative rig, parameter and log files are found from it);
    ``model`` replaces ``scenario.model`` (a rig built in Python).
    """
    where = Path(path).name if path else "scenario"
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: a scenario must be a table")
    for k in data:
        if k not in _SECTIONS:
            raise ConfigError(f"{where}: {k}: unknown section; expected one of {', '.join(sorted(_SECTIONS))}")
    sc = table(data, "scenario", where)
    check_keys(sc, {"name", "description", "model", "duration", "dt", "seed"}, f"{where}: scenario")
    for req in ("name", "duration"):
        if req not in sc:
            raise ConfigError(f"{where}: scenario.{req}: missing field")
    name = sc["name"]
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"{where}: scenario.name must be a non-empty string, got {name!r}")
    model = model if model is not None else _resolve_model(sc.get("model", "rig3"), path, where)
    duration = _num(sc["duration"], f"{where}: scenario.duration", positive=True, unit="s")
    dt = _num(sc.get("dt", 0.01), f"{where}: scenario.dt", positive=True, unit="s")
    if duration < dt:
        raise ConfigError(f"{where}: scenario.dt must be <= scenario.duration = {duration:g} s (at least one DAQ "
                          f"sample), got {dt:g} s")
    ctrls_raw = data.get("controllers", [])
    check_size(duration, dt, max(1, len(ctrls_raw) if isinstance(ctrls_raw, list) else 1), where)
    seed = sc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ConfigError(f"{where}: scenario.seed must be an integer, got {seed!r}")

    plant = table(data, "plant", where)
    check_keys(plant, {"params", "method", "nsub", "start", "max_speed"}, f"{where}: plant")
    ptxt = plant.get("params", "published")
    if not isinstance(ptxt, str):
        raise ConfigError(f"{where}: plant.params must be \"published\" or a file path, got {ptxt!r}")
    if ptxt == "published":
        nominal = model.published()
    else:
        ppath = Path(ptxt)
        if not ppath.is_absolute() and path:
            ppath = Path(path).parent / ppath
        nominal = load_params(ppath, model)
    mism = table(data, "mismatch", where)
    factors = {}
    for k, v in mism.items():
        if k not in nominal.names():
            raise ConfigError(f"{where}: mismatch.{k}: unknown parameter of rig {model.name!r}")
        factors[k] = _num(v, f"{where}: mismatch.{k}", positive=True)
    try:
        true = nominal.replace(**{k: nominal[k] * f for k, f in factors.items()})
    except ConfigError as exc:
        raise ConfigError(f"{where}: mismatch: {exc}") from None
    structure = dict(table(data, "structure", where))
    plant_model, plant_params, drift, notes = apply_structure(model, true, structure, where)
    sim_kw = {k: v for k, v in plant.items() if k not in ("params", "max_speed")}
    try:
        sim = SimOptions(**{"dt": dt, "seed": seed, **sim_kw})
    except (ConfigError, TypeError) as exc:
        raise ConfigError(f"{where}: plant: {exc}") from None
    max_speed = (_num(plant["max_speed"], f"{where}: plant.max_speed", positive=True, unit="rad/s")
                 if "max_speed" in plant else None)
    sensors_tab = table(data, "sensors", where)
    check_keys(sensors_tab, {"noise_scale", "quantise"}, f"{where}: sensors")
    try:
        sensors = SensorOptions(**sensors_tab)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None

    # servo overrides apply to the model and the plant alike (the controller knows its servo)
    acts = table(data, "actuators", where)
    for aname, tab in acts.items():
        if not isinstance(tab, Mapping):
            raise ConfigError(f"{where}: actuators.{aname} must be a table, got {tab!r}")
        spec_a = next((a for a in model.spec.actuators if a.name == aname), None)
        if spec_a is None:
            raise ConfigError(f"{where}: actuators.{aname}: rig {model.name!r} has no such actuator "
                              f"({', '.join(a.name for a in model.spec.actuators) or 'none'})")
        check_keys(tab, {"n_min", "n_max", "rate_max", "tau"}, f"{where}: actuators.{aname}")
        kinds = {"n_min": "force", "n_max": "force", "rate_max": "force_rate", "tau": "time"}
        ch = {k: si_value(v, kinds[k], f"{where}: actuators.{aname}.{k}") for k, v in tab.items()}
        new_a = dataclasses.replace(spec_a, **ch)
        if new_a.n_min < 0 or not new_a.n_max > new_a.n_min or not new_a.rate_max > 0 or new_a.tau < 0:
            raise ConfigError(f"{where}: actuators.{aname}: need 0 <= n_min < n_max, rate_max > 0 and tau >= 0, "
                              f"got n_min={new_a.n_min:g}, n_max={new_a.n_max:g}, rate_max={new_a.rate_max:g}, "
                              f"tau={new_a.tau:g}")

        def _swap(m: RigModel) -> RigModel:
            return RigModel(m.spec.with_changes(actuators=tuple(new_a if a.name == aname else a
                                                                for a in m.spec.actuators)), m.key)
        model, plant_model = _swap(model), _swap(plant_model)

    inp = table(data, "inputs", where)
    check_keys(inp, set(model.inputs), f"{where}: inputs")
    inputs = {}
    base = Path(path).parent if path else None
    for n, kind in zip(model.inputs, model.input_kinds):
        if n not in inp:
            if n in model.servo_inputs:
                inputs[n] = Profile("constant", (0.0,), (0.0,))
                continue
            raise ConfigError(f"{where}: inputs.{n}: missing field (inputs of {model.name}: {', '.join(model.inputs)})")
        inputs[n] = parse_profile(inp[n], f"{where}: inputs.{n}", duration, quantity=kind,
                                  nonnegative=(kind == "force"), base=base)

    control = parse_control(table(data, "control", where), model, dt, duration, where)

    est = dict(table(data, "estimator", where)) or {"kind": "ekf"}
    if not isinstance(est.get("kind", "ekf"), str):
        raise ConfigError(f"{where}: estimator.kind must be a string, got {est.get('kind')!r}")
    est.setdefault("kind", "ekf")

    if not isinstance(ctrls_raw, list):
        raise ConfigError(f"{where}: controllers must be an array of tables ([[controllers]]), "
                          f"got {type(ctrls_raw).__name__}")
    ctrls, seen = [], set()
    for i, c in enumerate(ctrls_raw):
        cw = controller_where(where, i, c.get("name") if isinstance(c, Mapping) else None)
        if not isinstance(c, Mapping):
            raise ConfigError(f"{cw} must be a table, got {c!r}")
        for req in ("name", "kind"):
            if not isinstance(c.get(req), str) or not c.get(req):
                raise ConfigError(f"{cw}.{req}: missing field or not a string (got {c.get(req)!r})")
        if c["name"] in seen:
            raise ConfigError(f"{cw}.name: duplicate controller name {c['name']!r}")
        seen.add(c["name"])
        ctrls.append(ControllerSpec(c["name"], c["kind"], {k: v for k, v in c.items() if k not in ("name", "kind")}))
    sweep = dict(table(data, "sweep", where))
    u0 = np.array([inputs[n](0.0) for n in model.inputs])
    if max_speed is None:
        max_speed = default_max_speed(model, inputs, control.speed, duration)
    # the plant states how it integrates when the rule changes what the scenario asked for
    # (more substeps for a stiff rig, the current of a fast motor quasi-static)
    integ = plant_integration(plant_model, plant_params, sim, u0)
    if integ.nsub != sim.nsub or integ.quasi_static or integ.implicit:
        notes.append(f"plant: {integ.note}" + (f" (plant.nsub = {sim.nsub} asked)" if integ.nsub != sim.nsub else ""))
        sim = dataclasses.replace(sim, nsub=integ.nsub)
    return Scenario(name=name.strip(), model=model, model_params=nominal, plant_model=plant_model,
                    plant_params=plant_params, duration=duration, dt=dt, seed=seed, inputs=inputs, sim=sim,
                    sensors=sensors, description=str(sc.get("description", "")), control=control,
                    estimator=est, controllers=tuple(ctrls), mismatch=factors,
                    structure=structure, drift=drift, max_speed=max_speed, sweep=sweep, path=str(path or ""),
                    messages=tuple(notes))


def load_scenario(path) -> Scenario:
    """Read and validate a scenario TOML file."""
    return parse_scenario(read_toml(path, "scenario file"), str(path))


def make_scenario(*, name: str = "scenario", model: str | RigModel = "rig3", duration: float = 60.0,
                  inputs: Mapping[str, Any] | None = None, controllers=(), estimator: str | Mapping = "ekf",
                  control_start: float = 0.0, dt: float = 0.01, seed: int = 0, **sections) -> Scenario:
    """Build a scenario from Python with the TOML file's fields as keyword arguments.

    Parameters
    ----------
    name, model, duration, dt, seed : the ``[scenario]`` fields (``model`` may be a RigModel)
    inputs : ``{input: profile}`` (a number, a quantity such as ``"30 rpm"``, or a profile table);
        default: the rig file's operating point
    controllers : ``[{"name": ..., "kind": ..., **options}, ...]`` or kind strings
    estimator : a kind (``"ekf"``) or an ``[estimator]`` table
    control_start : [s]
    **sections : any other section as a mapping: ``plant``, ``mismatch``, ``structure``,
        ``sensors``, ``actuators``, ``control``, ``sweep``

    Example
    -------
    >>> sc = make_scenario(name="demo", duration=30, inputs={"omega_ref": "30 rpm", "n1": 20},
    ...                    controllers=["pi", {"name": "NMPC", "kind": "nmpc"}], control_start=10)
    """
    m = get_model(model)
    if inputs is None:
        op = m.spec.extra.get("operating_point", {})
        inputs = {n: op[n] for n in m.inputs if n in op}
    ctrls = []
    for c in controllers:
        ctrls.append({"name": c, "kind": c} if isinstance(c, str) else dict(c))
    data: dict[str, Any] = {
        "scenario": {"name": name, "duration": duration, "dt": dt, "seed": seed},
        "inputs": dict(inputs),
        "estimator": {"kind": estimator} if isinstance(estimator, str) else dict(estimator),
        "controllers": ctrls,
    }
    control = dict(sections.pop("control", {}))
    control.setdefault("start", control_start)
    data["control"] = control
    for k, v in sections.items():
        if k not in _SECTIONS:
            raise ConfigError(f"make_scenario: unknown section {k!r}; expected one of {', '.join(sorted(_SECTIONS))}")
        data[k] = v
    return parse_scenario(data, model=m)
