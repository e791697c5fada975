"""Plug-ins that misbehave in every way issue 20 lists (tests/test_faults_*.py, tests/test_fuzz_faults.py).

Each controller follows the programme until it misbehaves; the estimators are finite-difference
speeds until they do.  The module is imported as ``tests.plugins.faulty`` with the repository root
on ``sys.path`` (as a user's own folder would be on theirs).
"""

import math
import os
import sys
import time

import numpy as np

from estimators.base import Estimate, StateEstimator
from mitigate.controllers.base import Action, Controller
from models.errors import SolverFailure


class Follow(Controller):
    """Sets the drive's set-point to the programme (a well-behaved plug-in)."""

    kind = "follow"
    calls = 0

    def _step_impl(self, t, measurement, estimate):
        return Action({"omega_ref": self.context.scheduled(t, "omega_ref")})

    def nth_call(self, option: str, default: int) -> bool:
        """Count this call; True on every ``n``-th, ``n`` the option ``option`` (else ``default``)."""
        self.calls += 1
        return self.calls % int(self.options.get(option, default)) == 0


class InitRaises(Follow):
    def __init__(self, options, context):
        raise RuntimeError("boom in __init__")


class SleepsInInit(Follow):
    def __init__(self, options, context):
        time.sleep(float(options.get("seconds", 10.0)))
        super().__init__(options, context)


class InitExits(Follow):
    def __init__(self, options, context):
        sys.exit(4)


class Abstract(Controller):
    kind = "abstract"


class ResetRaises(Follow):
    def reset(self):
        raise RuntimeError("boom in reset")


class StepRaises(Follow):
    def _step_impl(self, t, measurement, estimate):
        raise ValueError("boom in step")


class RaisesMidway(Follow):
    def _step_impl(self, t, measurement, estimate):
        if t > 1.5:
            raise ValueError("boom midway")
        return super()._step_impl(t, measurement, estimate)


class ReturnsNaN(Follow):
    def _step_impl(self, t, measurement, estimate):
        return Action({"omega_ref": float("nan")})


class ReturnsDict(Follow):
    def _step_impl(self, t, measurement, estimate):
        return {"omega_ref": 3.0}


class ReturnsText(Follow):
    def _step_impl(self, t, measurement, estimate):
        return Action({"omega_ref": "fast"})


class Exits(Follow):
    def _step_impl(self, t, measurement, estimate):
        sys.exit(3)


class Sleeps(Follow):
    """Sleeps ``seconds`` (option) in every step: far too long."""

    def _step_impl(self, t, measurement, estimate):
        time.sleep(float(self.options.get("seconds", 10.0)))
        return super()._step_impl(t, measurement, estimate)


class SlowEvery(Follow):
    """Takes ``seconds`` on every ``every``-th call (a controller that misses a deadline now and then)."""

    def _step_impl(self, t, measurement, estimate):
        if self.nth_call("every", 2):
            time.sleep(float(self.options.get("seconds", 0.03)))
        return Action({"omega_ref": self.context.scheduled(t, "omega_ref") + 1.0})


class KillsWorker(Follow):
    def _step_impl(self, t, measurement, estimate):
        os._exit(7)


class Prints(Follow):
    def _step_impl(self, t, measurement, estimate):
        print("garbage on stdout")
        return super()._step_impl(t, measurement, estimate)


class Transient(Follow):
    """Its solver fails (SolverFailure, the documented transient failure) on ``fail_every``-th calls."""

    def _step_impl(self, t, measurement, estimate):
        if self.nth_call("fail_every", 1):
            raise SolverFailure("did not converge")
        return super()._step_impl(t, measurement, estimate)


class Chatters(Follow):
    """Alternates the set-point between the programme - 3 and + 3 rad/s every call (hardware damage)."""

    derived = ("Kp", "f_t")
    Kp, f_t = 0.22, 0.43

    def _step_impl(self, t, measurement, estimate):
        self.calls += 1
        return Action({"omega_ref": self.context.scheduled(t, "omega_ref") + (3.0 if self.calls % 2 else -3.0)})


class Steps(Follow):
    """A step of +1 rad/s on the set-point at its first call (to measure latency by)."""

    def _step_impl(self, t, measurement, estimate):
        return Action({"omega_ref": self.context.scheduled(t, "omega_ref") + 1.0})


# ----------------------------------------------------------------------------- estimators
class FDSpeeds(StateEstimator):
    """The rig's state with the measured speeds where a channel reads them, zeros elsewhere."""

    kind = "fd_speeds"

    def __init__(self, options, context):
        super().__init__(options, context)
        m = context.model
        self.names = tuple(m.states)
        self.channels = tuple(c for c in m.measured if c.startswith("omega"))

    def _update_impl(self, t, y, mask, u):
        return Estimate(t, np.zeros(len(self.names)), np.eye(len(self.names)), self.names)


class EstimatorRaises(FDSpeeds):
    def _update_impl(self, t, y, mask, u):
        if t > 0.5:
            raise KeyError("theta9")
        return super()._update_impl(t, y, mask, u)


class EstimatorNaN(FDSpeeds):
    def _update_impl(self, t, y, mask, u):
        return Estimate(t, np.full(len(self.names), math.nan), np.eye(len(self.names)), self.names)


class EstimatorInitRaises(FDSpeeds):
    def __init__(self, options, context):
        raise RuntimeError("boom in the estimator's __init__")
