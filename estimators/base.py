"""The one interface of every online state estimator.

Every estimator answers ``update(measurement, u, t) -> Estimate``.  The closed loop,
the scenario runner and a scenario file can therefore swap an EKF for an MHE or for the
naive finite-difference baseline.  The public :meth:`StateEstimator.update` guards its
inputs and never raises inside a closed loop: a missing/NaN measurement skips the
correction (counted), and a failure inside ``_update_impl`` is caught, counted and
answered by a documented fallback (:meth:`StateEstimator._fallback`).
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

__all__ = ["Estimate", "StateEstimator", "EstimatorCounts"]


@dataclass(frozen=True)
class Estimate:
    """A state estimate with its covariance.

    Attributes
    ----------
    t : time [s]
    x : (nx,) estimated state, in the order of ``names``
    P : (nx, nx) covariance
    names : state names (model states, then augmented unknowns)
    status : human-readable message ("ok", "prediction only: missing omega1", "fallback: ...")
    success : False when the estimate came from a fallback
    corrected : whether a measurement update was applied
    solve_time : wall time of the update [s]
    """

    t: float
    x: np.ndarray
    P: np.ndarray
    names: tuple[str, ...]
    status: str = "ok"
    success: bool = True
    corrected: bool = True
    solve_time: float = 0.0

    def get(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def std(self, name: str) -> float:
        i = self.names.index(name)
        return float(math.sqrt(max(self.P[i, i], 0.0)))


@dataclass
class EstimatorCounts:
    """How often the estimator had to degrade (reported by the runner)."""

    steps: int = 0
    dropouts: int = 0      # correction skipped: missing or non-finite measurement
    failures: int = 0      # the estimator's own solve failed
    fallbacks: int = 0     # an estimate came from the fallback

    def as_dict(self) -> dict[str, int]:
        return dict(steps=self.steps, dropouts=self.dropouts, failures=self.failures, fallbacks=self.fallbacks)


class StateEstimator(ABC):
    """Template: :meth:`update` guards, times and counts; subclasses implement ``_update_impl``.

    Subclasses set ``self.names`` and ``self.channels`` (the measurement channels used),
    and implement ``_update_impl(y, mask, u, t) -> Estimate`` where ``y`` holds the
    channels in ``self.channels`` order and ``mask`` marks the finite ones.
    """

    names: tuple[str, ...] = ()
    channels: tuple[str, ...] = ()

    def __init__(self):
        self.counts = EstimatorCounts()
        self.last: Estimate | None = None

    def update(self, measurement: Mapping[str, float], u, t: float) -> Estimate:
        """Process one DAQ sample: measurement dict, applied input ``u`` over the last sample, time [s]."""
        t0 = time.perf_counter()
        y = np.array([float(measurement.get(c, np.nan)) if measurement is not None else np.nan
                      for c in self.channels])
        mask = np.isfinite(y)
        if not mask.all():
            self.counts.dropouts += 1
        u = np.asarray(u, dtype=float).ravel()
        self.counts.steps += 1
        try:
            est = self._update_impl(y, mask, u, float(t))
            if not (np.all(np.isfinite(est.x)) and np.all(np.isfinite(est.P))):
                raise FloatingPointError("non-finite estimate")
        except Exception as exc:  # never raise inside a closed loop
            self.counts.failures += 1
            self.counts.fallbacks += 1
            est = self._fallback(y, mask, u, float(t), f"fallback: {type(exc).__name__}: {exc}")
        est = Estimate(est.t, est.x, est.P, est.names, est.status, est.success, est.corrected,
                       time.perf_counter() - t0)
        self.last = est
        return est

    @abstractmethod
    def _update_impl(self, y: np.ndarray, mask: np.ndarray, u: np.ndarray, t: float) -> Estimate:
        ...

    def _fallback(self, y, mask, u, t, status: str) -> Estimate:
        """Default fallback: hold the last estimate (inflating nothing)."""
        if self.last is None:
            n = len(self.names)
            return Estimate(t, np.zeros(n), np.eye(n), self.names, status, False, False)
        return Estimate(t, self.last.x, self.last.P, self.names, status, False, False)
