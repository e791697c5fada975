"""EKF for rig3: textbook-KF agreement, Riccati steady state, convergence, stick-slip tracking, dropouts, options."""

import math

import casadi as ca
import numpy as np
import pytest

from estimators.ekf import EKF, EKFOptions, make_ekf
from estimators.factory import make_estimator
from models import get_model
from models.errors import ConfigError
from models.sensors import SensorOptions
from models.plant import SimOptions, simulate

M = get_model("rig3")
P3 = M.published()
U = np.array([math.pi, 20.0, 0.0])          # 30 rpm, N1 = 20 N: established stick-slip
SPEEDS_TORQUE = ("omega1", "omega2", "omega3", "motor_torque")


@pytest.fixture(scope="module")
def sim():
    return simulate(M, P3, U, 12.0, SimOptions(seed=3))


def run(est, sim, k0=1):
    n = len(sim.t)
    X = np.zeros((n, len(est.names)))
    S = np.zeros_like(X)
    for k in range(k0, n):
        e = est.update({c: sim.y[c][k] for c in sim.y}, sim.u[k - 1], sim.t[k])
        X[k], S[k] = e.x, np.sqrt(np.diag(e.P))
    return X, S


def test_one_step_equals_textbook_kalman_update():
    """Fused sequential update == batch KF formulas on the CasADi linearisation."""
    ekf = EKF(P3, SensorOptions(), 0.01, EKFOptions(compile=False))
    rng = np.random.default_rng(0)
    x = ekf.x + 0.1 * rng.standard_normal(ekf.em.nx)
    x[9] = 1.0
    Pm = ekf.P + 0.01 * np.eye(ekf.em.nx)
    ekf.reset(x, Pm)
    y = rng.standard_normal(len(ekf.channels))
    u = U
    e = ekf.update(dict(zip(ekf.channels, y)), u, 0.01)
    p = P3.vector()
    xs = ca.SX.sym("x", ekf.em.nx)
    A = np.array(ca.Function("A", [xs], [ca.jacobian(ekf.em.F(xs, u, p), xs)])(x))
    C = np.array(ca.Function("C", [xs], [ca.jacobian(ekf.em.h(xs, p), xs)])(x))
    xp = np.array(ekf.em.F(x, u, p)).ravel()
    Pp = A @ Pm @ A.T + np.diag(ekf.em.q)
    yi = np.array(ekf.em.to_internal(y, np.ones_like(y))[0]).ravel()
    S = C @ Pp @ C.T + np.diag(ekf.em.r)
    K = Pp @ C.T @ np.linalg.inv(S)
    x_kf = xp + K @ (yi - C @ xp)
    P_kf = (np.eye(len(x)) - K @ C) @ Pp
    np.testing.assert_allclose(e.x, x_kf, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(e.P, P_kf, rtol=1e-6, atol=1e-12)


def test_steady_state_covariance_matches_dlqe():
    """At steady sliding the EKF's covariance converges to python-control's dlqe Riccati solution."""
    import control

    o = EKFOptions(channels=SPEEDS_TORQUE, augment=(), compile=False)
    xe = M.steady_sliding(U, P3)
    ekf = EKF(P3, SensorOptions(), 0.01, o, x0=xe)
    y = np.array(M.meas_vector(list(ekf.channels))(xe, U, P3.vector())).ravel()
    for k in range(1500):
        e = ekf.update(dict(zip(ekf.channels, y)), U, 0.01 * (k + 1))
    np.testing.assert_allclose(e.x, xe, atol=1e-6)   # noise-free data at equilibrium: stays
    xs = ca.SX.sym("x", 7)
    A = np.array(ca.Function("A", [xs], [ca.jacobian(ekf.em.F(xs, U, P3.vector()), xs)])(xe))
    C = np.array(ca.Function("C", [xs], [ca.jacobian(ekf.em.h(xs, P3.vector()), xs)])(xe))
    L, P_dare, _ = control.dlqe(A, np.eye(7), C, np.diag(ekf.em.q), np.diag(ekf.em.r))
    P_prior = A @ e.P @ A.T + np.diag(ekf.em.q)
    scale = np.sqrt(np.outer(np.diag(P_dare), np.diag(P_dare)))
    np.testing.assert_allclose(P_prior / scale, P_dare / scale, atol=1e-4)


def test_converges_from_wrong_initial_state_and_tracks_stick_slip(sim):
    x0 = sim.x[0].copy()
    x0[0] += 0.3
    x0[1] -= 0.4
    x0[5] += 1.0
    o = EKFOptions(channels=SPEEDS_TORQUE, compile=False)   # no angle shortcut: twist from dynamics
    ekf = EKF(P3, SensorOptions(), 0.01, o, x0=x0)
    X, S = run(ekf, sim)
    late = sim.t > 4.0
    err = X[late, :2] - sim.x[late, :2]
    stick = late & (sim.x[:, 2] == 0)
    assert stick.sum() > 100                      # the data do contain established stick phases
    rmse = np.sqrt(np.mean(err ** 2, axis=0))
    rmse_stick = np.sqrt(np.mean((X[stick, :2] - sim.x[stick, :2]) ** 2, axis=0))
    assert np.all(rmse < 0.03), rmse              # initial errors were 0.3 / 0.4 rad
    assert np.all(rmse_stick < 0.03), rmse_stick
    assert np.max(np.abs(X[1:10, :2] - sim.x[1:10, :2])) > 0.1  # it did start wrong
    assert ekf.counts.failures == 0


def test_zeroed_encoders_with_pretwisted_start_beat_fd(sim):
    """Encoders zeroed at power-on on a pre-twisted plant: FD is off by the offset, the EKF is not."""
    from estimators.fd import FiniteDifference

    k0 = 300                                     # "power on" in the middle of stick-slip
    y = {c: v[k0:].copy() for c, v in sim.y.items()}
    for c in ("theta1", "theta2", "theta3"):
        y[c] -= sim.y[c][k0]
    sub = type(sim)(sim.t[k0:], sim.x[k0:], sim.u[k0:], y, {}, "rig3")
    ekf = EKF(P3, SensorOptions(), 0.01, EKFOptions(compile=False))
    X, _ = run(ekf, sub)
    fd = FiniteDifference(SensorOptions(), 0.01)
    XF, _ = run(fd, sub)
    late = sub.t > sub.t[0] + 3.0
    e_ekf = np.sqrt(np.mean((X[late, :2] - sub.x[late, :2]) ** 2))
    e_fd = np.sqrt(np.mean((XF[late, :2] - sub.x[late, :2]) ** 2))
    assert e_ekf < 0.03 and e_fd > 3 * e_ekf, (e_ekf, e_fd)


def test_dropout_skips_correction_and_is_counted():
    xe = M.steady_sliding(U, P3)
    o = EKFOptions(compile=False)
    a = EKF(P3, SensorOptions(), 0.01, o, x0=xe)
    b = EKF(P3, SensorOptions(), 0.01, o, x0=xe)
    e = a.update({}, U, 0.01)                                    # everything missing
    assert not e.corrected and a.counts.dropouts == 1 and "missing" in e.status
    xp = np.array(a.em.F(b.x, U, P3.vector())).ravel()
    np.testing.assert_allclose(e.x, xp, atol=1e-12)              # pure prediction
    xs = ca.SX.sym("x", a.em.nx)
    A = np.array(ca.Function("A", [xs], [ca.jacobian(a.em.F(xs, U, P3.vector()), xs)])(b.x))
    np.testing.assert_allclose(e.P, A @ b.P @ A.T + np.diag(a.em.q), rtol=1e-8, atol=1e-14)
    # one NaN channel: identical to a filter that never had that channel
    yv = np.array(M.meas_vector(list(SPEEDS_TORQUE))(xe, U, P3.vector())).ravel()
    y = dict(theta1=0.0, theta2=0.0, theta3=0.0, **dict(zip(SPEEDS_TORQUE, yv + [0.3, -0.2, 0.1, 0.05])))
    y2 = dict(y, omega2=float("nan"))
    c = EKF(P3, SensorOptions(), 0.01, EKFOptions(compile=False, channels=("theta1", "theta2", "theta3", "omega1",
                                                                             "omega3", "motor_torque")), x0=xe)
    e2 = b.update(y2, U, 0.01)
    e3 = c.update({k: v for k, v in y.items() if k != "omega2"}, U, 0.01)
    assert e2.corrected and b.counts.dropouts == 1 and "omega2" in e2.status
    np.testing.assert_allclose(e2.x, e3.x, atol=1e-10)
    np.testing.assert_allclose(e2.P, e3.P, atol=1e-12)
    assert np.all(np.isfinite(e2.x))


def test_factory_builds_ekf_and_rejects_bad_options():
    est = make_estimator({"kind": "ekf", "compile": False, "augment": ["load1", "load2"]}, P3, SensorOptions(), 0.01)
    assert est.names[-2:] == ("load1", "load2")
    with pytest.raises(ConfigError, match=r"estimator: unknown key 'q_nosie'"):
        make_estimator({"kind": "ekf", "q_nosie": 1.0}, P3, SensorOptions(), 0.01)
    with pytest.raises(ConfigError, match=r"estimator.q_torque must be a finite number >= 0"):
        make_ekf({"q_torque": -1.0}, P3, SensorOptions(), 0.01)
    with pytest.raises(ConfigError, match=r"channels: unknown channel 'omega4'"):
        make_ekf({"channels": ["omega4"]}, P3, SensorOptions(), 0.01)
    with pytest.raises(ConfigError, match=r"angles must be 'zeroed' or 'absolute'"):
        make_ekf({"angles": "relative"}, P3, SensorOptions(), 0.01)
    with pytest.raises(ConfigError, match=r"nsub must be an integer"):
        make_ekf({"nsub": 0}, P3, SensorOptions(), 0.01)


def test_compiled_step_matches_casadi_call(sim):
    """The gcc-built ctypes path gives the CasADi Function's numbers (build cached on disk)."""
    a = EKF(P3, SensorOptions(), 0.01, EKFOptions(compile=True))
    if not a.compiled:
        pytest.skip(f"no C compiler: {a.compile_status}")
    b = EKF(P3, SensorOptions(), 0.01, EKFOptions(compile=False))
    for k in range(1, 200):
        meas = {c: sim.y[c][k] for c in sim.y}
        if k % 37 == 0:
            meas["omega1"] = float("nan")
        ea, eb = a.update(meas, sim.u[k - 1], sim.t[k]), b.update(meas, sim.u[k - 1], sim.t[k])
    np.testing.assert_allclose(ea.x, eb.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ea.P, eb.P, rtol=1e-8, atol=1e-15)
