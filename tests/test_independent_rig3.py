"""Checks of the independent 3-disc rig simulator against references derived here.

Nothing here compares with the project's own models: each expected value is
derived in this file from first principles (closed-form Coulomb cycle, 2-DOF
eigenproblem, steady-sliding torque balance, conservation of angular
momentum, encoder arithmetic).
"""

import math

import numpy as np
import pytest

import independent_rig3 as ir

TWO_PI = 2.0 * math.pi


def _quiet(**kw):
    """Options without sensor noise."""
    return ir.RigOptions(torque_noise=0.0, n1_noise=0.0, n2_noise=0.0, **kw)


def _upcrossings(t, y, level):
    """Linearly interpolated times where y crosses level upward."""
    out = []
    for k in range(1, len(y)):
        if y[k - 1] < level <= y[k]:
            out.append(t[k - 1] + (level - y[k - 1]) / (y[k] - y[k - 1]) * (t[k] - t[k - 1]))
    return np.array(out)


def test_coulomb_stick_slip_cycle_period():
    """One disc on an undamped spring whose far end moves at V, Coulomb friction.

    Twist x = V t - theta.  Stick: x rises at rate V from 2 x_k - x_s to x_s
    (x_s = N r mu_s / k, x_k = N r mu_k / k), so t_stick = 2 (x_s - x_k) / V.
    Slip: x - x_k is harmonic at w_n = sqrt(k/J) starting from (x_s - x_k, V)
    and ends when x' = V again, after an angle pi + 2 phi of the phase circle,
    phi = atan2(V / w_n, x_s - x_k): t_slip = (pi + 2 phi) / w_n.  The peak
    disc speed is V + sqrt(V**2 + (w_n (x_s - x_k))**2).
    """
    V, N = 0.5, 20.0
    # near-ideal Coulomb law: mu drops from mu_s to mu_k within a few 1e-3 rad/s
    o = _quiet(ideal_drive="R2", d1=0.0, v_t=1e-5, v_s=3e-3)
    log = ir.simulate_log(o, V, N, 0.0, 10.0, seed=0)
    J, k = o.J1, o.k1
    wn = math.sqrt(k / J)
    dx = N * o.r1 * (o.mu_s - o.mu_k) / k
    phi = math.atan2(V / wn, dx)
    period = 2 * dx / V + (math.pi + 2 * phi) / wn
    w = log["omega1_true"]
    up = _upcrossings(log["t"], w, V)
    assert len(up) >= 6
    measured = (up[-1] - up[1]) / (len(up) - 2)     # skip the first (start-up) cycle
    assert measured == pytest.approx(period, rel=0.01)
    wmax = V + math.sqrt(V ** 2 + (wn * dx) ** 2)
    assert w[200:].max() == pytest.approx(wmax, rel=0.01)
    # it really sticks: long runs of (true) zero speed
    assert np.mean(np.abs(w) < 1e-3) > 0.3


def _peak_freqs(x, dt, count):
    """Frequencies of the `count` largest spectral peaks (Hann, zero padded)."""
    x = x - x.mean()
    n = len(x)
    X = np.abs(np.fft.rfft(x * np.hanning(n), 64 * n))
    f = np.fft.rfftfreq(64 * n, dt)
    pk = [i for i in range(1, len(X) - 1) if X[i] >= X[i - 1] and X[i] > X[i + 1]]
    pk = sorted(pk, key=lambda i: -X[i])[:count]
    return np.sort(f[pk])


def test_clamped_motor_modes_match_eigenvalues():
    """Free vibration of R1-R2 with R3 clamped vs the 2-DOF eigenproblem.

    M = diag(J1, J2), K = [[k1, -k1], [-k1, k1 + k2]]: w**2 = eig(M^-1 K).
    """
    o = _quiet(ideal_drive="R3", d1=0.0, d2=0.0, initial_condition="twisted",
               initial_twist12=0.3, initial_twist23=-0.2)
    log = ir.simulate_log(o, 0.0, 0.0, 0.0, 20.0, seed=0)
    J1, J2, k1, k2 = o.J1, o.J2, o.k1, o.k2
    tr = J1 * (k1 + k2) + J2 * k1      # det(K - w2 M) = 0: J1 J2 w^4 - tr w^2 + k1 k2 = 0
    disc = math.sqrt(tr ** 2 - 4 * J1 * J2 * k1 * k2)
    f_expected = np.sqrt(np.array([(tr - disc), (tr + disc)]) / (2 * J1 * J2)) / TWO_PI
    # the measured (quantised) encoder angles carry both modes
    for ch in ("theta1", "theta2"):
        f = _peak_freqs(log[ch], o.dt, 2)
        np.testing.assert_allclose(f, f_expected, rtol=0.01)
    # R3 really clamped
    assert np.all(log["theta3"] == 0.0)


