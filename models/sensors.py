"""Sensor models: what the DAQ records, from the rig file's ``[sensors]``.

Every sensor of a rig file becomes one or two log channels, sampled at the DAQ period:

- **encoder** (``theta``, ``omega``): an incremental encoder of ``ticks`` per turn of a shaft
  that turns ``ratio`` times per turn of its body (the thesis' motor encoder: 1000 ticks on
  the motor shaft, ratio 8, so 8000 per turn of R3).  It counts whole ticks; with
  ``zero = "power_on"`` (incremental encoders, the default) it reads 0 at power-on, whatever
  the twist then.  The speed is the backward difference of the counted angle over one sample,
  i.e. the mean speed over the previous sample (the first sample reports the true speed).
- **torque**, **load_cell**, **speed**: ``gain * quantity + offset + noise`` with Gaussian
  noise of standard deviation ``noise`` (times ``SensorOptions.noise_scale``).  What a torque
  sensor at a DC motor measures depends on its ``definition`` (README, "What the torque load
  cell measures"): the reaction of the free-mounted motor and gearbox (the thesis' load cell)
  or the electromagnetic torque ``ratio KT i``.
- every channel may arrive ``delay`` whole samples late (a DAQ or bus delay).

The gain and offset of a torque sensor or a load cell are parameters of the rig (named
``<channel>_gain``, ``<channel>_offset``), so the plant's true values may differ from what a
controller believes, and identification can fit them.  All randomness comes from a
``numpy.random.Generator`` seeded by the caller.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from models.checks import check_options, option, prefix
from models.errors import ConfigError

__all__ = ["SensorOptions", "Sensors", "quantise", "encoder_step", "channel_variance", "channel_std", "FLOOR",
           "ripple_floor", "NOISE_FLOOR_RISK"]

#: variance floor that keeps noise covariances positive when a channel is ideal
FLOOR = 1e-12
#: the chance that a speed sensor's noise alone reads a peak-to-peak above :func:`ripple_floor`
NOISE_FLOOR_RISK = 0.01


@dataclass(frozen=True, kw_only=True)
class SensorOptions:
    """Run-time settings applied on top of the rig's sensors (a scenario's ``[sensors]``).

    Parameters
    ----------
    noise_scale : multiplies every noise level (e.g. 3 for "triple noise")
    quantise : count whole encoder ticks (False: ideal angles)
    encoder_phase : each incremental encoder (zeroed at power-on) stands at a random phase within a
        tick at power-on, drawn from the noise generator (a real encoder's; False: every encoder at a
        tick boundary, so a log's quantisation errors repeat whatever the seed)
    """

    noise_scale: float = option(1.0, lo=0.0)
    quantise: bool = option(True)
    encoder_phase: bool = option(False)

    def __post_init__(self):
        check_options(self, prefix("sensors"))


def quantise(angle, step):
    """Incremental-encoder reading: angle floored to whole ticks of size ``step`` [rad]."""
    return np.floor(np.asarray(angle) / step) * step


def encoder_step(s) -> float:
    """Resolution of an encoder on its body [rad]: ``2 pi / (ticks ratio)``."""
    return 2 * math.pi / (s.ticks * s.ratio)


_encoder_step = encoder_step


def stuck_speed(model, channel: str | None, dt: float, w_scale: float) -> float:
    """The |measured speed| at or below which a body counts as stuck [rad/s]: half an encoder tick
    per DAQ period ``dt`` [s] when ``channel`` is an encoder's speed (a stuck body reads exactly 0,
    a turning one at least one tick), else 5 % of ``w_scale`` (the programmed speed) [rad/s]."""
    s = model.sensor_of(channel) if channel else None
    if s is not None and s.kind == "encoder":
        return 0.5 * encoder_step(s) / dt
    return 0.05 * abs(w_scale)


def ripple_floor(model, channel: str, dt: float, n: int, options: SensorOptions = SensorOptions()) -> float:
    """The smallest peak-to-peak ripple [rad/s] that a speed channel tells apart from a steady
    speed over ``n`` DAQ samples of period ``dt`` [s]: what the channel reads peak to peak when the
    true speed's ripple is below its resolution.

    - encoder speed (the backward difference of whole counts, :class:`Sensors`): two counts per
      sample, ``2 q / dt`` with ``q`` the tick on its body.  A true speed whose per-sample increment
      moves by less than one count reads at most three consecutive counts per sample (a steady speed
      one or two), so up to two counts peak to peak mean nothing; ideal angles (``quantise=False``): 0;
    - a speed sensor with Gaussian noise ``sigma`` (times ``noise_scale``): ``2 z sigma`` with ``z``
      the level that all ``n`` samples' noise stays within with probability 1 - :data:`NOISE_FLOOR_RISK`
      (two-sided, ``z = Phi^-1(1 - risk / (2 n))``; 0 for a noiseless sensor).

    Raises
    ------
    ConfigError : no sensor of ``model`` writes ``channel`` as a speed.
    """
    from statistics import NormalDist
    s = model.sensor_of(channel) if channel else None
    if s is None or channel != s.channels[-1] or s.kind not in ("encoder", "speed"):
        raise ConfigError(f"{model.name}: channel {channel!r} is not a speed channel of an encoder or speed sensor")
    if s.kind == "encoder":
        return 2.0 * encoder_step(s) / dt if options.quantise else 0.0
    sd = s.noise * options.noise_scale
    z = NormalDist().inv_cdf(1.0 - NOISE_FLOOR_RISK / (2.0 * max(int(n), 1)))
    return 2.0 * z * sd


def channel_variance(model, channel: str, dt: float, options: SensorOptions = SensorOptions()) -> float:
    """Noise variance of a log channel of ``model`` [SI unit squared].

    Encoder angles: uniform quantisation, ``q^2/12``; encoder speeds: the backward difference of
    two such errors, ``2 q^2/12 / dt^2`` (an MA(1) process, treated as white); other channels:
    ``(noise noise_scale)^2``.  At least :data:`FLOOR`.
    """
    for s in model.sensors:
        if channel not in s.channels:
            continue
        if s.kind == "encoder":
            q2 = _encoder_step(s) ** 2 / 12.0 if options.quantise else 0.0
            v = q2 if channel == s.channels[0] else 2.0 * q2 / (dt * dt)
        else:
            v = (s.noise * options.noise_scale) ** 2
        return max(float(v), FLOOR)
    raise ConfigError(f"{model.name}: no sensor writes channel {channel!r} (channels: {', '.join(model.measured)})")


def channel_std(model, channel: str, dt: float, options: SensorOptions = SensorOptions()) -> float:
    """Standard deviation of a channel's noise (see :func:`channel_variance`)."""
    return math.sqrt(channel_variance(model, channel, dt, options))


