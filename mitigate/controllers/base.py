"""The one interface of every controller, built-in or your own.

Every controller is built the same way, ``Controller(options, context)``, and answers the
same call::

    action = controller.step(t, measurement, estimate)

- ``t`` [s]: the time of the DAQ sample;
- ``measurement``: the DAQ's channels at ``t`` (a dict, e.g. ``{"omega1": ..., "motor_torque": ...}``);
- ``estimate``: the state estimate (:class:`estimators.base.Estimate`) or None;
- ``action``: an :class:`Action` whose ``u`` maps the inputs the controller sets to their
  values (e.g. ``{"omega_ref": 3.3, "n2": 12.0}``); every input it leaves out follows the
  scenario's programme.

The public :meth:`Controller.step` guards, times and counts; a subclass implements
``_step_impl`` with the same arguments.  What a failure does (:mod:`models.plugins`):

- ``SolverFailure`` raised by ``_step_impl`` is a transient failure: counted (``failures``) and
  answered by the controller's documented fallback (:meth:`Controller._fallback`; by default the
  scenario's programme, the rig as it runs without the controller), ``Status.FALLBACK``.  So is a
  fallback the controller returns itself (the NMPC's shifted plan).  Both count as ``fallbacks``;
  a run whose fallbacks exceed 1 % of its calls ends with ``Status.WARNING``;
- with a ``deadline`` in the context (``[control] deadline``), an answer that took longer is a
  counted deadline miss (``deadline_misses``, also a fallback) and the fallback acts instead;
- anything else -- another exception (also ``SystemExit``), a non-finite command, a command for an
  input the rig cannot set, a result that is not an :class:`Action`, a call that does not return
  within the context's ``timeout`` -- raises :class:`models.errors.PluginError` with the
  exception's type and first line: the closed loop ends that run as FAILED.

Your own controller is a subclass in any importable module, named in a scenario as
``kind = "my_module:MyController"`` (README, "Your own controller").
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping

import numpy as np

from models import plugins
from models.errors import ConfigError, PluginError, SolverFailure, quote
from models.params import ParameterSet
from models.sensors import SensorOptions
from models.status import Status
from mitigate.scenario_fields import ControlSection

__all__ = ["Action", "Controller", "ControllerCounts", "ControlContext", "NEEDS", "reading", "estimated",
           "sees_string"]

#: what a controller may declare in ``Controller.needs`` (a class attribute), and what it means
#: on a rig; :meth:`ControlContext.missing` says which of them a rig lacks (README, "What each
#: controller needs")
NEEDS: dict[str, str] = {
    "drive_speed": "the drive's measured speed (an encoder or speed sensor on the drive's body)",
    "drive_torque": "the torque at the drive (a torque sensor with at = \"drive\", or on the shaft at the drive)",
    "speed_drive": "a drive that sets a speed (its set-point is offset in rad/s; not a torque drive)",
    "servo": "a servo on a contact's normal force ([actuators] kind = \"servo\")",
    "servo_body_speed": "the speed of the body the servo's contact acts on: measured, or estimated by a model-based "
                        "estimator (an EKF or MHE)",
    "objective_speed": "the measured speed of the objective body",
    "string_sensor": "a sensor that sees the string: an encoder or speed sensor on a body a speed drive does not "
                     "set, or a torque sensor (a speed drive's own encoder reads only its set-point)",
}


def sees_string(model) -> bool:
    """Whether the rig's sensors see the string: a speed drive follows its set-point, so its own
    encoder reads the programme and nothing of the string; a motor's or a torque drive's body does
    respond to the string."""
    from models.rig.spec import NODE_DRIVE
    if model.drive.on_body:
        return True
    return any(s.kind == "torque" or (s.kind in ("encoder", "speed") and s.target != NODE_DRIVE)
               for s in model.spec.sensors)


def reading(measurement: Mapping[str, float] | None, channel: str) -> float:
    """The finite value of ``channel`` in a DAQ sample [SI]; a missing or non-finite reading (a
    dropout) raises :class:`SolverFailure`, which the built-in laws answer with their fallback."""
    v = measurement.get(channel) if measurement is not None else None
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise SolverFailure(f"no reading of channel {channel!r} in this sample") from None
    if not math.isfinite(v):
        raise SolverFailure(f"channel {channel!r} reads {v} in this sample")
    return v


def estimated(estimate, name: str) -> float:
    """The estimate's value of state ``name`` [SI] (a speed the rig does not measure); no estimate
    with that state raises :class:`SolverFailure`, answered like a missing reading."""
    if estimate is None or name not in estimate.names:
        raise SolverFailure(f"no estimate of {name!r} in this call")
    v = estimate.get(name)
    if not math.isfinite(v):
        raise SolverFailure(f"the estimate of {name!r} is {v} in this call")
    return v


@dataclass(frozen=True)
class Action:
    """A controller's output.

    Attributes
    ----------
    u : ``{input name: value}`` in SI units for the inputs the controller sets (the drive's
        set-point [rad/s], a servo's command [N], ...); the others follow the programme
    status : Status.OK, Status.HOLD (a multi-rate controller held its last plan),
        Status.FALLBACK (a documented fallback produced this action)
    message : detail (which fallback, and why)
    solve_time : wall time of the step [s] (set by :meth:`Controller.step`)
    """

    u: Mapping[str, float] = field(default_factory=dict)
    status: Status = Status.OK
    message: str = ""
    solve_time: float = 0.0

    @property
    def success(self) -> bool:
        return self.status.success


@dataclass(frozen=True)
class ControlContext:
    """What every controller is told about the loop it runs in.

    Attributes
    ----------
    model : the rig (:class:`models.rig.RigModel`) the controller believes
    params : its nominal parameters (never the plant's true ones)
    dt : DAQ period [s]
    programme : ``t -> (nu,)`` the scenario's scheduled inputs in ``model.inputs`` order
        (the speed programme, the normal forces)
    sensors : the sensor settings (noise levels follow from the rig file and these)
    where : prefix of error messages (``"scenario.toml: controller 2 'NMPC'"``)
    schedule : ``{input: t -> value}``, the same per input (faster for a law that needs one)
    control : the scenario's ``[control]`` section, whole (:class:`mitigate.scenario_fields.ControlSection`):
        the call period (:attr:`period`), the ``deadline`` a call may take before its answer counts as a
        deadline miss and the fallback acts, the ``timeout`` after which a call that has not returned fails
        the run, a torque drive's target ``speed`` (:meth:`target_speed`)
    estimated : the states the scenario's estimator estimates through the model (an EKF's or MHE's: all;
        the finite-difference baseline's: none): a speed the rig does not measure may come from there
        (:meth:`speed_source`)
    """

    model: Any
    params: ParameterSet
    dt: float
    programme: Callable[[float], np.ndarray]
    sensors: SensorOptions = SensorOptions()
    where: str = "controller"
    schedule: Mapping[str, Callable[[float], float]] = field(default_factory=dict)
    control: ControlSection = ControlSection()
    estimated: tuple[str, ...] = ()

    def speed_source(self, body: str) -> tuple[str, str] | None:
        """Where ``body``'s speed comes from: ``("channel", name)`` when the rig measures it, else
        ``("estimate", "omega_<body>")`` when the estimator estimates it, else None."""
        ch = self.model.speed_channel(body)
        if ch is not None:
            return "channel", ch
        name = f"omega_{body}"
        return ("estimate", name) if name in self.estimated else None

    @property
    def period(self) -> float:
        """The controller's call period [s] (``dt`` x ``control.every``)."""
        return self.control.period(self.dt)

    @property
    def deadline(self) -> float | None:
        """``control.deadline`` [s] or None."""
        return self.control.deadline

    @property
    def timeout(self) -> float | None:
        """``control.timeout`` [s] or None."""
        return self.control.timeout

    @property
    def speed(self) -> Callable[[float], float] | None:
        """``control.speed``: a torque drive's target speed ``t -> [rad/s]``, or None."""
        return self.control.speed

    def target_speed(self, t: float) -> float:
        """The drive speed the programme asks for at ``t`` [rad/s]: a speed-setting drive's scheduled
        input; a torque drive's ``[control] speed`` profile, else the rig file's operating-point
        ``speed`` (a torque programme sets no speed)."""
        m = self.model
        if m.drive.sets_speed:
            return self.scheduled(t, m.drive_input)
        return float(self.speed(t)) if self.speed is not None else m.nominal_speed()

    @property
    def torque_max(self) -> float:
        """The drive's torque limit [N m] (a torque drive's ``[drive] torque_max``; inf: none)."""
        return float(self.model.drive.torque_limit(self.params))

    def scheduled(self, t: float, name: str) -> float:
        """The programme's value of input ``name`` at ``t`` (one input's profile when the context
        has ``schedule``, else the whole programme)."""
        f = self.schedule.get(name)
        if f is not None:
            return float(f(t))
        return float(self.programme(t)[self.model.inputs.index(name)])

    def missing(self, needs) -> list[str]:
        """What of ``needs`` (names of :data:`NEEDS`) the rig lacks, each said for this rig
        (which body, which sensor to add); empty when it has everything."""
        m, out = self.model, []
        unknown = [n for n in needs if n not in NEEDS]
        if unknown:
            raise ConfigError(f"{self.where}: unknown need(s) {', '.join(map(repr, unknown))}; expected some of "
                              f"{', '.join(NEEDS)}")
        drive = m.drive_node
        for n in needs:
            if n == "drive_speed" and m.speed_channel(drive) is None:
                out.append(f"the drive's speed (add an encoder or speed sensor on body {drive!r})")
            elif n == "drive_torque" and m.drive_load_sensor() is None:
                out.append("the torque at the drive (add a torque sensor with at = \"drive\", or on the shaft at "
                           "the drive)")
            elif n == "speed_drive" and not m.drive.sets_speed:
                out.append(f"a speed-setting drive (rig {m.name!r} has a torque drive, input {m.drive_input!r} [N m])")
            elif n == "servo" and not m.servo_inputs:
                out.append(f"a servo on a contact's normal force (rig {m.name!r} has no actuator: add an "
                           "[actuators] entry of kind \"servo\")")
            elif n == "servo_body_speed" and m.servo_inputs:
                body = m.contact_of_input(m.servo_inputs[0]).body
                if self.speed_source(body) is None:
                    out.append(f"the speed of {body!r}, the body its servo's contact acts on (add an encoder or "
                               f"speed sensor on {body!r}, or estimate it: an estimator of kind \"ekf\" or \"mhe\")")
            elif n == "string_sensor" and not sees_string(m):
                out.append(f"a sensor that sees the string (rig {m.name!r} is read only at its speed drive, whose "
                           f"encoder reads the set-point it follows: add an encoder on a body of the string or a "
                           f"torque sensor)")
            elif n == "objective_speed" and m.speed_channel(m.objective_body) is None:
                out.append(f"the speed of the objective body {m.objective_body!r} (add an encoder or speed sensor "
                           f"on {m.objective_body!r})")
        return out

    def require(self, needs) -> None:
        """A one-line ConfigError listing everything of ``needs`` the rig lacks (:meth:`missing`)."""
        miss = self.missing(needs)
        if miss:
            raise ConfigError(f"{self.where}: needs {'; '.join(miss)}; rig {self.model.name!r} lacks "
                              f"{'it' if len(miss) == 1 else 'them'}")

    def require_channels(self, *channels: str) -> None:
        """A one-line ConfigError unless the rig's sensors write every channel named."""
        missing = [c for c in channels if c not in self.model.measured]
        if missing:
            raise ConfigError(f"{self.where}: needs the channel(s) {', '.join(missing)}, which rig "
                              f"{self.model.name!r} does not measure (channels: {', '.join(self.model.measured)})")

    def require_input(self, name: str, what: str) -> None:
        if name not in self.model.commands:
            raise ConfigError(f"{self.where}: needs {what} {name!r}, which rig {self.model.name!r} cannot set "
                              f"(it can set: {', '.join(self.model.commands)})")


@dataclass
class ControllerCounts:
    """How often a controller degraded (reported by the runner)."""

    steps: int = 0
    failures: int = 0          # SolverFailure answered by the fallback
    fallbacks: int = 0         # actions that came from a fallback (failures, deadline misses, the controller's own)
    holds: int = 0
    deadline_misses: int = 0   # answers later than the context's deadline (the fallback acted)

    def as_dict(self) -> dict[str, int]:
        return dict(steps=self.steps, failures=self.failures, fallbacks=self.fallbacks, holds=self.holds,
                    deadline_misses=self.deadline_misses)


class Controller(ABC):
    """Template: :meth:`step` guards, times and counts; subclasses implement ``_step_impl``.

    Subclasses set ``kind`` (the scenario name) and ``options_class`` (a frozen, keyword-only
    dataclass that validates itself; None to take the raw options table as a dict), optionally
    ``derived`` (attributes that hold self-derived tuning values) and ``needs`` (what the rig
    must provide: names of :data:`NEEDS`; checked before anything runs).
    """

    kind: ClassVar[str] = "controller"
    options_class: ClassVar[type | None] = None
    #: ``{option: mitigate.tunables.Tunable}``: what a benchmark may tune (``mitigate tune``)
    tunables: ClassVar[Mapping[str, Any]] = {}
    #: names of attributes holding values the controller derived (reported with a set-point chatter warning)
    derived: ClassVar[tuple[str, ...]] = ()
    #: the unit of each of those values, by name (the report prints it beside the value)
    derived_units: ClassVar[dict[str, str]] = {}
    #: what it needs of a rig (names of :data:`NEEDS`): checked for every controller of a
    #: scenario before anything runs, all missing items listed at once
    needs: ClassVar[tuple[str, ...]] = ()
    #: the controller estimates the state itself from every DAQ sample: the closed loop calls
    #: ``sample(t, measurement, active)`` at every sample (``active`` from ``[control] start``)
    #: before :meth:`step` (an exported library with its own estimator)
    own_estimator: ClassVar[bool] = False

    def __init__(self, options: Any, context: ControlContext):
        self.options = options
        self.context = context
        self.counts = ControllerCounts()
        context.require(type(self).needs)

    @property
    def name(self) -> str:
        return self.kind

    def reset(self) -> None:
        """Forget internal state (called before a run)."""

    def actuated_inputs(self) -> tuple[str, ...]:
        """The rig inputs this controller sets (the benchmark's like-for-like class follows from
        them); default: every input a controller may set.  Override it to say less."""
        return tuple(self.context.model.commands)

    def step(self, t: float, measurement: Mapping[str, float], estimate=None) -> Action:
        """One control decision at time ``t`` [s] (module docstring).

        Raises
        ------
        PluginError : the controller broke its contract (module docstring); its run is FAILED.
        """
        ctx = self.context
        t0 = time.perf_counter()
        self.counts.steps += 1
        try:
            a = self._guarded_step(float(t), measurement, estimate)
        except SolverFailure as exc:
            self.counts.failures += 1
            a = self._guarded_fallback(f"SolverFailure: {exc}")
        took = time.perf_counter() - t0
        if ctx.deadline is not None and took > ctx.deadline:
            self.counts.deadline_misses += 1
            a = self._guarded_fallback(f"deadline miss: the answer took {1e3 * took:.3g} ms > "
                                       f"{1e3 * ctx.deadline:g} ms")
        if a.status is Status.FALLBACK:
            self.counts.fallbacks += 1
        elif a.status is Status.HOLD:
            self.counts.holds += 1
        return Action(dict(a.u), a.status, a.message, took)

    def _guarded_step(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        """:meth:`_step_impl` under the plug-in rule (:func:`models.plugins.call`: its timeout, every
        exception but a SolverFailure a PluginError) and the action's check (:meth:`_check_action`)."""
        a = plugins.call(self._step_impl, t, measurement, estimate, timeout=self.context.timeout, what="step")
        self._check_action(a)
        return a

    def _check_action(self, a) -> None:
        # (exact-type tests first: this runs on every call, and an ABC's isinstance costs a microsecond)
        if type(a) is not Action and not isinstance(a, Action):
            raise PluginError(f"TypeError: step must return an Action, got {type(a).__name__}")
        if not isinstance(a.status, Status):
            raise PluginError(f"TypeError: Action.status must be a Status, got {a.status!r}")
        if type(a.u) is not dict and not isinstance(a.u, Mapping):
            raise PluginError(f"TypeError: Action.u must be a mapping {{input: value}}, got {type(a.u).__name__}")
        if not a.u:
            return
        commands = self.context.model.commands
        for k, v in a.u.items():
            if k not in commands:
                raise PluginError(f"ValueError: command for {k!r}, which the rig cannot set "
                                  f"({', '.join(commands)})")
            if type(v) is float:        # the usual case, without the conversion's try
                ok = math.isfinite(v)
            else:
                try:
                    ok = math.isfinite(float(v))
                except (TypeError, ValueError):
                    raise PluginError(f"TypeError: command {k} must be a number, got {quote(v)} "
                                      f"({type(v).__name__})") from None
            if not ok:
                raise PluginError(f"FloatingPointError: non-finite command {k} = {v}")

    def _guarded_fallback(self, why: str) -> Action:
        try:
            a = plugins.call(self._fallback, why, timeout=self.context.timeout, what="fallback")
        except SolverFailure as exc:
            raise PluginError(f"the fallback failed: SolverFailure: {exc}") from exc
        self._check_action(a)
        return a

    def tuning_values(self) -> dict[str, float]:
        """The values the controller derived for itself (gains, filter times), by name, for
        reports and warnings: the attributes named in ``derived`` (a class attribute), or, where
        the controller has no such attribute, the option of that name (a gain given in the file)."""
        out = {}
        for n in getattr(self, "derived", ()):
            v = getattr(self, n, getattr(getattr(self, "options", None), n, None))
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                out[n] = float(v)
        return out

    @abstractmethod
    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        ...

    def _fallback(self, why: str) -> Action:
        """The documented fallback: leave every input to the programme."""
        return Action({}, Status.FALLBACK, f"fallback to the programme: {why}")
