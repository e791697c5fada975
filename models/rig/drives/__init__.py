"""Drive kinds and their registry (:mod:`models.rig.drives.base`).

A rig file's ``[drive] kind`` names one of :data:`DRIVES`; the built rig holds it as
``model.drive`` and every question about the drive (its set-point and unit, its speed target, its
states, limits and energy, the boundary it puts on the string) is asked there.

Kinds shipped
-------------
``dc_motor``  a DC gear motor under its own PI speed loop (:mod:`.dc_motor`; thesis Ch. 3)
``speed``     a prescribed speed of the node ``"drive"`` (:mod:`.speed`)
``torque``    a torque on the drive body (:mod:`.torque`; seed 001's rig2)

A new kind is one :class:`Drive` subclass and one line, ``register(MyDrive)``
(``tests/test_new_drive_kind.py`` adds an AC servo that way).
"""

from models.rig.drives.base import DRIVES, Drive, DriveField, DriveState, drive_of, get_drive, register
from models.rig.drives.dc_motor import DCMotor
from models.rig.drives.speed import SpeedDrive
from models.rig.drives.torque import TorqueDrive

__all__ = ["DRIVES", "Drive", "DriveField", "DriveState", "register", "get_drive", "drive_of", "DCMotor",
           "SpeedDrive", "TorqueDrive"]

register(DCMotor)
register(SpeedDrive)
register(TorqueDrive)
