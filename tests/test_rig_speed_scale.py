"""The rig's own speed scale carries the model's speed-like defaults (issue 28: "every default that
carries a unit comes from the rig"): the friction regularisation ``RigModel.eps_default`` and the
lowest speed the integration's rates are taken at (:func:`models.rates.speed_floor`).

rig3 keeps its numbers to the bit (0.05 rad/s, 1 rad/s at 30 rpm); the paper spring-slider of
Colas et al. (2019), pulled at 42 um/s, gets a regularisation 1e4 times smaller than rig3's -- with
rig3's 0.05 m/s (1,200 times its pulling speed) the regularised friction at the pulling speed was
0.08 % of the law's and the steady-sliding spring force with it."""

import math
from pathlib import Path

import numpy as np
import pytest

from models import get_model
from models.rates import speed_floor, stiff_rates
from models.rig.steady import RIG3_SPEED, by_speed

pytestmark = pytest.mark.unit

DATA = Path(__file__).resolve().parent / "data"
SLIDER = DATA / "paper_slider" / "slider_k1002.toml"


def test_rig3_keeps_its_numbers_to_the_bit():
    m = get_model("rig3")
    assert m.nominal_speed() == RIG3_SPEED == math.pi
    assert m.eps_default == 0.05 and speed_floor(m) == 1.0 and by_speed(0.005, m) == 0.005


def test_a_faster_rig_gets_a_proportionally_larger_regularisation(tmp_path):
    from models.rig import RIGS_DIR
    text = (RIGS_DIR / "rig3.toml").read_text()
    assert 'omega_ref = "30 rpm"' in text
    f = tmp_path / "rig3_fast.toml"
    f.write_text(text.replace('omega_ref = "30 rpm"', 'omega_ref = "120 rpm"').replace('name = "rig3"', 'name = "rig3_fast"'))
    m = get_model(str(f))
    assert m.eps_default == pytest.approx(4 * 0.05, rel=1e-12)
    assert speed_floor(m) == pytest.approx(4.0, rel=1e-12)


def test_the_slider_slides_steadily_at_the_laws_friction_not_a_smoothed_fraction_of_it():
    m = get_model(str(SLIDER))
    p = m.published()
    v = m.nominal_speed()
    assert v == pytest.approx(4.2e-5)
    assert m.eps_default == pytest.approx(0.05 * v / math.pi, rel=1e-12)        # 6.7e-7 m/s
    u = np.array([v])
    x = m.steady_sliding(u, p)
    assert x[m.states.index("omega_slider")] == pytest.approx(v, rel=1e-9)
    # the spring holds the law's friction at the pulling speed, by hand from the rig file (thesis eq.
    # 3-13: N [mu_k + (mu_s - mu_k) exp(-v / v_s)], 1 m lever); the regularisation's tanh(v / eps) =
    # 1 - 1e-54 takes nothing from it, its |v| smoothed at 1e-3 eps (v - 7e-10 m/s) 1.2e-6 of it
    by_hand = 0.301167 * (0.3 + (0.4 - 0.3) * math.exp(-4.2e-5 / 1e-4))
    assert abs(float(m.contact_friction(0, v, u, p.as_dict(), s=1.0))) == pytest.approx(by_hand, rel=1e-12)
    spring = x[m.states.index("twist_spring")] * p.k
    assert spring == pytest.approx(by_hand, rel=2e-6)


def test_the_rates_of_a_slow_rig_are_taken_at_its_speeds_not_at_1_rad_per_s():
    m = get_model(str(SLIDER))
    assert speed_floor(m) == pytest.approx(4.2e-5 / math.pi, rel=1e-12)
    p = m.published()
    # the undamped slider's spring oscillation sqrt(k/m) = 181 rad/s bounds the rate while sliding on
    # the law's falling branch at its own speeds; the regularisation's slope at rest adds N mu_s / (m eps)
    lam = stiff_rates(m, p, np.array([m.nominal_speed()]))
    assert lam >= math.sqrt(p.k / p.m) * 0.99
