"""NMPC in closed loop (mitigate.controllers.nmpc): RTI against converged SQP; bounds and rate
limits; stick-slip of R1 suppressed on the exact stick/slip plant (N1 = 20 N, 30 rpm) with both
inputs, the pin only and the motor only; and the same code on other rigs (the ``disc`` rig with
its speed drive as the only command, a two-disc rig file with a servo brake, rig2's torque drive).
The unit-level checks (options, QP, RTI step, fallbacks) are in tests/test_nmpc.py.
No compilation here (``compile=False``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mitigate.controllers.base import ControlContext
from mitigate.controllers.factory import make_controller
from mitigate.metrics import severity
from mitigate.scenario_fields import ControlSection
from models import get_model
from models.plant import Plant, SimOptions
from models.status import Status

from nmpc_setup import M, P, U0, W0, apply_action as _apply, context as _ctx, estimate as _est, nmpc as _nmpc


# ----------------------------------------------------------------------------- closed loop, rig3

def _closed_loop(c, plant, t0, n, u_prog=U0, model=M, log_actions=False):
    w, acts, forces = [], [], []
    b = model.speed_index(c.body)
    for k in range(n):
        t = t0 + k * 0.01
        forces.append(plant.u_applied.copy())   # what the servos apply when the command is computed
        a = c.step(t, plant.measure(), _est(t, plant.x, model))
        acts.append(a)
        plant.step(_apply(model, u_prog, a))
        w.append(plant.x[b])
    return np.array(w), acts, np.array(forces)


@pytest.fixture(scope="module")
def stick_slip_start():
    """Stick-slip established from rest (10 s, N1 = 20 N, 30 rpm)."""
    base = Plant(M, P, SimOptions(seed=0), sensors=None, u0=U0)
    for _ in range(1000):
        base.step(U0)
    return base.x.copy(), base.t


@pytest.mark.slow
def test_rti_closed_loop_matches_converged_sqp(stick_slip_start):
    """RTI (one QP per plan) and SQP iterated to convergence out of stick-slip: the same
    trajectory of R1 to within a few percent of its speed, and both suppress the stick-slip."""
    x0, t0 = stick_slip_start
    runs = {}
    for solver in ("rti", "sqp"):
        c = _nmpc({"horizon": 15, "solver": solver})
        plant = Plant(M, P, SimOptions(seed=0), sensors=None, x0=x0, u0=U0)
        runs[solver], _, _ = _closed_loop(c, plant, t0, 300)
        assert c.counts.failures == 0
    assert np.max(np.abs(runs["rti"] - runs["sqp"])) < 0.05 * W0
    assert severity(runs["rti"][-100:]) < 0.02 and severity(runs["sqp"][-100:]) < 0.02


@pytest.fixture(scope="module")
def variants(stick_slip_start):
    """5 s without control and with the NMPC on both inputs, the pin only and the motor only."""
    x0, t0 = stick_slip_start
    n = 500
    free = Plant(M, P, SimOptions(seed=0), sensors=None, x0=x0, u0=U0)
    out = {"free": np.array([free.step(U0) and free.x[2] for _ in range(n)])}
    for inputs in ("both", "pin", "motor"):
        c = _nmpc({"horizon": 20, "inputs": inputs})
        plant = Plant(M, P, SimOptions(seed=0), sensors=None, x0=x0, u0=U0)
        w, acts, forces = _closed_loop(c, plant, t0, n)
        out[inputs] = dict(w1=w, acts=acts, forces=forces, c=c)
    return out


@pytest.mark.slow
def test_stick_slip_of_r1_suppressed(variants):
    tail = slice(-250, None)  # last 2.5 s (a stick-slip cycle takes about 2 s)
    s_free = severity(variants["free"][tail])
    assert s_free > 0.8       # established stick-slip without control
    # the pin alone cannot move the set-point: the drive's PI loop brings the mean speed back slowly
    for inputs, limit, mean_tol in (("both", 0.02, 0.02), ("motor", 0.02, 0.02), ("pin", 0.1, 0.1)):
        r = variants[inputs]
        assert severity(r["w1"][tail]) < limit * s_free, inputs
        assert abs(np.mean(r["w1"][tail]) - W0) < mean_tol * W0, inputs
        assert r["c"].counts.failures == 0


@pytest.mark.slow
def test_pin_only_never_moves_the_set_point_and_motor_only_never_presses(variants):
    pin, motor = variants["pin"], variants["motor"]
    assert all(set(a.u) == {"n2"} for a in pin["acts"])              # the set-point follows the programme
    assert max(a.u["n2"] for a in pin["acts"]) > 5.0                 # and the pin does the work
    assert all(set(a.u) == {"omega_ref"} for a in motor["acts"])
    assert np.all(motor["forces"][:, 2] == 0.0)                      # no pin force, ever
    assert np.ptp([a.u["omega_ref"] for a in motor["acts"]]) > 0.5   # the set-point does the work


@pytest.mark.slow
def test_inputs_respect_bounds_and_rate_limits(variants):
    r = variants["both"]
    c, acts, forces = r["c"], r["acts"], r["forces"]
    servo = M.actuator("n2")
    o = c.cfg          # the settings in force: the rig's defaults here
    wref = np.array([a.u["omega_ref"] for a in acts])
    n2 = np.array([a.u["n2"] for a in acts])
    assert np.all(n2 >= servo.n_min - 1e-9) and np.all(n2 <= servo.n_max + 1e-9)
    assert np.all(np.abs(wref - W0) <= o.setpoint_band + 1e-9) and np.all(wref >= 0)
    # changes only at plan times (every dt = 5 samples); the set-point by at most rate * dt; a new
    # command asks the servo for at most its rate limit: |command - force| <= rate_max * tau
    d_w, d_n = np.abs(np.diff(wref)), np.abs(np.diff(n2))
    assert np.all(d_w <= o.setpoint_rate * o.dt * (1 + 1e-6) + 1e-9)
    plans = np.array([a.status is not Status.HOLD for a in acts])
    gap = np.abs(n2 - forces[:, 2])[plans]
    assert np.all(gap <= servo.rate_max * servo.tau * (1 + 1e-6) + 1e-9)
    assert np.max(gap) > 0.3 * servo.rate_max * servo.tau     # the limit is approached
    changed = np.nonzero((d_w > 1e-12) | (d_n > 1e-12))[0] + 1
    assert np.all(plans[changed])


# ----------------------------------------------------------------------------- other rigs
def test_disc_rig_with_its_speed_drive_as_the_only_command():
    """The one-disc rig: the drive end's prescribed speed is the only command; the NMPC turns it
    into a set-point trajectory that stops the disc's stick-slip."""
    m = get_model("disc")
    u0 = np.array([W0, 20.0])
    base = Plant(m, m.published(), SimOptions(seed=0), sensors=None, u0=u0)
    for _ in range(1000):
        base.step(u0)
    c = make_controller({"kind": "nmpc", "horizon": 20, "compile": False}, _ctx(model=m, programme=u0))
    assert c.inputs == ("omega3",) and c.body == "disc"
    plant = Plant(m, m.published(), SimOptions(seed=0), sensors=None, x0=base.x, u0=u0)
    free = Plant(m, m.published(), SimOptions(seed=0), sensors=None, x0=base.x, u0=u0)
    w_free = np.array([free.step(u0) and free.x[1] for _ in range(500)])
    w, acts, _ = _closed_loop(c, plant, 0.0, 500, u_prog=u0, model=m)
    assert severity(w_free[-200:]) > 0.8
    assert severity(w[-200:]) < 0.02 * severity(w_free[-200:])
    assert all(set(a.u) == {"omega3"} for a in acts) and c.counts.failures == 0

