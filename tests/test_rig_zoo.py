"""The rig zoo (issue 18, item 10): generated rigs (tests/rig_zoo.py) go through every command's
Python call -- modal, simulate, the EKF, a two-parameter identification and every controller
kind -- and each either works or refuses in one line naming what is missing.

Physics check: the closed-loop linearisation's least-damped oscillatory mode (models.modal) and a
small-amplitude simulation of the exact plant started on that mode's shape agree on the damped
frequency within 2 %.

CI runs four fixed corners (a lab rig on a DC motor with L/R = 0.05 ms, a field-scale string on
a torque drive, a lab speed drive, a DC motor with L/R = 5 ms) and a derandomised handful of rigs
(``ZOO_EXAMPLES``, default 3): about 50 s with a warm compiled-code cache on the shared 2 cores.
``HYPOTHESIS_PROFILE=zoo`` runs 40 random rigs of up to 6 bodies, with shrinking.

The NMPC against PI (:func:`nmpc_vs_pi`), on every rig the zoo draws (the corners and the
examples alike): a slow programme (0.1 of the nominal speed, below the laws' weakening range; 0.5 on
a torque drive), the controllers switched on after 4 of the rig's stick-slip periods T, then 8 T;
the NMPC's residual severity (last 3 T, against the programmed speed) is not above PI's unless
both are below 1e-3.  ``pytest -s`` prints, per rig, what PI left (stick-slip,
a stuck string, an oscillation without sticking, quiet) and the NMPC/PI ratio.  On a torque drive a
constant torque below the static level never starts a string at rest: PI's "stuck" (severity 1) is
what the NMPC is compared with there.  An NMPC that refuses the rig in one line (its RK4 substeps at
the programme's regularisation) is recorded, not compared; so is an NMPC above PI on a rig whose
string the estimator cannot observe (``NMPC_BLIND``; the cases seen, rigs read only at a speed
drive, are refused by the NMPC now: ``string_sensor``), and a string the NMPC stalls (below half its programmed speed: the residual severity cannot see it) is flagged.

Every law of the registry is drawn, the lead screw's (seed 002) included.  Findings, reported:
the identification confidently wrong on the field-scale corner (:data:`IDENT_FINDINGS`, fixed)
and with the lead-screw law (:data:`IDENT_LAW_FINDINGS`, :func:`test_leadscrew_identification_finding`).
"""

import math
import os

import numpy as np
import pytest
import scipy.linalg
from hypothesis import HealthCheck, Phase, find, given, seed, settings

from rig_zoo import CORNERS, zoo_rigs
from estimators.identify import IdentifyOptions, identify
from mitigate.controllers.base import NEEDS, sees_string  # noqa: F401 - NEEDS: the vocabulary the refusals use
from mitigate.controllers.factory import CONTROLLER_KINDS, context_for, controller_class
from mitigate.runner import run
from mitigate.scenario import make_scenario
from models import get_model
from models.errors import ConfigError, SolverFailure
from mitigate.metrics import rig_period
from models.modal import linearise, operating_point, stick_slip_period
from models.plant import SimOptions, simulate
from models.status import Status

ZOO = os.environ.get("HYPOTHESIS_PROFILE") == "zoo"
EXAMPLES = 40 if ZOO else int(os.environ.get("ZOO_EXAMPLES", "3"))


def _write(tmp_path_factory, z):
    d = tmp_path_factory.mktemp("zoo")
    p = d / "rig.toml"
    p.write_text(z.text)
    return p


