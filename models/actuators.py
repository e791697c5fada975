"""Actuators: the servo that sets a contact's normal force (a rig file's ``[actuators]``).

The thesis names only the R2 pin servo (Hobbico CS-80 giant-scale, Sect. 3.1.1); its range,
rate and lag in ``models/rigs/rig3.toml`` are ASSUMPTIONS documented in the README (a
first-order lag of 50 ms from the CS-80's ~0.2 s/60 deg no-load speed over a short stroke, a
rate limit of 200 N/s, a range of 0-40 N).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["Servo"]


class Servo:
    """Discrete servo: saturate the command to ``[n_min, n_max]``, then a first-order lag of
    time constant ``tau`` [s] whose rate is limited to ``rate_max`` [N/s].

    Parameters
    ----------
    spec : any object with ``n_min``, ``n_max`` [N], ``rate_max`` [N/s] and ``tau`` [s]
        (:class:`models.rig.spec.ActuatorSpec`)
    dt : DAQ period [s]; the command is held over each sample
    n0 : initial force [N]
    """

    def __init__(self, spec, dt: float, n0: float = 0.0):
        self.spec = spec
        self.dt = float(dt)
        self.force = float(np.clip(n0, spec.n_min, spec.n_max))

    def step(self, command: float) -> float:
        """Advance one sample with the held ``command`` [N]; returns the force [N] applied over it."""
        o = self.spec
        # min/max: np.clip's values on scalars, without its call overhead (this runs every sample)
        target = float(min(max(command, o.n_min), o.n_max)) if math.isfinite(command) else self.force
        alpha = 1.0 - math.exp(-self.dt / o.tau) if o.tau > 0 else 1.0
        delta = alpha * (target - self.force)
        lim = o.rate_max * self.dt
        self.force += float(min(max(delta, -lim), lim))
        return self.force
