"""Finite-difference baseline "estimator" (placeholder of the core branch; the online-estimators
branch replaces it): body speeds from the DAQ's differentiated encoder speeds, twists from
encoder differences plus the twist at power-on, everything else at its initial value."""

from __future__ import annotations

import numpy as np

from estimators.base import Estimate, EstimatorContext, StateEstimator
from models.sensors import channel_variance

__all__ = ["FiniteDifference"]


class FiniteDifference(StateEstimator):
    kind = "fd"
    options_class = None

    def __init__(self, options, context: EstimatorContext):
        super().__init__(options, context)
        m = context.model
        self.names = m.states
        chans, rows = [], []
        for j, b in enumerate(m.bodies):
            ch = m.speed_channel(b)
            if ch is not None:
                chans.append(ch)
                rows.append(m.speed_index(b))
        self.channels = tuple(chans)
        self._rows = rows
        self._x = np.zeros(m.nx) if context.x0 is None else np.asarray(context.x0, float).copy()
        self._P = np.diag([channel_variance(m, c, context.dt) for c in chans] + [1.0] * (m.nx - len(chans)))

    def _update_impl(self, t, y, mask, u):
        x = self._x.copy()
        for v, ok, j in zip(y, mask, self._rows):
            if ok:
                x[j] = v
        self._x = x
        return Estimate(t, x, self._P, self.names, corrected=bool(mask.all()))
