"""Your own controller: the drive's set-point minus g times the high-passed torque channel.

Put it in any importable module and name it in a scenario (or a benchmark suite)::

    [[controllers]]
    name = "mine"
    kind = "my_controller:HighPassTorque"     # module:Class, loaded with importlib
    gain = 2.0                                # its options (HighPassTorqueOptions)
"""

import math
from dataclasses import dataclass

from mitigate.controllers.base import Action, Controller
from models.errors import ConfigError


@dataclass(frozen=True, kw_only=True)
class HighPassTorqueOptions:
    gain: float = 2.0    # g [rad/s per N m]
    tau: float = 5.0     # high-pass time constant [s]

    def __post_init__(self):
        if not self.gain >= 0:
            raise ConfigError(f"gain must be >= 0 rad/s per N m, got {self.gain!r}")
        if not self.tau > 0:
            raise ConfigError(f"tau must be > 0 s, got {self.tau!r}")


class HighPassTorque(Controller):
    """omega_ref = programme - g HP(motor_torque): the drive yields to the torque's swings."""

    kind = "high_pass_torque"
    options_class = HighPassTorqueOptions
    slow = None              # the low-passed torque [N m]; the high-pass is torque - slow

    def actuated_inputs(self):   # what it sets: its benchmark class ("drive": the drive's set-point only)
        return ("omega_ref",)

    def reset(self):         # called before every run
        self.slow = None

    def _step_impl(self, t, measurement, estimate):
        torque = measurement["motor_torque"]
        a = 1.0 - math.exp(-self.context.period / self.options.tau)
        self.slow = torque if self.slow is None else self.slow + a * (torque - self.slow)
        w = self.context.scheduled(t, "omega_ref") - self.options.gain * (torque - self.slow)
        return Action({"omega_ref": w})
