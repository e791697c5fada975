"""The closed loop (mitigate.closedloop): plant + sensors + servos + estimator + controller at the DAQ
rate; multi-rate hold; what a controller may see; failure handling; divergence; drive limits."""

import math

import numpy as np
import pytest

from estimators.base import Estimate, StateEstimator
from mitigate.closedloop import run_closed_loop
from mitigate.controllers.base import Action, Controller
from mitigate.controllers.factory import context_for, make_controller
from mitigate.metrics import closed_loop_metrics
from mitigate.scenario import make_scenario
from models import get_model
from models.plant import Plant, SimOptions, simulate
from models.sensors import encoder_step
from models.errors import ConfigError, PluginError, SolverFailure
from models.status import Status


def _scenario(duration=3.0, start=1.0, every=1, controllers=("pi",), **extra):
    return make_scenario(name="t", duration=duration, seed=3, inputs={"omega_ref": "30 rpm", "n1": 20.0},
                         controllers=list(controllers), estimator="fd", control_start=start,
                         control={"start": start, "every": every}, **extra)


class Spy(Controller):
    """Records what it is given; raises the set-point by ``0.5 + t / 10`` rad/s and presses N2 = 3 N."""

    kind = "spy"

    def __init__(self, options, context):
        super().__init__(options, context)
        self.calls = []

    def _step_impl(self, t, measurement, estimate):
        self.calls.append((t, dict(measurement), estimate))
        w = self.context.scheduled(t, "omega_ref")
        return Action({"omega_ref": w + 0.5 + t / 10, "n2": 3.0})


class Raiser(Controller):
    kind = "raiser"

    def _step_impl(self, t, measurement, estimate):
        raise RuntimeError("solver exploded")


def _spy(sc):
    return Spy(None, context_for(sc))


def test_pi_equals_the_open_loop_simulation_with_the_same_seed():
    """'PI only' sets nothing: the loop is the open-loop plant, sample for sample, noise included."""
    sc = _scenario()
    r = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    ref = simulate(sc.plant_model, sc.plant_params, sc.programme, sc.duration, sc.sim, sensors=sc.sensors)
    n = 300
    assert r.status is Status.OK and r.success and r.message == "ok"
    assert r.t.shape == (n + 1,) and r.x.shape == (n + 1, 7) and r.u.shape == (n + 1, 3)
    np.testing.assert_array_equal(r.x, ref.x)
    np.testing.assert_array_equal(r.u, ref.u)
    for ch in sc.model.measured:
        np.testing.assert_array_equal(r.y[ch], ref.y[ch], err_msg=ch)
    assert np.all(r.controller_active == (r.t >= 1.0 - 1e-12))
    assert r.controller_counts["steps"] == 201 and r.controller_counts["failures"] == 0
    np.testing.assert_allclose(r.commands["omega_ref"], math.pi)
    np.testing.assert_allclose(r.commands["n2"], 0.0)
    # the FD estimate is the measured speeds
    np.testing.assert_array_equal(r.estimate("omega_R1"), r.y["omega1"])
    assert np.max(r.state("omega_R3")) > 2.0        # the rig did start turning
    log = r.to_log()
    assert {"true_twist_shaft1", "true_twist_shaft2", "omega1", "theta1", "motor_torque", "omega_ref",
            "n2"} <= set(log.channels)
    np.testing.assert_array_equal(log["true_twist_shaft1"], r.state("twist_shaft1"))


def test_the_controller_never_sees_the_true_state():
    sc = _scenario(duration=2.0, start=0.5)
    spy = _spy(sc)
    r = run_closed_loop(sc, spy)
    assert len(spy.calls) == 151
    q1 = encoder_step(sc.model.sensor_of("theta1"))          # 2 pi / 1000 rad
    for t, meas, est in spy.calls:
        assert set(meas) <= set(sc.model.measured)         # channels only: no twist, state or parameter
        assert not any(k.startswith(("twist", "omega_R", "current", "pi_")) for k in meas)
        assert isinstance(est, Estimate) and est.t == t
        # the angle is a count of whole encoder ticks, never the true angle
        assert abs(meas["theta1"] / q1 - round(meas["theta1"] / q1)) < 1e-9
        assert est.get("omega_R1") == meas["omega1"]
    # ... while the true angles are not on the encoder grid
    tw = r.state("twist_shaft1")
    assert np.any(np.abs(tw / q1 - np.round(tw / q1)) > 1e-3)
    # the actions are applied: the set-point from the controller, N2 through the servo (lag, rate limit)
    on = r.t >= 0.5 - 1e-12
    np.testing.assert_allclose(r.commands["omega_ref"][on], math.pi + 0.5 + r.t[on] / 10)
    k0 = int(np.argmax(on))
    assert 0 < r.input("n2")[k0] < 3.0 and r.input("n2")[-2] == pytest.approx(3.0, abs=1e-3)


