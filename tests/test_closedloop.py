"""The closed loop: plant + sensors + servo + estimator + controller, multi-rate, failure handling."""

import numpy as np
import pytest

from estimators.base import Estimate, StateEstimator
from mitigate.closedloop import MEAS_CHANNELS, run_closed_loop
from mitigate.controllers.base import Action, Controller
from mitigate.controllers.factory import make_controller
from mitigate.scenario import parse_scenario
from models.rigs import get_model
from models.plant import Plant


def _scenario(duration=3.0, start=1.0, every=1, controllers=({"name": "pi", "kind": "pi"},), **extra):
    d = {"scenario": {"name": "t", "duration": duration, "seed": 3},
         "inputs": {"omega_ref": {"kind": "constant", "value": 30, "unit": "rpm"}, "n1": 20},
         "control": {"start": start, "every": every}, "estimator": {"kind": "fd"},
         "controllers": list(controllers)}
    d.update(extra)
    return parse_scenario(d, "t.toml")


class Spy(Controller):
    """Records what it is given; commands a constant N2."""

    name = "spy"

    def __init__(self, omega, n2=3.0):
        super().__init__(omega)
        self.calls = []
        self.n2 = n2

    def _step_impl(self, t, estimate, measurement):
        self.calls.append((t, estimate, dict(measurement)))
        return Action(self.n2, self.omega_nominal + 0.5)


class Raiser(Controller):
    name = "raiser"

    def _step_impl(self, t, estimate, measurement):
        raise RuntimeError("solver exploded")


def test_pi_with_fd_estimator_matches_open_loop_baseline():
    sc = _scenario()
    r = run_closed_loop(sc, make_controller(sc.controllers[0], sc, 0))
    n = 300
    assert r.success and r.status == "ok"
    assert r.t.shape == (n + 1,) and r.x.shape == (n + 1, 7) and r.u.shape == (n + 1, 3)
    assert r.xhat.shape == (n + 1, 7) and r.xhat_names[0] == "phi12"
    assert np.all(r.controller_active == (r.t >= 1.0 - 1e-12))
    np.testing.assert_allclose(r.action_omega_ref, np.pi)
    np.testing.assert_allclose(r.input("n2"), 0.0)
    assert r.controller_counts["steps"] == 201 and r.controller_counts["failures"] == 0
    # fd estimator: the speeds are the measured ones
    np.testing.assert_allclose(r.xhat[:, 2], r.y["omega1"])
    # the rig did start moving and the log has the true twists
    assert np.max(r.state("omega3")) > 2.0
    log = r.to_log()
    assert {"twist12", "twist23", "omega1", "theta1", "motor_torque", "n2", "omega_ref"} <= set(log.channels)
    np.testing.assert_allclose(log["twist12"], r.state("phi12"))


def test_brake_acts_on_established_stick_slip():
    sc = _scenario(duration=8.0, start=4.0, controllers=[{"name": "b", "kind": "brake"}])
    r = run_closed_loop(sc, make_controller(sc.controllers[0], sc, 0))
    before, after = r.t < 4.0, r.t >= 4.0
    assert np.all(r.input("n2")[before] == 0.0)
    assert np.max(r.input("n2")[after]) > 1.0          # it brakes R2 when it overspeeds
    assert np.max(r.input("n2")) <= sc.servo.n_max
    assert r.success


