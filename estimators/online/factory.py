"""Build an online state estimator from a scenario's ``[estimator]`` table.

One call for every kind, one constructor shape (``Kind(options, context)``)::

    est = make_estimator({"kind": "mhe", "window": 20}, EstimatorContext(model, params, dt))

Kinds: ``ekf`` (:class:`estimators.online.ekf.EKF`), ``mhe``
(:class:`estimators.online.mhe.MHE`), ``fd`` (:class:`estimators.online.fd.FiniteDifference`).
Bad keys and values are one-line ConfigErrors naming ``<where>.<field>``.
"""

from __future__ import annotations

from typing import Any, Mapping

from estimators.base import EstimatorContext, StateEstimator
from estimators.online.options import EKFOptions, FDOptions, MHEOptions, options_from_mapping
from models.errors import ConfigError

__all__ = ["make_estimator", "ESTIMATOR_KINDS", "estimator_class"]

ESTIMATOR_KINDS = ("ekf", "mhe", "fd")


def estimator_class(kind: str, where: str = "estimator"):
    """``(class, options class)`` of an estimator kind."""
    if kind == "ekf":
        from estimators.online.ekf import EKF
        return EKF, EKFOptions
    if kind == "mhe":
        from estimators.online.mhe import MHE
        return MHE, MHEOptions
    if kind == "fd":
        from estimators.online.fd import FiniteDifference
        return FiniteDifference, FDOptions
    raise ConfigError(f"{where}.kind must be one of {', '.join(ESTIMATOR_KINDS)}, got {kind!r}")


def make_estimator(spec: Mapping[str, Any], context: EstimatorContext) -> StateEstimator:
    """An estimator from ``spec`` (``{"kind": "ekf"|"mhe"|"fd", ...options}``; kind default "ekf").

    Parameters
    ----------
    spec : the ``[estimator]`` table
    context : rig, parameters, DAQ period, sensor settings, initial guess, and ``where`` (the
        prefix of error messages, e.g. ``"scenario.toml: estimator"``)
    """
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{context.where} must be a table with a kind, got {type(spec).__name__}")
    if not isinstance(context, EstimatorContext):
        raise ConfigError(f"{context!r} must be an EstimatorContext")
    cls, ocls = estimator_class(spec.get("kind", "ekf"), context.where)
    options = options_from_mapping(ocls, {k: v for k, v in spec.items() if k != "kind"}, context.where)
    return cls(options, context)
