"""The one interface of every controller.

``step(t, estimate, measurement) -> Action``: given the time [s], the current state
estimate (:class:`estimators.base.Estimate`, may be None for measurement-only laws) and
the latest DAQ measurement (dict of log channels), return the R2 pin force command N2
[N] and the motor speed set-point omega_ref [rad/s] (disc side).  The public
:meth:`Controller.step` never raises: a failure in ``_step_impl`` is counted and answered
by :meth:`Controller._fallback` (baseline (a): nominal set-point, no pin force).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Mapping

import numpy as np

__all__ = ["Action", "Controller", "ControllerCounts"]


@dataclass(frozen=True)
class Action:
    """Controller output.

    Attributes
    ----------
    n2 : R2 pin normal force command [N]
    omega_ref : motor speed set-point, disc side [rad/s]
    status : human-readable message; success : False if this came from a fallback
    fallback : which fallback produced it ("" if none, "shift", "baseline")
    solve_time : wall time of the step [s]
    """

    n2: float
    omega_ref: float
    status: str = "ok"
    success: bool = True
    fallback: str = ""
    solve_time: float = 0.0


@dataclass
class ControllerCounts:
    steps: int = 0
    failures: int = 0
    fallbacks_shift: int = 0
    fallbacks_baseline: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(steps=self.steps, failures=self.failures, fallbacks_shift=self.fallbacks_shift,
                    fallbacks_baseline=self.fallbacks_baseline)


class Controller(ABC):
    """Template: :meth:`step` guards, times and counts; subclasses implement ``_step_impl``."""

    name: str = "controller"

    def __init__(self, omega_nominal: float):
        self.omega_nominal = float(omega_nominal)
        self.counts = ControllerCounts()

    def reset(self) -> None:
        """Forget internal state (called before a run)."""

    def set_nominal(self, omega_nominal: float) -> None:
        """The speed programme's current set-point [rad/s]."""
        self.omega_nominal = float(omega_nominal)

    def step(self, t: float, estimate, measurement: Mapping[str, float]) -> Action:
        t0 = time.perf_counter()
        self.counts.steps += 1
        try:
            a = self._step_impl(float(t), estimate, measurement)
            if not (np.isfinite(a.n2) and np.isfinite(a.omega_ref)):
                raise FloatingPointError("non-finite action")
        except Exception as exc:  # never raise inside a closed loop
            self.counts.failures += 1
            self.counts.fallbacks_baseline += 1
            a = self._fallback(f"fallback baseline: {type(exc).__name__}: {exc}")
        if a.fallback == "shift":
            self.counts.fallbacks_shift += 1
        elif a.fallback == "baseline" and a.success is False and "fallback baseline" not in a.status:
            self.counts.fallbacks_baseline += 1
        return Action(a.n2, a.omega_ref, a.status, a.success, a.fallback, time.perf_counter() - t0)

    @abstractmethod
    def _step_impl(self, t: float, estimate, measurement: Mapping[str, float]) -> Action:
        ...

    def _fallback(self, status: str) -> Action:
        """Baseline (a): the nominal set-point and no pin force."""
        return Action(0.0, self.omega_nominal, status, False, "baseline")
