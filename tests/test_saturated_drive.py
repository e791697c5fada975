"""A DC motor that starts at its limits: the integration rule counts the rate of a current with no
loop around it (``R/L``), which the points of steady sliding, where the PI loop acts, do not show.

The rig (tests/data/saturating_motor.toml, a rig of the zoo) asks 856 V of a 31 V supply from rest:
the drive sits at its 10 A current limit for the first second, and its current relaxes at
R/L = 2867 1/s there, against 1524 1/s at steady sliding.  The exact plant took 10 RK4 substeps of
1 ms (h R/L = 2.9, beyond RK4's stability limit 2.79) and diverged (1e300 by 6 s; the
identification benchmark's zoo case had no log to fit).  Checked against a second method: CVODES on
the regularised model (adaptive, 1e-10 tolerances).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from models import get_model
from models.discretise import RHO
from models.modal import operating_point
from models.plant import SimOptions, simulate
from models.plant.simulator import plant_integration
from models.status import Status

RIG = Path(__file__).resolve().parent / "data" / "saturating_motor.toml"


def test_the_rule_counts_the_current_at_the_drives_limit():
    m = get_model(RIG)
    p = m.published()
    u, _ = operating_point(m, p)
    integ = plant_integration(m, p, SimOptions(), u)
    r_over_l = 1.0 / m.electrical_time_constant(p)
    assert 2860 < r_over_l < 2870
    assert integ.rate >= r_over_l and 0.01 / integ.nsub * r_over_l <= RHO


def test_the_plant_starting_at_its_limits_stays_within_them_and_matches_cvodes():
    m = get_model(RIG)
    u, _ = operating_point(m, m.published())
    a = simulate(m, None, u, 3.0, SimOptions(seed=1))
    b = simulate(m, None, u, 3.0, SimOptions(seed=1, method="cvodes"))
    assert a.status is Status.OK and b.status is Status.OK
    i = a.state("current")
    assert np.all(np.abs(i) <= 10.0 + 1e-9) and np.mean(i[:50] > 9.9) > 0.9      # at its limit first
    assert abs(a.state("omega_mot")[-1] / u[0] - 1.0) < 0.01                     # then on its set-point
    for name, scale in (("omega_mot", u[0]), ("omega_b1", u[0]), ("current", 10.0)):
        assert np.max(np.abs(a.state(name) - b.state(name))) < 0.05 * scale, name
