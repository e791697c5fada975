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
(its lowest mode with the drive held; rig3: 2 x 2.3 s), so the stick-slip band passes and the
mean load does not; ``Z = sqrt(k J)`` from the rig (:mod:`mitigate.controllers.tuning`).  ``z`` is
0.35: NORCE's 0.25 gave a severity of 0.733 on the main scenario, 0.35 the sweep's lowest, 0.666
(``benchmarks/industry_tuning.py``).  On a rig
whose drive is a torque input the law is the speed loop itself: ``T = Kp e + Ki int(e)`` with
the error above and a stiff ``Kp = kp_factor Z`` (NORCE: 50 Z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers._opts import check_number
from mitigate.controllers.base import Action, Controller, ControlContext, reading
from mitigate.controllers.tuning import PipeTorque, drive_speed_channel, first_order, np_clip, tuning_for

__all__ = ["ZTorqueOptions", "ZTorque"]


@dataclass(frozen=True, kw_only=True)
class ZTorqueOptions:
    """Z-Torque options (scenario keys of ``kind = "ztorque"``); 0 means "derive from the rig".

    Parameters
    ----------
    z : the torque-feedback factor [-] (0.35: the gain sweep's best on the main scenario; NORCE uses 0.25)
    Z : string impedance [N m s/rad] (0: ``sqrt(k J)`` from the rig)
    tau_hp : high-pass time constant [s] (0: twice the rig's stick-slip period)
    tau_lp : low-pass time constant [s]
    band : the set-point stays within the programme +- band [rad/s]
    kp_factor, ki : a torque drive's stiff loop ``Kp = kp_factor Z`` [-], ``Ki`` [N m/rad] (0: ``5 J_drive``, NORCE)
    """

    z: float = 0.35
    Z: float = 0.0
    tau_hp: float = 0.0
    tau_lp: float = 0.02
    band: float = 3.0
    kp_factor: float = 50.0
    ki: float = 0.0

    def __post_init__(self):
        check_number(self, "z", lo=0.0)
        for n, u in (("Z", "N m s/rad"), ("tau_hp", "s"), ("tau_lp", "s"), ("band", "rad/s"), ("ki", "N m/rad")):
            check_number(self, n, lo=0.0, unit=u)
        check_number(self, "kp_factor", lo=0.0, lo_open=True)


class ZTorque(Controller):
    """Z-Torque as an outer loop on the drive's set-point (module docstring)."""

    kind = "ztorque"
    options_class = ZTorqueOptions
    derived = ("Z", "gain", "tau_hp", "Kp", "Ki")

    def __init__(self, options: ZTorqueOptions, context: ControlContext):
        super().__init__(options, context)
        m = context.model
        context.require_input(m.drive_input, "the drive's input")
        self.pipe = PipeTorque(context, tau=options.tau_lp)
        self.speed_ch = drive_speed_channel(context)
        t = tuning_for(m, context.params)
        self.tuning = t
        self.Z = options.Z or t.Z
        self.tau_hp = options.tau_hp or 2.0 * t.period
        self.gain = options.z / self.Z                 # [rad/s per N m]
        self.torque_drive = m.drive_kind == "torque"
        self.Kp = options.kp_factor * self.Z
        self.Ki = options.ki or 5.0 * t.J_drive
        self.reset()

    def reset(self) -> None:
        self.pipe.reset()
        self._lp = None          # the slow part of the pipe torque (its high-pass is T - slow)
        self._I = None

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        m, dt = self.context.model, self.context.period
        T = self.pipe.update(measurement)
        self._lp = T if self._lp is None else first_order(self._lp, T, dt, self.tau_hp)
        hp = T - self._lp
        if self.torque_drive:
            w_nom = m.nominal_speed()
            e = w_nom - reading(measurement, self.speed_ch) - self.gain * hp
            if self._I is None:
                self._I = T
            self._I += self.Ki * e * dt
            return Action({m.drive_input: self.Kp * e + self._I})
        w_nom = self.context.scheduled(t, m.drive_input)
        w = np_clip(w_nom - self.gain * hp, max(0.0, w_nom - self.options.band), w_nom + self.options.band)
        return Action({m.drive_input: w})
