"""A new drive kind is one class plus one registry line (issue 25's target).

The kind below is defined HERE and nowhere else: an AC servo, a speed-setting drive whose own
PI speed loop applies a torque to its body, limited to ``+-T_max`` (anti-windup while it is at
the limit).  It declares what it is -- a speed set-point, a body it acts on, three parameters, one
state (the loop's integral, whose estimator prior is the PI family's) -- and implements its torque,
its state's rate, its torque limit and its power.  A small rig file uses it; the rig is then
simulated, analysed modally, tracked by the EKF, identified and controlled (PI and SoftSpeed)
without any other module knowing the kind.
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from models import get_model
from models.modal import chain_matrices, modes
from models.plant import SimOptions, simulate
from models.rig.drives import DRIVES, Drive, DriveField, DriveState, register


class ACServo(Drive):
    """``T = sat(kp (w_ref - w) + ki z, +-T_max)`` on the drive body, ``z' = w_ref - w`` (held while the
    torque is at its limit against the error)."""

    kind = "ac_servo"
    doc = "AC servo: PI speed loop with a torque limit"
    setpoint = "speed"
    fields = (DriveField("kp", "damping", strict=True), DriveField("ki", "stiffness"),
              DriveField("T_max", "torque", strict=True))
    states = (DriveState("servo_integral", "rad", prior="pi", doc="the speed loop's integral"),)

    def _loop(self, model, x, un, P):
        e = un[self.input] - x[model.speed_index(self.body)]
        z = x[self.state_index(model, "servo_integral")]
        return e, self.param("kp").value(P, un) * e + self.param("ki").value(P, un) * z, self.param("T_max").value(P, un)

    def torque(self, model, x, un, P):
        _, T, lim = self._loop(model, x, un, P)
        return ca.fmin(ca.fmax(T, -lim), lim)

    def rates(self, model, x, un, P):
        e, T, lim = self._loop(model, x, un, P)
        return [ca.if_else(ca.logic_and(ca.fabs(T) > lim, ca.sign(T) == ca.sign(e)), 0, e)]

    def torque_limit(self, P=None) -> float:
        return math.inf if P is None else float(self.param("T_max").value(P))

    def power(self, model, params, X, U):
        P = params.as_dict()
        e = U[:, model.inputs.index(self.input)] - X[:, model.speed_index(self.body)]
        T = P["kp_s"] * e + P["ki_s"] * X[:, self.state_index(model, "servo_integral")]
        return np.clip(T, -P["T_max"], P["T_max"]) * X[:, model.speed_index(self.body)]


RIG = """
[rig]
name = "servo_string"
description = "one disc with a pin on a shaft from a top under an AC servo (tests/test_new_drive_kind.py)"
operating_point = { omega_ref = "30 rpm", n1 = "20 N" }
objective_body = "R1"

[parameters]
J1 = { value = 0.02888, unit = "kg m^2", max = 10, positive = true, source = "thesis Table 3.2 (disc R1)" }
J_top = { value = 0.02368, unit = "kg m^2", max = 10, positive = true, source = "thesis: R3 = eta^2 Jm" }
k1 = { value = 0.276, unit = "N m/rad", max = 1e3, positive = true, source = "rig3's two shafts in series" }
d1 = { value = 0.01, unit = "N m s/rad", max = 1e2, source = "this test" }
kp_s = { value = 2.0, unit = "N m s/rad", max = 1e3, positive = true, source = "this test" }
ki_s = { value = 20.0, unit = "N m/rad", max = 1e4, source = "this test" }
T_max = { value = 1.5, unit = "N m", max = 1e3, positive = true, source = "this test" }
mu_s = { value = 0.5, max = 5, source = "thesis eq. 3-11" }
mu_k = { value = 0.306, max = 5, source = "thesis eq. 3-14" }
v_s = { value = 1.0, unit = "rad/s", max = 1e3, positive = true, source = "thesis eq. 3-13" }
r1 = { value = 0.047, unit = "m", max = 1, positive = true, source = "thesis eq. 3-10" }

