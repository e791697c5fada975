"""SoftSpeed / Soft Torque: the drive's speed loop tuned to behave as a damper matched to the string.

The industry's law (Shell's Soft Torque Rotary System, NOV SoftSpeed; NORCE's Simulator4nDOF
``TopdriveController.cs``): the top drive's PI speed controller ``T = Kp e + Ki int(e)`` with
``e = w_set - w_drive`` is tuned so that, near the stick-slip frequency ``f_t``, the drive acts
as a pure damper matched to the pipe: ``Kp = 4 Z`` (NORCE) and ``Ki = (2 pi f_t)^2 (J_drive -
J_comp)``, so that the integral's "spring" ``Ki/s`` cancels the drive's inertia ``J_drive s`` at
``f_t``.  Torsional waves reaching the top are then absorbed instead of reflected.

The lab rig's gear motor has a fixed, stiff internal PI loop (about ``ratio KT kp / R = 8.6 N m
s/rad`` against ``Z = 0.11``): the user reaches it only through the set-point.  So the lab-rig
version is an OUTER loop that makes the drive follow a virtual soft drive (admittance
control)::

    J_v w_v' = Kp (w_nom - w_v) + Ki int(w_nom - w_v) - T_pipe,     w_ref = w_v

with ``T_pipe`` the torque the string loads the drive with, estimated from the measured torque
and drive speed (:class:`mitigate.controllers.tuning.PipeTorque`), ``J_v`` the drive's inertia
(``ratio^2 Jm`` on rig3), ``Kp = kp_factor Z`` and ``Ki = (2 pi f_t)^2 J_v``.  The stiff inner loop
makes the drive follow ``w_v`` (its bandwidth, ~57 Hz on rig3, is far above ``f_t``).  On a rig whose
drive is a torque input, the law IS the speed loop: the torque ``T`` is commanded directly.

Defaults come from the rig (:mod:`mitigate.controllers.tuning`): ``Z = sqrt(k J)`` of the string
and ``f_t`` its lowest torsional mode with the drive held.  ``kp_factor`` is 2: the derivation's
matched damper is ``Kp = Z`` (``kp_factor = 1``), and the gain sweep on the main scenario
(``benchmarks/industry_tuning.py``, results/industry_tuning.md) found the severity flat from 1.5 to 3
with its minimum at 2 (0.678 against 0.724 at 1 and 0.763 at NORCE's 4); every value can be
overridden.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers._opts import check_number
from mitigate.controllers.base import Action, Controller, ControlContext, reading
from mitigate.controllers.tuning import PipeTorque, drive_speed_channel, np_clip, tuning_for
from models.errors import ConfigError

__all__ = ["SoftSpeedOptions", "SoftSpeed"]


@dataclass(frozen=True, kw_only=True)
class SoftSpeedOptions:
    """SoftSpeed options (scenario keys of ``kind = "softspeed"``); 0 means "derive from the rig".

    Parameters
    ----------
    kp_factor : ``Kp = kp_factor Z`` [-] (2: the sweep's best; 1 is the matched damper, NORCE uses 4)
    Z : string impedance [N m s/rad] (0: ``sqrt(k J)`` from the rig)
    f_t : tuning frequency [Hz] (0: the rig's lowest mode with the drive held)
    J_v : virtual drive inertia [kg m^2] (0: the drive's inertia; a torque drive: its body's)
    J_comp : inertia compensated by the drive, subtracted from ``J_v`` in ``Ki`` [kg m^2]
    band : the set-point stays within the programme +- band [rad/s]
    tau_torque : low-pass of the pipe-torque estimate [s]
    """

    kp_factor: float = 2.0
    Z: float = 0.0
    f_t: float = 0.0
    J_v: float = 0.0
    J_comp: float = 0.0
    band: float = 3.0
    tau_torque: float = 0.02

    def __post_init__(self):
        check_number(self, "kp_factor", lo=0.0, lo_open=True)
        for n, u in (("Z", "N m s/rad"), ("f_t", "Hz"), ("J_v", "kg m^2"), ("J_comp", "kg m^2"),
                     ("band", "rad/s"), ("tau_torque", "s")):
            check_number(self, n, lo=0.0, unit=u)


class SoftSpeed(Controller):
    """SoftSpeed as an outer loop on the drive's set-point (module docstring)."""

    kind = "softspeed"
    options_class = SoftSpeedOptions
    derived = ("Z", "J_v", "Kp", "Ki", "f_t")

    def __init__(self, options: SoftSpeedOptions, context: ControlContext):
        super().__init__(options, context)
        m = context.model
        context.require_input(m.drive_input, "the drive's input")
        self.pipe = PipeTorque(context, tau=options.tau_torque)
        self.speed_ch = drive_speed_channel(context)
        t = tuning_for(m, context.params)
        self.tuning = t
        self.Z = options.Z or t.Z
        self.f_t = options.f_t or t.f_ss
        self.J_v = options.J_v or t.J_drive
        if not self.J_v > 0:
            raise ConfigError(f"{context.where}.J_v: the drive has no inertia to derive it from; give J_v > 0 kg m^2")
        self.Kp = options.kp_factor * self.Z
        self.Ki = (2 * math.pi * self.f_t) ** 2 * max(self.J_v - options.J_comp, 0.0)
        self.torque_drive = m.drive_kind == "torque"
        self.reset()

    def reset(self) -> None:
        self.pipe.reset()
        self._w = None
        self._I = None

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        m, dt = self.context.model, self.context.period
        w_nom = self.context.scheduled(t, m.drive_input) if not self.torque_drive else self._w_nominal(t)
        T_pipe = self.pipe.update(measurement)
        w_meas = reading(measurement, self.speed_ch)
        if self.torque_drive:
            if self._I is None:
                self._I = T_pipe
            e = w_nom - w_meas
            self._I += self.Ki * e * dt
            return Action({m.drive_input: self.Kp * e + self._I})
        if self._w is None:            # bumpless start: the virtual drive where the real one is, loaded
            self._w, self._I = w_meas, T_pipe
        e = w_nom - self._w
        self._I += self.Ki * e * dt
        self._w += dt * (self.Kp * e + self._I - T_pipe) / self.J_v
        self._w = np_clip(self._w, max(0.0, w_nom - self.options.band), w_nom + self.options.band)
        return Action({m.drive_input: self._w})

    def _w_nominal(self, t: float) -> float:
        """A torque drive's speed set-point: the scenario's ``speed`` programme if it has one, else the
        operating point's speed of the rig file."""
        return self.context.model.nominal_speed()