def test_the_controller_and_estimator_see_the_nominal_model_not_the_plant(monkeypatch):
    sc = _scenario(duration=0.5, start=0.0, mismatch={"k1": 1.2}, structure={"pi_error": "motor"})
    assert sc.plant_params["k1"] == pytest.approx(1.2 * sc.model_params["k1"])
    assert sc.plant_model.spec.drive.pi_error == "motor" and sc.model.spec.drive.pi_error == "disc"
    import estimators.online.factory as ef
    seen = {}
    real = ef.make_estimator

    def spy_make(spec, context):
        seen["context"] = context
        return real(spec, context)

    monkeypatch.setattr(ef, "make_estimator", spy_make)
    spy = _spy(sc)
    run_closed_loop(sc, spy)
    assert spy.context.params is sc.model_params and spy.context.model is sc.model
    assert seen["context"].params is sc.model_params and seen["context"].model is sc.model
    assert seen["context"].params["k1"] != sc.plant_params["k1"]


def test_multirate_holds_the_action_between_calls():
    sc = _scenario(duration=2.0, start=0.5, every=5)
    spy = _spy(sc)
    r = run_closed_loop(sc, spy)
    ts = np.array([c[0] for c in spy.calls])
    assert len(ts) == 31 and ts[0] == pytest.approx(0.5)
    np.testing.assert_allclose(np.diff(ts), 0.05)
    assert r.solve_times.shape == (31,) and r.plan_calls.all()
    # between two calls the command is the one of the last call
    on = np.flatnonzero(r.t >= 0.5 - 1e-12)
    last_call = ts[np.searchsorted(ts, r.t[on] + 1e-9) - 1]
    np.testing.assert_allclose(r.commands["omega_ref"][on], math.pi + 0.5 + last_call / 10)
    assert len(np.unique(r.commands["omega_ref"][on])) == 31


class Transient(Controller):
    """Its solver fails (SolverFailure, the one transient failure) at every call."""

    kind = "transient"

    def _step_impl(self, t, measurement, estimate):
        raise SolverFailure("solver exploded")


def test_a_transient_solver_failure_is_answered_by_the_fallback_counted_and_a_warning():
    sc = _scenario(duration=2.0, start=1.0)
    a = Transient(None, context_for(sc)).step(0.0, {}, None)
    assert a.status is Status.FALLBACK and not a.success and a.u == {} and "solver exploded" in a.message
    r = run_closed_loop(sc, Transient(None, context_for(sc)))
    assert r.success and r.status is Status.WARNING and r.t[-1] == pytest.approx(2.0)
    assert r.controller_counts["failures"] == 101 == r.controller_counts["fallbacks"]
    assert not np.any(r.controller_ok[r.t >= 1.0]) and np.all(r.controller_ok[r.t < 1.0])
    np.testing.assert_allclose(r.commands["omega_ref"], math.pi)     # the fallback is the programme
    np.testing.assert_allclose(r.commands["n2"], 0.0)
    assert r.message.startswith("101 controller fallback(s) in 101 call(s) (1e+02 %), the first at t = 1.000 s: "
                                "fallback to the programme: SolverFailure: solver exploded")


def test_a_raising_controller_fails_its_run_with_the_reason():
    sc = _scenario(duration=2.0, start=1.0)
    with pytest.raises(PluginError, match=r"^RuntimeError: solver exploded$"):
        Raiser(None, context_for(sc)).step(0.0, {}, None)
    r = run_closed_loop(sc, Raiser(None, context_for(sc)))
    assert r.status is Status.FAILED and not r.success
    assert r.message == "controller failed at t = 1.000 s in step: RuntimeError: solver exploded"
    assert r.t[-1] == pytest.approx(1.0) and r.x.shape == (101, 7) and r.xhat.shape[0] == 101
    np.testing.assert_allclose(r.commands["omega_ref"], math.pi)     # nothing it said was applied


