"""Build a state estimator from a scenario's ``[estimator]`` table.

Kinds: ``fd`` (finite-difference baseline); ``ekf`` and ``mhe`` are added by
:mod:`estimators.ekf` and :mod:`estimators.mhe`.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from estimators.base import StateEstimator
from estimators.fd import FiniteDifference
from models.errors import ConfigError
from models.params import Rig3Params
from models.sensors import SensorOptions

__all__ = ["make_estimator", "ESTIMATOR_KINDS"]

ESTIMATOR_KINDS = ("ekf", "mhe", "fd")


def make_estimator(spec: Mapping[str, Any], model_params: Rig3Params, sensors: SensorOptions, dt: float,
                   x0: np.ndarray | None = None, where: str = "estimator") -> StateEstimator:
    """An estimator for the 3-disc rig.

    Parameters
    ----------
    spec : ``{"kind": "ekf"|"mhe"|"fd", ...options}``
    model_params : the parameters the estimator believes
    sensors : sensor specification (noise covariances derive from it)
    dt : DAQ period [s]
    x0 : initial state guess (rig3 order); zeros if None
    """
    kind = spec.get("kind", "ekf")
    opts = {k: v for k, v in spec.items() if k != "kind"}
    if kind == "fd":
        if opts:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(opts)} for kind 'fd'")
        return FiniteDifference(sensors, dt)
    if kind == "ekf":
        from estimators.ekf import make_ekf
        return make_ekf(opts, model_params, sensors, dt, x0, where)
    if kind == "mhe":
        from estimators.mhe import make_mhe
        return make_mhe(opts, model_params, sensors, dt, x0, where)
    raise ConfigError(f"{where}.kind must be one of {', '.join(ESTIMATOR_KINDS)}, got {kind!r}")
