"""The drill-string rig (models/rigs/drillstring.toml) identified from its synthetic 1 kHz log
(tests/data/drillstring_stickslip.csv, written by tests/data/make_drillstring_log.py with our plant).

The point: the torque-on-bit sensor pins the friction level.  The fit is run with and without
that channel, from the data-derived guess, with the encoder zero free (as on a real rig log).
Measured (this log): with the torque, mu_cb -0.1 %, mu_sb +0.8 %, k +0.0 %, d +0.1 %; without it,
mu_cb -0.8 %, mu_sb +1.3 %, d +15 %, and the standard error of mu_cb 20x larger (the slowly
varying weight on bit still separates the friction level from a constant twist; with a constant
one, nothing would).
"""

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from estimators.identify import IdentifiabilityWarning, IdentifyOptions, identify
from models import get_model
from models.logs import read_csv
from models.signals import dominant_frequency, moving_average, stick_slip_cycles

DATA = Path(__file__).parent / "data"
sys.path.insert(0, str(DATA))
from make_drillstring_log import TRUE, truth  # noqa: E402

FREE = ("k", "d", "mu_sb", "mu_cb")


@pytest.fixture(scope="module")
def log():
    return read_csv(DATA / "drillstring_stickslip.csv")


@pytest.fixture(scope="module")
def fits(log):
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        out["with"] = identify(log, "drillstring", None, IdentifyOptions(free=FREE))
        out["without"] = identify(log, "drillstring", None, IdentifyOptions(free=FREE, exclude=("torque_bit",)))
    return out


def test_fixture_is_a_1khz_stick_slip_log_near_2_7_hz(log):
    m = get_model("drillstring")
    assert log.dt == pytest.approx(1e-3) and len(log.t) == 3001
    assert set(m.measured) <= set(log.channels)
    w = log["omega_bit"][500:]
    assert 2.4 < dominant_frequency(w, log.dt) < 3.0                 # stick-slip at about 2.7 Hz
    # the bit stops: a 10-sample mean (half a tick over 10 ms: 0.03 rad/s) reaches zero in every cycle
    cyc = stick_slip_cycles(moving_average(w, 10), log.dt, 0.03)
    assert cyc is not None and cyc.cycles >= 5 and 2.4 < 1 / cyc.period < 3.0
    assert np.std(log["wob"] - moving_average(log["wob"], 51)) > 2.0  # noisy WOB


@pytest.mark.slow
def test_torque_on_bit_pins_the_friction_level(fits):
    w, wo = fits["with"], fits["without"]
    true = truth()
    assert w.success and wo.success, (w.message, wo.message)
    assert [c.name for c in w.problem.channels] == ["omega_bit", "torque_bit", "theta_top-theta_bit"]
    assert "torque_bit" not in [c.name for c in wo.problem.channels]
    err = {n: e / true[n] - 1 for n, e in zip(w.names, w.estimate)}
    assert abs(err["mu_cb"]) < 0.05 and abs(err["mu_sb"]) < 0.05      # the friction level, within 5 %
    assert abs(err["k"]) < 0.03 and abs(err["d"]) < 0.3
    se = dict(zip(w.names, w.stderr))
    se_wo = dict(zip(wo.names, wo.stderr))
    assert se_wo["mu_cb"] > 5 * se["mu_cb"] and se_wo["mu_sb"] > 3 * se["mu_sb"]   # the torque is what pins it
    assert wo.condition > 2 * w.condition
    assert w.input_noise["wob"] == pytest.approx(4.0, rel=0.15)          # the noisy WOB: errors in the variables
    assert set(TRUE) == set(FREE)


@pytest.mark.slow
def test_guess_comes_from_the_torque_sensor(fits):
    notes = " ".join(fits["with"].guess_notes)
    assert "torque_bit regressed on the encoder twist of pipe" in notes and "torque balance behind torque_bit" in notes
    true = truth()
    init = dict(zip(fits["with"].names, fits["with"].initial))
    assert init["k"] == pytest.approx(true.k, rel=0.05) and init["mu_cb"] == pytest.approx(true.mu_cb, rel=0.1)