[bodies.R1]
inertia = "J1"
[bodies.top]
inertia = "J_top"

[connections.shaft]
between = ["R1", "top"]
stiffness = "k1"
damping = "d1"

[contacts.pin1]
body = "R1"
law = "stribeck"
normal = "n1"
radius = "r1"
mu_s = "mu_s"
mu_k = "mu_k"
v_s = "v_s"

[drive]
kind = "ac_servo"
body = "top"
input = "omega_ref"
kp = "kp_s"
ki = "ki_s"
T_max = "T_max"

[sensors.enc1]
kind = "encoder"
body = "R1"
ticks = 1000
angle = "theta1"
speed = "omega1"
[sensors.enc_top]
kind = "encoder"
body = "top"
ticks = 8000
angle = "theta_top"
speed = "omega_top"
[sensors.servo_torque]
kind = "torque"
at = "drive"
channel = "servo_torque"
noise = "0.01 N m"
[sensors.load1]
kind = "load_cell"
contact = "pin1"
noise = "0.2 N"
"""


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    register(ACServo)
    path = tmp_path_factory.mktemp("drive") / "servo_string.toml"
    path.write_text(RIG)
    yield get_model(path)
    DRIVES.pop(ACServo.kind)


@pytest.fixture(scope="module")
def run(rig):
    p = rig.published()
    r = simulate(rig, p, np.array([math.pi, 20.0]), 15.0, SimOptions(seed=3))
    assert r.success, r.message
    return r


def test_the_rig_asks_the_drive(rig):
    d = rig.drive
    assert isinstance(d, ACServo) and rig.drive_node == "top"
    assert d.sets_speed and not d.reverses and d.boundary == "clamped" and d.unit == "rad/s"
    assert rig.states[-1] == "servo_integral" and rig.state_units[-1] == "rad"
    assert rig.input_kinds == ("speed", "force") and rig.current_index is None
    # the speed-setting drive's target and operating point: its input is the speed
    assert rig.nominal_speed() == pytest.approx(math.pi) and rig.drive_speed_index() == 0
    u, x = rig.operating_point(math.pi, np.array([0.0, 20.0]), rig.published())
    assert u[0] == math.pi and x[rig.speed_index("R1")] == pytest.approx(math.pi, rel=1e-9)
    # in steady sliding the loop's integral carries the pin's friction (kp e = 0): ki z = -T_friction
    p = rig.published()
    T_f = float(rig.contact_friction(0, math.pi, u, p.as_dict(), eps=rig.eps_default))
    assert T_f < 0 and p["ki_s"] * x[-1] == pytest.approx(-T_f, rel=1e-9)


def test_simulated_plant_stick_slips_under_the_servo(rig, run):
    """From rest at 30 rpm and 20 N the disc stick-slips (thesis rig: ~2.3 s cycles); the servo holds
    the top near its set-point and never exceeds its torque limit."""
    w1, wt = run.state("omega_R1"), run.state("omega_top")
    late = run.t > 5.0
    assert np.mean(w1[late] == 0.0) > 0.1                         # the exact plant's stuck phases
    assert np.mean(wt[late]) == pytest.approx(math.pi, rel=0.05)
    assert np.max(np.abs(run.y["servo_torque"])) < 1.5 + 5 * 0.01
    # what the torque sensor reads is the servo's applied torque, the drive's own answer
    assert np.max(np.abs(run.y["servo_torque"])) > 0.3


def test_modes_take_the_drive_s_boundary(rig):
    """The servo holds a speed: the clamped chain is one disc on a damped spring, whose mode is the
    analytic ``sqrt(k/J - (d/2J)^2)``; the free chain has the top's inertia."""
    p = rig.published()
    r = modes(rig, p, "clamped")
    J, k, d = 0.02888, 0.276, 0.01
    wd = math.sqrt(k / J - (d / (2 * J)) ** 2)
    assert r.damped_hz[0] == pytest.approx(wd / (2 * math.pi), rel=1e-9)
    M, _, K, dofs = chain_matrices(rig, p, clamped=False)
    assert dofs == ("theta_R1", "theta_top") and M[1, 1] == pytest.approx(0.02368)
    closed = modes(rig, p, "closed")
    assert closed.status.success and len(closed.freq_hz) > 0