@pytest.mark.parametrize("start", ["sliding", "rest"])
def test_steady_sliding_load_cell_reads_pin_friction(start):
    """Steady sliding at w: T_lc = (N1 r1 + N2 r2) mu(w); eta KT i adds eta (Tf + Cm eta w).

    Torque balance of every body at constant speed: the shaft carries the
    pin torques to R3, so T_delivered = T_r1 + T_r2 and the acceleration term
    vanishes; the motor must in addition overcome its own friction on the
    motor shaft (Tf + Cm wm), i.e. eta (Tf + Cm eta w) on the disc side.
    From rest, higher shaft damping is used only to settle quickly.
    """
    w, n1, n2 = math.pi, 20.0, 10.0
    extra = {} if start == "sliding" else {"d1": 0.3, "d2": 0.3}
    o = ir.RigOptions(initial_condition=start, **extra)
    mu = 0.306 + (0.5 - 0.306) * math.exp(-w / 1.0)
    expected = (n1 * 0.047 + n2 * 0.040) * mu
    motor_loss = 8.0 * (0.1196 + 1.784e-4 * 8.0 * w)
    dur = 3.0 if start == "sliding" else 8.0
    for definition, value in (("reaction", expected), ("electromagnetic", expected + motor_loss)):
        log = ir.simulate_log(o.replace(torque_definition=definition), w, n1, n2, dur, seed=3)
        tail = slice(-200, None)
        m = log["motor_torque"][tail]
        # noise 0.01 N m over 200 samples: standard error 7e-4
        assert m.mean() == pytest.approx(value, abs=3e-3)
        assert log["omega3_true"][tail].mean() == pytest.approx(w, abs=1e-3)
        # measured speeds: quantised backward differences average to w
        assert log["omega1"][tail].mean() == pytest.approx(w, rel=0.01)
    # the two definitions differ by ~1 N m: the load cell is not a current sensor
    assert motor_loss > 0.9


@pytest.mark.slow
@pytest.mark.parametrize("backlash", [0.0, 0.02])
def test_reaction_torque_conserves_angular_momentum(backlash):
    """Whole rig (discs, shaft, floating motor+gearbox): d/dt H = T_lc - T_r1 - T_r2.

    H = J1 w1 + J2 w2 + Jm (eta w_rotor) (+ J_out w3 with backlash): the
    rotor's own angular momentum, as the housing is held still.  The
    electromagnetic torque eta KT i does not satisfy this balance.
    """
    o = _quiet(dt=0.001, backlash=backlash)
    j_out = o.gear_output_inertia if backlash else 0.0
    rig = ir.IndependentRig3(o, seed=0)
    rig.reset(0.0, 20.0, 0.0)
    H, R, E, T = [], [], [], []
    for k in range(2000):
        tr = rig.truth()
        H.append(o.J1 * tr["omega1"] + o.J2 * tr["omega2"] + j_out * tr["omega3"]
                 + o.eta * o.Jm * tr["omega_rotor"])
        R.append(tr["torque_reaction"] - tr["friction1"] - tr["friction2"])
        E.append(tr["torque_em"] - tr["friction1"] - tr["friction2"])
        T.append(abs(tr["torque_reaction"]))
        # forward and backward rotation, stick-slip, servo force switched on
        rig.step(2.0 * math.sin(3e-3 * k), 20.0, 8.0 if k > 500 else 0.0)
    H, R, E = map(np.array, (H, R, E))

    def integral(y):
        return np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * o.dt)])

    dH = H - H[0]
    scale = np.sum(T) * o.dt           # integral of |T_lc|, ~0.35 N m s
    assert scale > 0.2
    assert np.abs(dH - integral(R)).max() < 1e-3 * scale
    assert np.abs(dH - integral(E)).max() > 0.5 * scale


