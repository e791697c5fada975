"""Baseline (b): a semi-active R2 brake -- pin force from simple speed feedback.

The law (all speeds disc side, [rad/s])::

    N2 = clip( gain_overspeed * max(0, w2 - omega_ref - deadband)
             + gain_relative  * max(0, w2 - w3      - deadband), 0, n_max )

It brakes R2 only when it overspeeds (it is pulled ahead by the R1 release at the end
of a stick phase) or runs faster than the motor side.  A brake can only remove energy,
so it acts as a one-sided damper on the torsional mode that drives the limit cycle.
Speeds come from the state estimate (if one is given and ``use_estimate``) or from
the DAQ measurement, low-pass filtered with time constant ``filter_tau`` because the
differentiated encoder speeds are quantised (one tick per 10 ms = 0.63 rad/s).
The gains of the scenario suite come from a grid search on the stick-slip scenario
(see ``benchmarks/brake_tuning.py`` and the report).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers._opts import check_bool, check_number
from mitigate.controllers.base import Action, Controller

__all__ = ["BrakeOptions", "BrakeController"]


@dataclass(frozen=True, kw_only=True)
class BrakeOptions:
    """Semi-active brake law options.

    Parameters
    ----------
    gain_overspeed : pin force per rad/s of R2 overspeed above the set-point [N s/rad]
    gain_relative : pin force per rad/s of R2 running faster than R3 [N s/rad]
    deadband : speed error ignored [rad/s]
    n_max : largest commanded pin force [N]
    filter_tau : first-order low-pass time constant on the speeds [s] (0: none)
    use_estimate : take speeds from the state estimate when one is available
    """

    gain_overspeed: float = 20.0
    gain_relative: float = 0.0
    deadband: float = 0.0
    n_max: float = 40.0
    filter_tau: float = 0.03
    use_estimate: bool = True

    def __post_init__(self):
        check_number(self, "gain_overspeed", lo=0.0, unit="N s/rad")
        check_number(self, "gain_relative", lo=0.0, unit="N s/rad")
        check_number(self, "deadband", lo=0.0, unit="rad/s")
        check_number(self, "n_max", lo=0.0, lo_open=True, unit="N")
        check_number(self, "filter_tau", lo=0.0, unit="s")
        check_bool(self, "use_estimate")


def speeds(estimate, measurement: Mapping[str, float], use_estimate: bool) -> tuple[float, float, float]:
    """(omega1, omega2, omega3) [rad/s] from the estimate if usable, else from the measurement."""
    if use_estimate and estimate is not None and all(n in estimate.names for n in ("omega1", "omega2", "omega3")):
        return estimate.get("omega1"), estimate.get("omega2"), estimate.get("omega3")
    return (float(measurement["omega1"]), float(measurement["omega2"]), float(measurement["omega3"]))


class BrakeController(Controller):
    """Semi-active R2 brake (see module docstring)."""

    name = "brake"

    def __init__(self, options: BrakeOptions, omega_nominal: float, dt: float):
        super().__init__(omega_nominal)
        self.options = options
        self.dt = float(dt)
        self._w = None
        self._t = None

    def reset(self) -> None:
        self._w = None
        self._t = None

    def _filtered(self, t: float, w: tuple[float, float, float]) -> tuple[float, ...]:
        tau = self.options.filter_tau
        if self._w is None or tau <= 0:
            self._w = tuple(w)
        else:
            h = max(t - self._t, self.dt) if self._t is not None else self.dt
            a = 1.0 - math.exp(-h / tau)
            self._w = tuple(f + a * (x - f) for f, x in zip(self._w, w))
        self._t = t
        return self._w

    def _step_impl(self, t: float, estimate, measurement: Mapping[str, float]) -> Action:
        o = self.options
        _, w2, w3 = self._filtered(t, speeds(estimate, measurement, o.use_estimate))
        n2 = (o.gain_overspeed * max(0.0, w2 - self.omega_nominal - o.deadband)
              + o.gain_relative * max(0.0, w2 - w3 - o.deadband))
        return Action(min(max(n2, 0.0), o.n_max), self.omega_nominal, "ok")