@pytest.mark.slow
def test_two_disc_rig_file_with_a_servo_brake():
    """A rig file (tests/data/two_disc_servo_brake.toml): speed drive, two discs, a servo brake on the upper disc.  The pin-only
    NMPC sets only the brake (within that servo's 30 N and 150 N/s x 40 ms) and stops D1's
    stick-slip."""
    m = get_model(str(Path(__file__).resolve().parent / "data" / "two_disc_servo_brake.toml"))
    u0 = np.array([W0, 20.0, 0.0])
    c = make_controller({"kind": "nmpc", "horizon": 20, "compile": False, "inputs": "pin"}, _ctx(model=m, programme=u0))
    assert c.inputs == ("n_brake",) and c.body == "D1" and c.spec.taus == (0.04,)
    assert c.layout.states == ("twist_lower", "twist_upper", "omega_D1", "omega_D2", "servo:n_brake")
    base = Plant(m, m.published(), SimOptions(seed=0), sensors=None, u0=u0)
    for _ in range(1000):
        base.step(u0)
    plant = Plant(m, m.published(), SimOptions(seed=0), sensors=None, x0=base.x, u0=u0)
    w_free = severity(np.array([base.step(u0) and base.x[2] for _ in range(300)]))
    w, acts, forces = _closed_loop(c, plant, 0.0, 600, u_prog=u0, model=m)
    assert w_free > 0.8 and severity(w[-200:]) < 0.05 * w_free
    cmd = np.array([a.u["n_brake"] for a in acts])
    assert all(set(a.u) == {"n_brake"} for a in acts) and c.counts.failures == 0
    assert cmd.max() <= 30.0 + 1e-9 and cmd.max() > 5.0
    plans = np.array([a.status is not Status.HOLD for a in acts])
    assert np.all(np.abs(cmd - forces[:, 2])[plans] <= 150.0 * 0.04 * (1 + 1e-6) + 1e-9)


