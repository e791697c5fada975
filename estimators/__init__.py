"""Estimators: parameter estimation from logs, and online state estimation (EKF, MHE).

Identification (:mod:`estimators.identify`)::

    from estimators import identify, IdentifyOptions
    fit = identify(log, "rig3", options=IdentifyOptions(free=("k1", "k2", "mu_s", "mu_k")))
    fit.status, fit.estimate, fit.stderr, fit.weak_directions

Online state estimation (:mod:`estimators.online`): every estimator is built as
``Estimator(options, context)`` and answers ``estimate = estimator.update(t, measurement, u)``::

    from estimators import EKF, EKFOptions, EstimatorContext
    ekf = EKF(EKFOptions(), EstimatorContext(model, params, dt))
    ekf.observability.message, ekf.observability_steady.message   # what this configuration can know

Over a recorded log, as ``mitigate estimate`` does::

    from estimators import estimate_log
    res = estimate_log(read_csv("run.csv"), "ekf", "rig3")   # -> EstimationResult
    res.state("twist_k1"), res.std, res.status, res.counts

Also here: :mod:`estimators.twostep` (seed 002's two-step identification) and
:mod:`estimators.thesis_id` (the thesis' own identification, recomputed from its raw data).
"""

import models.portable  # noqa: F401 - first: it pins OpenBLAS's kernels before numpy loads them

import importlib
import sys
import types

from estimators.base import Estimate, EstimatorContext, StateEstimator
from estimators.online.ekf import EKF
from estimators.online.factory import ESTIMATOR_KINDS, make_estimator
from estimators.online.fd import FiniteDifference
from estimators.online.mhe import MHE
from estimators.online.observability import ObservabilityReport, observability
from estimators.online.options import EKFOptions, FDOptions, MHEOptions
from estimators.online.replay import EstimationResult, estimate_log

__all__ = [
    "identify", "IdentifyOptions", "LinearConstraint", "IdentificationProblem", "FitResult", "initial_guess",
    "bootstrap", "BootstrapOptions", "BootstrapResult",
    "Estimate", "EstimatorContext", "StateEstimator",
    "EKF", "MHE", "FiniteDifference", "EKFOptions", "MHEOptions", "FDOptions", "make_estimator", "ESTIMATOR_KINDS",
    "observability", "ObservabilityReport", "estimate_log", "EstimationResult",
]

#: identification's names, imported on first use (PEP 562): a process that only runs a closed loop
#: (every worker of `mitigate run` and `mitigate benchmark`) does not pay for importing it (0.2 s)
_IDENTIFY = ("BootstrapOptions", "BootstrapResult", "FitResult", "IdentificationProblem", "IdentifyOptions",
             "LinearConstraint", "bootstrap", "identify", "initial_guess")


def __getattr__(name: str):
    if name in _IDENTIFY:
        return getattr(importlib.import_module("estimators.identify"), name)
    raise AttributeError(f"module 'estimators' has no attribute {name!r}")


class _Package(types.ModuleType):
    """``estimators.identify`` is the function, as it was when this package imported it eagerly: the
    import system binds the subpackage of that name here when it is first imported; keep the function."""

    def __setattr__(self, name, value):
        if name == "identify" and isinstance(value, types.ModuleType):
            value = value.identify
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
