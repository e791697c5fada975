"""Baseline: the rig as it runs without a stick-slip controller -- the programme alone.

The drive's own loop (the DC motor's PI speed loop, part of the rig model) follows the
programmed set-point and no servo pin is pressed (beyond the programme).  It is the
reference every other law is compared with.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers.base import Action, Controller

__all__ = ["PIOptions", "PIOnly"]


@dataclass(frozen=True, kw_only=True)
class PIOptions:
    """No options: the drive's own PI loop (inside the plant model) does all the work."""


class PIOnly(Controller):
    """The programme, unchanged (``Action(u={})``)."""

    kind = "pi"
    options_class = PIOptions

    def actuated_inputs(self) -> tuple[str, ...]:
        return ()

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        return Action({})
