"""Build a controller from a scenario's ``[[controllers]]`` entry.

``kind`` is a built-in name (:data:`CONTROLLER_KINDS`), an entry point of the group
``stickslip.controllers`` (a package that registers its own controllers), or
``"module:Class"``: any importable :class:`mitigate.controllers.base.Controller` subclass
(loaded with :mod:`importlib`, never ``eval``).  The entry's other keys are the controller's
options: validated by its ``options_class`` (a frozen dataclass) when it has one, else
passed as a dict.  Every error is one line naming ``controllers[i].<field>``.
"""

from __future__ import annotations

import importlib
import re
from dataclasses import fields, is_dataclass
from typing import Any, Mapping

from mitigate.controllers.base import ControlContext, Controller
from models.errors import ConfigError

__all__ = ["make_controller", "controller_class", "CONTROLLER_KINDS", "parse_options", "context_for"]

#: built-in kinds -> "module:Class"
CONTROLLER_KINDS: dict[str, str] = {
    "pi": "mitigate.controllers.pi:PIOnly",
    "brake": "mitigate.controllers.brake:BrakeController",
    "supervisor": "mitigate.controllers.supervisor:SpeedSupervisor",
    "nmpc": "mitigate.controllers.nmpc:NMPC",
    "softspeed": "mitigate.controllers.softspeed:SoftSpeed",
    "ztorque": "mitigate.controllers.ztorque:ZTorque",
    "doskil": "mitigate.controllers.doskil:DOSKIL",
}
ENTRY_POINT_GROUP = "stickslip.controllers"
_REF = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


def _one_line(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())


def _load(ref: str, where: str) -> type:
    mod_name, _, cls_name = ref.partition(":")
    try:
        mod = importlib.import_module(mod_name)
    except ModuleNotFoundError as exc:
        if exc.name and (mod_name == exc.name or mod_name.startswith(exc.name + ".")):
            raise ConfigError(f"{where}.kind: module {mod_name!r} not found (is it installed or on PYTHONPATH?)") from None
        raise ConfigError(f"{where}.kind: module {mod_name!r} could not be imported: {_one_line(exc)}") from None
    except Exception as exc:  # noqa: BLE001 - a user's module may fail in any way; say so on one line
        raise ConfigError(f"{where}.kind: module {mod_name!r} could not be imported: {_one_line(exc)}") from None
    cls = getattr(mod, cls_name, None)
    if cls is None:
        raise ConfigError(f"{where}.kind: module {mod_name!r} has no {cls_name!r}")
    if not (isinstance(cls, type) and issubclass(cls, Controller)):
        raise ConfigError(f"{where}.kind: {ref!r} is not a Controller subclass "
                          f"(mitigate.controllers.base.Controller)")
    return cls


def controller_class(kind: str, where: str = "controller") -> type:
    """The Controller subclass of a kind (built-in, entry point or ``module:Class``)."""
    if not isinstance(kind, str) or not kind:
        raise ConfigError(f"{where}.kind must be a controller kind, got {kind!r}")
    if kind in CONTROLLER_KINDS:
        return _load(CONTROLLER_KINDS[kind], where)
    if _REF.match(kind):
        return _load(kind, where)
    from importlib.metadata import entry_points
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name == kind:
            try:
                cls = ep.load()
            except Exception as exc:  # noqa: BLE001 - as for module:Class
                raise ConfigError(f"{where}.kind: entry point {kind!r} could not be loaded: {_one_line(exc)}") from None
            if not (isinstance(cls, type) and issubclass(cls, Controller)):
                raise ConfigError(f"{where}.kind: entry point {kind!r} is not a Controller subclass")
            return cls
    raise ConfigError(f"{where}.kind must be one of {', '.join(CONTROLLER_KINDS)}, a registered "
                      f"'{ENTRY_POINT_GROUP}' entry point or 'module:Class', got {kind!r}")


def parse_options(cls, options: Mapping[str, Any], where: str):
    """``cls(**options)`` with one-line errors naming ``where.<field>``."""
    if hasattr(cls, "from_mapping"):
        return cls.from_mapping(options, where)
    names = [f.name for f in fields(cls)]
    for k in options:
        if k not in names:
            raise ConfigError(f"{where}.{k}: unknown option; expected one of {', '.join(names) or '(none)'}")
    try:
        return cls(**options)
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(where) else f"{where}.{msg}") from None
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def context_for(scenario, index: int | None = None) -> ControlContext:
    """The :class:`ControlContext` of a scenario (the nominal model, never the plant)."""
    where = f"{scenario.where}: controllers[{index}]" if index is not None else f"{scenario.where}: controller"
    return ControlContext(model=scenario.model, params=scenario.model_params, dt=scenario.dt,
                          period=scenario.dt * scenario.control_every, programme=scenario.programme,
                          sensors=scenario.sensors, where=where, schedule=dict(scenario.inputs))


def make_controller(spec, scenario, index: int | None = None) -> Controller:
    """The controller of a ``[[controllers]]`` entry (``spec``: a ControllerSpec), built the
    one way every controller is built: ``cls(options, context)``.

    Raises
    ------
    ConfigError : unknown kind, bad option, or a channel/input the rig lacks (one line).
    """
    context = context_for(scenario, index)
    cls = controller_class(spec.kind, context.where)
    oc = getattr(cls, "options_class", None)
    opts = parse_options(oc, dict(spec.options), context.where) if oc is not None and is_dataclass(oc) \
        else dict(spec.options)
    try:
        return cls(opts, context)
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(context.where) else f"{context.where}: {msg}") from None