def test_non_finite_or_foreign_commands_fail_the_run():
    sc = _scenario(duration=0.1, start=0.0)

    class Bad(Controller):
        def _step_impl(self, t, m, e):
            return Action({"omega_ref": float("nan")}) if t < 0.05 else Action({"n1": 5.0})

    c = Bad(None, context_for(sc))
    with pytest.raises(PluginError, match=r"^FloatingPointError: non-finite command omega_ref = nan$"):
        c.step(0.0, {}, None)
    with pytest.raises(PluginError, match=r"^ValueError: command for 'n1', which the rig cannot set"):
        c.step(0.06, {}, None)           # n1 is set by hand, not a command
    r = run_closed_loop(sc, Bad(None, context_for(sc)))
    assert r.status is Status.FAILED and "non-finite command omega_ref" in r.message


class BrokenEstimator(StateEstimator):
    """Finite-difference speeds until t = 0.5 s, then a singular matrix at every update."""

    kind = "broken"

    def __init__(self, options, context):
        super().__init__(options, context)
        self.names = context.model.states
        self.channels = ("omega1",)

    def _update_impl(self, t, y, mask, u):
        if t > 0.5:
            raise np.linalg.LinAlgError("singular")
        return Estimate(t, np.zeros(len(self.names)), np.eye(len(self.names)), self.names)


def test_an_estimator_that_raises_fails_the_run_with_the_reason():
    from estimators.base import EstimatorContext
    sc = _scenario(duration=1.0, start=0.2)
    spy = _spy(sc)
    est = BrokenEstimator(None, EstimatorContext(sc.model, sc.model_params, sc.dt))
    r = run_closed_loop(sc, spy, estimator=est)
    assert r.status is Status.FAILED and r.message == "estimator failed at t = 0.510 s in update: LinAlgError: singular"
    assert r.t[-1] == pytest.approx(0.51) and r.xhat.shape == (52, 7) and np.all(np.isnan(r.xhat[-1]))
    assert spy.calls[-1][2].status is Status.OK and spy.calls[-1][0] == pytest.approx(0.5)


def test_an_estimator_solver_failure_is_answered_by_its_fallback():
    from estimators.base import EstimatorContext

    class Transient(BrokenEstimator):
        def _update_impl(self, t, y, mask, u):
            if t > 0.5:
                raise SolverFailure("singular")
            return super()._update_impl(t, y, mask, u)

    sc = _scenario(duration=1.0, start=0.2)
    spy = _spy(sc)
    r = run_closed_loop(sc, spy, estimator=Transient(None, EstimatorContext(sc.model, sc.model_params, sc.dt)))
    assert r.status is Status.WARNING and r.t[-1] == pytest.approx(1.0)
    assert r.estimator_counts["failures"] == r.estimator_counts["fallbacks"] == 50
    assert spy.calls[-1][2].status is Status.FALLBACK and "singular" in spy.calls[-1][2].message
    assert "50 estimator fallback(s) in 101 call(s)" in r.message


def test_a_plant_failure_ends_the_run_cleanly():
    sc = _scenario(duration=1.0, start=0.2)
    plant = Plant(sc.plant_model, sc.plant_params, sc.sim, sensors=sc.sensors, u0=sc.programme(0.0))
    real = plant.step

    def step(u):
        if plant.t >= 0.5 - 1e-9:
            raise RuntimeError("integrator blew up")
        return real(u)

    plant.step = step
    r = run_closed_loop(sc, _spy(sc), plant=plant)
    assert r.status is Status.FAILED and not r.success
    assert r.message == "plant step failed at t = 0.510 s: RuntimeError: integrator blew up"
    assert r.t.shape == (51,) and np.all(np.isfinite(r.x)) and r.x.shape == (51, 7)


class Torque(Controller):
    """Commands a torque-drive rig's torque (rig2: motor_torque [N m])."""

    kind = "torque"

    def _step_impl(self, t, measurement, estimate):
        return Action({"motor_torque": 1e6})


