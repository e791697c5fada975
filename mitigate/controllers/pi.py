"""Baseline (a): the rig as it runs today -- the PI speed loop on the programmed set-point, no pin force."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers.base import Action, Controller

__all__ = ["PIOptions", "PIOnly"]


@dataclass(frozen=True, kw_only=True)
class PIOptions:
    """No options: the motor's own PI loop (inside the plant model) does all the work."""


class PIOnly(Controller):
    """Constant set-point (the speed programme), ``N2 = 0``.

    The PI speed loop itself is part of the rig model (states ``i``, ``z``); this
    controller only forwards the programme, so it is the reference every other law is
    compared with.
    """

    name = "pi"

    def __init__(self, options: PIOptions, omega_nominal: float):
        super().__init__(omega_nominal)
        self.options = options

    def _step_impl(self, t: float, estimate, measurement: Mapping[str, float]) -> Action:
        return Action(0.0, self.omega_nominal, "ok")