def modal_vs_simulation(m) -> str:
    """Damped frequency of the least-damped oscillatory sliding mode: linearisation vs a
    small-amplitude simulation of the exact plant started on the mode's shape (assert within 2 %)."""
    p = m.published()
    u, x_op = operating_point(m, p)
    if x_op is None:
        x_op = m.steady_sliding(u, p)
    lin = linearise(m, p, u, x_op=x_op)
    lam, V = scipy.linalg.eig(lin.A)
    cand = [j for j in range(lam.size) if lam[j].imag > 1e-6 * abs(lam[j]) and -lam[j].real < 0.1 * abs(lam[j])]
    if not cand:
        return "no lightly damped oscillatory mode"
    j = min(cand, key=lambda i: abs(lam[i].real) / abs(lam[i]))
    f_d = lam[j].imag / (2 * math.pi)
    speeds = [i for i, s in enumerate(m.states) if s.startswith("omega_")]
    v = V[:, j] / V[speeds, j][np.argmax(np.abs(V[speeds, j]))]      # speed component of largest size = 1
    w0 = max(abs(m.nominal_speed()), 1e-3)
    x0 = np.asarray(x_op, float) + 0.01 * w0 * np.real(v)
    grow = max(lam[j].real, 0.0)
    periods = 6.0 if grow == 0 else min(6.0, math.log(3.0) / grow * f_d)
    if periods < 3:
        return f"mode at {f_d:.3g} Hz grows too fast to measure ({lam[j].real:.3g} 1/s)"
    dt = 1.0 / (50.0 * f_d)
    sim = simulate(m, p, u, periods / f_d, SimOptions(dt=dt, seed=0), sensors=None, x0=x0)
    assert sim.success, sim.message
    k = speeds[int(np.argmax(np.abs(v[speeds])))]
    s = sim.x[:, k] - x_op[k]
    assert np.all(np.abs(sim.x[:, m.contacts[0]]) > 0), "left sliding: amplitude too large"
    zc = np.flatnonzero(np.sign(s[:-1]) * np.sign(s[1:]) < 0)
    tz = sim.t[zc] - s[zc] * dt / (s[zc + 1] - s[zc])
    tz = tz[tz > 0.5 / f_d]
    assert tz.size >= 4, (tz, f_d)
    f_sim = 0.5 / np.mean(np.diff(tz))
    assert f_sim == pytest.approx(f_d, rel=0.02), (f_sim, f_d)
    return f"{f_d:.4g} Hz (simulation {f_sim:.4g} Hz)"


def one_line(exc) -> str:
    msg = str(exc)
    assert "\n" not in msg and msg, msg
    return msg


def _inputs(m, z):
    op = m.spec.extra.get("operating_point", {})
    return {n: float(op[n]) for n in m.inputs}


def pipeline(m, z, path):
    """simulate, the EKF and every controller kind; a two-parameter identification."""
    p = m.published()
    ins = _inputs(m, z)
    try:
        period = stick_slip_period(m, p)
    except ConfigError:
        period = 1.0
    duration = min(max(3.0, 3 * period), 6.0)
    # open loop from rest, sensors on
    sim = simulate(m, p, np.array([ins[n] for n in m.inputs]), duration, SimOptions(seed=1))
    assert sim.status in (Status.OK, Status.DIVERGED), sim.message
    # every controller kind: refused in one line, or run
    ctrls = []
    for kind in CONTROLLER_KINDS:
        if kind == "exported":      # runs a folder `mitigate export` wrote, not a law built for this rig
            continue
        spec = {"name": kind, "kind": kind}
        if kind == "nmpc":
            spec["compile"] = False
        ctrls.append(spec)
    sc = make_scenario(name="zoo", model=str(path), duration=duration, seed=2, inputs=ins, controllers=ctrls,
                       estimator={"kind": "ekf", "compile": False}, control_start=duration / 2)
    able = [c for i, c in enumerate(ctrls) if not context_for(sc, i).missing(controller_class(c["kind"]).needs)]
    # PI needs nothing; the NMPC needs a sensor that sees the string (not a speed drive's own encoder alone)
    assert "pi" in {c["kind"] for c in able}
    assert ("nmpc" in {c["kind"] for c in able}) is sees_string(m)
    if len(able) < len(ctrls):
        # a rig lacking something for some controller is refused in one line, before anything runs
        # (where every controller is able, the run below is that run: it was run twice before)
        with pytest.raises(ConfigError) as refused:
            run(sc, jobs=1)
        msg = one_line(refused.value)
        assert "lacks what the controllers need" in msg, msg
    note = ""
    try:
        sc = make_scenario(name="zoo", model=str(path), duration=duration, seed=2, inputs=ins, controllers=able,
                           estimator={"kind": "ekf", "compile": False}, control_start=duration / 2)
        res = run(sc, jobs=1)
    except ConfigError as exc:               # e.g. the EKF's channels: a one-line refusal; the FD then
        note = f"EKF refused: {one_line(exc)}; "
        sc = make_scenario(name="zoo", model=str(path), duration=duration, seed=2, inputs=ins, controllers=able,
                           estimator="fd", control_start=duration / 2)
        res = run(sc, jobs=1)
    bad = [f"{r.name}: {r.message}" for r in res.runs if r.status is Status.FAILED]
    assert not bad, bad
    return note + str({r.name: (r.status.value, round(float(r.metrics.get("sss", float("nan"))), 3))
                       for r in res.runs})


