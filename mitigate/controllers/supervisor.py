"""Baseline: a speed-raise supervisor -- the driller's rule of thumb, automated.

Raise the rotary speed when stick-slip is detected and bring it back once it has stopped
(the industry's tuned speed loops, SoftSpeed and Z-Torque, are separate controllers).  On this rig the idea is sound physics: at
N1 = 20 N the stick-slip limit cycle coexists with a linearly stable steady sliding
(bistability); above roughly 45-50 rpm the limit cycle no longer exists, so a raise
followed by a slow return lands the rig on the stable sliding branch at the nominal
speed.

Detection uses the MEASURED speed of the objective body only (no model) over a sliding window of
``window`` seconds:

- ``detect = "stuck"``: the fraction of samples with ``|omega| <= stuck_speed``
  (default half an encoder tick per DAQ period, so a stuck disc reads 0: 0.31 rad/s on rig3;
  without an encoder on that body, 5 % of the programmed speed);
- ``detect = "severity"``: (max - min) / (2 mean) of the windowed speed.

Every unit-carrying default comes from the rig (:func:`resolve`): the window from its stick-slip
period T (:func:`mitigate.controllers.tuning.stick_slip_frequency`), the raise and its rates from
the programmed speed w and T.  The ratios are the values tuned on rig3 (T = 2.33 s, w = pi rad/s:
window 3 s, min_window 1 s, raise_max 2.1 rad/s, rate_up 0.4 and rate_down 0.15 rad/s^2).

Above ``on`` the supervisor raises the speed offset towards ``raise_max`` at
``rate_up``; at or below ``off`` (a band: ``off < on``) it lowers the offset towards 0
at ``rate_down``; in between it holds.
"""

from __future__ import annotations

from collections import deque
import dataclasses
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from mitigate.controllers.base import Action, Controller, ControlContext, reading
from mitigate.tunables import Tunable
from models.checks import check_options, option
from models.errors import ConfigError

__all__ = ["SupervisorOptions", "SpeedSupervisor", "resolve"]


def _band_and_window(o: "SupervisorOptions", name) -> None:
    """``off < on`` (a band) and ``min_window <= window``."""
    if not o.off < o.on:
        raise ConfigError(f"{name('off')} must be < on = {o.on} (a band), got {o.off}")
    if o.min_window is not None and o.window is not None and o.min_window > o.window:
        raise ConfigError(f"{name('min_window')} must be <= window = {o.window} s, got {o.min_window}")


@dataclass(frozen=True, kw_only=True)
class SupervisorOptions:
    """Speed-raise supervisor options.

    Parameters
    ----------
    detect : "stuck" (fraction of time stuck) or "severity" (windowed SSS)
    window : detection window [s] (default: 1.29 stick-slip periods)
    stuck_speed : |omega| at or below which a sample counts as stuck [rad/s] (default: half an encoder
        tick per DAQ period, else 5 % of the programmed speed)
    on, off : raise above ``on``; lower at or below ``off`` (``off < on``) [-]
    raise_max : largest speed offset above the programme [rad/s] (default: 0.668 x the programmed speed)
    rate_up, rate_down : rate limits of the offset [rad/s^2] (default: raise_max over 2.25 and 6.0
        stick-slip periods)
    min_window : samples needed before detection starts [s] (default: window / 3)
    Unset (None) fields are derived from the rig when the controller is built (:func:`resolve`).
    """

    detect: str = option("stuck", choices=("stuck", "severity"))
    window: float | None = option(None, lo=0.0, lo_open=True, unit="s", none=True)
    stuck_speed: float | None = option(None, lo=0.0, unit="rad/s", none=True)
    on: float = option(0.02, lo=0.0)
    off: float = option(0.0, lo=0.0)
    raise_max: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s", none=True)
    rate_up: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s^2", none=True)
    rate_down: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s^2", none=True)
    min_window: float | None = option(None, lo=0.0, unit="s", none=True)

    def __post_init__(self):
        check_options(self, cross=_band_and_window)


#: the defaults as ratios to the rig's stick-slip period T and programmed speed w (rig3's tuned values)
WINDOW_PERIODS = 3.0 / 2.3335          # window = 1.29 T
MIN_WINDOW_FRACTION = 1.0 / 3.0        # min_window = window / 3
RAISE_SPEEDS = 2.1 / 3.1416            # raise_max = 0.668 w
RAISE_UP_PERIODS = 2.1 / 0.4 / 2.3335  # rate_up = raise_max / (2.25 T)
RAISE_DOWN_PERIODS = 2.1 / 0.15 / 2.3335   # rate_down = raise_max / (6.0 T)


