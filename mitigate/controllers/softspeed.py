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

Defaults come from the rig (:mod:`mitigate.controllers.tuning`): ``Z = sqrt(k J)`` of the string;
``f_t`` the lowest mode of the string with the drive acting as the law makes it (inertia ``J_v``, the
damper ``Kp``, the integral's spring; :func:`~mitigate.controllers.tuning.absorber_frequency`: near
the drive-held mode, rig3 0.414 Hz, the field string 0.062 Hz -- not its 0.12 Hz stick-slip limit
cycle, whose stick phase is no property of the string: the wave the law must absorb is the linear
mode that the friction's negative damping makes grow).  ``kp_factor`` is 2: the derivation's
matched damper is ``Kp = Z`` (``kp_factor = 1``), and the gain sweep on the main scenario
(``benchmarks/industry_tuning.py``, results/industry_tuning.md) found the severity flat from 1.5 to 3
with its minimum at 2 (0.678 against 0.724 at 1 and 0.763 at NORCE's 4).  The set-point's band is the
programme's speed (the set-point stays in ``[0, 2 w_nom]``), the torque filters follow the stick-slip
period (``tau_torque = T/100``, the acceleration's ``T/80`` but at least 3 DAQ periods); every value
can be overridden.

Discretisation: the virtual drive is integrated exactly over each control period
(:class:`~mitigate.controllers.tuning.VirtualDrive`); an explicit Euler step diverges when
``Kp dt / J_v > 2`` (a small geared motor at a 10 ms DAQ) and the set-point then chatters between the
ends of its band.  A torque drive's law commands the torque within ``[drive] torque_max`` (the
integral stops while the command is at the limit), aims at the scenario's target speed
(:meth:`~mitigate.controllers.base.ControlContext.target_speed`: ``[control] speed``, else the rig's
operating point), and keeps ``Kp dt <= J_drive`` (a sampled P loop on the drive's inertia is stable
only below ``2 J/dt``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers.base import Action, ControlContext, reading
from mitigate.controllers.compiled import LawOptions, compiled_action, law_config
from mitigate.controllers.setpoint import DriveSetpointLaw
from mitigate.controllers.tuning import PipeTorque, VirtualDrive, absorber_frequency, np_clip, tuning_for
from mitigate.tunables import Tunable
from models.checks import option
from models.errors import ConfigError

__all__ = ["SoftSpeedOptions", "SoftSpeed"]


@dataclass(frozen=True, kw_only=True)
class SoftSpeedOptions(LawOptions):
    """SoftSpeed options (scenario keys of ``kind = "softspeed"``); 0 means "derive from the rig".

    Parameters
    ----------
    kp_factor : ``Kp = kp_factor Z`` [-] (2: the sweep's best; 1 is the matched damper, NORCE uses 4)
    Z : string impedance [N m s/rad] (0: ``sqrt(k J)`` from the rig)
    f_t : tuning frequency [Hz] (0: the string's lowest mode with the drive acting as the law makes it)
    J_v : virtual drive inertia [kg m^2] (0: the drive's inertia; a torque drive: its body's)
    J_comp : inertia compensated by the drive, subtracted from ``J_v`` in ``Ki`` [kg m^2]
    band : the set-point stays within the programme +- band [rad/s] (0: the programme's speed, so
        the set-point stays in ``[0, 2 w_nom]``)
    tau_torque : low-pass of the pipe-torque estimate [s] (0: 1/100 of the period ``1/f_t``)
    implementation : "c" (compiled) or "python" (:class:`~mitigate.controllers.compiled.LawOptions`)
    """

    kp_factor: float = option(2.0, lo=0.0, lo_open=True)
    Z: float = option(0.0, lo=0.0, unit="N m s/rad")
    f_t: float = option(0.0, lo=0.0, unit="Hz")
    J_v: float = option(0.0, lo=0.0, unit="kg m^2")
    J_comp: float = option(0.0, lo=0.0, unit="kg m^2")
    band: float = option(0.0, lo=0.0, unit="rad/s")
    tau_torque: float = option(0.0, lo=0.0, unit="s")


class SoftSpeed(DriveSetpointLaw):
    """SoftSpeed as an outer loop on the drive's set-point (module docstring)."""

    kind = "softspeed"
    options_class = SoftSpeedOptions
    tunables = {
        "kp_factor": Tunable(low=0.25, high=8.0, doc="Kp in multiples of the string impedance Z"),
        "f_t": Tunable(low=0.25, high=4.0, scale=lambda c: tuning_for(c.model, c.params).f_ss, derived=1.0,
                       doc="tuning frequency in multiples of the rig's stick-slip frequency"),
    }
    derived = ("Z", "J_v", "Kp", "Ki", "f_t", "tau_torque")
    derived_units = {"Z": "N m s/rad", "J_v": "kg m^2", "Kp": "N m s/rad", "Ki": "N m/rad", "f_t": "Hz",
                     "tau_torque": "s"}

    def __init__(self, options: SoftSpeedOptions, context: ControlContext):
        super().__init__(options, context)
        m, t = context.model, self.tuning
        self.Z = options.Z or t.Z
        self.J_v = options.J_v or t.J_drive
        if not self.J_v > 0:
            raise ConfigError(f"{context.where}.J_v: the drive has no inertia to derive it from; give J_v > 0 kg m^2")
        self.Kp = options.kp_factor * self.Z
        if self.torque_drive:
            self.Kp = min(self.Kp, self.J_v / context.period)
        self.f_t = options.f_t or absorber_frequency(m, context.params, self.Kp)
        self.Ki = (2 * math.pi * self.f_t) ** 2 * max(self.J_v - options.J_comp, 0.0)
        self.tau_torque = options.tau_torque or 1.0 / (100.0 * self.f_t)
        self.pipe = PipeTorque(context, tau=self.tau_torque, tau_acc=max(1.0 / (80.0 * self.f_t), 3.0 * context.period))
        self.drive = VirtualDrive(self.J_v, self.Kp, self.Ki, context.period)
        self.compile_step()

    def c_config(self):
        """The law's C configuration, the channels it reads, the estimates it reads (none)."""
        fields, channels = self.drive_config(J_v=self.J_v, band=self.options.band)
        return law_config("softspeed", **fields), channels, ()

    def reset_reference(self) -> None:
        self.pipe.reset()
        self._w = None
        self._I = None

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        ctx = self.context
        m = ctx.model
        w_nom = ctx.target_speed(t)
        if self.compiled is not None:
            return compiled_action(self, t, measurement, estimate, m.drive_input, w_nom)
        T_pipe = self.pipe.update(measurement)
        w_meas = reading(measurement, self.speed_ch)
        if self.torque_drive:
            return self.stiff_loop(w_nom - w_meas, T_pipe)
        if self._w is None:            # bumpless start: the virtual drive where the real one is, loaded
            self._w, self._I = w_meas, T_pipe
        band = self.options.band or abs(w_nom)
        w, I = self.drive.step(self._w, self._I, w_nom, T_pipe)
        lo, hi = max(0.0, w_nom - band), w_nom + band
        if lo <= w <= hi:
            self._I = I                # (the integral holds while the set-point is at the band's edge)
        self._w = np_clip(w, lo, hi)
        return Action({m.drive_input: self._w})