#: the NMPC-vs-PI programme as a fraction of the rig's nominal speed: below the generated laws'
#: weakening range (0.3 of the nominal speed), where a start from rest sticks and slips under PI.
#: (Chosen by the linear stability of sliding instead, the DC-motor corners got 0.2 or 0.5, where PI
#: left an oscillation without sticking, severity 0.57 / 0.22; at 0.1 sliding is linearly stable on
#: them and the stick-slip cycle from rest stays all the same, severity 1.04.)  A torque drive at
#: 0.5: the torque that holds 0.1 lies near the static level and once the string breaks away it runs
#: off under PI (severity 11-20 on four rigs); at 0.5 PI left stick-slip on two of them, a stuck
#: string and an oscillation on the others
SLOW_FRACTION = 0.1
SLOW_FRACTION_TORQUE = 0.5
#: a residual severity below which a run counts as quiet (so two quiet runs are equal) [-]
QUIET = 1e-3
#: controlled periods after the switch-on, and periods of PI before it
CONTROLLED_PERIODS, SWITCH_ON_PERIODS = 8, 4
#: the NMPC's mean speed over the residual window below this fraction of the programme: a stalled string
STALLED = 0.5
#: per rig, the NMPC-vs-PI record (printed at the end of the module: ``pytest -s``)
NMPC_RECORDS: list[dict] = []
#: rigs on which the NMPC's residual severity was found above PI's: xfail with the numbers until fixed
NMPC_FINDINGS: dict[str, str] = {}
#: the NMPC above PI on rigs whose string the estimator cannot observe (its observability report
#: says so).  Reported; the zoo records such a rig and goes on.  The rigs read only at a speed drive
#: (its own encoder, perhaps a load cell) were the cases seen: the NMPC refuses them now
#: (``string_sensor``; test_the_nmpc_refuses_a_rig_read_only_at_its_speed_drive)
NMPC_BLIND = ("a 1-body lead-screw rig read by the drive's encoder alone: PI 1.00 (stuck), NMPC 3.84 (stuck 68 %); "
              "in the zoo also 2.02 / 2.21 on a 2-body lead-screw rig with the drive encoder and a load cell; "
              "both refused now (string_sensor)")


def slow_programme(m):
    """The programme of the NMPC-vs-PI check: ``(inputs, [control] table, fraction)`` at
    :data:`SLOW_FRACTION` of the nominal speed (a torque drive: :data:`SLOW_FRACTION_TORQUE`, its
    torque that of steady sliding at that speed and the speed its ``[control] speed``).  From rest a
    torque below the static level never starts the string: PI's string is then stuck (severity 1)."""
    f = SLOW_FRACTION if m.drive.sets_speed else SLOW_FRACTION_TORQUE
    w = f * m.nominal_speed()
    u, _ = operating_point(m, m.published(), omega=w)
    return {n: float(v) for n, v in zip(m.inputs, u)}, ({} if m.drive.sets_speed else {"speed": w}), f


