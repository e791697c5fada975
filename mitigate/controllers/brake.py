"""Baseline: a semi-active brake -- a servo pin's force from simple speed feedback.

The law (speeds [rad/s], output side)::

    N = clip( gain_overspeed * max(0, w_b - w_ref - deadband)
            + gain_relative  * max(0, w_b - w_d   - deadband), 0, n_max )

``w_b`` is the speed of the body whose pin the servo presses (rig3: R2), ``w_ref`` the
programmed drive speed and ``w_d`` the drive body's speed (rig3: R3).  It brakes the body only
when it overspeeds (pulled ahead by the release at the end of a stick phase) or runs faster
than the drive.  A brake can only remove energy, so it acts as a one-sided damper on the
torsional mode that drives the limit cycle.  Speeds come from the state estimate (when one is
given and ``use_estimate``; always, for a body the rig does not measure, when the scenario's
estimator is model-based) or from the measured channels, low-pass filtered with
``filter_tau`` (a differentiated encoder speed is quantised: one tick per 10 ms is 0.63 rad/s
on a 1000-tick encoder).  The shipped gains come from a grid search on the stick-slip
scenario (``benchmarks/brake_tuning.py``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers.base import Action, ControlContext, estimated, reading
from mitigate.controllers.compiled import CompiledStepLaw, LawOptions, compiled_action, law_config
from mitigate.tunables import Tunable
from models.checks import option
from models.errors import ConfigError

__all__ = ["BrakeOptions", "BrakeController", "body_speed"]

#: the overspeed gain in the servo's range per programmed speed (rig3's tuned 20 N s/rad)
GAIN_FACTOR = math.pi / 2
#: the speed filter's time constant in DAQ periods (rig3's 0.03 s: 3 x 10 ms)
FILTER_PERIODS = 3.0


@dataclass(frozen=True, kw_only=True)
class BrakeOptions(LawOptions):
    """Semi-active brake law options.

    Parameters
    ----------
    input : the servo input it commands (default: the rig's first servo, rig3 ``n2``)
    gain_overspeed : pin force per rad/s of overspeed above the programmed speed [N s/rad] (default:
        pi/2 x the servo's range per programmed speed, :func:`force_per_speed`: 20 on rig3, as tuned there)
    gain_relative : pin force per rad/s of running faster than the drive body [N s/rad]
    deadband : speed error ignored [rad/s]
    n_max : largest commanded pin force [N] (0: the servo's range)
    filter_tau : first-order low-pass time constant on the speeds [s] (0: none; default: 3 DAQ periods)
    use_estimate : take speeds from the state estimate when one is available
    implementation : "c" (compiled) or "python" (:class:`~mitigate.controllers.compiled.LawOptions`)
    """

    input: str = option("", what="a servo input name")
    gain_overspeed: float | None = option(None, lo=0.0, unit="N s/rad", none=True)
    gain_relative: float = option(0.0, lo=0.0, unit="N s/rad")
    deadband: float = option(0.0, lo=0.0, unit="rad/s")
    n_max: float = option(0.0, lo=0.0, unit="N")
    filter_tau: float | None = option(None, lo=0.0, unit="s", none=True)
    use_estimate: bool = option(True)


def body_speed(model, body: str, estimate, measurement: Mapping[str, float], use_estimate: bool) -> float:
    """Speed of ``body`` [rad/s] from the estimate if usable, else from its measured channel; a body
    the rig does not measure, from the estimate (or :class:`SolverFailure` without one)."""
    name = f"omega_{body}"
    if use_estimate and estimate is not None and name in estimate.names:
        return estimate.get(name)
    ch = model.speed_channel(body)
    if ch is None:
        return estimated(estimate, name)
    return reading(measurement, ch)


def force_per_speed(context) -> float:
    """A brake gain's natural unit on a rig [N s/rad]: the first servo's force range per programmed
    drive speed (rig3: 40 N / pi rad/s = 12.7 N s/rad)."""
    m = context.model
    a = m.actuator(m.servo_inputs[0]) if m.servo_inputs else None
    w = abs(context.target_speed(0.0))
    return a.n_max / w if a is not None and w > 0 else float("nan")


class BrakeController(CompiledStepLaw):
    """Semi-active servo-pin brake (see module docstring)."""

    kind = "brake"
    options_class = BrakeOptions
    needs = ("servo", "servo_body_speed")
    derived = ("gain_overspeed", "gain_relative", "filter_tau", "n_max")     # reported (runner.tuning_of)
    derived_units = {"gain_overspeed": "N s/rad", "gain_relative": "N s/rad", "filter_tau": "s", "n_max": "N"}
    tunables = {
        "gain_overspeed": Tunable(low=0.3, high=30.0, scale=force_per_speed,
                                  doc="overspeed gain in multiples of the servo's range per programmed speed"),
        "gain_relative": Tunable(low=0.0, high=10.0, log=False, scale=force_per_speed,
                                 doc="relative-speed gain, same unit"),
    }

    def __init__(self, options: BrakeOptions, context: ControlContext):
        super().__init__(options, context)
        m = context.model
        if not m.servo_inputs:
            raise ConfigError(f"{context.where}: a brake needs a servo pin; rig {m.name!r} has no actuator")
        self.input = options.input or m.servo_inputs[0]
        context.require_input(self.input, "the servo input")
        if self.input not in m.servo_inputs:
            raise ConfigError(f"{context.where}.input must be a servo input ({', '.join(m.servo_inputs)}), "
                              f"got {self.input!r}")
        self.body = m.contact_of_input(self.input).body
        self.drive_body = m.drive_body or None
        self.n_max = options.n_max or m.actuator(self.input).n_max
        if options.gain_overspeed is None or options.filter_tau is None:
            g = options.gain_overspeed
            if g is None:
                g = GAIN_FACTOR * force_per_speed(context)
                if not math.isfinite(g):
                    raise ConfigError(f"{context.where}.gain_overspeed: no programmed speed at the start to derive it "
                                      f"from; give gain_overspeed [N s/rad]")
            tau = options.filter_tau if options.filter_tau is not None else FILTER_PERIODS * context.dt
            #: the options it runs with: the given ones, the rest derived from the rig
            self.options = options = dataclasses.replace(options, gain_overspeed=g, filter_tau=tau)
        src = context.speed_source(self.body)
        if src is None or (src[0] == "estimate" and not options.use_estimate):
            raise ConfigError(f"{context.where}: the brake needs the speed of {self.body!r}, which rig {m.name!r} does "
                              f"not measure and " + ("the estimator does not estimate" if src is None else
                                                     "use_estimate = false forbids estimating"))
        if options.gain_relative > 0 and m.speed_channel(self.drive_body) is None:
            raise ConfigError(f"{context.where}: the brake's gain_relative needs the speed of {self.drive_body!r}, "
                              f"which rig {m.name!r} does not measure")
        #: the body's speed comes from the estimate only (the rig does not measure it)
        self.est_body = src[0] == "estimate"
        self.compile_step()

    def c_config(self):
        """The law's C configuration, the channels it reads (its body's speed, the drive body's when
        the rig measures it), the estimates it reads (the same two speeds)."""
        m, o = self.context.model, self.options
        drive_ch = m.speed_channel(self.drive_body) if self.drive_body else None
        body_ch = () if self.est_body else (m.speed_channel(self.body),)
        channels = body_ch + ((drive_ch,) if drive_ch is not None else ())
        return (law_config("brake", n_ch=len(channels), ch_body=-1 if self.est_body else 0,
                           ch_drive=channels.index(drive_ch) if drive_ch is not None else -1, est_body=int(self.est_body),
                           use_estimate=int(o.use_estimate), period=self.context.period, gain=o.gain_overspeed,
                           gain_relative=o.gain_relative, deadband=o.deadband, tau=o.filter_tau, n_max=self.n_max),
                channels, (f"omega_{self.body}", f"omega_{self.drive_body}"))

    def actuated_inputs(self) -> tuple[str, ...]:
        return (self.input,)

    def reset_reference(self) -> None:
        self._w = None
        self._t = None

    def _filtered(self, t: float, w: tuple[float, float]) -> tuple[float, ...]:
        tau = self.options.filter_tau
        if self._w is None or tau <= 0:
            self._w = tuple(w)
        else:
            h = max(t - self._t, self.context.period) if self._t is not None else self.context.period
            a = 1.0 - math.exp(-h / tau)
            self._w = tuple(f + a * (x - f) for f, x in zip(self._w, w))
        self._t = t
        return self._w

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        o, m = self.options, self.context.model
        if self.compiled is not None:
            return compiled_action(self, t, measurement, estimate, self.input, self.context.target_speed(t))
        wb = body_speed(m, self.body, estimate, measurement, o.use_estimate)
        wd = body_speed(m, self.drive_body, estimate, measurement, o.use_estimate) if o.gain_relative > 0 else 0.0
        wb, wd = self._filtered(t, (wb, wd))
        w_ref = self.context.target_speed(t)        # a torque drive's target speed, not its torque
        n = (o.gain_overspeed * max(0.0, wb - w_ref - o.deadband)
             + o.gain_relative * max(0.0, wb - wd - o.deadband))
        return Action({self.input: min(max(n, 0.0), self.n_max)})
