"""The one interface of every online state estimator.

Every estimator is built the same way, ``StateEstimator(options, context)``, and answers
the same call, with its arguments in the order of :meth:`mitigate.controllers.base.Controller.step`::

    estimate = estimator.update(t, measurement, u)

- ``t`` [s]: the time of the DAQ sample;
- ``measurement``: the DAQ's channels at ``t`` (a dict);
- ``u``: the model inputs applied over the sample that ended at ``t`` (``model.inputs``
  order; logged normal forces are corrected for their load cells' gain and offset inside).

The closed loop, the scenario runner and a scenario file can therefore swap an EKF for an
MHE or for the finite-difference baseline.  The public :meth:`StateEstimator.update` guards
its inputs: a missing or NaN channel skips its correction (counted); a
:class:`models.errors.SolverFailure` raised inside ``_update_impl`` (the one transient failure,
e.g. the MHE's QP) is counted and answered by the documented fallback
(:meth:`StateEstimator._fallback`); anything else -- another exception, ``SystemExit``, a
non-finite estimate, a result that is not an :class:`Estimate`, a call that does not return
within the context's ``timeout`` -- raises :class:`models.errors.PluginError` with the reason,
and the closed loop ends that run as FAILED (:mod:`models.plugins`).

Estimators are built by :func:`estimators.online.factory.make_estimator` (built-in kinds, the
``stickslip.estimators`` entry points, or ``module:Class``), the same way as controllers.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Mapping

import numpy as np

from models import plugins
from models.errors import ConfigError, PluginError, SolverFailure
from models.params import ParameterSet
from models.sensors import SensorOptions
from models.status import Outcome, Status

__all__ = ["Estimate", "StateEstimator", "EstimatorCounts", "EstimatorContext"]


@dataclass(frozen=True)
class Estimate(Outcome):
    """A state estimate with its covariance.

    Attributes
    ----------
    t : time [s]
    x : (nx,) estimated state, in the order of ``names``
    P : (nx, nx) covariance
    names : state names (the rig's states, then augmented unknowns)
    status : Status.OK, or Status.FALLBACK when a fallback produced it
    message : detail ("prediction only: missing omega1", "fallback: ...")
    corrected : whether a measurement update was applied
    solve_time : wall time of the update [s]
    """

    t: float
    x: np.ndarray
    P: np.ndarray
    names: tuple[str, ...]
    status: Status = Status.OK
    message: str = "ok"
    corrected: bool = True
    solve_time: float = 0.0

    def get(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def std(self, name: str) -> float:
        i = self.names.index(name)
        return float(math.sqrt(max(self.P[i, i], 0.0)))

    def has(self, name: str) -> bool:
        return name in self.names


@dataclass(frozen=True)
class EstimatorContext:
    """What every estimator is told.

    Attributes
    ----------
    model : the rig (:class:`models.rig.RigModel`) the estimator believes
    params : its parameters (nominal, or fitted)
    dt : DAQ period [s]
    sensors : sensor settings (noise covariances follow from the rig's sensors and these)
    x0 : initial state guess in ``model.states`` order (None: at rest)
    where : prefix of error messages
    timeout : wall time after which an update that has not returned fails the run [s]
        (``[control] timeout`` of a scenario; None: never)
    """

    model: Any
    params: ParameterSet
    dt: float
    sensors: SensorOptions = SensorOptions()
    x0: np.ndarray | None = None
    where: str = "estimator"
    timeout: float | None = None


@dataclass
class EstimatorCounts:
    """How often the estimator had to degrade (reported by the runner)."""

    steps: int = 0
    dropouts: int = 0      # correction skipped: missing or non-finite measurement
    failures: int = 0      # the estimator's own solve failed
    fallbacks: int = 0     # an estimate came from the fallback

    def as_dict(self) -> dict[str, int]:
        return dict(steps=self.steps, dropouts=self.dropouts, failures=self.failures, fallbacks=self.fallbacks)


def _with_solve_time(est: Estimate, seconds: float) -> Estimate:
    """``dataclasses.replace(est, solve_time=seconds)``; for an :class:`Estimate` itself (it has no
    ``__post_init__``) without the generated ``__init__``'s field-by-field frozen assignments: this
    runs every sample."""
    if type(est) is not Estimate:
        return replace(est, solve_time=seconds)
    new = object.__new__(Estimate)
    new.__dict__.update(est.__dict__)
    new.__dict__["solve_time"] = seconds
    return new


class StateEstimator(ABC):
    """Template: :meth:`update` guards, times and counts; subclasses implement ``_update_impl``.

    Subclasses set ``kind``, ``options_class`` (the options are checked to be one), and in ``__init__`` ``self.names`` and
    ``self.channels`` (the measurement channels used); ``_update_impl(t, y, mask, u)`` gets
    the channels in ``self.channels`` order and ``mask`` marking the finite ones.
    """

    kind: ClassVar[str] = "estimator"
    options_class: ClassVar[type | None] = None
    #: it estimates every state of :attr:`names` through the rig's model (the EKF, the MHE), so a
    #: controller may take from it the speed of a body the rig does not measure; False (the
    #: finite-difference baseline, and a plug-in unless it says so): it only reads what is measured
    model_based: ClassVar[bool] = False
    names: tuple[str, ...] = ()
    channels: tuple[str, ...] = ()
    #: how the step functions were built ("compiled (...)", "compile failed, ..."); None: nothing compiled
    compile_status: str | None = None
    #: construction-time observability reports (:class:`estimators.online.observability.ObservabilityReport`);
    #: None: not checked, or nothing to check
    observability: Any = None
    observability_steady: Any = None

    def __init__(self, options: Any, context: EstimatorContext):
        oc = type(self).options_class
        if oc is not None and not isinstance(options, oc):
            raise ConfigError(f"{context.where}: {self.kind.upper()} options must be {oc.__name__}, "
                              f"got {type(options).__name__}")
        self.options = options
        self.context = context
        self.counts = EstimatorCounts()
        self.last: Estimate | None = None

    @property
    def units(self) -> tuple[str, ...]:
        """SI units of :attr:`names` (default: the rig's states)."""
        return tuple(self.context.model.state_units)

    @property
    def observability_message(self) -> str:
        """One line: what this configuration can know (default: not checked)."""
        return "observability not checked"

    def observability_windows(self, x, u, *, window: float | None = None, max_windows: int = 12) -> list:
        """Observability along windows of a run (default: none checked)."""
        return []

    def prior(self) -> Estimate | None:
        """The estimate before the first sample (row 0 of a log's estimates); None: no prior."""
        return None

    def update(self, t: float, measurement: Mapping[str, float], u) -> Estimate:
        """Process one DAQ sample (module docstring)."""
        t0 = time.perf_counter()
        y = np.array([float(measurement.get(c, np.nan)) if measurement is not None else np.nan
                      for c in self.channels])
        mask = np.isfinite(y)
        if not mask.all():
            self.counts.dropouts += 1
        u = np.asarray(u, dtype=float).ravel()
        self.counts.steps += 1
        try:
            est = plugins.call(self._update_impl, float(t), y, mask, u, timeout=self.context.timeout, what="update")
            self._check_estimate(est)
        except SolverFailure as exc:
            self.counts.failures += 1
            try:
                est = plugins.call(self._fallback, float(t), y, mask, u, f"fallback: SolverFailure: {exc}",
                                   timeout=self.context.timeout, what="fallback")
            except SolverFailure as exc2:
                raise PluginError(f"the fallback failed: SolverFailure: {exc2}") from exc2
            self._check_estimate(est)
        if est.status is Status.FALLBACK:
            self.counts.fallbacks += 1
        est = _with_solve_time(est, time.perf_counter() - t0)
        self.last = est
        return est

    @staticmethod
    def _check_estimate(est) -> None:
        if not isinstance(est, Estimate):
            raise PluginError(f"TypeError: update must return an Estimate, got {type(est).__name__}")
        try:
            finite = bool(np.isfinite(np.asarray(est.x, float)).all() and np.isfinite(np.asarray(est.P, float)).all())
        except (TypeError, ValueError) as exc:
            raise PluginError(f"TypeError: the estimate's x and P must be numbers ({exc})") from None
        if not finite:
            raise PluginError("FloatingPointError: non-finite estimate")

    @abstractmethod
    def _update_impl(self, t: float, y: np.ndarray, mask: np.ndarray, u: np.ndarray) -> Estimate:
        ...

    def _fallback(self, t, y, mask, u, message: str) -> Estimate:
        """Default fallback: hold the last estimate."""
        if self.last is None:
            n = len(self.names)
            return Estimate(t, np.zeros(n), np.eye(n), self.names, Status.FALLBACK, message, False)
        return Estimate(t, self.last.x, self.last.P, self.names, Status.FALLBACK, message, False)