@pytest.mark.slow
def test_ekf_tracks_the_rig(rig):
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.scenario import make_scenario

    sc = make_scenario(name="servo_ekf", model=rig, duration=6.0, controllers=["pi"], estimator="ekf")
    r = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    assert r.status.success and r.estimator_counts["failures"] == 0
    i, j = r.xhat_names.index("omega_R1"), rig.speed_index("R1")
    late = r.t > 3.0
    assert np.sqrt(np.mean((r.xhat[late, i] - r.x[late, j]) ** 2)) < 0.1 * np.max(np.abs(r.x[late, j]))
    # the servo's integral is a state of the filter; its prior and process noise are the PI family's
    from estimators.online.model import build_estimation_model
    from estimators.online.options import EKFOptions, for_rig
    em = build_estimation_model(rig, rig.published(), EKFOptions(), 0.01)
    o = for_rig(EKFOptions(), rig, rig.published())
    k = em.names.index("servo_integral")
    assert em.P0[k, k] == pytest.approx(o.p0_pi ** 2) and o.p0_pi > 0


def test_identification_recovers_the_friction_level(rig, run):
    from estimators.identify import IdentifiabilityWarning, IdentifyOptions, identify

    start = rig.published().replace(mu_k=0.25)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        fit = identify(run.to_log(), rig, start, IdentifyOptions(free=("mu_k",), encoder_zero="untwisted"))
    assert fit.success, fit.message
    assert dict(zip(fit.names, fit.estimate))["mu_k"] == pytest.approx(0.306, rel=0.02)


@pytest.mark.parametrize("kind", ["pi", "softspeed"])
def test_controllers_run_on_the_rig(rig, kind):
    """PI leaves the stick-slip as it is; SoftSpeed, tuned from the rig (the drive's inertia, the
    string's impedance, its clamped mode) and reading the servo's torque, damps it."""
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.metrics import closed_loop_metrics
    from mitigate.scenario import make_scenario

    sc = make_scenario(name=f"servo_{kind}", model=rig, duration=30.0, controllers=[kind], estimator="fd",
                       control_start=10.0)
    c = make_controller(sc.controllers[0], context_for(sc, 0))
    r = run_closed_loop(sc, c)
    assert r.status.success and r.controller_counts["failures"] == 0
    met = closed_loop_metrics(r, sc)
    assert math.isfinite(met["drive_energy"]) and met["drive_energy"] > 0      # the drive's own power
    stuck = np.mean(r.state("omega_R1")[r.t > 20.0] == 0.0)
    if kind == "pi":
        assert stuck > 0.1
    else:
        assert c.J_v == pytest.approx(0.02368) and stuck == 0.0


def test_no_module_outside_the_registry_tests_a_drive_kind_by_name():
    """The registry (models/rig/drives) is the only place that knows the kinds' names: elsewhere a
    kind's name appears in messages and examples only, never in a comparison.  The rig zoo
    (models/rig/zoo.py) is exempt: it writes rig files of the shipped kinds, each kind's own data."""
    root = Path(__file__).resolve().parents[1]
    by_name = re.compile(r"(drive_kind|drive\.kind)\s*(==|!=|in\b|not in\b)|(==|!=|\bin\b).*[\"']dc_motor[\"']")
    hits = [f"{f.relative_to(root)}:{n}: {line.strip()}"
            for pkg in ("models", "estimators", "mitigate") for f in sorted((root / pkg).rglob("*.py"))
            if "drives" not in f.relative_to(root).parts[:3] and f.name != "zoo.py"
            for n, line in enumerate(f.read_text().splitlines(), 1) if by_name.search(line)]
    assert not hits, "\n".join(hits)