def resolve(options: SupervisorOptions, period: float, speed: float, stuck: float) -> SupervisorOptions:
    """``options`` with every unset (None) unit-carrying field derived from the rig: its stick-slip
    period ``period`` [s], the programmed speed ``speed`` [rad/s] and the stuck threshold of its
    speed channel ``stuck`` [rad/s] (:func:`models.sensors.stuck_speed`)."""
    o = options
    window = o.window if o.window is not None else WINDOW_PERIODS * period
    raise_max = o.raise_max if o.raise_max is not None else RAISE_SPEEDS * abs(speed)
    return dataclasses.replace(
        o, window=window, raise_max=raise_max,
        min_window=o.min_window if o.min_window is not None else min(MIN_WINDOW_FRACTION * window, window),
        stuck_speed=o.stuck_speed if o.stuck_speed is not None else stuck,
        rate_up=o.rate_up if o.rate_up is not None else raise_max / (RAISE_UP_PERIODS * period),
        rate_down=o.rate_down if o.rate_down is not None else raise_max / (RAISE_DOWN_PERIODS * period))


class SpeedSupervisor(Controller):
    """Raise the speed while stick-slip is detected, lower it back when it has stopped.

    It watches the measured speed of the rig's objective body (rig3: R1, channel omega1) and
    offsets the drive's set-point above the programme.
    """

    kind = "supervisor"
    options_class = SupervisorOptions
    needs = ("speed_drive", "objective_speed")
    tunables = {
        "raise_max": Tunable(low=0.1, high=1.5, scale=lambda c: abs(c.scheduled(0.0, c.model.drive_input)),
                             doc="largest raise in multiples of the programmed speed"),
        "rate_down": Tunable(low=0.01, high=1.0, scale=lambda c: abs(c.scheduled(0.0, c.model.drive_input)),
                             doc="return rate in programmed speeds per second"),
    }

    def __init__(self, options: SupervisorOptions, context: ControlContext):
        super().__init__(options, context)
        m = context.model
        context.require_input(m.drive_input, "the drive's set-point")
        if not m.drive.sets_speed:
            # its offset is a speed [rad/s]: added to a torque input it would be a unit error
            raise ConfigError(f"{context.where}: the supervisor raises a speed set-point; rig {m.name!r} has a torque "
                              f"drive ({m.drive_input!r} [N m]): use softspeed or ztorque there")
        self.channel = m.speed_channel(m.objective_body)
        if self.channel is None:
            raise ConfigError(f"{context.where}: the supervisor needs the speed of {m.objective_body!r}, which rig "
                              f"{m.name!r} does not measure")
        self.dt = context.period
        from mitigate.controllers.tuning import stick_slip_frequency
        from models.sensors import stuck_speed
        w = self.context.scheduled(0.0, m.drive_input)
        if not (np.isfinite(w) and w != 0):
            w = m.nominal_speed()
        if self.options.raise_max is None and not w:
            raise ConfigError(f"{context.where}.raise_max: the programme's drive speed is 0 at the start, so the "
                              f"raise cannot be derived from it; give raise_max [rad/s]")
        #: the options it runs with: the given ones, the rest derived from the rig (:func:`resolve`)
        self.options = resolve(self.options, 1.0 / stick_slip_frequency(m, context.params), w,
                               stuck_speed(m, self.channel, context.dt, w))
        self.reset()

    derived = ("window", "min_window", "stuck_speed", "raise_max", "rate_up", "rate_down")
    derived_units = {"window": "s", "min_window": "s", "stuck_speed": "rad/s", "raise_max": "rad/s",
                     "rate_up": "rad/s^2", "rate_down": "rad/s^2"}

    def actuated_inputs(self) -> tuple[str, ...]:
        return (self.context.model.drive_input,)

    def reset(self) -> None:
        self._buf: deque = deque()
        self.offset = 0.0
        self.mode = "hold"
        self._t = None

    def indicator(self) -> float:
        """Current detection value of the window (stuck fraction or severity)."""
        w = np.fromiter((v for _, v in self._buf), float)
        if self.options.detect == "stuck":
            return float(np.mean(np.abs(w) <= self.options.stuck_speed))
        m = abs(float(np.mean(w)))
        return float(np.max(w) - np.min(w)) / (2 * m) if m > 0 else float("inf")

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        o = self.options
        w1 = reading(measurement, self.channel)
        h = self.dt if self._t is None else max(t - self._t, 0.0)
        self._t = t
        if np.isfinite(w1):
            self._buf.append((t, w1))
        while self._buf and self._buf[0][0] <= t - o.window:
            self._buf.popleft()
        if self._buf and self._buf[-1][0] - self._buf[0][0] >= o.min_window - 1e-9:
            ind = self.indicator()
            self.mode = "raise" if ind > o.on else ("lower" if ind <= o.off else "hold")
        if self.mode == "raise":
            self.offset = min(o.raise_max, self.offset + o.rate_up * h)
        elif self.mode == "lower":
            self.offset = max(0.0, self.offset - o.rate_down * h)
        w_ref = self.context.scheduled(t, self.context.model.drive_input)
        return Action({self.context.model.drive_input: w_ref + self.offset}, message=f"{self.mode} (+{self.offset:.3g} rad/s)")
