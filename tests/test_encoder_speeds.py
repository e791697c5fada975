"""Speed derivation follows the sensor's kind, not a channel name (issue 28, item 5).

A log read alone derives ``omega<X>`` from ``theta<X>`` (the log vocabulary).  Once the rig is known,
each encoder's speed channel is derived from that encoder's angle channel, whatever the two are
named: on main, a torque drive whose encoder logs the position as ``q`` (the EMPS benchmark's
naming) had no speed, and identification stopped with "no output channel of rig ... found".
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.identify import IdentifyOptions, identify
from models import get_model
from models.logs import Log
from models.plant import SimOptions, simulate

RIG = """
[rig]
name = "emps_like"
description = "one body under a logged torque, viscous and Coulomb friction; its encoder logs the position as q"
operating_point = { speed = "1 rad/s" }

[parameters]
M = { value = 0.1, unit = "kg m^2", max = 10, positive = true }
fv = { value = 0.2, unit = "N m s/rad", max = 10 }
Fc = { value = 0.3, unit = "N m", max = 10 }

[bodies.cart]
inertia = "M"

[connections.guide_viscous]
between = ["cart", "ground"]
damping = "fv"

[contacts.guide]
body = "cart"
law = "coulomb"
mu_k = "Fc"

[drive]
kind = "torque"
body = "cart"
input = "tau"

[sensors.enc]
kind = "encoder"
body = "cart"
ticks = 100000
angle = "q"
speed = "qd"
"""


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    p = tmp_path_factory.mktemp("emps") / "emps_like.toml"
    p.write_text(RIG)
    return get_model(str(p))


@pytest.fixture(scope="module")
def position_log(rig):
    """4 s of the rig under 0.2 + 0.5 sin(pi t) N m (it sticks and slides), position and torque only."""
    r = simulate(rig, rig.published(), lambda t: np.array([0.2 + 0.5 * math.sin(math.pi * t)]), duration=4.0,
                 options=SimOptions(dt=0.005))
    assert r.success
    log = r.to_log()
    return Log(log.t, {"q": log["q"], "tau": log["tau"]}, "q-only", (), {"q": "rad", "tau": "N m"}), r


def test_the_encoder_gives_its_speed_whatever_its_channels_are_named(rig, position_log):
    log, r = position_log
    assert "qd" not in log.with_speeds().channels                     # no theta*, no speed by name
    d = log.with_speeds(rig)
    assert d.derived == ("qd",) and d.units["qd"] == "rad/s"
    w = r.state("omega_cart")
    # central differences of the 1e5-tick angle: the true speed to the sampling's own error
    assert np.max(np.abs(d["qd"][1:-1] - 0.5 * (w[1:-1] + w[2:]))) < 0.02 * np.max(np.abs(w))


def test_a_speed_derived_by_name_that_no_encoder_writes_is_dropped(rig):
    """``theta_cart`` read alone gives ``omega_cart`` by the vocabulary; for a rig whose encoder on the
    cart writes ``theta_cart``/``v_cart`` the speed is ``v_cart`` and the name-made one goes."""
    t = np.arange(0.0, 1.0, 0.01)
    th = 2.0 * t + 0.5 * t ** 2
    read = Log(t, {"theta_cart": th}, "read", (), {"theta_cart": "rad"}).with_speeds()
    assert read.derived == ("omega_cart",)
    spec = rig.spec
    enc = spec.sensors[0]
    renamed = type(rig)(spec.with_changes(sensors=(type(enc)(enc.name, enc.kind, enc.target, ("theta_cart", "v_cart"),
                                                            ticks=enc.ticks),)))
    d = read.with_speeds(renamed)
    assert d.derived == ("v_cart",) and "omega_cart" not in d.channels
    np.testing.assert_allclose(d["v_cart"][1:-1], 2.0 + t[1:-1], atol=1e-9)


def test_identification_fits_a_position_only_log_of_a_torque_drive(rig, position_log):
    """Truth recovery from ``q`` and ``tau`` alone: viscous 0.2 and Coulomb 0.3 from a start at 0.3 / 0.2
    (on main: DataError, no output channel)."""
    log, _ = position_log
    start = rig.published().replace(fv=0.3, Fc=0.2)
    fit = identify(log, rig, start, IdentifyOptions(free=("fv", "Fc")))
    assert "qd" in [c.name for c in fit.problem.channels]
    est = dict(zip(fit.names, fit.estimate))
    assert est["fv"] == pytest.approx(0.2, rel=0.05) and est["Fc"] == pytest.approx(0.3, rel=0.03)
