"""Build a state estimator from a scenario's ``[estimator]`` table (placeholder of the core
branch: only ``fd``; the online-estimators branch adds ``ekf`` and ``mhe``)."""

from __future__ import annotations

from typing import Any, Mapping

from estimators.base import EstimatorContext, StateEstimator
from models.errors import ConfigError

__all__ = ["make_estimator", "ESTIMATOR_KINDS"]

ESTIMATOR_KINDS = ("fd",)


def make_estimator(spec: Mapping[str, Any], context: EstimatorContext) -> StateEstimator:
    kind = spec.get("kind", "fd")
    opts = {k: v for k, v in spec.items() if k != "kind"}
    if kind == "fd":
        from estimators.fd import FiniteDifference
        if opts:
            raise ConfigError(f"{context.where}: unknown key(s) {', '.join(opts)} for kind 'fd'")
        return FiniteDifference(None, context)
    raise ConfigError(f"{context.where}.kind must be one of {', '.join(ESTIMATOR_KINDS)}, got {kind!r}")
