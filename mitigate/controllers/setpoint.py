"""The shape SoftSpeed and Z-Torque share: an outer loop on the drive's set-point.

Both read the drive's speed and the pipe torque and command the drive input
(:class:`DriveSetpointLaw`).  On a rig whose drive is a torque input the law closes the speed
loop itself with a stiff PI (:meth:`DriveSetpointLaw.stiff_loop`): ``T = Kp e + I``, its integral
starting at the pipe torque and stopping while the command is at ``[drive] torque_max``.
"""

from __future__ import annotations

from mitigate.controllers.base import Action, ControlContext
from mitigate.controllers.compiled import CompiledStepLaw
from mitigate.controllers.tuning import drive_speed_channel, np_clip, tuning_for

__all__ = ["DriveSetpointLaw"]


class DriveSetpointLaw(CompiledStepLaw):
    """Base of a law acting on the drive's input (module docstring).

    Sets ``speed_ch`` (the drive's speed channel), ``tuning`` (:func:`tuning_for` of the rig),
    ``torque_drive``; a subclass sets ``Kp`` [N m s/rad], ``Ki`` [N m/rad] and resets ``_I``
    (None) before :meth:`stiff_loop` is used.
    """

    needs = ("drive_speed", "drive_torque")

    def __init__(self, options, context: ControlContext):
        super().__init__(options, context)
        m = context.model
        context.require_input(m.drive_input, "the drive's input")
        self.speed_ch = drive_speed_channel(context)
        self.tuning = tuning_for(m, context.params)
        self.torque_drive = not m.drive.sets_speed

    def actuated_inputs(self) -> tuple[str, ...]:
        return (self.context.model.drive_input,)

    def drive_config(self, **law_fields) -> tuple[dict, tuple[str, ...]]:
        """The C configuration's fields of the drive's loop and pipe torque (with ``law_fields``)
        and the channels it reads (:mod:`mitigate.controllers.compiled`)."""
        ctx = self.context
        fields = dict(n_ch=2, ch_drive=0, ch_torque=1, torque_drive=int(self.torque_drive), period=ctx.period,
                      Kp=self.Kp, Ki=self.Ki, torque_max=ctx.torque_max, **self.pipe.c_fields(), **law_fields)
        return fields, (self.speed_ch, self.pipe.torque_ch)

    def stiff_loop(self, e: float, T_pipe: float) -> Action:
        """A torque drive's command ``Kp e + I`` for the speed error ``e`` [rad/s] within
        ``+-torque_max``; the integral starts at ``T_pipe`` [N m] and holds while the command is
        at the limit."""
        lim = self.context.torque_max
        if self._I is None:
            self._I = T_pipe
        I = self._I + self.Ki * e * self.context.period
        if abs(self.Kp * e + I) <= lim:
            self._I = I
        return Action({self.context.model.drive_input: np_clip(self.Kp * e + self._I, -lim, lim)})