def nmpc_vs_pi(m, z, path, name="", blind_ok=True):
    """PI and the NMPC (compile=False, with the EKF) on the slow programme (:func:`slow_programme`):
    switched on after ``SWITCH_ON_PERIODS`` of the rig's stick-slip period T (its lowest mode with its drive's
    boundary, :func:`mitigate.metrics.rig_period`), then ``CONTROLLED_PERIODS``; DAQ period T / 100 (the
    NMPC's interval is T / 50). The NMPC's ``residual_severity`` (last 3 T, against the programmed
    speed) must not be above PI's unless both are below :data:`QUIET`.  ``blind_ok``: where the
    estimator's observability report says the string is not observable from the rig's sensors, an
    NMPC above PI is the named finding :data:`NMPC_BLIND` (recorded; :func:`test_nmpc_blind_finding`
    is its strict xfail), not a failure."""
    p = m.published()
    T = rig_period(m, p)
    ins, control, frac = slow_programme(m)
    start = SWITCH_ON_PERIODS * T
    ctrls = ["pi", {"name": "nmpc", "kind": "nmpc", "compile": False}]
    est = {"kind": "ekf", "compile": False}
    common = dict(name="zoo_nmpc", model=str(path), duration=start + CONTROLLED_PERIODS * T, dt=T / 100, seed=4,
                  inputs=ins, controllers=ctrls, control={"start": start, **control})
    try:
        # (a lone encoder: the EKF reads its speed, not its angle.  Not the FD baseline: it holds the
        # twists it does not read at 0, and the NMPC fed that lost to PI on 4 of 5 such rigs: PI 1.03 /
        # NMPC 1.69 on a 2-body lead-screw rig, 0.056 / 0.178 on a 1-body Vahid-Araghi rig, 1.53 / 2.55
        # on a 6-body DC-motor rig)
        res = run(make_scenario(estimator=est, **common), jobs=1)
    except ConfigError as exc:
        # the NMPC refusing the rig in one line (its substeps at the slow programme's eps): recorded
        msg = one_line(exc)
        assert "'nmpc'" in msg, msg
        NMPC_RECORDS.append(dict(rig=f"{name}: {z.describe()}" if name else z.describe(), law=z.law, drive=z.drive,
                                 fraction=frac, refused=msg))
        return f"NMPC refused at {frac:g} w0: {msg}"
    bad = [f"{r.name}: {r.message}" for r in res.runs if r.status is Status.FAILED]
    assert not bad, bad
    pi, nmpc = res.run("pi").metrics, res.run("nmpc").metrics
    s_pi, s_nmpc = pi["residual_severity"], nmpc["residual_severity"]
    stuck = pi["residual_stuck_fraction"]
    kind = ("stuck" if stuck >= 1 else "stick-slip" if stuck > 0 and s_pi > 0.1
            else "oscillation" if s_pi > QUIET else "quiet")
    rec = dict(rig=f"{name}: {z.describe()}" if name else z.describe(), law=z.law, drive=z.drive, fraction=frac,
               pi_under=kind, pi=s_pi, nmpc=s_nmpc, ratio=s_nmpc / s_pi if s_pi > 0 else float("inf"),
               nmpc_speed_ratio=nmpc["residual_speed_ratio"], nmpc_stuck=nmpc["residual_stuck_fraction"],
               fallbacks=res.run("nmpc").result.controller_counts.get("fallbacks", 0))
    if all(r["rig"] != rec["rig"] for r in NMPC_RECORDS):     # (hypothesis replays a failing example)
        NMPC_RECORDS.append(rec)
    # a string the NMPC holds nearly at rest has a small residual severity (it is not stuck throughout,
    # so the stuck rule does not give it 1): not a win, recorded and printed (seen once in ~35 random
    # rigs: a 5-body torque-drive bit-rock string at 0.0002 of its target speed, severity 0.0014)
    rec["stalled"] = bool(rec["nmpc_speed_ratio"] < STALLED)
    note = (f"NMPC vs PI at {frac:g} w0: PI {kind}, residual PI {s_pi:.4f} NMPC {s_nmpc:.4f} (ratio "
            f"{rec['ratio']:.3g}, NMPC speed {rec['nmpc_speed_ratio']:.3g} x programme, stuck {rec['nmpc_stuck']:.2f}, "
            f"{rec['fallbacks']} fallbacks{', STALLED' if rec['stalled'] else ''})")
    obs = res.run("nmpc").result.observability
    if not s_nmpc <= max(s_pi, QUIET) and blind_ok and obs is not None and not obs.observable:
        rec["blind"] = obs.message
        return f"{note}: the known finding NMPC_BLIND ({obs.message})"
    if not s_nmpc <= max(s_pi, QUIET):
        if name in NMPC_FINDINGS:
            pytest.xfail(f"NMPC above PI on {name}: {NMPC_FINDINGS[name]} ({note})")
        raise AssertionError(f"the NMPC's residual severity is above PI's: {note}")
    return note