@pytest.mark.slow
def test_torque_drive_rig2_holds_its_operating_speed():
    """rig2 (seed 001): the motor torque is the command and the nominal speed is the rig file's
    operating_point.speed (1 rad/s); the NMPC stops the disc's stick-slip at that speed."""
    m = get_model("rig2")
    p = m.published()
    u0, _ = m.operating_point(1.0, [0.0], p)
    u0 = np.asarray(u0, float)
    c = make_controller({"kind": "nmpc", "horizon": 20, "compile": False, "setpoint_band": 0.3, "setpoint_rate": 2.0},
                  _ctx(model=m, programme=u0))
    assert c.inputs == ("motor_torque",) and c.body == "disc" and c.spec.setpoint_scale == 0.3
    base = Plant(m, p, SimOptions(seed=0), sensors=None, u0=u0)
    for _ in range(1000):
        base.step(u0)
    plant = Plant(m, p, SimOptions(seed=0), sensors=None, x0=base.x, u0=u0)
    w_free = severity(np.array([base.step(u0) and base.x[1] for _ in range(300)]))
    w, acts, _ = _closed_loop(c, plant, 0.0, 500, u_prog=u0, model=m)
    assert w_free > 0.1 and severity(w[-200:]) < 0.01 * w_free
    assert np.mean(w[-200:]) == pytest.approx(1.0, abs=0.02)
    assert all(abs(a.u["motor_torque"] - u0[0]) <= 0.3 + 1e-9 for a in acts) and c.counts.failures == 0


@pytest.mark.slow
def test_torque_drive_follows_the_scenarios_control_speed():
    """A torque drive's target is the scenario's ``[control] speed`` (ControlContext.speed), as for
    SoftSpeed and Z-Torque, not the rig file's operating_point.speed: at 0.7 rad/s on rig2 the NMPC
    once held the disc at the file's 1 rad/s (the rig zoo found it: 1.9-5x the target speed).  Started
    from rest with the offset-free trim on: it once wound up while the disc was still (a calm record)
    and the disc ran at 0.78 rad/s after 8 s; it integrates only while the disc slides now."""
    m = get_model("rig2")
    p = m.published()
    u0 = np.asarray(m.operating_point(0.7, [0.0], p)[0], float)
    ctx = ControlContext(m, p, 0.01, lambda t: u0, where="nmpc", control=ControlSection(speed=lambda t: 0.7))
    c = make_controller({"kind": "nmpc", "horizon": 20, "compile": False, "setpoint_band": 0.3, "setpoint_rate": 2.0},
                        ctx)
    assert c.tuning_values()["eps"] == pytest.approx(0.016 * 0.7)
    plant = Plant(m, p, SimOptions(seed=0), sensors=None, u0=u0)
    w, acts, _ = _closed_loop(c, plant, 0.0, 800, u_prog=u0, model=m)
    assert np.mean(w[-200:]) == pytest.approx(0.7, abs=0.02) and severity(w[-200:]) < 0.05
    assert c.counts.failures == 0


