"""EKF on any rig: the generic model, the textbook update, dlqe, truth recovery on our plant, dropouts, options."""

import math
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from estimators.base import EstimatorContext
from estimators.online.ekf import EKF
from estimators.online.factory import make_estimator
from estimators.online.fd import FiniteDifference
from estimators.online.model import build_estimation_model, rig_rhs
from estimators.online.options import EKFOptions, FDOptions
from models import get_model
from models.errors import ConfigError
from models.plant import SimOptions, simulate
from models.status import Status

from daq_run import powered_on

DATA = Path(__file__).resolve().parent / "data"

M = get_model("rig3")
P3 = M.published()
U = np.array([math.pi, 20.0, 0.0])          # 30 rpm, N1 = 20 N: established stick-slip (thesis Ch. 3)
ENCODERS = ["theta1", "theta2", "theta3", "omega1", "omega2", "omega3"]
SPEEDS_TORQUE = ["omega1", "omega2", "omega3", "motor_torque"]
K0 = 300                                    # the DAQ powers on at 3 s, in stick-slip, on a twisted shaft


def ctx(model=M, params=P3, **kw):
    return EstimatorContext(model, params, 0.01, **kw)


def ekf(**kw):
    kw.setdefault("check_observability", False)
    kw.setdefault("compile", False)
    return EKF(EKFOptions(**kw), ctx())


@pytest.fixture(scope="module")
def run3():
    """15 s of stick-slip of our exact plant; DAQ powered on at 3 s (encoders zeroed there)."""
    return powered_on(simulate(M, P3, U, 15.0, SimOptions(seed=3)), K0)


def drive(est, t, y):
    n = len(t)
    X = np.zeros((n, len(est.names)))
    out = []
    for k in range(1, n):
        e = est.update(t[k], {c: y[c][k] for c in est.channels}, np.array([y[i][k] for i in M.inputs]))
        X[k] = e.x
        out.append(e)
    return X, out


def rmse(X, truth, mask):
    return np.sqrt(np.mean((X[mask, :2] - truth[mask, :2]) ** 2, axis=0))


# ----------------------------------------------------------------------------- the generic model
def test_model_reproduces_the_rig_ode_and_its_reaction_torque():
    """Load factors 1: the estimator's dynamics are the rig's ``ode``; h is the rig's own outputs
    (rig3's motor_torque the REACTION torque, nonlinear in the state)."""
    em = build_estimation_model(M, P3, EKFOptions(), 0.01)
    assert em.names == M.states + ("zero:twist_shaft1", "zero:twist_shaft2", "load:pin1", "offset:motor_torque")
    assert em.channels == ("theta1", "omega1", "theta2", "omega2", "theta3", "omega3", "motor_torque")
    rng = np.random.default_rng(0)
    x = rng.standard_normal(M.nx) * [0.3, 0.5, 2, 2, 2, 1, 1]
    xs, us = ca.SX.sym("x", M.nx), ca.SX.sym("u", M.nu)
    f = ca.Function("f", [xs, us], [rig_rhs(M, xs, us, M.unpack(ca.DM(P3.vector())), 0.05, {})])
    np.testing.assert_allclose(np.array(f(x, U)), np.array(M.ode(0.05)(x, U, P3.vector())), rtol=1e-12, atol=1e-12)
    xe = em.full_state(x)
    xe[em.index("offset:motor_torque")] = 0.03
    y = np.array(em.h(xe, U, em.p)).ravel()
    outs = M.outputs(x, U, P3.replace(motor_torque_offset=0.03).as_dict(), 0.0)
    np.testing.assert_allclose(y[2:], [float(outs[c]) for c in ("omega1", "omega2", "omega3", "motor_torque")],
                               rtol=1e-10)
    np.testing.assert_allclose(y[:2], 0.0, atol=1e-12)            # zero: states = the initial twist
    # near rest the motor friction's tanh makes the torque row depend on the state
    Cf = ca.Function("C", [xs], [ca.jacobian(em.h(ca.vertcat(xs, xe[7:]), U, em.p), xs)])
    slow = x.copy()
    slow[4] = 0.001
    C, C2 = np.array(Cf(slow)), np.array(Cf(slow * [1, 1, 1, 1, 5, 1, 1]))
    assert not np.allclose(C[-1], C2[-1])                           # the torque row depends on the state


