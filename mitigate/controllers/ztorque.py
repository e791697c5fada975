"""Z-Torque: wave-absorbing torque feedback in the drive's speed loop (Dwars, SPE/IADC-173037, 2015).

The industry's law: the speed error of the top drive's (stiff) PI loop gets an extra term from
the pipe torque, ``e = w_set - w_drive - z T_pipe / Z``, with ``T_pipe`` the drive torque minus
the drive's inertia times its acceleration, high-passed around the stick-slip band (NORCE's
Simulator4nDOF: high-pass 20 s, low-pass 5 ms, ``z = 0.25``).  With a stiff loop the drive then
turns at ``w_set - (z/Z) HP(T_pipe)``: towards the string it acts as a damper of ``Z/z`` on the
oscillating part of the torque, and holds the mean speed.

The lab rig's fixed internal PI loop is stiff (~8.6 N m s/rad on rig3), so the lab-rig version
is an outer loop on the set-point::

    w_ref = w_nom - (z / Z) HP_tau_hp(LP_tau_lp(T_pipe))

with ``T_pipe`` from :class:`mitigate.controllers.tuning.PipeTorque` (the reaction load cell minus
``ratio Jm w'``).  The high-pass time constant defaults to twice the stick-slip period of the rig
(:func:`models.modal.stick_slip_period`; rig3: 2 x 2.3 s), so the stick-slip band passes and the
mean load does not; ``Z = sqrt(k J)`` from the rig (:mod:`mitigate.controllers.tuning`).  ``z`` is
0.35: NORCE's 0.25 gave a severity of 0.733 on the main scenario, 0.35 the sweep's lowest, 0.666
(``benchmarks/industry_tuning.py``).  On a rig
whose drive is a torque input the law is the speed loop itself: ``T = Kp e + Ki int(e)`` with
the error above and a stiff ``Kp = kp_factor Z`` (NORCE: 50 Z), kept at ``Kp dt <= J_drive`` (a
sampled P loop on the drive's inertia is stable only below ``2 J/dt``); it aims at the scenario's
target speed (:meth:`~mitigate.controllers.base.ControlContext.target_speed`), commands within
``[drive] torque_max`` (the integral stops at the limit), keeps the torque's noise from the speed
channel (``Kp`` times its std) below 5 % of the steady torque at the target speed; its integral starts at the pipe torque.

Scale-free defaults: the band of the set-point is the programme's speed (``[0, 2 w_nom]``), the
torque's low-pass 1/100 of the stick-slip period (rig3: 23 ms), the acceleration's 1/80 of it but at
least 3 DAQ periods (a backward difference needs that much averaging: 30 ms on rig3 and rig2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from models.checks import option
from mitigate.controllers.base import Action, ControlContext, reading
from mitigate.controllers.compiled import LawOptions, compiled_action, law_config
from mitigate.controllers.setpoint import DriveSetpointLaw
from mitigate.controllers.tuning import PipeTorque, first_order, np_clip, tuning_for
from mitigate.tunables import Tunable

__all__ = ["ZTorqueOptions", "ZTorque", "NOISE_TORQUE_FRACTION"]

#: a torque drive's stiff loop is kept below the gain at which the speed channel's noise moves its
#: torque by this fraction of the programme's torque (std): 50 Z on a field string's 4096-count
#: encoder at 10 ms made 8 kN m steps on a 10 kN m drive, a set-point that chattered
NOISE_TORQUE_FRACTION = 0.05


@dataclass(frozen=True, kw_only=True)
class ZTorqueOptions(LawOptions):
    """Z-Torque options (scenario keys of ``kind = "ztorque"``); 0 means "derive from the rig".

    Parameters
    ----------
    z : the torque-feedback factor [-] (0.35: the gain sweep's best on the main scenario; NORCE uses 0.25)
    Z : string impedance [N m s/rad] (0: ``sqrt(k J)`` from the rig)
    tau_hp : high-pass time constant [s] (0: twice the rig's stick-slip period)
    tau_lp : low-pass time constant [s] (0: 1/100 of the stick-slip period)
    band : the set-point stays within the programme +- band [rad/s] (0: the programme's speed)
    kp_factor, ki : a torque drive's stiff loop ``Kp = kp_factor Z`` [-], ``Ki`` [N m/rad] (0: ``5 J_drive``, NORCE)
    implementation : "c" (compiled) or "python" (:class:`~mitigate.controllers.compiled.LawOptions`)
    """

    z: float = option(0.35, lo=0.0)
    Z: float = option(0.0, lo=0.0, unit="N m s/rad")
    tau_hp: float = option(0.0, lo=0.0, unit="s")
    tau_lp: float = option(0.0, lo=0.0, unit="s")
    band: float = option(0.0, lo=0.0, unit="rad/s")
    kp_factor: float = option(50.0, lo=0.0, lo_open=True)
    ki: float = option(0.0, lo=0.0, unit="N m/rad")


class ZTorque(DriveSetpointLaw):
    """Z-Torque as an outer loop on the drive's set-point (module docstring)."""

    kind = "ztorque"
    options_class = ZTorqueOptions
    tunables = {
        "z": Tunable(low=0.05, high=2.0, doc="the torque-feedback factor"),
        "tau_hp": Tunable(low=0.25, high=10.0, scale=lambda c: tuning_for(c.model, c.params).period, derived=2.0,
                          doc="high-pass time constant in multiples of the rig's stick-slip period"),
    }
    derived = ("Z", "gain", "tau_hp", "tau_lp", "Kp", "Ki")
    derived_units = {"Z": "N m s/rad", "gain": "rad/(N m s)", "tau_hp": "s", "tau_lp": "s", "Kp": "N m s/rad",
                     "Ki": "N m/rad"}

    def __init__(self, options: ZTorqueOptions, context: ControlContext):
        super().__init__(options, context)
        t = self.tuning
        self.tau_lp = options.tau_lp or t.period / 100.0
        self.pipe = PipeTorque(context, tau=self.tau_lp, tau_acc=max(t.period / 80.0, 3.0 * context.period))
        self.Z = options.Z or t.Z
        self.tau_hp = options.tau_hp or 2.0 * t.period
        self.gain = options.z / self.Z                 # [rad/s per N m]
        self.Kp = options.kp_factor * self.Z
        if self.torque_drive:
            self.Kp = min(self.Kp, t.J_drive / context.period, self._kp_noise_bound(context))
        self.Ki = options.ki or 5.0 * t.J_drive
        self.compile_step()

    def c_config(self):
        """The law's C configuration, the channels it reads, the estimates it reads (none)."""
        fields, channels = self.drive_config(gain=self.gain, tau_hp=self.tau_hp, band=self.options.band)
        return law_config("ztorque", **fields), channels, ()

    def _kp_noise_bound(self, context) -> float:
        """A torque drive's ``Kp`` at which the speed channel's noise (encoder quantisation
        differenced over a sample) moves the command by NOISE_TORQUE_FRACTION of the drive's
        steady torque at the target speed (std) [N m s/rad]; inf for a noise-free channel."""
        from models.modal import operating_point
        from models.sensors import channel_std
        m = context.model
        u, _ = operating_point(m, context.params, omega=context.target_speed(0.0))
        T_nom = abs(float(u[m.inputs.index(m.drive_input)]))
        sd = channel_std(m, self.speed_ch, context.period, context.sensors)
        return NOISE_TORQUE_FRACTION * T_nom / sd if T_nom > 0 and sd > 1e-9 else math.inf

    def reset_reference(self) -> None:
        self.pipe.reset()
        self._lp = None          # the slow part of the pipe torque (its high-pass is T - slow)
        self._I = None

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        m, dt = self.context.model, self.context.period
        if self.compiled is not None:
            return compiled_action(self, t, measurement, estimate, m.drive_input, self.context.target_speed(t))
        T = self.pipe.update(measurement)
        self._lp = T if self._lp is None else first_order(self._lp, T, dt, self.tau_hp)
        hp = T - self._lp
        w_nom = self.context.target_speed(t)
        if self.torque_drive:
            return self.stiff_loop(w_nom - reading(measurement, self.speed_ch) - self.gain * hp, T)
        band = self.options.band or abs(w_nom)
        w = np_clip(w_nom - self.gain * hp, max(0.0, w_nom - band), w_nom + band)
        return Action({m.drive_input: w})