# ----------------------------------------------------------------------------- the programme's force band
def _pin_only_with_programme(opts, n=200):
    """rig3 with N2 programmed at 10 N (a servo force that is a job, like a weight on bit), the pin-only
    NMPC from established stick-slip; the Python reference and the compiled step on the same loop.
    Returns ``{impl: (commands, applied forces)}`` [N] (the force the servo applied over each sample)."""
    u = np.array([W0, 20.0, 10.0])
    base = Plant(M, P, SimOptions(seed=0), sensors=None, u0=u)
    for _ in range(1000):
        base.step(u)
    out = {}
    for impl in ("python", "c"):
        c = make_controller({"kind": "nmpc", "inputs": "pin", "horizon": 15, "compile": impl == "c",
                             "implementation": impl, **opts}, _ctx(programme=u))
        assert (c.compiled is not None) == (impl == "c")
        plant = Plant(M, P, SimOptions(seed=0), sensors=None, x0=base.x, u0=u)
        _, acts, forces = _closed_loop(c, plant, base.t, n, u_prog=u)
        assert c.counts.failures == 0 and c.counts.fallbacks == 0
        out[impl] = (np.array([a.u["n2"] for a in acts]), np.append(forces[1:, 2], plant.u_applied[2]), c)
    return out


def _moving_means(x, n):
    return np.array([np.mean(x[k:k + n]) for k in range(len(x) - n + 1)])


def test_a_programmed_servo_force_keeps_its_band_in_c_and_python():
    """A servo force with a positive programme stays within NMPCOptions.force_band (default: the
    metrics' band, 0.8-1.25 of the programme) at every sample by default, or, with a force_window
    (here rig3's stick-slip period, 2.33 s), on its mean over every such window, counting the servo's
    lag and rate limit; inside that it is free: the commands leave the per-sample band (it lowers the
    force, then makes up for it).  The compiled step bounds it as the Python reference does, bit for
    bit.  Without the band ([0, inf]) the same NMPC presses far beyond it."""
    banded = _pin_only_with_programme({"force_window": 2.33}, n=500)
    for cmd, applied, c in banded.values():
        n = c.force_window_n
        assert n == 233 and len(applied) > n
        # the windows before the switch-on held the programme (the plant ran at 10 N)
        history = np.concatenate([np.full(n - 1, 10.0), applied])
        mean = _moving_means(history, n) / 10.0
        assert mean.min() >= 0.8 - 1e-9 and mean.max() <= 1.25 + 1e-9
        assert mean.min() < 0.8 + 5e-3                     # the band binds (its look-ahead keeps a margin)
        assert cmd.min() < 8.0 - 1.0                        # and the commands use the window's freedom
    np.testing.assert_array_equal(banded["c"][0], banded["python"][0])
    per_sample = _pin_only_with_programme({})
    for cmd, _, _ in per_sample.values():
        assert cmd.min() >= 8.0 - 1e-9 and cmd.max() <= 12.5 + 1e-9
        assert cmd.min() < 8.0 + 1e-6 or cmd.max() > 12.5 - 1e-6      # and it uses the band to its edge
    np.testing.assert_allclose(per_sample["c"][0], per_sample["python"][0], rtol=1e-9, atol=1e-9)
    free = _pin_only_with_programme({"force_band": [0.0, float("inf")]}, n=100)
    assert free["python"][0].max() > 20.0
    np.testing.assert_allclose(free["c"][0], free["python"][0], rtol=1e-9, atol=1e-9)
