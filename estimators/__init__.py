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

from estimators.base import Estimate, EstimatorContext, StateEstimator
from estimators.identify import (BootstrapOptions, BootstrapResult, FitResult, IdentificationProblem,
                                 IdentifyOptions, LinearConstraint, bootstrap, identify, initial_guess)
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