def test_a_runaway_torque_drive_ends_as_diverged_with_the_samples_before_it():
    sc = make_scenario(name="runaway", model="rig2", duration=3.0, inputs={"motor_torque": 0.0}, estimator="fd",
                       control_start=1.0)
    r = run_closed_loop(sc, Torque(None, context_for(sc)))
    assert r.status is Status.DIVERGED and not r.success
    assert "\n" not in r.message and r.message.startswith("diverged at t = 1.010 s: |omega_motor|")
    assert "plant.max_speed = 31.831 rad/s" in r.message          # 100/pi times rig2's nominal 1 rad/s
    # 1e6 N m on Jm = 0.0237 kg m^2 leaves 32 rad/s within the first sample after the start
    assert r.t.shape == (102,) and r.t[-1] == pytest.approx(1.01)
    assert np.all(np.isfinite(r.x)) and abs(r.state("omega_motor")[-1]) > 100
    assert np.all(np.abs(r.x[:101, [r.states.index("omega_disc"), r.states.index("omega_motor")]]) <= 100)
    # every array has a row per sample, the diverged one included: the run can be logged and scored
    assert set(r.y) >= {"omega1", "omega3", "motor_torque"}
    assert all(len(v) == 102 for v in r.y.values()) and r.xhat.shape[0] == r.u.shape[0] == 102
    assert r.commands["motor_torque"][-1] == 1e6 and np.all(np.isnan(r.xhat[-1]))
    assert r.to_log().t.shape == (102,)
    m = closed_loop_metrics(r, sc)
    assert m["diverged"] == 1 and m["controller_steps"] == 1


class Absurd(Controller):
    kind = "absurd"

    def _step_impl(self, t, measurement, estimate):
        return Action({"omega_ref": 1e4})


def test_the_drive_limits_keep_an_absurd_set_point_bounded():
    """rig3.toml: v_max = 24 V, i_max = 10 A.  A set-point of 1e4 rad/s saturates the supply: the
    drive settles below its no-load speed v_max / (KE eta) = 49.8 rad/s, at the speed where the
    supply balances the load, and the current never passes i_max."""
    sc = _scenario(duration=8.0, start=1.0)
    r = run_closed_loop(sc, Absurd(None, context_for(sc)))
    assert r.status is Status.OK
    p = sc.plant_params
    eta, KE, KT, R = p["eta"], p["KE"], p["KT"], p["R"]
    w0 = p["v_max"] / (KE * eta)
    assert w0 == pytest.approx(49.83, abs=0.01)
    i = r.state("current")
    # the current limit is a voltage limit, V <= R i_max + KE eta w, that holds i at i_max without
    # overshoot (its lag is the electrical time constant L/R = 2.6 ms, while the back-emf moves slowly)
    assert np.max(i) <= p["i_max"] * 1.001 and np.max(i) > 0.99 * p["i_max"]
    # steady state: V_max = R i + KE eta w, eta KT i = load (pin 1 + motor friction)
    w3 = r.state("omega_R3")
    tail = r.t > 6.0
    w_end = float(np.mean(w3[tail]))
    mu = p["mu_k"] + (p["mu_s"] - p["mu_k"]) * math.exp(-w_end / p["v_s"])
    load = p["r1"] * mu * 20.0 + eta * (p["Tf"] + p["Cm"] * eta * w_end)
    w_ss = (p["v_max"] - R * load / (eta * KT)) / (KE * eta)
    assert w_end < w0 and w_end == pytest.approx(w_ss, rel=0.02)
    # when the wound-up shaft pushes the drive past its no-load speed, the motor generates (i < 0)
    over = w3 > 1.01 * w0
    assert np.all(i[over] < 0)
    assert np.max(np.abs(r.x[:, [r.states.index(f"omega_{b}") for b in sc.plant_model.bodies]])) < sc.max_speed


def test_results_give_trajectories_by_name_and_refuse_an_unknown_one_in_one_line():
    """SimResult and ClosedLoopResult share models.plant.Trajectory: state(name), input(name)."""
    m = get_model("rig3")
    r = simulate(m, m.published(), [math.pi, 20.0, 0.0], 0.2, SimOptions())
    assert np.array_equal(r.input("n1"), r.u[:, m.inputs.index("n1")])
    assert np.array_equal(r.state("omega_R1"), r.x[:, r.states.index("omega_R1")])
    for f, bad in ((r.input, "n9"), (r.state, "omega_R9")):
        with pytest.raises(ConfigError, match=rf"^no (input|state) '{bad}'; (inputs|states): "):
            f(bad)