def identification(m):
    """Two parameters (the first spring's stiffness, the contact's kinetic level) from 4 s of a
    simulated log from rest (the start-up excites the string), started 20 % off: a fit whose truth
    lies within 4 of its reported errors (or 6 %), or a one-line refusal."""
    p = m.published()
    kin = m.law("pin").with_role("kinetic")
    free = ("k0", kin)
    u, _ = operating_point(m, p)
    log = simulate(m, p, u, 4.0, SimOptions(seed=3)).to_log()
    start = p.replace(**{n: 1.2 * getattr(p, n) for n in free})
    try:
        # the log starts from rest, untwisted (with the encoders' zero free the friction level and the
        # power-on twist trade off on a 1-body string: tests/test_identify_zero.py)
        fit = identify(log, m, start, IdentifyOptions(free=free, encoder_zero="untwisted"))
    except ConfigError as exc:
        return f"refused: {one_line(exc)}"
    if fit.status is Status.OK:            # (a WARNING says which parameter the log does not pin down)
        # within 4 of its reported errors, or 6 %.  fit.error holds the regularisation's first-order
        # bias and the encoders' unknown phase within a tick at power-on (a micro Stribeck rig's twist
        # of a few ticks: mu_k 0.278, SE 0.002, total error 0.026, true 0.3)
        for n, v, se in zip(fit.names, fit.estimate, fit.error):
            true = getattr(p, n)
            assert abs(v - true) <= max(4 * se, 0.06 * abs(true)), (n, v, se, true)
    return f"{fit.status.value}: " + ", ".join(f"{n} {v:.4g} +- {se:.2g} (true {getattr(p, n):.4g})"
                                             for n, v, se in zip(fit.names, fit.estimate, fit.error))




#: corners where the zoo found the identification confidently wrong (status OK, the truth many
#: standard errors away): reported to the identification's owner, xfail until fixed.  Fixed:
#: field_torque_drive (k0 931 +- 11 N m/rad against 780: an unmeasured body's start-up simulation ran
#: off and the states' scales with it, tests/test_identify_scales.py; its unmeasured node states now
#: start from the EKF where a torque is known, estimators.identify.start.filtered_states)
IDENT_FINDINGS: dict[str, str] = {}
#: laws with which the zoo found the identification confidently wrong: reported to the identification's
#: owner; a zoo rig with such a law records the failure and goes on (a hypothesis test ends at its first
#: xfail, hiding the rigs after it), and :func:`test_leadscrew_identification_finding` is the strict xfail
IDENT_LAW_FINDINGS = {"leadscrew": "mu1 0.337 +- 0.010 against 0.290 (1 body, torque drive); the speed-drive cases "
                                   "read by one encoder (k0 36.7 +- 0.16 against 39.5, mu1 -0.035 +- 0.0009 against "
                                   "0.246) warn now: no torque and no twist measured"}


def check(tmp_path_factory, z, corner=None):
    path = _write(tmp_path_factory, z)
    m = get_model(str(path))
    notes = [z.describe(), modal_vs_simulation(m), str(pipeline(m, z, path)), nmpc_vs_pi(m, z, path, corner or "")]
    try:
        notes.append(identification(m))
    except AssertionError as exc:
        if corner in IDENT_FINDINGS:
            pytest.xfail(f"identification confidently wrong on {corner}: {IDENT_FINDINGS[corner]} ({exc})")
        if z.law not in IDENT_LAW_FINDINGS:
            raise
        notes.append(f"identification confidently wrong (the known {z.law} finding): {exc}".replace("\n", " "))
    print(" | ".join(notes))


@pytest.mark.slow
@pytest.mark.parametrize("corner", list(CORNERS))
def test_rig_zoo_corners(tmp_path_factory, corner):
    @seed(list(CORNERS).index(corner) + 18)      # fixed (the simplest rig of a corner is a rich one: rig_zoo)
    @settings(max_examples=1, deadline=None, database=None, suppress_health_check=list(HealthCheck),
              phases=(Phase.explicit, Phase.generate))
    @given(z=zoo_rigs(max_bodies=3, **CORNERS[corner]))
    def one(z):
        check(tmp_path_factory, z, corner)
    one()


@pytest.mark.slow
@settings(max_examples=EXAMPLES, deadline=None, derandomize=not ZOO, database=None,
          suppress_health_check=list(HealthCheck),
          phases=(Phase.explicit, Phase.generate) + ((Phase.shrink,) if ZOO else ()))
@given(z=zoo_rigs(max_bodies=6 if ZOO else 3))
def test_rig_zoo(tmp_path_factory, z):
    check(tmp_path_factory, z)


#: a fixed rig with a property: the simplest (shrunk) derandomised draw that has it
FIND = settings(database=None, derandomize=True, suppress_health_check=list(HealthCheck))


