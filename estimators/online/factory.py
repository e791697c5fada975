"""Build an online state estimator from a scenario's ``[estimator]`` table.

One factory shape for estimators and controllers (:mod:`models.plugins`)::

    est = make_estimator({"kind": "mhe", "window": 20}, EstimatorContext(model, params, dt))
    ctrl = make_controller({"kind": "brake"}, context_for(scenario, 0))

``kind`` is a built-in name (:data:`ESTIMATOR_KINDS`: ``ekf``
:class:`estimators.online.ekf.EKF`, ``mhe`` :class:`estimators.online.mhe.MHE`, ``fd``
:class:`estimators.online.fd.FiniteDifference`), an entry point of the group
``stickslip.estimators``, or ``"module:Class"``: any importable
:class:`estimators.base.StateEstimator` subclass (importing it runs its module: a scenario file
is code you trust).  ``kind`` is a class attribute of the estimator; its options are its
``options_class`` (a frozen dataclass; None: the raw table as a dict).  Bad keys and values are
one-line ConfigErrors naming ``<where>.<field>``; a constructor that fails otherwise is a
PluginError (a broken plug-in).
"""

from __future__ import annotations

from dataclasses import is_dataclass
from typing import Any, Mapping

from estimators.base import EstimatorContext, StateEstimator
from models.checks import options_from_mapping
from models import plugins
from models.errors import ConfigError

__all__ = ["make_estimator", "ESTIMATOR_KINDS", "ENTRY_POINT_GROUP", "estimator_class"]

#: built-in kinds -> "module:Class"
ESTIMATOR_KINDS: dict[str, str] = {
    "ekf": "estimators.online.ekf:EKF",
    "mhe": "estimators.online.mhe:MHE",
    "fd": "estimators.online.fd:FiniteDifference",
}
ENTRY_POINT_GROUP = "stickslip.estimators"


def estimator_class(kind: str, where: str = "estimator") -> type:
    """The StateEstimator subclass of a kind (built-in, entry point or ``module:Class``)."""
    return plugins.load_class(kind, registry=ESTIMATOR_KINDS, group=ENTRY_POINT_GROUP, base=StateEstimator,
                              where=where)


def make_estimator(spec: Mapping[str, Any], context: EstimatorContext) -> StateEstimator:
    """An estimator from ``spec`` (``{"kind": "ekf"|"mhe"|"fd"|<entry point>|"module:Class", ...options}``;
    kind default "ekf").

    Parameters
    ----------
    spec : the ``[estimator]`` table
    context : rig, parameters, DAQ period, sensor settings, initial guess, and ``where`` (the
        prefix of error messages, e.g. ``"scenario.toml: estimator"``)

    Raises
    ------
    ConfigError : unknown kind, bad option (one line naming the field).
    PluginError : the estimator's constructor failed otherwise (a broken plug-in).
    """
    if not isinstance(context, EstimatorContext):
        raise ConfigError(f"make_estimator needs an EstimatorContext, got {type(context).__name__}")
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{context.where} must be a table with a kind, got {type(spec).__name__}")
    kind = spec.get("kind", "ekf")
    cls = estimator_class(kind, context.where)
    table = {k: v for k, v in spec.items() if k != "kind"}
    oc = getattr(cls, "options_class", None)
    options = options_from_mapping(oc, table, context.where, kind=kind) if oc is not None and is_dataclass(oc) else table
    return plugins.construct(cls, options, context, context.where,
                             timeout=plugins.construction_timeout(kind, ESTIMATOR_KINDS, context.timeout))