def test_one_step_equals_the_batch_ekf_update():
    """Fused sequential update == the batch EKF formulas, h linearised at the predicted state."""
    est = ekf()
    em = est.em
    rng = np.random.default_rng(0)
    x = em.x0 + 0.1 * rng.standard_normal(em.nx)
    x[2:5] = [2.0, 2.5, 3.0]
    Pm = em.P0 + 0.01 * np.eye(em.nx)
    est.reset(x, Pm)
    est._uh = U.copy()                       # not the first sample (no speed initialisation)
    yraw = np.array(em.h(np.array(em.F(x, U, em.p)).ravel(), U, em.p)).ravel()
    meas = {"theta1": 0.01, "theta2": -0.02, "theta3": 0.05, "omega1": 2.2, "omega2": 2.4, "omega3": 3.1,
            "motor_torque": 0.4}
    e = est.update(0.01, meas, U)
    xs = ca.SX.sym("x", em.nx)
    A = np.array(ca.Function("A", [xs], [ca.jacobian(em.F(xs, U, em.p), xs)])(x))
    xp = np.array(em.F(x, U, em.p)).ravel()
    C = np.array(ca.Function("C", [xs], [ca.jacobian(em.h(xs, U, em.p), xs)])(xp))
    Q = np.diag(em.q + np.array(em.stick(x, U, em.p)).ravel())
    Pp = A @ Pm @ A.T + Q
    yi = np.array(em.to_internal([meas[c] for c in em.channels], np.ones(len(em.channels)))[0]).ravel()
    S = C @ Pp @ C.T + np.diag(em.r)
    K = Pp @ C.T @ np.linalg.inv(S)
    hx = np.array(em.h(xp, U, em.p)).ravel()
    np.testing.assert_allclose(e.x, xp + K @ (yi - hx), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(e.P, (np.eye(em.nx) - K @ C) @ Pp, rtol=1e-6, atol=1e-10)
    assert yraw.shape == (em.ny,)


@pytest.mark.slow
def test_steady_state_covariance_matches_dlqe():
    """At steady sliding (a linear time-invariant case) the covariance converges to
    python-control's dlqe Riccati solution."""
    import control

    est = EKF(EKFOptions(channels=SPEEDS_TORQUE, augment=[], compile=False, check_observability=False),
              ctx(x0=M.steady_sliding(U, P3)))
    em = est.em
    xe = em.x0.copy()
    y = dict(zip(SPEEDS_TORQUE, np.array(M.meas_vector(SPEEDS_TORQUE)(xe, U, P3.vector())).ravel()))
    for k in range(1500):
        e = est.update(0.01 * (k + 1), y, U)
    np.testing.assert_allclose(e.x, xe, atol=1e-6)      # noise-free data at the equilibrium: it stays
    xs = ca.SX.sym("x", em.nx)
    A = np.array(ca.Function("A", [xs], [ca.jacobian(em.F(xs, U, em.p), xs)])(xe))
    C = np.array(ca.Function("C", [xs], [ca.jacobian(em.h(xs, U, em.p), xs)])(xe))
    Q = np.diag(em.q + np.array(em.stick(xe, U, em.p)).ravel())
    _, P_dare, _ = control.dlqe(A, np.eye(em.nx), C, Q, np.diag(em.r))
    P_prior = A @ e.P @ A.T + Q
    scale = np.sqrt(np.outer(np.diag(P_dare), np.diag(P_dare)))
    np.testing.assert_allclose(P_prior / scale, P_dare / scale, atol=1e-4)


# ----------------------------------------------------------------------------- truth recovery
def test_default_recovers_the_twist_of_a_shaft_twisted_at_power_on(run3):
    """Our exact stick/slip plant, DAQ powered on in stick-slip with 0.39 / 1.25 rad of twist:
    the FD baseline is off by that for ever, the EKF (from rest) is not."""
    t, X, y = run3
    assert abs(X[0, 1]) > 1.0 and abs(X[0, 0]) > 0.3            # it IS twisted at power-on
    late = t > t[0] + 3.0
    stick = late & (X[:, 2] == 0.0)
    assert stick.sum() > 100                                     # the data hold established stick phases
    est = EKF(EKFOptions(check_observability=False), ctx())      # compiled if gcc is there
    XE, ests = drive(est, t, y)
    rng = np.ptp(X[late, :2], axis=0)                            # 0.53 / 2.16 rad
    r, rs = rmse(XE, X, late), rmse(XE, X, stick)
    assert np.all(r < 0.05 * rng) and np.all(rs < 0.05 * rng), (r, rs, rng)   # measured 13 / 38 mrad
    assert np.max(np.abs(XE[1:10, :2] - X[1:10, :2])) > 0.3      # it did start wrong
    assert est.counts.failures == 0
    fd = FiniteDifference(FDOptions(), ctx())
    XF, _ = drive(fd, t, y)
    assert np.all(rmse(XF, X, late) > 10 * r)
    # the estimator says how sure it is: consistent within a factor 3 at the end
    sd = np.sqrt(np.diag(ests[-1].P)[:2])
    assert np.all(np.abs(XE[-1, :2] - X[-1, :2]) < 3 * sd + 0.005)


@pytest.mark.slow
def test_without_the_stick_noise_the_ekf_rides_the_regularised_creep(run3):
    """q_stick = 0 trusts the regularised creep in stick; on an exact stick plant the twist at
    power-on then converges slowly and to a wrong value (measured 0.13 / 0.39 rad RMSE over the
    first 5 s here, against 0.04 / 0.10 rad; 0.2-0.7 rad over the benchmark's 60 s)."""
    t, X, y = run3
    first = (t > t[0] + 0.5) & (t < t[0] + 5.0)
    r0 = rmse(drive(ekf(q_stick=0.0), t, y)[0], X, first)
    r2 = rmse(drive(ekf(), t, y)[0], X, first)
    assert np.all(r0 > 2 * r2), (r0, r2)


@pytest.mark.slow
def test_torque_offset_is_estimated_on_a_plant_with_an_offset():
    """Plant: motor_torque_offset = 0.05 N m (the estimator believes 0): the offset state
    finds it, and without it the twist of shaft 2 is off by about 0.05 / k2."""
    plant = P3.replace(motor_torque_offset=0.05)
    sim = simulate(M, plant, U, 25.0, SimOptions(seed=4))
    t, y = sim.t, sim.y
    est = EKF(EKFOptions(check_observability=False), ctx())
    XE, ests = drive(est, t, y)
    j = est.names.index("offset:motor_torque")
    assert abs(XE[-1, j] - 0.05) < 0.02, XE[-1, j]                # measured 0.062 +- 0.007
    late = t > 10.0
    with_offset = rmse(XE, sim.x, late)
    without = rmse(drive(EKF(EKFOptions(augment=["load:pin1"], check_observability=False), ctx()), t, y)[0],
                   sim.x, late)
    assert without[1] > 2 * with_offset[1] and without[1] > 0.05, (with_offset, without)


def test_encoders_only_track_stick_slip_and_warn_while_unsure(run3):
    t, X, y = run3
    est = ekf(channels=ENCODERS)
    XE, ests = drive(est, t, y)
    late = t > t[0] + 3.0
    assert np.all(rmse(XE, X, late) < 0.05 * np.ptp(X[late, :2], axis=0))
    # while the twist std exceeds p0_twist / 10 the estimates carry a warning that says so
    first = ests[0]
    assert first.status is Status.WARNING and "twist uncertain" in first.message and first.success


def test_a_configuration_that_cannot_know_the_twist_says_so_on_every_estimate(run3):
    t, X, y = run3
    est = EKF(EKFOptions(channels=["omega3", "motor_torque"], compile=False), ctx())
    assert not est.observability.twist_observable
    _, ests = drive(est, t[:50], y)
    assert all(e.status is Status.WARNING and "twist not observable" in e.message for e in ests)


# ----------------------------------------------------------------------------- robustness
def test_dropout_skips_correction_and_is_counted():
    xe = M.steady_sliding(U, P3)
    a = EKF(EKFOptions(compile=False, check_observability=False), ctx(x0=xe))
    b = EKF(EKFOptions(compile=False, check_observability=False), ctx(x0=xe))
    em = a.em
    x_before, P_before = a.x.copy(), a.P.copy()
    e = a.update(0.01, {}, U)                                  # everything missing
    assert not e.corrected and a.counts.dropouts == 1 and "missing" in e.message
    np.testing.assert_allclose(e.x, np.array(em.F(x_before, U, em.p)).ravel(), atol=1e-12)   # pure prediction
    xs = ca.SX.sym("x", em.nx)
    A = np.array(ca.Function("A", [xs], [ca.jacobian(em.F(xs, U, em.p), xs)])(x_before))
    Q = np.diag(em.q + np.array(em.stick(x_before, U, em.p)).ravel())
    np.testing.assert_allclose(e.P, A @ P_before @ A.T + Q, rtol=1e-8, atol=1e-14)
    # one NaN speed channel: identical to a filter that never had that channel
    yv = np.array(M.meas_vector(SPEEDS_TORQUE)(xe, U, P3.vector())).ravel() + [0.3, -0.2, 0.1, 0.05]
    y = dict(theta1=0.0, theta2=0.0, theta3=0.0, **dict(zip(SPEEDS_TORQUE, yv)))
    c = EKF(EKFOptions(compile=False, check_observability=False,
                       channels=["theta1", "theta2", "theta3", "omega1", "omega3", "motor_torque"]), ctx(x0=xe))
    e2 = b.update(0.01, dict(y, omega2=float("nan")), U)
    e3 = c.update(0.01, {k: v for k, v in y.items() if k != "omega2"}, U)
    assert e2.corrected and b.counts.dropouts == 1 and "omega2" in e2.message
    np.testing.assert_allclose(e2.x, e3.x, atol=1e-10)
    np.testing.assert_allclose(e2.P, e3.P, atol=1e-12)


def test_a_failing_step_falls_back_to_prediction_and_is_counted():
    est = ekf()
    est.update(0.01, {}, U)

    def broken(*a):
        raise RuntimeError("injected")

    est._c = None
    good = est.step_fn
    est.step_fn = broken
    e = est.update(0.02, {}, U)
    assert e.status is Status.FALLBACK and "injected" in e.message and not e.success
    assert est.counts.failures == 1 and est.counts.fallbacks == 1
    est.step_fn = good
    assert est.update(0.03, {}, U).success


def test_compiled_step_matches_the_casadi_call(run3):
    """The gcc-built ctypes path gives the CasADi Function's numbers (build cached on disk)."""
    t, X, y = run3
    a = EKF(EKFOptions(check_observability=False), ctx())
    if not a.compiled:
        pytest.skip(f"no C compiler: {a.compile_status}")
    b = ekf()
    for k in range(1, 200):
        meas = {c: y[c][k] for c in a.channels}
        if k % 37 == 0:
            meas["omega1"] = float("nan")
        u = np.array([y[i][k] for i in M.inputs])
        ea, eb = a.update(t[k], meas, u), b.update(t[k], meas, u)
    np.testing.assert_allclose(ea.x, eb.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ea.P, eb.P, rtol=1e-8, atol=1e-15)


# ----------------------------------------------------------------------------- options and factory
def test_factory_builds_every_kind_and_rejects_bad_options():
    c = EstimatorContext(M, P3, 0.01, where="scenario.toml: estimator")
    est = make_estimator({"kind": "ekf", "compile": False, "check_observability": False,
                          "augment": ["load:pin1", "load:pin2", "gain:n1"]}, c)
    assert est.names[-3:] == ("load:pin1", "load:pin2", "gain:n1")
    assert isinstance(make_estimator({"kind": "fd"}, c), FiniteDifference)
    cases = [
        ({"kind": "ekf", "q_nosie": 1.0}, r"scenario.toml: estimator.q_nosie: unknown key for kind 'ekf'"),
        ({"kind": "ekf", "q_torque": -1.0}, r"scenario.toml: estimator.q_torque must be >= 0, got -1.0"),
        ({"kind": "ekf", "channels": ["omega4"]}, r"estimator.channels: unknown channel 'omega4' of rig 'rig3'"),
        ({"kind": "ekf", "channels": ["n1"]}, r"estimator.channels: 'n1' is an input of rig 'rig3'"),
        ({"kind": "ekf", "channels": ["theta1", "omega1"]}, r"one encoder angle \(theta1\) alone"),
        ({"kind": "ekf", "angles": "relative"}, r"estimator.angles must be one of zeroed, absolute, got 'relative'"),
        ({"kind": "ekf", "nsub": 0}, r"estimator.nsub must be an integer >= 1, got 0"),
        ({"kind": "ekf", "augment": ["load:pin9"]}, r"estimator.augment: 'load:pin9': rig 'rig3' has no contact 'pin9'"),
        ({"kind": "ekf", "augment": ["offset:theta1"]}, r"'offset:theta1': 'theta1' is not a channel with an offset"),
        ({"kind": "ekf", "augment": ["drift:pin1"]}, r"estimator.augment entries must be 'load:<contact>'"),
        ({"kind": "ekf", "augment": "load:pin1"}, r"estimator.augment must be a list"),
        ({"kind": "kalman"}, r"scenario.toml: estimator.kind must be one of ekf, mhe, fd, a registered 'stickslip.estimators' entry point or 'module:Class', got 'kalman'"),
        ({"kind": "fd", "window": 3}, r"estimator.window: unknown key for kind 'fd'"),
    ]
    for spec, msg in cases:
        with pytest.raises(ConfigError, match=msg):
            make_estimator({"compile": False, "check_observability": False, **spec}
                           if spec.get("kind") not in ("fd", "kalman") else spec, c)
    with pytest.raises(ConfigError, match=r"estimator.x0 must be 7 \(the rig's states\) or 11 finite numbers"):
        EKF(EKFOptions(compile=False, check_observability=False), ctx(x0=np.zeros(3)))


# ----------------------------------------------------------------------------- any rig


@pytest.mark.slow
def test_a_rig_file_where_nothing_is_rig3_specific():
    """A two-disc rig (tests/data/two_disc_speed_drive.toml) with a speed drive, encoders at the
    drive end and at the bit, a torque sensor on the upper spring and a weight-on-bit load cell.  The defaults follow its sensors
    (the drive speed and the weight on bit are inputs).  Its Coulomb friction has no shape to
    tell a load factor from a sensor offset: with both states the twist is not observable at
    steady sliding, the report says so, and so does the check along the run's estimates; with
    the offset known the EKF recovers both twists."""
    rig = get_model(str(DATA / "two_disc_speed_drive.toml"))
    assert rig.inputs == ("omega_top", "wob")
    u = np.array([2.0, 30.0])
    sim = simulate(rig, rig.published(), u, 8.0, SimOptions(seed=1))
    c = EstimatorContext(rig, rig.published(), 0.01)
    default = EKF(EKFOptions(compile=False), c)
    assert default.channels == ("theta_drive", "theta_bit", "omega_bit", "torque_upper")
    assert default.names[-3:] == ("zero:twist_lower", "load:rock", "offset:torque_upper")
    rep = default.observability_steady
    assert not rep.twist_observable
    assert "load:rock" in rep.message and "offset:torque_upper" in rep.message
    known = EKF(EKFOptions(compile=False, augment=["load:rock"]), c)
    assert known.observability.twist_observable and known.observability_steady.twist_observable
    late = sim.t > 3.0
    for est in (default, known):
        XE = np.zeros((len(sim.t), len(est.names)))
        for k in range(1, len(sim.t)):
            XE[k] = est.update(sim.t[k], {ch: sim.y[ch][k] for ch in est.channels},
                               np.array([sim.y[i][k] for i in rig.inputs])).x
        err = np.sqrt(np.mean((XE[late, :2] - sim.x[late, :2]) ** 2, axis=0))
        along = est.observability_along(XE[late], sim.u[np.flatnonzero(late) - 1])
        if est is known:
            assert np.all(err < 0.01), err                          # measured 2 mrad
            assert along.twist_observable and est.counts.failures == 0
        else:
            assert np.all(err > 0.05), err                          # measured 0.13 rad: it cannot know ...
            assert not along.twist_observable                       # ... and the check along the run says so
            assert "load:rock" in along.message


def test_disc_rig_fd_and_ekf():
    """The shipped one-disc rig (speed drive) sliding after its start: FD and an EKF with a
    known friction level track the twist; with ``load:pin`` the report names the trade-off."""
    disc = get_model("disc")
    u = np.array([math.pi, 20.0])
    sim = simulate(disc, disc.published(), u, 6.0, SimOptions(seed=2))
    c = EstimatorContext(disc, disc.published(), 0.01)
    default = EKF(EKFOptions(compile=False), c)
    assert "twist_spring trades off against load:pin" in default.observability_steady.message
    for est in (FiniteDifference(FDOptions(), c), EKF(EKFOptions(compile=False, augment=[]), c)):
        XE = np.zeros(len(sim.t))
        for k in range(1, len(sim.t)):
            XE[k] = est.update(sim.t[k], {ch: sim.y[ch][k] for ch in est.channels},
                               np.array([sim.y[i][k] for i in disc.inputs])).x[0]
        late = sim.t > 2.0
        assert np.sqrt(np.mean((XE[late] - sim.x[late, 0]) ** 2)) < 0.01, est.kind


def test_load_cell_offset_and_gain_act_through_the_input_correction():
    """A logged normal force is corrected for its cell inside the model (N = (reading -
    offset) / gain); an augmented ``offset:n1`` / ``gain:n1`` replaces the parameter."""
    em = build_estimation_model(M, P3, EKFOptions(augment=["offset:n1", "gain:n1"]), 0.01)
    plain = build_estimation_model(M, P3.replace(n1_offset=2.0, n1_gain=1.1), EKFOptions(augment=[]), 0.01)
    x = em.full_state(M.steady_sliding(U, P3))
    x[em.index("offset:n1")], x[em.index("gain:n1")] = 2.0, 1.1
    u_logged = np.array([math.pi, 1.1 * 20.0 + 2.0, 0.0])       # the cell reads 1.1 N + 2
    np.testing.assert_allclose(np.array(em.F(x, u_logged, em.p)).ravel()[:7],
                               np.array(plain.F(x[:9], u_logged, plain.p)).ravel()[:7], rtol=1e-12)
    truth = build_estimation_model(M, P3, EKFOptions(augment=[]), 0.01)
    np.testing.assert_allclose(np.array(em.F(x, u_logged, em.p)).ravel()[:7],
                               np.array(truth.F(x[:9], U, truth.p)).ravel()[:7], rtol=1e-12)


@pytest.mark.slow
def test_delayed_channels_use_lagged_states_exactly():
    """A rig file whose sensors arrive one sample late: the estimator carries lag1 copies of the
    rig's states and its prediction reproduces the delayed readings of the instantaneous
    channels exactly (noise-free regularised plant); on our exact plant its speeds are 2-5x
    closer than those of an estimator that ignores the delay (the twists' level error, set by the
    slowly separating twist / load / offset direction, is the same for both)."""
    import dataclasses

    from models.rig import RigModel
    from models.sensors import SensorOptions

    spec = dataclasses.replace(M.spec, sensors=tuple(dataclasses.replace(s, delay=1) for s in M.spec.sensors))
    md = RigModel(spec, "rig3_delay")
    em = build_estimation_model(md, md.published(), EKFOptions(angles="absolute", augment=[]), 0.01)
    assert em.delay == 1 and em.names[-7:] == tuple(f"lag1:{n}" for n in M.states)
    sim = simulate(md, md.published(), U, 2.0, SimOptions(method="smooth", nsub=4, seed=1),
                   sensors=SensorOptions(noise_scale=0.0, quantise=False))
    x, uh = em.full_state(sim.x[0]), np.tile(sim.u[0], 2)
    j = em.meas_names.index("motor_torque")
    worst = 0.0
    for k in range(1, len(sim.t)):
        u = np.array([sim.y[n][k] for n in md.inputs])
        uh = np.concatenate([u, uh[:3]])
        x = np.array(em.F(x, uh, em.p)).ravel()
        worst = max(worst, abs(float(em.h(x, uh, em.p)[j]) - sim.y["motor_torque"][k]))
    assert worst < 1e-9
    # on the exact plant with its one-sample delay
    t, X, y = powered_on(simulate(md, md.published(), U, 15.0, SimOptions(seed=3)), K0)
    late = t > t[0] + 3.0
    speeds = slice(2, 5)

    def speed_rmse(est):
        XE = drive(est, t, y)[0]
        return np.sqrt(np.mean((XE[late, speeds] - X[late, speeds]) ** 2, axis=0))

    knows = speed_rmse(EKF(EKFOptions(check_observability=False), EstimatorContext(md, md.published(), 0.01)))
    ignores = speed_rmse(EKF(EKFOptions(check_observability=False), ctx()))
    assert np.all(knows < 0.6 * ignores), (knows, ignores)       # measured 0.025 / 0.013 / 0.0005 against 0.072 / 0.057 / 0.0026 rad/s


def test_pi_integral_stays_where_the_anti_windup_keeps_it():
    """Realistic rig3 (structural mismatch) from rest, the benchmark's noise seed of switch-on
    phase 1: the start-up saturates the drive's voltage, and an EKF correction once pushed the PI
    integral beyond the limit, where the current no longer depends on it (0.06 rad in the plant,
    255 rad in the filter, the torque then explained by a 30-fold friction; the NMPC fed that held
    the programme and left full stick-slip).  The projection keeps it within reach."""
    import dataclasses

    from mitigate.benchmark.plan import run_seed
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.scenario import ControllerSpec, load_scenario

    sc = load_scenario("scenarios/benchmark/realistic.toml")
    seed = run_seed(sc.seed, 1, 0)
    sc = sc.replace(duration=1.0, control=sc.control.replace(start=0.5), seed=seed,
                    sim=dataclasses.replace(sc.sim, seed=seed), controllers=(ControllerSpec("PI only", "pi", {}),))
    res = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    z_true, z_hat = res.state("pi_integral"), res.estimate("pi_integral")
    load = res.estimate("load:pin1")
    assert np.max(np.abs(z_hat)) < 1.0, np.max(np.abs(z_hat))          # plant: |z| < 0.1 rad
    assert abs(z_hat[-1] - z_true[-1]) < 0.5
    assert 0.1 < load[-1] < 3.0, load[-1]


def test_projection_clips_pi_integral_and_load_factors():
    """The EKF's projection: a PI integral beyond the voltage limit goes back to it, a negative
    load factor to 0, a reachable state stays as it is."""
    em = build_estimation_model(M, P3, EKFOptions(augment=("load:pin1",)), 0.01)
    iz, il = em.names.index("pi_integral"), em.names.index("load:pin1")
    uh = np.tile(U, em.delay + 1)
    x = em.x0.copy()
    ok = np.asarray(em.project(x, uh, em.p)).ravel()
    assert np.allclose(ok, x)
    x[iz], x[il] = 1e4, -0.4
    out = np.asarray(em.project(x, uh, em.p)).ravel()
    assert out[il] == 0.0
    assert 0.0 < out[iz] < 1e3                   # at the limit, G ki z = the voltage limit
    x[iz] = -1e4
    assert -1e3 < float(np.asarray(em.project(x, uh, em.p)).ravel()[iz]) < 0.0