@pytest.mark.slow
def test_leadscrew_identification_says_what_the_log_cannot_tell(tmp_path_factory):
    """The lead-screw finding on the simplest zoo rig that showed it: one body on a speed drive, read
    by one encoder on the screw (k0 36.7 +- 0.16 N m/rad against 39.5, status OK).  No torque and no
    twist is measured: the friction level and the twist at the log's start trade off, and the fit
    now says so (status WARNING, estimators.identify.result.level_twist_warning) instead of
    returning a confident number."""
    z = find(zoo_rigs(max_bodies=1, drives=("speed",), laws=("leadscrew",)), lambda z: z.sensors == ("enc_c",),
             settings=FIND)
    note = identification(get_model(str(_write(tmp_path_factory, z))))
    assert note.startswith("ok, with warnings"), note


@pytest.mark.slow
def test_the_nmpc_refuses_a_rig_read_only_at_its_speed_drive(tmp_path_factory):
    """The zoo's NMPC_BLIND rig (a 1-body lead screw read by the speed drive's own encoder: PI 1.00,
    the NMPC planning on what the EKF could not see 3.84): the drive follows its set-point, so that
    encoder reads the programme and nothing of the string.  The NMPC declares ``string_sensor`` and
    the scenario is refused in one line, before anything runs, naming what to add."""
    z = find(zoo_rigs(max_bodies=1, drives=("speed",), laws=("leadscrew",)), lambda z: z.sensors == ("enc_d",),
             settings=FIND)
    path = _write(tmp_path_factory, z)
    m = get_model(str(path))
    assert not sees_string(m)
    note = nmpc_vs_pi(m, z, path, blind_ok=False)           # the refusal is recorded, one line
    assert note.startswith("NMPC refused") and "a sensor that sees the string" in note, note
    assert "for controller 2 'nmpc'" in note, note


def teardown_module():
    """The NMPC-vs-PI records of this session, one line each (``pytest -s`` shows them)."""
    if NMPC_RECORDS:
        under = [r.get("pi_under", "-") for r in NMPC_RECORDS]
        print(f"\nNMPC vs PI on {len(NMPC_RECORDS)} zoo rigs: PI {under.count('stick-slip')} stick-slip, "
              f"{under.count('stuck')} stuck, {under.count('oscillation')} oscillating, {under.count('quiet')} quiet, "
              f"{under.count('-')} refused by the NMPC")
        for r in NMPC_RECORDS:
            if "refused" in r:
                print(f"  {r['law']:12s} {r['drive']:8s} NMPC refused: {r['refused']} | {r['rig']}")
                continue
            print(f"  {r['law']:12s} {r['drive']:8s} {r['pi_under']:11s} PI {r['pi']:.4f} NMPC {r['nmpc']:.4f} "
                  f"ratio {r['ratio']:.3g} speed {r['nmpc_speed_ratio']:.3g} stuck {r['nmpc_stuck']:.2f} "
                  f"fallbacks {r['fallbacks']}{' BLIND' if 'blind' in r else ''}{' STALLED' if r['stalled'] else ''}"
                  f" | {r['rig']}")


@pytest.mark.slow
def test_stiff_rates_where_no_sliding_is_sustained(tmp_path_factory):
    """A lead screw on a torque drive under 2.5 x its axial load (a servo's n_max): no torque up to
    twice the programme's turns it, the steady-sliding guess runs off to ~1e8 rad/s, and the rate the
    integration rule took there (the dampers against the screw's speed-dependent inertia) was 1e8-1e9
    1/s: the NMPC and the identification refused the rig.  Taken at the sliding speed: the string's own."""
    from models.rates import stiff_rates
    z = find(zoo_rigs(max_bodies=1, drives=("torque",), laws=("leadscrew",)), lambda z: True,
             settings=FIND)
    m = get_model(str(_write(tmp_path_factory, z)))
    p = m.published()
    u, x = operating_point(m, p)
    low = stiff_rates(m, p, u, eps=0.016 * z.speed, speed=z.speed)
    u_max = u * np.array([2.0 if n == m.drive_input else 2.5 for n in m.inputs])
    with pytest.raises(SolverFailure, match="no steady sliding"):               # no steady sliding there
        m.sliding_guess(u_max, p)
    for speed in (z.speed, None):
        assert stiff_rates(m, p, u_max, eps=0.016 * z.speed, speed=speed) < 10 * low
