"""One implementation of each law (issue 26): SoftSpeed, Z-Torque, D-OSKIL and the brake run a
compiled C step (mitigate/controllers/csrc/ss_laws.c) by default; the Python step stays as the
reference (``implementation = "python"``).  Both see the same closed loop call by call (a twin
controller steps both with the same sample and estimate and hands the loop the reference's action):
Z-Torque, D-OSKIL and the brake agree bit for bit, SoftSpeed to 1e-12 (its virtual drive's exact
discretisation is a matrix exponential, computed by scipy in Python and in C at init), on rig3's
main scenario, on the lab drill string (a DC top drive at a 2 ms DAQ), on rig2's torque drive (the
laws are the speed loop there), with dropouts answered by the same fallback, and with the motor's
electromagnetic torque channel (the motor friction's tanh)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mitigate.closedloop import run_closed_loop
from mitigate.controllers.base import Action, Controller
from mitigate.controllers.compiled import CompiledLaw, law_config
from mitigate.controllers.factory import context_for, make_controller
from mitigate.scenario import ControllerSpec, load_scenario, make_scenario, parse_scenario
from models.errors import ConfigError, SolverFailure
from models.rig import RIGS_DIR
from models.status import Status

ROOT = Path(__file__).resolve().parent.parent
MAIN = ROOT / "scenarios" / "stick_slip_30rpm.toml"
DRILL = ROOT / "scenarios" / "benchmark" / "drillstring.toml"
LAWS = ("softspeed", "ztorque", "doskil", "brake")
#: the laws whose C is the Python step operation by operation: the same bits
BITWISE = ("ztorque", "doskil", "brake")


class Twin(Controller):
    """Steps the compiled law and the Python reference with the same sample and estimate; the loop
    runs on the reference's action.  ``drop(k, t) -> channel or None`` removes a channel from call
    ``k``'s sample (a dropout) for both."""

    kind = "twin"

    def __init__(self, spec: dict, context, drop=None):
        super().__init__({}, context)
        self.c = make_controller({**spec, "implementation": "c"}, context)
        self.p = make_controller({**spec, "implementation": "python"}, context)
        if self.c.compiled is None or self.p.compiled is not None:
            raise AssertionError(f"expected one compiled and one Python law, got {self.c.compile_status}")
        self.drop, self.rows = drop, []

    def actuated_inputs(self):
        return self.p.actuated_inputs()

    def reset(self):
        self.c.reset()
        self.p.reset()

    def _step_impl(self, t, measurement, estimate):
        y = dict(measurement)
        ch = self.drop(len(self.rows), t) if self.drop else None
        if ch is not None:
            y.pop(ch, None)
        a, b = self.c.step(t, dict(y), estimate), self.p.step(t, dict(y), estimate)
        self.rows.append((a, b))
        return Action(dict(b.u), b.status, b.message)


def _twin(sc, spec: dict, drop=None):
    """The closed loop of ``sc`` on a twin of ``spec``; ``(twin, result)``."""
    sc = replace(sc, controllers=(ControllerSpec(spec.get("name", "law"), spec["kind"],
                                                 {k: v for k, v in spec.items() if k not in ("kind", "name")}),))
    ctx = context_for(sc, 0)
    tw = Twin({k: v for k, v in spec.items() if k != "name"}, ctx, drop)
    return tw, run_closed_loop(sc, tw)


def _agreement(tw) -> tuple[float, int]:
    """``(worst relative difference, calls not bit-identical)``; statuses, messages and the inputs
    set must be the same on every call."""
    worst, differ = 0.0, 0
    for a, b in tw.rows:
        assert (a.status, a.message, set(a.u)) == (b.status, b.message, set(b.u))
        for k, v in b.u.items():
            worst = max(worst, abs(a.u[k] - v) / max(1.0, abs(v)))
            differ += a.u[k] != v
    return worst, differ


def _check(tw, r, kind: str) -> None:
    assert r.status in (Status.OK, Status.WARNING), r.message
    assert tw.c.counts.as_dict() == tw.p.counts.as_dict()
    worst, differ = _agreement(tw)
    assert len(tw.rows) > 100
    if kind in BITWISE:
        assert differ == 0 and worst == 0.0
    else:
        assert worst <= 1e-12


@pytest.mark.slow
@pytest.mark.parametrize("kind", LAWS)
def test_compiled_law_equals_the_python_step_call_by_call_on_the_main_scenario(kind):
    """rig3, 30 rpm, N1 = 20 N, the controllers from 20 s (the scenario's own options: the brake's
    tuned 80 N s/rad, no filter); 40 s of control, 4,001 calls."""
    sc = load_scenario(MAIN)
    spec = next(dict(c.options, kind=c.kind) for c in sc.controllers if c.kind == kind)
    tw, r = _twin(sc, spec)
    assert len(tw.rows) == 4001
    _check(tw, r, kind)


