"""Identification of any rig's parameters from logs: multiple shooting, constrained Gauss-Newton.

Problem, function, result (as python-control's ``optimal``)::

    from estimators.identify import IdentifyOptions, identify
    fit = identify(log, "rig3", options=IdentifyOptions(free=("k1", "k2", "mu_s", "mu_k")))
    fit.status, fit.message          # Status.OK / WARNING / NOT_CONVERGED / FAILED, and why
    fit.estimate, fit.stderr, fit.params
    fit.condition, fit.weak_directions
    fit.method, fit.structure       # how it was solved; what the model's structure misses in the data
    boot = bootstrap(fit)            # the fit keeps its problem: nothing else is needed

Modules (one concept each):

- :mod:`~estimators.identify.options`: :class:`IdentifyOptions`, :class:`LinearConstraint`
- :mod:`~estimators.identify.outputs`: which log channels are compared and how the model predicts them
- :mod:`~estimators.identify.noise`: noise levels of outputs (weights) and inputs (errors in the variables)
- :mod:`~estimators.identify.guess`: starting values derived from the data (stick-slip cycle, torque balance)
- :mod:`~estimators.identify.shooting`: per-sample sensitivities, residuals, gaps, sparse Jacobians
- :mod:`~estimators.identify.problem`: :class:`IdentificationProblem` (``.solve()``, ``.refit()``)
- :mod:`~estimators.identify.gauss_newton`, :mod:`~estimators.identify.ipopt`: the solvers
- :mod:`~estimators.identify.continuation`: the globalisation (a continuation in eps when the direct
  fit fails or its structure misses; the lower consistent cost kept)
- :mod:`~estimators.identify.single`: single shooting (simulation error), where the gaps do not close
- :mod:`~estimators.identify.assemble`: a solver's end made into a :class:`FitResult`
- :mod:`~estimators.identify.diagnostics`: what the structure misses (the residual's slow part,
  spectrum and whiteness; the continuity gaps)
- :mod:`~estimators.identify.covariance`: standard errors, correlations, conditioning, weak directions
- :mod:`~estimators.identify.result`: :class:`FitResult`
- :mod:`~estimators.identify.validation`: hold-out prediction with the exact plant
- :mod:`~estimators.identify.bootstrap`: parametric bootstrap error bars
"""

from __future__ import annotations

from models.params import ParameterSet
from estimators.identify.bootstrap import BootstrapOptions, BootstrapResult, bootstrap
from estimators.identify.continuation import Attempt
from estimators.identify.covariance import WeakDirection
from estimators.identify.diagnostics import StructureDiagnostics
from estimators.identify.guess import Guess, initial_guess
from estimators.identify.noise import detect_input_noise, input_noise_hints
from estimators.identify.options import IdentifyOptions, LinearConstraint
from estimators.identify.problem import IdentificationProblem
from estimators.identify.result import FitResult, IdentifiabilityWarning
from estimators.identify.validation import Validation

__all__ = ["IdentifyOptions", "LinearConstraint", "IdentificationProblem", "FitResult", "Validation",
           "WeakDirection", "IdentifiabilityWarning", "identify", "initial_guess", "Guess", "bootstrap",
           "BootstrapOptions", "BootstrapResult", "detect_input_noise", "input_noise_hints", "StructureDiagnostics",
           "Attempt"]


def identify(logs, model, initial: ParameterSet | None = None, options: IdentifyOptions | None = None, *,
             holdout: float = 0.0) -> FitResult:
    """Fit the free parameters of ``model`` to one or several logs (one shot).

    Parameters
    ----------
    logs : a :class:`models.logs.Log` or a sequence of them (one sample period; shared
        parameters, separate state nodes and encoder zeros)
    model : a rig name (``"rig3"``), rig-file path or :class:`models.rig.RigModel`
    initial : starting values and fixed parameters; None: the published set with the free
        parameters guessed from the data (:func:`initial_guess`)
    options : :class:`IdentifyOptions` (required: at least ``free``)
    holdout : fraction in [0, 0.9) of the end of each log kept out and, for the first log,
        predicted with the exact plant afterwards (``fit.validation``)

    Returns
    -------
    FitResult (``fit.problem`` is the :class:`IdentificationProblem`)

    Raises
    ------
    ConfigError : bad options, unknown parameters or channels, an initial value outside its bounds
    DataError : a log lacks a column, has another sample period or is too short
    SolverFailure : the solver returned non-finite values
    """
    return IdentificationProblem(model, logs, initial, options, holdout=holdout).solve()
