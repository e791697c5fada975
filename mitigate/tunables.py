"""What a controller lets a benchmark tune, and which actuators it uses.

A controller class declares its tunables (``tunables = {"kp_factor": Tunable(low=0.5, high=8)}``):
each is one of its options (a dotted name reaches into a table option: ``"weights.speed"``) with a
search range.  Ranges are scale-free where the option is (SoftSpeed's multiple of ``Z``, Z-Torque's
``z``); an option with a unit gives ``scale``, a function of the :class:`ControlContext` that returns
its natural unit on the rig (the brake's gain: the servo's force range per programmed speed), and
the range is in multiples of it.  ``needs = "drive"`` or ``"force"`` marks a tunable that only
matters when the controller sets that kind of input (the NMPC's force weights on a motor-only NMPC).

A built controller says what it sets (:meth:`mitigate.controllers.base.Controller.actuated_inputs`);
:func:`actuator_class` turns that into the benchmark's like-for-like classes: ``"drive"`` (the drive's
set-point only), ``"force"`` (normal forces only), ``"both"``, or ``"none"`` (the programme alone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from models.checks import finite_number
from models.errors import ConfigError

__all__ = ["Tunable", "tunables_of", "actuator_class", "ACTUATOR_CLASSES", "set_option"]

#: the like-for-like classes, in the order the benchmark reports them
ACTUATOR_CLASSES = ("drive", "force", "both", "none")


@dataclass(frozen=True, kw_only=True)
class Tunable:
    """The search range of one option.

    Parameters
    ----------
    low, high : range, in multiples of ``scale(context)`` (or in the option's own unit without one)
    log : search on a log scale (gains, time constants, weights)
    integer : the option is an integer
    scale : ``context -> float``, the option's natural unit on the rig (None: 1)
    needs : "drive" or "force": the option only matters when the controller sets that kind of input
    derived : the multiple the option stands for when it is 0 ("derive it from the rig"), where the
        controller derives it as a multiple of ``scale`` (the tuning's first trial starts there)
    doc : what it is
    """

    low: float
    high: float
    log: bool = True
    integer: bool = False
    scale: Callable[[Any], float] | None = None
    needs: str = ""
    derived: float | None = None
    doc: str = ""

    def __post_init__(self):
        lo = finite_number(self.low, "tunable.low")
        hi = finite_number(self.high, "tunable.high")
        if not hi > lo:
            raise ConfigError(f"tunable range must have low < high, got [{lo:g}, {hi:g}]")
        if self.log and not lo > 0:
            raise ConfigError(f"a log-scale tunable needs low > 0, got {lo:g}")
        if self.needs not in ("", "drive", "force"):
            raise ConfigError(f"tunable.needs must be '', 'drive' or 'force', got {self.needs!r}")

    def unit_value(self, context) -> float:
        """The option value of a multiple of 1 on this rig."""
        if self.scale is None:
            return 1.0
        v = float(self.scale(context))
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"{context.where}: the tunable's scale on this rig is {v!r}; expected > 0")
        return v


def actuator_class(model, inputs) -> str:
    """``"drive"``, ``"force"``, ``"both"`` or ``"none"`` for the inputs a controller sets."""
    inputs = set(inputs)
    drive = model.drive_input in inputs
    force = bool(inputs & set(model.servo_inputs))
    return "both" if drive and force else "drive" if drive else "force" if force else "none"


def tunables_of(controller) -> dict[str, Tunable]:
    """The tunables a BUILT controller declares that matter for what it sets (``needs``)."""
    cls = type(controller)
    decl = dict(getattr(cls, "tunables", {}) or {})
    for k, v in decl.items():
        if not isinstance(v, Tunable):
            raise ConfigError(f"{cls.__name__}.tunables[{k!r}] must be a Tunable, got {type(v).__name__}")
    klass = actuator_class(controller.context.model, controller.actuated_inputs())
    keep = {"drive": ("drive", "both"), "force": ("force", "both")}
    return {k: v for k, v in decl.items() if not v.needs or klass in keep[v.needs]}


def set_option(options: Mapping[str, Any], name: str, value: Any) -> dict:
    """A copy of a raw options table with ``name`` set (a dotted name sets inside a table option)."""
    out = dict(options)
    head, _, rest = name.partition(".")
    if rest:
        sub = out.get(head, {})
        if not isinstance(sub, Mapping):
            raise ConfigError(f"option {head!r} must be a table to set {name!r}, got {sub!r}")
        out[head] = set_option(sub, rest, value)
    else:
        out[head] = value
    return out
