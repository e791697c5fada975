"""Build a controller from a scenario's ``[[controllers]]`` entry.

One factory shape for controllers and estimators (:mod:`models.plugins`)::

    ctrl = make_controller({"kind": "brake", "gain_overspeed": 80.0}, context_for(scenario, 0))
    est = make_estimator({"kind": "ekf"}, EstimatorContext(model, params, dt))

``kind`` is a built-in name (:data:`CONTROLLER_KINDS`), an entry point of the group
``stickslip.controllers`` (a package that registers its own controllers), or
``"module:Class"``: any importable :class:`mitigate.controllers.base.Controller` subclass
(loaded with :mod:`importlib`, never ``eval``; importing it runs the module's code: a scenario
file is code you trust).  ``kind`` is a class attribute of the controller.  The entry's other
keys are the controller's options: validated by its ``options_class`` (a frozen dataclass) when
it has one, else passed as a dict.  Every error of the entry is one line naming
``controllers[i].<field>`` (ConfigError); a constructor that fails otherwise is a broken plug-in
(PluginError: the runner marks that controller's run FAILED, the others go on).
"""

from __future__ import annotations

from dataclasses import is_dataclass
from typing import Any, Mapping

from mitigate.controllers.base import ControlContext, Controller
from models import plugins
from models.checks import options_from_mapping
from models.errors import ConfigError, PluginError

__all__ = ["make_controller", "controller_class", "CONTROLLER_KINDS", "ENTRY_POINT_GROUP", "parse_options",
           "context_for"]

#: built-in kinds -> "module:Class"
CONTROLLER_KINDS: dict[str, str] = {
    "pi": "mitigate.controllers.pi:PIOnly",
    "brake": "mitigate.controllers.brake:BrakeController",
    "supervisor": "mitigate.controllers.supervisor:SpeedSupervisor",
    "nmpc": "mitigate.controllers.nmpc:NMPC",
    "exported": "mitigate.controllers.exported:ExportedController",
    "softspeed": "mitigate.controllers.softspeed:SoftSpeed",
    "ztorque": "mitigate.controllers.ztorque:ZTorque",
    "doskil": "mitigate.controllers.doskil:DOSKIL",
    "ztorque_doskil": "mitigate.controllers.combined:ZTorqueDOSKIL",
}
ENTRY_POINT_GROUP = "stickslip.controllers"


def controller_class(kind: str, where: str = "controller") -> type:
    """The Controller subclass of a kind (built-in, entry point or ``module:Class``)."""
    return plugins.load_class(kind, registry=CONTROLLER_KINDS, group=ENTRY_POINT_GROUP, base=Controller, where=where)


def parse_options(cls, options: Mapping[str, Any], where: str):
    """``cls(**options)`` with one-line errors naming ``where.<field>``: the class's own
    ``from_mapping(options, where)`` if it has one, else :func:`models.checks.options_from_mapping`."""
    if hasattr(cls, "from_mapping"):
        try:
            return cls.from_mapping(options, where)
        except ConfigError:
            raise
        except Exception as exc:  # noqa: BLE001 - a plug-in's from_mapping may raise anything: still bad input
            raise ConfigError(f"{where}: {plugins.describe(exc)}") from None
    return options_from_mapping(cls, options, where)


def options_of(cls, options: Mapping[str, Any], where: str):
    """The options object of a controller class from its raw table (its ``options_class``, or the dict)."""
    oc = getattr(cls, "options_class", None)
    return parse_options(oc, dict(options), where) if oc is not None and is_dataclass(oc) else dict(options)


def context_for(scenario, index: int | None = None) -> ControlContext:
    """The :class:`ControlContext` of a scenario (the nominal model, never the plant; its ``[control]``
    section whole)."""
    from mitigate.scenario import controller_where
    where = (controller_where(scenario.where, index, scenario.controllers[index].name)
             if index is not None and index < len(scenario.controllers) else f"{scenario.where}: controller")
    return ControlContext(model=scenario.model, params=scenario.model_params, dt=scenario.dt,
                          programme=scenario.programme, sensors=scenario.sensors, where=where,
                          schedule=dict(scenario.inputs), control=scenario.control, estimated=_estimated(scenario))


def _estimated(scenario) -> tuple[str, ...]:
    """The states the scenario's estimator estimates through the model: every state of the rig for a
    model-based kind (``StateEstimator.model_based``), else none (an unknown kind is refused where the
    estimator is built)."""
    from estimators.online.factory import estimator_class
    try:
        cls = estimator_class(scenario.estimator.get("kind"), f"{scenario.where}: estimator")
    except (ConfigError, PluginError):
        return ()
    return tuple(scenario.model.states) if getattr(cls, "model_based", False) else ()


def _split(spec) -> tuple[Any, dict]:
    if isinstance(spec, Mapping):
        return spec.get("kind"), {k: v for k, v in spec.items() if k not in ("kind", "name")}
    kind, options = getattr(spec, "kind", None), getattr(spec, "options", None)
    if options is None:
        raise ConfigError(f"a controller spec must be a table with a kind or a ControllerSpec, got {type(spec).__name__}")
    return kind, dict(options)


def make_controller(spec, context: ControlContext) -> Controller:
    """The controller of a ``[[controllers]]`` entry, built the one way every controller is
    built: ``cls(options, context)``.

    Parameters
    ----------
    spec : a :class:`mitigate.scenario.ControllerSpec`, or a table ``{"kind": ..., **options}``
        (a ``name`` key is ignored)
    context : :class:`ControlContext` (:func:`context_for` gives a scenario's)

    Raises
    ------
    ConfigError : unknown kind, bad option, or a channel/input the rig lacks (one line).
    PluginError : the controller's constructor failed otherwise (a broken plug-in).
    """
    if not isinstance(context, ControlContext):
        raise ConfigError(f"make_controller needs a ControlContext (context_for(scenario, i)), got "
                          f"{type(context).__name__}")
    kind, options = _split(spec)
    cls = controller_class(kind, context.where)
    return plugins.construct(cls, options_of(cls, options, context.where), context, context.where,
                             timeout=plugins.construction_timeout(kind, CONTROLLER_KINDS, context.timeout))
