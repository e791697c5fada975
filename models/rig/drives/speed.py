"""A speed drive: the input is the speed of the node ``"drive"`` [rad/s] that connections join (a
stiff speed loop taken as ideal: thesis rig's disc test bench, a top drive, a lead screw's gearbox).
It adds no state and no body; the torque it applies is whatever the string needs, so the model
does not know it (no torque sensor at it, no energy)."""

from __future__ import annotations

from models.rig.drives.base import Drive

__all__ = ["SpeedDrive"]


class SpeedDrive(Drive):
    """The input prescribes the speed of the node ``"drive"`` (module docstring)."""

    kind = "speed"
    doc = "a prescribed speed of the node 'drive' (the input, rad/s)"
    setpoint = "speed"
    on_body = False

    def pipe_torque_terms(self, model, sensor, P):
        return 0.0, None