def test_encoders_zero_at_power_on_and_quantised():
    """Power-on zero, floor quantisation, 1000 ticks/rev on discs, 8000/rev of R3."""
    o = _quiet(initial_condition="twisted", initial_twist12=0.37, initial_twist23=-0.21)
    rig = ir.IndependentRig3(o, seed=1)
    m0 = rig.reset(1.5, 15.0, 0.0)
    tr0 = rig.truth()
    assert tr0["twist12"] == pytest.approx(0.37) and tr0["twist23"] == pytest.approx(-0.21)
    for ch in ("theta1", "theta2", "theta3", "omega1", "omega2", "omega3"):
        assert m0[ch] == 0.0
    tick = TWO_PI / 1000
    tick3 = TWO_PI / 8000
    rows = []
    for k in range(300):
        m = rig.step(1.5, 15.0, 0.0)
        tr = rig.truth()
        rows.append((m["theta1"], m["theta2"], m["theta3"], m["omega1"], m["omega3"],
                     tr["theta1"] - tr0["theta1"], tr["theta2"] - tr0["theta2"],
                     tr["theta3"] - tr0["theta3"]))
    a = np.array(rows)
    for j, (meas, true, q) in enumerate(((a[:, 0], a[:, 5], tick), (a[:, 1], a[:, 6], tick),
                                         (a[:, 2], a[:, 7], tick3))):
        counts = meas / q
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
        assert np.all(meas <= true + 1e-12) and np.all(true < meas + q + 1e-12)
    # the motor encoder resolves 1/8 of a disc tick: odd multiples of 2 pi/8000 occur
    c3 = np.round(a[:, 2] / tick3).astype(int)
    assert np.any(c3 % 8 != 0)
    assert np.gcd.reduce(c3) == 1
    # speeds are backward differences of the quantised angles
    th1 = np.concatenate([[0.0], a[:, 0]])
    np.testing.assert_allclose(a[:, 3], np.diff(th1) / o.dt, atol=1e-9)
    th3 = np.concatenate([[0.0], a[:, 2]])
    np.testing.assert_allclose(a[:, 4], np.diff(th3) / o.dt, atol=1e-9)
    speeds = np.unique(np.round(a[:, 4] / (tick3 / o.dt)))
    assert np.allclose(a[:, 4] / (tick3 / o.dt), np.round(a[:, 4] / (tick3 / o.dt)))
    assert len(speeds) > 1


def test_daq_delay_shifts_channels_by_whole_samples():
    base = ir.RigOptions()
    kw = dict(omega_ref_profile=lambda t: 1.0 + 0.5 * math.sin(2 * t), n1_profile=20.0,
              n2_profile=lambda t: 10.0 if t > 0.5 else 0.0, duration=2.0, seed=7)
    ref = ir.simulate_log(base, **kw)
    delays = {"motor_torque": 3, "theta1": 2, "omega2": 1, "n2": 4}
    log = ir.simulate_log(base.replace(daq_delay=delays), **kw)
    for ch in ir.CHANNELS:
        d = delays.get(ch, 0)
        np.testing.assert_array_equal(log[ch][d:], ref[ch][:len(ref[ch]) - d])
        np.testing.assert_array_equal(log[ch][:d], np.full(d, ref[ch][0]))
    # true twists are not delayed
    np.testing.assert_array_equal(log["twist12"], ref["twist12"])
    log = ir.simulate_log(base.replace(daq_delay=5), **kw)
    for ch in ir.CHANNELS:
        np.testing.assert_array_equal(log[ch][5:], ref[ch][:-5])


def test_sensor_gain_offset_and_noise():
    o = ir.RigOptions(initial_condition="sliding", torque_gain=1.1, torque_offset=0.05,
                      n1_gain=0.9, n1_offset=1.0, n2_gain=1.2, n2_offset=-0.5)
    log = ir.simulate_log(o, math.pi, 20.0, 10.0, 2.0, seed=2)
    t_true = log["torque_reaction_true"]
    np.testing.assert_allclose((log["motor_torque"] - 1.1 * t_true - 0.05).std(), 0.01, rtol=0.2)
    assert (log["motor_torque"] - 1.1 * t_true - 0.05).mean() == pytest.approx(0.0, abs=3e-3)
    assert (log["n1"] - (0.9 * 20.0 + 1.0)).mean() == pytest.approx(0.0, abs=0.05)
    assert (log["n1"] - 19.0).std() == pytest.approx(0.2, rel=0.2)
    assert (log["n2"] - (1.2 * 10.0 - 0.5)).mean() == pytest.approx(0.0, abs=0.05)


def test_servo_saturation_lag_and_rate_limit():
    """Command 100 N: target 40 N; slope 200 N/s while (40 - N)/tau > 200, i.e.
    until N = 30 N at t = 0.15 s; then N = 40 - 10 exp(-(t - 0.15)/0.05)."""
    log = ir.simulate_log(_quiet(initial_n2=0.0), 0.0, 0.0, 100.0, 0.5, seed=0)
    t, n2 = log["t"], log["n2_true"]
    expected = np.where(t <= 0.15, 200.0 * t, 40.0 - 10.0 * np.exp(-(t - 0.15) / 0.05))
    np.testing.assert_allclose(n2, expected, atol=1e-3)