class Sensors:
    """Turns noise-free readings (:meth:`models.rig.RigModel.outputs`) into what the DAQ records.

    Parameters
    ----------
    model : the rig (its ``sensors``)
    options : SensorOptions
    dt : DAQ period [s]
    rng : the seeded generator of the noise
    """

    def __init__(self, model, options: SensorOptions, dt: float, rng: np.random.Generator):
        self.model = model
        self.options = options
        self.dt = float(dt)
        self.rng = rng
        self.reset()

    def reset(self) -> None:
        self._zero: dict[str, float] = {}
        self._phase: dict[str, float] = {}
        self._prev: dict[str, float] = {}
        self._prev_true: dict[str, float] = {}
        self._queues: dict[str, deque] = {}

    def _delayed(self, s, name: str, value: float) -> float:
        if s.delay == 0:
            return value
        q = self._queues.get(name)
        if q is None:
            q = self._queues[name] = deque([value] * (s.delay + 1), maxlen=s.delay + 1)
        else:
            q.append(value)
        return q[0]

    def measure(self, ideal: dict[str, float]) -> dict[str, float]:
        """One DAQ sample from the noise-free readings ``ideal`` (channel -> value)."""
        o = self.options
        out: dict[str, float] = {}
        for s in self.model.sensors:
            if s.kind == "encoder":
                ang, spd = s.channels
                true = float(ideal[ang])
                step = _encoder_step(s)
                if ang in self._prev and abs(true - self._prev_true[ang]) <= 1e-9:
                    # a body at rest keeps its count: its angle is rebuilt from twist coordinates, and
                    # ~1e-13 rad of round-off must not flip a tick at a boundary
                    val = self._prev[ang]
                else:
                    if ang not in self._phase:
                        self._phase[ang] = float(self.rng.uniform(0.0, step)) \
                            if o.encoder_phase and o.quantise and s.zero == "power_on" else 0.0
                    raw = float(quantise(true + self._phase[ang], step)) if o.quantise else true
                    if ang not in self._zero:
                        self._zero[ang] = raw if s.zero == "power_on" else 0.0
                    val = raw - self._zero[ang]
                self._prev_true[ang] = true
                speed = (val - self._prev[ang]) / self.dt if ang in self._prev else float(ideal[spd])
                self._prev[ang] = val
                out[ang] = self._delayed(s, ang, val)
                out[spd] = self._delayed(s, spd, speed)
            else:
                ch = s.channels[0]
                sd = s.noise * o.noise_scale
                v = float(ideal[ch]) + (sd * self.rng.standard_normal() if sd > 0 else 0.0)
                out[ch] = self._delayed(s, ch, v)
        for n in self.model.inputs:
            if n not in out and n in ideal:
                out[n] = float(ideal[n])     # commands and prescribed inputs are logged as they are
        return out
