"""Actuator model of the R2 pin servo.

The thesis names only the servo (Hobbico CS-80 giant-scale, Sect. 3.1.1).  Its pin force
dynamics are ASSUMPTIONS, documented in the README: a first-order lag (time constant
50 ms, from the CS-80's ~0.2 s/60 deg no-load speed over a small stroke), a rate limit
of 200 N/s and a force range [0, 40 N].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.errors import ConfigError

__all__ = ["ServoOptions", "Servo"]


@dataclass(frozen=True, kw_only=True)
class ServoOptions:
    """R2 pin servo: force range [N], rate limit [N/s] and first-order lag [s]."""

    n_min: float = 0.0
    n_max: float = 40.0
    rate_max: float = 200.0
    tau: float = 0.05

    def __post_init__(self):
        for name in ("n_min", "n_max", "rate_max", "tau"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"servo.{name} must be a finite number, got {v!r}")
        if self.n_min < 0:
            raise ConfigError(f"servo.n_min must be >= 0 N, got {self.n_min}")
        if not self.n_max > self.n_min:
            raise ConfigError(f"servo.n_max must be > n_min = {self.n_min} N, got {self.n_max}")
        if not self.rate_max > 0:
            raise ConfigError(f"servo.rate_max must be > 0 N/s, got {self.rate_max}")
        if self.tau < 0:
            raise ConfigError(f"servo.tau must be >= 0 s, got {self.tau}")


class Servo:
    """Discrete servo: saturate the command, then a rate-limited first-order lag."""

    def __init__(self, options: ServoOptions, dt: float, n0: float = 0.0):
        self.options = options
        self.dt = float(dt)
        self.force = float(np.clip(n0, options.n_min, options.n_max))

    def step(self, command: float) -> float:
        """Advance one sample with the held ``command`` [N]; returns the force [N] applied over it."""
        o = self.options
        target = float(np.clip(command, o.n_min, o.n_max)) if np.isfinite(command) else self.force
        alpha = 1.0 - math.exp(-self.dt / o.tau) if o.tau > 0 else 1.0
        delta = alpha * (target - self.force)
        lim = o.rate_max * self.dt
        self.force += float(np.clip(delta, -lim, lim))
        return self.force
