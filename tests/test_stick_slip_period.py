"""One owner of the stick-slip period (:func:`models.modal.stick_slip_period`), checked against
numbers derived independently of it.

The estimate is the rig's lowest torsional mode with the boundary condition its drive puts on the
top of the string: held by a drive that sets a speed, free (with the drive's inertia) under a torque
drive.  Its checks: the analytic 1-DOF and 2-DOF modes, the stick-slip cycle of the independent
simulator of the thesis rig (``tests/independent_rig3.py``, which imports nothing from ``models``),
and the limit cycle of the field drill string under its torque drive, whose cycle a table held at
the top would get wrong by a factor of two.  The metrics' windows, the industry laws' tuning and
the estimators' scales ask the same function.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import independent_rig3 as ir
from models import get_model
from models.modal import modes, stick_slip_period
from models.plant import SimOptions, simulate

FIELD = Path(__file__).resolve().parent / "rigs" / "field_drillstring.toml"


def _cycle(t, w, level, after):
    """Mean time between upward crossings of ``level`` after ``after`` [s] (linear interpolation)."""
    k = np.flatnonzero((w[:-1] < level) & (w[1:] >= level)) + 1
    up = t[k - 1] + (level - w[k - 1]) / (w[k] - w[k - 1]) * (t[k] - t[k - 1])
    up = up[up > after]
    assert len(up) >= 4, "too few cycles to measure"
    return (up[-1] - up[0]) / (len(up) - 1)


def test_a_speed_drive_holds_the_top_one_disc_on_a_spring():
    """disc.toml: one disc (J) on a spring (k, damper d) from a prescribed speed.  A damped 1-DOF
    oscillator's eigenvalues have ``|lambda| = sqrt(k/J)`` whatever ``d``: the period 2 pi sqrt(J/k)."""
    m = get_model("disc")
    p = m.published()
    assert m.drive.boundary == "clamped"
    assert stick_slip_period(m, p) == pytest.approx(2 * math.pi * math.sqrt(p["J"] / p["k"]), rel=1e-12)


def test_a_torque_drive_leaves_the_top_free_with_its_inertia():
    """rig2: the motor (Jm, torque input) and the disc (Jd) on a shaft (k, c), no damping to the
    frame.  The free chain's relative mode has ``|lambda|^2 = k (1/Jd + 1/Jm)`` whatever ``c``; held
    at the motor it would be ``k / Jd``."""
    m = get_model("rig2")
    p = m.published()
    assert m.drive.boundary == "free" and p["cd"] == 0 and p["cm"] == 0
    w = math.sqrt(p["k"] * (1 / p["Jd"] + 1 / p["Jm"]))
    assert stick_slip_period(m, p) == pytest.approx(2 * math.pi / w, rel=1e-12)
    assert stick_slip_period(m, p) < 2 * math.pi * math.sqrt(p["Jd"] / p["k"]) * 0.8


def test_the_thesis_rig_stick_slips_at_its_clamped_mode_in_the_independent_simulator():
    """rig3 at 30 rpm and N1 = 20 N in the independent simulator (DC motor, PI loop, Stribeck pins):
    its cycle is 2.38 s; the estimate (the chain held at the motor) 2.33 s; the free chain's 1.39 s
    would be 40 % short."""
    o = ir.RigOptions(torque_noise=0.0, n1_noise=0.0, n2_noise=0.0)
    log = ir.simulate_log(o, math.pi, 20.0, 0.0, 40.0, seed=0)
    T = _cycle(log["t"], log["omega1_true"], math.pi, 10.0)
    m = get_model("rig3")
    assert m.drive.boundary == "clamped"
    assert stick_slip_period(m) == pytest.approx(T, rel=0.05)
    free = modes(m, m.published(), "free")
    assert 1 / free.freq_hz[free.oscillatory][0] < 0.7 * T


def test_the_field_string_stick_slips_near_its_free_mode_under_its_torque_drive():
    """The field drill string (Navarro-Lopez & Cortes 2007) from rest under 10 kN m and 97 kN on
    the bit: its limit cycle is 8.3 s (the rig file's note); the estimate, the free chain with the
    table's inertia, 7.19 s (the stick phase makes the cycle longer than the mode); the table held
    would give 15.7 s, nearly twice the cycle."""
    m = get_model(FIELD)
    p = m.published()
    r = simulate(m, p, np.array([1e4, 97347.0]), 200.0, SimOptions(dt=0.01, nsub=2, seed=1), sensors=None)
    assert r.success
    T = _cycle(r.t, r.state("omega_bit"), 5.0, 60.0)
    assert T == pytest.approx(8.3, abs=0.1)
    est = stick_slip_period(m, p)
    assert 0.8 * T < est < T
    held = modes(m, p, "clamped")
    assert 1 / held.freq_hz[held.oscillatory][0] > 1.8 * T


@pytest.mark.parametrize("rig", ["rig3", "rig2", "drillstring", FIELD])
def test_the_metrics_the_tuning_rules_and_the_estimators_ask_the_one_owner(rig):
    from estimators.online.options import rig_scales
    from mitigate.controllers.tuning import tuning_for
    from mitigate.metrics import rig_period

    m = get_model(rig)
    p = m.published()
    T = stick_slip_period(m, p)
    assert rig_period(m, p) == T
    assert tuning_for(m, p).period == pytest.approx(T, rel=1e-15)
    assert rig_scales(m, p).period == T
