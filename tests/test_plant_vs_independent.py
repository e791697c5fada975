"""Our plant (models.plant, built from models/rigs/rig3.toml) against the independent scipy
simulator of the 3-disc rig (tests/independent_rig3.py: written from the thesis' description
alone, no code shared, sharp smooth friction with a stiff solver, the reaction load cell derived
from a torque balance on the free-mounted motor).  The two must agree on what a stick-slip study
measures: the cycle's frequency, the peak speed, the time stuck, the torque channel and the twist."""

import math

import numpy as np
import pytest

import independent_rig3 as ir
from models.plant import SimOptions, simulate
from mitigate.metrics import dominant_frequency


@pytest.fixture(scope="module")
def both():
    indep = ir.simulate_log(ir.RigOptions(), math.pi, 20.0, 0.0, 40.0, seed=1)
    ours = simulate("rig3", None, np.array([math.pi, 20.0, 0.0]), 40.0, SimOptions(seed=1))
    k = slice(1500, None)     # after the start-up transient
    return ({c: np.asarray(indep[c])[k] for c in ("omega1", "motor_torque", "twist12")},
            {"omega1": ours.y["omega1"][k], "motor_torque": ours.y["motor_torque"][k],
             "twist12": ours.state("twist_shaft1")[k]})


@pytest.mark.slow
def test_stick_slip_cycle_agrees(both):
    a, b = both
    assert dominant_frequency(b["omega1"], 0.01) == pytest.approx(dominant_frequency(a["omega1"], 0.01), rel=0.02)
    assert b["omega1"].max() == pytest.approx(a["omega1"].max(), rel=0.02)
    stuck = lambda w: float(np.mean(np.abs(w) < 0.31))  # noqa: E731  half a tick per sample
    assert stuck(b["omega1"]) == pytest.approx(stuck(a["omega1"]), abs=0.02)


@pytest.mark.slow
def test_torque_channel_and_twist_agree(both):
    """The reaction load cell: same mean (the pins' friction, not the motor's) and same swing."""
    a, b = both
    assert b["motor_torque"].mean() == pytest.approx(a["motor_torque"].mean(), rel=0.02)
    assert b["motor_torque"].std() == pytest.approx(a["motor_torque"].std(), rel=0.03)
    assert np.ptp(b["twist12"]) == pytest.approx(np.ptp(a["twist12"]), rel=0.02)
