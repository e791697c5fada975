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
``_step_impl`` with the same arguments.  It never raises inside a closed loop: an exception
or a non-finite command is counted as a failure and answered by the fallback, the scenario's
programme (the rig as it runs without the controller), with ``Status.FALLBACK``.

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

from models.errors import ConfigError
from models.params import ParameterSet
from models.sensors import SensorOptions
from models.status import Status

__all__ = ["Action", "Controller", "ControllerCounts", "ControlContext"]


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
        return self.status is not Status.FALLBACK


@dataclass(frozen=True)
class ControlContext:
    """What every controller is told about the loop it runs in.

    Attributes
    ----------
    model : the rig (:class:`models.rig.RigModel`) the controller believes
    params : its nominal parameters (never the plant's true ones)
    dt : DAQ period [s]; period : the controller's call period [s] (``dt`` x ``control.every``)
    programme : ``t -> (nu,)`` the scenario's scheduled inputs in ``model.inputs`` order
        (the speed programme, the normal forces)
    schedule : ``{input: t -> value}``, the same per input (faster for a law that needs one)
    sensors : the sensor settings (noise levels follow from the rig file and these)
    where : prefix of error messages (``"scenario.toml: controllers[2]"``)
    """

    model: Any
    params: ParameterSet
    dt: float
    period: float
    programme: Callable[[float], np.ndarray]
    sensors: SensorOptions = SensorOptions()
    where: str = "controller"
    schedule: Mapping[str, Callable[[float], float]] = field(default_factory=dict)

    def scheduled(self, t: float, name: str) -> float:
        """The programme's value of input ``name`` at ``t`` (one input's profile when the context
        has ``schedule``, else the whole programme)."""
        f = self.schedule.get(name)
        if f is not None:
            return float(f(t))
        return float(self.programme(t)[self.model.inputs.index(name)])

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
    failures: int = 0
    fallbacks: int = 0
    holds: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(steps=self.steps, failures=self.failures, fallbacks=self.fallbacks, holds=self.holds)


class Controller(ABC):
    """Template: :meth:`step` guards, times and counts; subclasses implement ``_step_impl``.

    Subclasses set ``kind`` (the scenario name) and ``options_class`` (a frozen, keyword-only
    dataclass that validates itself; None to take the raw options table as a dict).
    """

    kind: ClassVar[str] = "controller"
    options_class: ClassVar[type | None] = None
    #: ``{option: mitigate.tunables.Tunable}``: what a benchmark may tune (``mitigate tune``)
    tunables: ClassVar[Mapping[str, Any]] = {}

    def __init__(self, options: Any, context: ControlContext):
        self.options = options
        self.context = context
        self.counts = ControllerCounts()

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
        """One control decision at time ``t`` [s] (module docstring)."""
        t0 = time.perf_counter()
        self.counts.steps += 1
        try:
            a = self._step_impl(float(t), measurement, estimate)
            if not isinstance(a, Action):
                raise TypeError(f"_step_impl must return an Action, got {type(a).__name__}")
            for k, v in a.u.items():
                if k not in self.context.model.commands:
                    raise ValueError(f"command for {k!r}, which the rig cannot set "
                                     f"({', '.join(self.context.model.commands)})")
                if not math.isfinite(float(v)):
                    raise FloatingPointError(f"non-finite command {k} = {v}")
        except Exception as exc:  # never raise inside a closed loop
            self.counts.failures += 1
            a = self._fallback(f"{type(exc).__name__}: {exc}")
        if a.status is Status.FALLBACK:
            self.counts.fallbacks += 1
        elif a.status is Status.HOLD:
            self.counts.holds += 1
        return Action(dict(a.u), a.status, a.message, time.perf_counter() - t0)

    @abstractmethod
    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        ...

    def _fallback(self, why: str) -> Action:
        """The documented fallback: leave every input to the programme."""
        return Action({}, Status.FALLBACK, f"fallback to the programme: {why}")
