"""An outside group's controller, written from docs/plugins.md and docs/benchmark.md alone and submitted
through the documented command (tests/test_benchmark_standard.py)::

    mitigate benchmark scenarios/benchmark/suite.toml --controller tests.plugins.submitted:TwistDamper --alone \\
        --out entries/twist
    mitigate benchmark leaderboard entries --out leaderboard

It damps the string's twist rate with the drive: ``omega_ref = programme + g (w_objective - w_drive)``
(the drive follows the bit's swings, a damper between them), from the two measured speeds.

Also here: two controllers that break the benchmark's like-for-like rule, for the tests (one that sets
only the drive without declaring it, one that declares the drive and sets a normal force too).
"""

from dataclasses import dataclass

from mitigate.controllers.base import Action, Controller, reading
from models.errors import ConfigError


@dataclass(frozen=True, kw_only=True)
class TwistDamperOptions:
    gain: float = 0.5    # g [-]: set-point change per rad/s of speed difference

    def __post_init__(self):
        if not self.gain >= 0:
            raise ConfigError(f"gain must be >= 0, got {self.gain!r}")


class TwistDamper(Controller):
    """omega_ref = programme + g (w_objective - w_drive)."""

    kind = "twist_damper"
    options_class = TwistDamperOptions
    needs = ("drive_speed", "objective_speed", "speed_drive")

    def __init__(self, options, context):
        super().__init__(options, context)
        m = context.model
        self.drive_ch = m.speed_channel(m.drive_body)
        self.bit_ch = m.speed_channel(m.objective_body)

    def actuated_inputs(self):
        return (self.context.model.drive_input,)

    def _step_impl(self, t, measurement, estimate):
        m = self.context.model
        d = reading(measurement, self.bit_ch) - reading(measurement, self.drive_ch)
        w = self.context.scheduled(t, m.drive_input) + self.options.gain * d
        return Action({m.drive_input: max(0.0, w)})


class Undeclared(Controller):
    """Sets the drive's set-point (a fixed offset) and declares nothing: the benchmark classes it by
    what it set."""

    kind = "undeclared"

    def _step_impl(self, t, measurement, estimate):
        m = self.context.model
        return Action({m.drive_input: 1.01 * self.context.scheduled(t, m.drive_input)})


class Misdeclared(Controller):
    """Declares the drive only, and sets a normal force too: its benchmark runs fail."""

    kind = "misdeclared"

    def actuated_inputs(self):
        return (self.context.model.drive_input,)

    def _step_impl(self, t, measurement, estimate):
        m = self.context.model
        n = m.servo_inputs[0]
        return Action({m.drive_input: self.context.scheduled(t, m.drive_input),
                       n: 1.05 * self.context.scheduled(t, n)})
