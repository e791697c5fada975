"""Sensor models of the rigs: quantised encoders, differentiated speeds, noisy load cells.

Defaults follow the thesis (Sect. 3.1.1): LS Mecapion incremental encoders of 1000
ticks/rev on R1, R2 and on the motor shaft (which turns ``eta`` = 8 times faster than
R3), a 10 ms DAQ (cDAQ-9174), speeds by numerical differentiation of the angles, load
cells on the pins and on the motor torque.  The load-cell noise levels are not printed:
the defaults are ASSUMPTIONS (0.2 N on the pin forces, 0.01 N m on the motor torque,
one standard deviation), documented in the README.

All randomness comes from a ``numpy.random.Generator`` seeded by the caller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.errors import ConfigError

__all__ = ["SensorOptions", "quantise", "Sensors"]


@dataclass(frozen=True, kw_only=True)
class SensorOptions:
    """Sensor specification.

    Parameters
    ----------
    ticks_per_rev : encoder ticks per revolution on R1/R2 (and on the motor shaft)
    motor_ratio : motor shaft turns per R3 turn (the gearbox ratio); the motor encoder
        therefore resolves ``2 pi / (ticks_per_rev * motor_ratio)`` rad on the disc side
    force_noise : pin load-cell noise, standard deviation [N]
    torque_noise : motor-torque load-cell noise, standard deviation [N m]
    noise_scale : multiplies both noise levels (e.g. 3 for "triple noise")
    quantise : apply encoder quantisation
    """

    ticks_per_rev: int = 1000
    motor_ratio: float = 8.0
    force_noise: float = 0.2
    torque_noise: float = 0.01
    noise_scale: float = 1.0
    quantise: bool = True

    def __post_init__(self):
        if int(self.ticks_per_rev) != self.ticks_per_rev or self.ticks_per_rev < 1:
            raise ConfigError(f"sensors.ticks_per_rev must be an integer >= 1, got {self.ticks_per_rev!r}")
        for name in ("motor_ratio",):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"sensors.{name} must be a finite number > 0, got {v!r}")
        for name in ("force_noise", "torque_noise", "noise_scale"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f"sensors.{name} must be a finite number >= 0, got {v!r}")

    @property
    def angle_step(self) -> float:
        """Disc-side encoder resolution on R1/R2 [rad]."""
        return 2 * math.pi / self.ticks_per_rev

    @property
    def motor_angle_step(self) -> float:
        """Disc-side resolution of the motor-shaft encoder [rad]."""
        return 2 * math.pi / (self.ticks_per_rev * self.motor_ratio)

    def angle_variance(self, motor: bool = False) -> float:
        """Variance of uniform quantisation error, ``q^2/12`` [rad^2]."""
        q = self.motor_angle_step if motor else self.angle_step
        return q * q / 12.0 if self.quantise else 0.0

    def speed_variance(self, dt: float, motor: bool = False) -> float:
        """Variance of a backward-difference speed from quantised angles, ``2 q^2/12 / dt^2``."""
        return 2.0 * self.angle_variance(motor) / (dt * dt)


def quantise(angle, step):
    """Incremental-encoder reading: angle floored to whole ticks of size ``step`` [rad]."""
    return np.floor(np.asarray(angle) / step) * step


class Sensors:
    """Turns true quantities into what the DAQ records, one sample at a time.

    Angles are quantised; speeds are backward differences of the quantised angles over
    ``dt``; forces and torques get Gaussian noise.  The first sample's speed uses the
    true speed (no previous angle exists).
    """

    ANGLE_CHANNELS = {"theta1": "omega1", "theta2": "omega2", "theta3": "omega3"}

    def __init__(self, options: SensorOptions, dt: float, rng: np.random.Generator):
        self.options = options
        self.dt = float(dt)
        self.rng = rng
        self._prev: dict[str, float] = {}
        self._prev_true: dict[str, float] = {}

    def reset(self):
        self._prev = {}
        self._prev_true = {}

    def measure(self, truth: dict[str, float]) -> dict[str, float]:
        o = self.options
        out: dict[str, float] = {}
        for ang, spd in self.ANGLE_CHANNELS.items():
            if ang not in truth:
                continue
            step = o.motor_angle_step if ang == "theta3" else o.angle_step
            true = float(truth[ang])
            if ang in self._prev and abs(true - self._prev_true[ang]) <= 1e-9:
                # a body at rest keeps its encoder count: the absolute angle is rebuilt from twist
                # coordinates, and its ~1e-13 rad round-off must not flip a tick at a boundary
                val = self._prev[ang]
            else:
                val = float(quantise(true, step)) if o.quantise else true
            self._prev_true[ang] = true
            out[ang] = val
            if ang in self._prev:
                out[spd] = (val - self._prev[ang]) / self.dt
            elif spd in truth:
                out[spd] = float(truth[spd])
            self._prev[ang] = val
        if "theta_drive" in truth:
            out["theta_drive"] = float(truth["theta_drive"])
        for name in ("omega1", "omega2", "omega3"):
            if name in truth and name not in out:
                out[name] = float(truth[name])
        sf, st = o.force_noise * o.noise_scale, o.torque_noise * o.noise_scale
        for name in ("n1", "n2", "axial_force"):
            if name in truth:
                out[name] = float(truth[name]) + (sf * self.rng.standard_normal() if sf > 0 else 0.0)
        if "motor_torque" in truth:
            out["motor_torque"] = float(truth["motor_torque"]) + (st * self.rng.standard_normal() if st > 0 else 0.0)
        if "omega_ref" in truth:
            out["omega_ref"] = float(truth["omega_ref"])
        return out
