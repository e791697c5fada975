"""The rig zoo's hypothesis strategy (tests/test_rig_zoo.py): :func:`models.rig.zoo.zoo_rig` drawn
by hypothesis, so a failing rig shrinks to a simple one (the generator itself lives in the package:
the benchmark's generated scenarios draw it from a seed)."""

from __future__ import annotations

import math

from hypothesis import strategies as st

from models.rig.zoo import DRIVE_INPUT_NAMES, LAWS, NORMAL_INPUT_NAMES, ZooRig, zoo_rig

__all__ = ["zoo_rigs", "CORNERS", "ZooRig", "LAWS", "DRIVE_INPUT_NAMES", "NORMAL_INPUT_NAMES"]


class _HypothesisDraw:
    """:class:`models.rig.zoo.Draw` over hypothesis' ``draw`` (each draw labelled as before)."""

    def __init__(self, draw):
        self.draw = draw

    def _d(self, strategy, label):
        return self.draw(strategy, label=label) if label else self.draw(strategy)

    def floats(self, low, high, label=None):
        return self._d(st.floats(low, high), label)

    def integers(self, low, high, label=None):
        return self._d(st.integers(low, high), label)

    def booleans(self, label=None):
        return self._d(st.booleans(), label)

    def sampled_from(self, items, label=None):
        return self._d(st.sampled_from(items), label)


@st.composite
def zoo_rigs(draw, max_bodies: int = 6, drives=("speed", "torque", "dc_motor"), log_scale=(-3.0, 3.0),
             log_tau_e=(math.log10(5e-5), math.log10(5e-3)), laws=LAWS) -> ZooRig:
    """A rig (:func:`models.rig.zoo.zoo_rig`); ``drives``, ``log_scale`` (log10 of the inertia scale),
    ``log_tau_e`` (log10 of a DC motor's L/R [s]) and ``laws`` narrow the draw."""
    return zoo_rig(_HypothesisDraw(draw), max_bodies, drives, log_scale, log_tau_e, laws)


#: CI's corners of the zoo (tests/test_rig_zoo.py; the benchmarks draw them too), one rig each (derandomised): a lab rig on a DC motor with the fastest
#: electrical time constant, a field-scale string on a torque drive, a micro rig on a speed drive
CORNERS = {
    "lab_dc_motor_LR_0.05ms": dict(drives=("dc_motor",), log_scale=(-3.0, -2.0), log_tau_e=(math.log10(5e-5),) * 2),
    "field_torque_drive": dict(drives=("torque",), log_scale=(2.5, 3.0)),
    "lab_speed_drive": dict(drives=("speed",), log_scale=(-3.0, -1.0)),
    "dc_motor_LR_5ms": dict(drives=("dc_motor",), log_scale=(-1.0, 1.0), log_tau_e=(math.log10(5e-3),) * 2),
}