@pytest.mark.slow
@pytest.mark.parametrize("kind", LAWS)
def test_compiled_law_equals_the_python_step_on_the_drill_string(kind):
    """The lab drill string (models/rigs/drillstring_motor.toml): a DC top drive on a reaction load
    cell, the weight on bit as the servo input, a 2 ms DAQ; 4 s of control."""
    sc = replace(load_scenario(DRILL), duration=12.0)
    tw, r = _twin(sc, {"kind": kind})
    _check(tw, r, kind)


@pytest.mark.parametrize("kind", ["softspeed", "ztorque"])
def test_compiled_law_equals_the_python_step_on_a_torque_drive(kind):
    """rig2 (seed 001): the motor torque is the input, the law is the speed loop with its integral
    held at the torque limit; from rest, 3 s."""
    sc = make_scenario(name="r2", model="rig2", duration=3.0, inputs={"motor_torque": 0.0}, controllers=[kind],
                       estimator="fd")
    tw, r = _twin(sc, {"kind": kind})
    assert tw.c.torque_drive and set(tw.rows[-1][0].u) == {"motor_torque"}
    _check(tw, r, kind)


def _dropouts(channels):
    """Every 37th call loses one of ``channels`` in turn."""
    def drop(k, t):
        return channels[(k // 37) % len(channels)] if k % 37 == 5 else None
    return drop


@pytest.mark.parametrize("kind,options,channels", [
    ("softspeed", {}, ["omega3", "motor_torque"]),
    ("ztorque", {}, ["omega3", "motor_torque"]),
    ("doskil", {}, ["omega2", "omega3"]),
    ("brake", {"gain_relative": 4.0, "filter_tau": 0.03, "deadband": 0.05, "use_estimate": False}, ["omega2", "omega3"]),
])
def test_a_dropout_is_the_same_counted_fallback_in_c_and_python(kind, options, channels):
    """rig3 in stick-slip, control from 2 s to 6 s; a dropout of a channel the law reads is answered by
    the programme (Status.FALLBACK, the same message), and the law goes on from the state it had."""
    sc = make_scenario(name="d", duration=6.0, seed=3, inputs={"omega_ref": "30 rpm", "n1": 20.0}, controllers=[kind],
                       estimator="fd", control_start=2.0)
    tw, r = _twin(sc, {"kind": kind, **options}, _dropouts(channels))
    _check(tw, r, kind)
    assert tw.c.counts.failures == tw.c.counts.fallbacks > 5
    messages = {a.message for a, _ in tw.rows if a.status is Status.FALLBACK}
    assert all(f"no reading of channel '{c}'" in " ".join(messages) for c in channels)


def test_the_brake_reads_the_estimate_and_filters_over_the_call_interval_alike():
    """The brake with the EKF's speeds (use_estimate), both gains, a deadband and a filter, called
    every 3rd DAQ period (its filter integrates over max(t - t_prev, period))."""
    sc = make_scenario(name="b", duration=5.0, seed=4, inputs={"omega_ref": "30 rpm", "n1": 20.0}, controllers=["brake"],
                       estimator="ekf", control={"start": 1.0, "every": 3})
    tw, r = _twin(sc, {"kind": "brake", "gain_overspeed": 30.0, "gain_relative": 10.0, "deadband": 0.02,
                       "filter_tau": 0.05})
    _check(tw, r, "brake")
    assert max(a.u["n2"] for a, _ in tw.rows) > 0.0


@pytest.mark.parametrize("kind", ["softspeed", "ztorque"])
def test_the_motor_friction_of_an_electromagnetic_torque_channel_alike(tmp_path, kind):
    """rig3 with its torque channel reading the motor's electromagnetic torque: the pipe torque
    subtracts the motor's friction eta (Tf tanh(eta w / eps) + Cm eta w)."""
    text = (RIGS_DIR / "rig3.toml").read_text()
    assert text.count('definition = "reaction"') == 1
    rig = tmp_path / "rig3_em.toml"
    rig.write_text(text.replace('definition = "reaction"', 'definition = "electromagnetic"')
                   .replace('name = "rig3"', 'name = "rig3_em"', 1))
    sc = parse_scenario({"scenario": {"name": "em", "duration": 4.0, "model": str(rig)},
                         "inputs": {"omega_ref": 3.0, "n1": 20.0, "n2": 0.0}, "estimator": {"kind": "fd"},
                         "control": {"start": 1.0}, "controllers": [{"name": "c", "kind": kind}]}, str(tmp_path / "em.toml"))
    tw, r = _twin(sc, {"kind": kind})
    assert tw.c.pipe.motor is not None
    _check(tw, r, kind)


def _expm_60_digits(M: np.ndarray) -> np.ndarray:
    """exp(M) in 60-digit decimal arithmetic (Taylor, 40 terms of M / 2^20, squared 20 times)."""
    from decimal import Decimal, localcontext
    with localcontext() as ctx:
        ctx.prec = 60
        n = len(M)
        X = [[Decimal(float(v)) / (2 ** 20) for v in row] for row in M]

        def mul(A, B):
            return [[sum(A[i][k] * B[k][j] for k in range(n)) for j in range(n)] for i in range(n)]
        E = [[Decimal(int(i == j)) for j in range(n)] for i in range(n)]
        T = [row[:] for row in E]
        for k in range(1, 41):
            T = [[v / k for v in row] for row in mul(T, X)]
            E = [[E[i][j] + T[i][j] for j in range(n)] for i in range(n)]
        for _ in range(20):
            E = mul(E, E)
        return np.array([[float(v) for v in row] for row in E])


@pytest.mark.parametrize("J_v", [0.0, 2 * 0.1099 * 0.01 / 60, 1.0])
def test_the_virtual_drive_of_the_c_core_is_the_exact_step(J_v):
    """Kp dt / J_v = 0.09 (rig3), 60 (a tiny drive), 0.002: the C core's matrix exponential (Taylor,
    scaled and squared as exp - I) against a 60-digit decimal one (normwise 1e-16) and scipy's expm
    (Pade; normwise 1e-14: scipy's own error on the stiff drive is 4e-15)."""
    sc = make_scenario(name="s", duration=1.0, inputs={"omega_ref": "30 rpm", "n1": 20.0},
                       controllers=[{"name": "s", "kind": "softspeed", "J_v": J_v}], estimator="fd")
    c = make_controller(sc.controllers[0], context_for(sc, 0))
    C = np.hstack(c.compiled.virtual_drive())
    M = np.block([[np.array([[-c.Kp / c.J_v, 1 / c.J_v], [-c.Ki, 0.0]]),
                   np.array([[c.Kp / c.J_v, -1 / c.J_v], [c.Ki, 0.0]])], [np.zeros((2, 4))]]) * 0.01
    exact = _expm_60_digits(M)[:2]
    scale = np.max(np.abs(exact))
    assert np.max(np.abs(C - exact)) <= 1e-16 * scale
    assert np.max(np.abs(C - np.hstack([c.drive.Ad, c.drive.Bd]))) <= 1e-14 * scale


def test_the_c_core_refuses_a_configuration_it_cannot_run():
    ok = law_config("brake", n_ch=1, ch_body=0, period=0.01, gain=10.0, n_max=40.0)
    CompiledLaw(ok, ("omega2",))
    # a relative gain reads the drive body's speed, which this configuration has no channel for
    with pytest.raises(SolverFailure, match="refused its configuration"):
        CompiledLaw({**ok, "gain_relative": 1.0}, ("omega2",))
    with pytest.raises(SolverFailure, match="refused its configuration"):
        CompiledLaw(law_config("softspeed", n_ch=2, ch_drive=0, ch_torque=1, period=0.01, Kp=1.0), ("w", "T"))
    with pytest.raises(ValueError, match="law kind must be one of"):
        law_config("pid")


def test_implementation_is_checked_in_one_line():
    sc = make_scenario(name="s", duration=1.0, inputs={"omega_ref": "30 rpm", "n1": 20.0},
                       controllers=[{"name": "z", "kind": "ztorque", "implementation": "fortran"}], estimator="fd")
    with pytest.raises(ConfigError, match=r"implementation must be one of c, python, got 'fortran'$"):
        make_controller(sc.controllers[0], context_for(sc, 0))


def test_by_default_the_laws_run_the_compiled_step():
    sc = load_scenario(MAIN)
    for i, c in enumerate(sc.controllers):
        if c.kind in LAWS:
            law = make_controller(c, context_for(sc, i))
            assert law.compiled is not None and law.compile_status.startswith("c (ss_laws_"), law.compile_status
            assert math.isfinite(law.step(20.0, {"omega1": 3.0, "omega2": 3.1, "omega3": 3.0, "motor_torque": 0.3},
                                          None).u[law.actuated_inputs()[0]])