def test_backlash_dead_zone_in_steady_sliding():
    """Rotor leads the gearbox output by b/2 + T/k_mesh when driving forward,
    and lags by as much when driving backward."""
    b = 0.04
    for w in (math.pi, -math.pi):
        o = _quiet(backlash=b, initial_condition="sliding")
        rig = ir.IndependentRig3(o, seed=0)
        rig.reset(w, 20.0, 0.0)
        for _ in range(100):
            rig.step(w, 20.0, 0.0)
        tr = rig.truth()
        t_del = 20.0 * 0.047 * (0.306 + 0.194 * math.exp(-math.pi))
        gap = tr["theta_rotor"] - tr["theta3"]
        assert gap == pytest.approx(math.copysign(b / 2 + t_del / o.mesh_stiffness, w), rel=1e-3)
        assert tr["omega3"] == pytest.approx(w, abs=1e-3)


@pytest.mark.parametrize("kw", [{}, {"backlash": 0.03}, {"shaft_elements": 3},
                                {"pi_side": "motor", "v_max": 2.0, "i_max": 1.0},
                                {"friction_law": "stribeck_viscous", "c_v": 0.02, "drift_rate": 0.01}])
def test_analytic_jacobian_matches_finite_differences(kw):
    rig = ir.IndependentRig3(ir.RigOptions(**kw), seed=0)
    rig.reset(1.0, 20.0, 5.0)
    for _ in range(120):
        rig.step(1.0 if _ < 60 else 2.5, 20.0, 5.0)
    x, t = rig.x.copy(), rig.t
    J = rig._jac(t, x)
    Jn = np.zeros_like(J)
    for j in range(len(x)):
        h = 1e-7 * max(1.0, abs(x[j]))
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        Jn[:, j] = (rig._fun(t, xp) - rig._fun(t, xm)) / (2 * h)
    np.testing.assert_allclose(J, Jn, rtol=1e-4, atol=1e-6 * np.abs(Jn).max())
    # the fast scalar right-hand side is the same function as the one differentiated
    # (interior shaft nodes: ~1 N m torques cancel on 1e-8 kg m^2, hence the atol)
    np.testing.assert_allclose(rig._fun(t, x), rig._rhs_jac(t, x, False)[0], rtol=1e-9,
                               atol=1e-6)


def test_stick_creep_is_below_one_tick():
    log = ir.simulate_log(ir.RigOptions(), 1.0, 20.0, 0.0, 8.0, seed=0)
    c = ir.measure_creep(log)
    assert c["phases"] >= 2
    assert c["max_drift"] < 0.1 * TWO_PI / 1000


def test_write_csv_format(tmp_path):
    log = ir.simulate_log(ir.RigOptions(), 1.0, 20.0, 0.0, 0.1, seed=0)
    p = tmp_path / "rig.csv"
    ir.write_csv(p, log)
    lines = p.read_text().splitlines()
    assert lines[0] == ("t [s],theta1 [rad],theta2 [rad],theta3 [rad],omega1 [rad/s],"
                        "omega2 [rad/s],omega3 [rad/s],motor_torque [N m],n1 [N],n2 [N],"
                        "omega_ref [rad/s],twist12 [rad],twist23 [rad]")
    data = np.loadtxt(p, delimiter=",", skiprows=1)
    assert data.shape == (11, 13)
    np.testing.assert_allclose(data[:, 0], np.arange(11) * 0.01, atol=1e-12)
    np.testing.assert_allclose(data[:, 11], log["twist12"], rtol=1e-9, atol=1e-15)


def test_module_is_independent_of_the_project():
    import pathlib
    entry = pathlib.Path(ir.__file__)
    files = sorted(entry.parent.glob("independent_rig3*.py"))   # the entry and its sibling modules
    assert entry in files and len(files) > 1
    for f in files:
        src = f.read_text()
        for pkg in ("models", "estimators", "mitigate"):
            assert "import %s" % pkg not in src and "from %s" % pkg not in src, f.name


@pytest.mark.slow
def test_integrators_agree():
    """ODEPACK LSODA (default) and the solve_ivp solvers give the same trajectory."""
    kw = dict(omega_ref_profile=lambda t: 1.0 if t < 0.5 else 2.0, n1_profile=20.0,
              n2_profile=5.0, duration=1.5, seed=0)
    ref = ir.simulate_log(_quiet(method="Radau", rtol=1e-8), **kw)
    # (solve_ivp's BDF needs a tighter rtol than its default to place the
    # stick-slip breakaway as precisely as the others)
    for method, rtol in (("odepack", None), ("Radau", None), ("BDF", 1e-6), ("LSODA", None)):
        log = ir.simulate_log(_quiet(method=method, rtol=rtol), **kw)
        for ch, tol in (("theta1_true", 1e-4), ("omega1_true", 1e-3), ("current", 1e-3),
                        ("torque_reaction_true", 1e-3)):
            np.testing.assert_allclose(log[ch], ref[ch], atol=tol, err_msg=method + " " + ch)
