"""Naive finite-difference baseline "estimator" for the 3-disc rig.

Twists are encoder angle differences (``theta1 - theta2``, ``theta2 - theta3``) plus the
initial twist given at construction (incremental encoders read zero at power-on);
speeds are the DAQ's differentiated speeds.  The covariance is the quantisation
variance.  It estimates nothing it cannot read, so the PI states are left at zero.
"""

from __future__ import annotations

import numpy as np

from estimators.base import Estimate, StateEstimator
from models.sensors import SensorOptions

__all__ = ["FiniteDifference"]


class FiniteDifference(StateEstimator):
    """Finite-difference baseline for ``rig3`` (states phi12, phi23, omega1..3, i, z)."""

    names = ("phi12", "phi23", "omega1", "omega2", "omega3", "i", "z")
    channels = ("theta1", "theta2", "theta3", "omega1", "omega2", "omega3")

    def __init__(self, sensors: SensorOptions = SensorOptions(), dt: float = 0.01, twist0=(0.0, 0.0)):
        super().__init__()
        self.twist0 = np.asarray(twist0, dtype=float)
        qa = sensors.angle_variance()
        qs = sensors.speed_variance(dt)
        self._P = np.diag([2 * qa, 2 * qa, qs, qs, sensors.speed_variance(dt, motor=True), 1.0, 1.0])
        self._x = np.zeros(7)

    def _update_impl(self, y, mask, u, t):
        x = self._x.copy()
        if mask[0] and mask[1]:
            x[0] = y[0] - y[1] + self.twist0[0]
        if mask[1] and mask[2]:
            x[1] = y[1] - y[2] + self.twist0[1]
        for j in range(3):
            if mask[3 + j]:
                x[2 + j] = y[3 + j]
        self._x = x
        status = "ok" if mask.all() else "held: missing " + ",".join(c for c, m in zip(self.channels, mask) if not m)
        return Estimate(t, x, self._P, self.names, status, True, bool(mask.all()))