def test_controller_never_sees_the_true_state():
    sc = _scenario(duration=2.0, start=0.5)
    spy = Spy(np.pi)
    r = run_closed_loop(sc, spy)
    assert len(spy.calls) == 151
    step = sc.sensors.angle_step
    for t, est, meas in spy.calls:
        assert set(meas) <= set(MEAS_CHANNELS)            # no twist, no state, no parameters
        assert isinstance(est, Estimate)
        k = int(round(t / sc.dt))
        # the angles are quantised encoder readings, never the true angles
        assert abs(meas["theta1"] / step - round(meas["theta1"] / step)) < 1e-9
        np.testing.assert_allclose(est.x[:2], [meas["theta1"] - meas["theta2"], meas["theta2"] - meas["theta3"]])
    # ... while the true twist is not on the encoder grid
    assert np.any(np.abs(r.state("phi12") / step - np.round(r.state("phi12") / step)) > 1e-3)
    # the actions are applied: set-point raised, N2 through the servo (lag, rate limit)
    on = r.t >= 0.5
    np.testing.assert_allclose(r.action_omega_ref[on], np.pi + 0.5)
    assert r.input("n2")[np.argmax(on)] < 3.0 and r.input("n2")[-2] == pytest.approx(3.0, abs=1e-3)


def test_controller_sees_nominal_not_plant_parameters():
    sc = _scenario(duration=0.5, start=0.0, mismatch={"k1": 1.2})
    assert sc.plant_params.k1 == pytest.approx(1.2 * sc.model_params.k1)
    captured = {}

    def fake_make_estimator(spec, model_params, sensors, dt, x0=None, where=""):
        from estimators.fd import FiniteDifference
        captured["params"] = model_params
        return FiniteDifference(sensors, dt)

    import mitigate.closedloop as cl
    orig = cl.make_estimator
    cl.make_estimator = fake_make_estimator
    try:
        run_closed_loop(sc, Spy(np.pi))
    finally:
        cl.make_estimator = orig
    assert captured["params"] is sc.model_params


def test_multirate_holds_the_action():
    sc = _scenario(duration=2.0, start=0.5, every=5)
    spy = Spy(np.pi)
    r = run_closed_loop(sc, spy)
    ts = np.array([c[0] for c in spy.calls])
    np.testing.assert_allclose(np.diff(ts), 0.05)
    assert len(ts) == 31 and ts[0] == pytest.approx(0.5)
    assert r.solve_times.shape == (31,)


def test_controller_failure_is_counted_and_loop_finishes():
    sc = _scenario(duration=2.0, start=1.0)
    r = run_closed_loop(sc, Raiser(np.pi))
    assert r.success and r.t[-1] == pytest.approx(2.0)
    assert r.controller_counts["failures"] == 101 == r.controller_counts["fallbacks_baseline"]
    assert not np.any(r.controller_ok[r.t >= 1.0]) and np.all(r.controller_ok[r.t < 1.0])
    np.testing.assert_allclose(r.action_omega_ref, np.pi)     # fallback = baseline (a)
    np.testing.assert_allclose(r.action_n2, 0.0)
    assert "fallback" in r.status


class BrokenEstimator(StateEstimator):
    names = ("phi12", "phi23", "omega1", "omega2", "omega3", "i", "z")
    channels = ("omega1",)

    def _update_impl(self, y, mask, u, t):
        if t > 0.5:
            raise np.linalg.LinAlgError("singular")
        return Estimate(t, np.zeros(7), np.eye(7), self.names)


def test_estimator_failure_is_counted_and_loop_finishes():
    sc = _scenario(duration=1.0, start=0.2)
    spy = Spy(np.pi)
    r = run_closed_loop(sc, spy, estimator=BrokenEstimator())
    assert r.success
    assert r.estimator_counts["failures"] == r.estimator_counts["fallbacks"] == 50
    assert spy.calls[-1][1].success is False


def test_plant_failure_ends_run_cleanly():
    sc = _scenario(duration=1.0, start=0.2)
    m = get_model("rig3")
    plant = Plant(m, sc.plant_params, sc.sim, sensors=sc.sensors, servo=sc.servo, u0=sc.input_vector(0))
    orig = plant.step

    def step(u):
        if plant.t >= 0.5 - 1e-9:
            raise RuntimeError("integrator blew up")
        return orig(u)
    plant.step = step
    r = run_closed_loop(sc, Spy(np.pi), plant=plant)
    assert not r.success and "plant failed at t = 0.510" in r.status
    assert r.t.shape == (51,) and np.all(np.isfinite(r.x))
