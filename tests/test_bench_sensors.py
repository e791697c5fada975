"""The sensors a bench really has (issue 28): an inline torque flange on the shaft at the drive serves
the laws that need the drive's torque; a controller that needs the speed of a body the rig does not
measure takes the model-based estimator's.

Fixtures: the user's pin rig (tests/data/userrig/pin_rig.toml: a small DC gear motor, two discs,
a brake pin on the lower one) with its torque sensor moved into the first shaft (``between = ["up",
"mot"]``: the flange reads minus the torque the motor delivers), or without the lower disc's
encoder; the lab drill string read at the surface only (no bit encoder, a torque sub in the pipe).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mitigate.cli import main
from mitigate.closedloop import run_closed_loop
from mitigate.controllers.compiled import CompiledLaw
from mitigate.controllers.factory import context_for, make_controller
from mitigate.scenario import load_scenario, make_scenario
from models import get_model
from models.errors import ConfigError, SolverFailure
from models.status import Status
from test_laws_compiled import _check, _twin

ROOT = Path(__file__).resolve().parent.parent
PIN = ROOT / "tests" / "data" / "userrig" / "pin_rig.toml"
DRILL = ROOT / "scenarios" / "benchmark" / "drillstring.toml"
AT_DRIVE = '[sensors.tq]\nkind = "torque"\nat = "drive"\n'
ENC_LOW = '[sensors.enc_low]\nkind = "encoder"\nbody = "low"\nticks = 1024\n'


def _rig(tmp_path, name: str, old: str, new: str) -> Path:
    text = PIN.read_text()
    assert text.count(old) == 1
    p = tmp_path / f"{name}.toml"
    p.write_text(text.replace(old, new).replace('name = "pin_rig"', f'name = "{name}"'))
    return p


def _flange(tmp_path, shaft: str = "shaft1") -> Path:
    return _rig(tmp_path, f"pin_flange_{shaft}", AT_DRIVE,
                f'[sensors.tq]\nkind = "torque"\nat = "{shaft}"\nnoise = "0.002 N m"\n')


def _scenario(rig: Path, kind: str, *, rpm: float, force: float, duration: float, start: float,
              estimator: str = "ekf", **options):
    return make_scenario(name="bench", model=str(rig), duration=duration, seed=3,
                         inputs={"omega_ref": f"{rpm} rpm", "f_pin": force},
                         controllers=[{"name": kind, "kind": kind, **options}], estimator=estimator,
                         control_start=start)


def _run(sc):
    c = make_controller(sc.controllers[0], context_for(sc, 0))
    return c, run_closed_loop(sc, c)


# ------------------------------------------------------------------ the torque at the drive
def test_which_torque_sensor_tells_the_torque_at_the_drive(tmp_path):
    """At the drive first; else a flange in the one shaft at the drive's node, signed by the shaft's
    direction; a flange further down the string does not serve."""
    s = get_model("rig3").drive_load_sensor()
    assert s.at_drive and s.channel == "motor_torque" and s.sign == 1.0
    s = get_model(str(_flange(tmp_path))).drive_load_sensor()
    assert not s.at_drive and s.channel == "torque_shaft1" and s.sign == -1.0       # between = ["up", "mot"]
    s = get_model("drillstring").drive_load_sensor()           # a speed drive: "pipe" between "drive" and "bit"
    assert not s.at_drive and s.channel == "torque_bit" and s.sign == 1.0
    assert get_model(str(_flange(tmp_path, "shaft2"))).drive_load_sensor() is None


def test_a_flange_beyond_the_first_body_is_refused_in_one_line(tmp_path, capsys):
    rig = _flange(tmp_path, "shaft2")
    sc = tmp_path / "sc.toml"
    sc.write_text(f'[scenario]\nname = "f"\nmodel = "{rig}"\nduration = 2.0\n[inputs]\nomega_ref = "20 rpm"\n'
                  'f_pin = 20.0\n[[controllers]]\nname = "SoftSpeed"\nkind = "softspeed"\n')
    assert main(["run", str(sc), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the torque at the drive (add a torque sensor with at = \"drive\", or on the " \
                                    "shaft at the drive)" in err, err
    assert not (tmp_path / "out").exists()


def test_the_flange_reads_the_friction_torque_in_steady_sliding(tmp_path):
    """50 rpm and 12 N: the lower disc slides steadily, so the shaft carries the pin's friction
    r_pin f_pin mu_k = 0.035 x 12 x 0.32 = 0.1344 N m (the Stribeck term is exp(-(5.24/0.5)^2) ~ 0).
    The pipe torque from the flange (sign flipped: the shaft runs from "up" to "mot") and from the
    reaction load cell at the drive both find it."""
    expected = 0.035 * 12.0 * 0.32
    for rig in (_flange(tmp_path), PIN):
        c, r = _run(_scenario(rig, "softspeed", rpm=50, force=12.0, duration=6.0, start=3.0,
                              implementation="python"))
        assert r.status is Status.OK, r.message
        assert c.pipe.value == pytest.approx(expected, rel=0.02), rig.name


@pytest.mark.parametrize("kind", ["softspeed", "ztorque"])
def test_the_flange_runs_the_same_law_in_c_and_python(tmp_path, kind):
    """The flipped torque channel in the compiled core and the Python reference, call by call."""
    sc = _scenario(_flange(tmp_path), kind, rpm=20, force=20.0, duration=6.0, start=2.0)
    tw, r = _twin(sc, {"kind": kind})
    assert tw.c.compiled.config["torque_flip"] == 1 and tw.c.pipe.J == 0.0 and tw.c.pipe.motor is None
    _check(tw, r, kind)


def test_softspeed_on_a_flange_suppresses_the_stick_slip_pi_leaves(tmp_path):
    """20 rpm, 20 N: under PI the lower disc sticks (its true speed reaches 0); SoftSpeed reading the
    flange holds it within 5 % of the programme over the last 10 s."""
    rig, target = _flange(tmp_path), 20 * math.pi / 30
    out = {}
    for kind in ("pi", "softspeed"):
        _, r = _run(_scenario(rig, kind, rpm=20, force=20.0, duration=30.0, start=10.0))
        assert r.status is Status.OK, r.message
        w = np.asarray(r.to_log()["true_omega_low"])[-1000:]
        out[kind] = (w.min(), w.max())
    assert out["pi"][0] < 0.05 * target
    assert abs(out["softspeed"][0] - target) < 0.05 * target and abs(out["softspeed"][1] - target) < 0.05 * target


# ------------------------------------------------------------------ a body the rig does not measure
def _no_encoder(tmp_path) -> Path:
    return _rig(tmp_path, "pin_no_low_encoder", ENC_LOW, "")


def test_an_unmeasured_body_is_refused_without_a_model_based_estimator(tmp_path):
    rig = _no_encoder(tmp_path)
    for kind in ("brake", "doskil"):
        sc = _scenario(rig, kind, rpm=20, force=20.0, duration=2.0, start=1.0, estimator="fd")
        with pytest.raises(ConfigError, match=r"the speed of 'low'.*or estimate it: an estimator of kind \"ekf\" "
                                              r"or \"mhe\""):
            make_controller(sc.controllers[0], context_for(sc, 0))
    sc = _scenario(rig, "brake", rpm=20, force=20.0, duration=2.0, start=1.0, use_estimate=False)
    with pytest.raises(ConfigError, match="use_estimate = false forbids estimating"):
        make_controller(sc.controllers[0], context_for(sc, 0))


@pytest.mark.parametrize("kind", ["brake", "doskil"])
def test_a_law_takes_the_estimated_speed_of_an_unmeasured_body_alike_in_c_and_python(tmp_path, kind):
    sc = _scenario(_no_encoder(tmp_path), kind, rpm=20, force=20.0, duration=6.0, start=2.0)
    assert context_for(sc, 0).speed_source("low") == ("estimate", "omega_low")
    tw, r = _twin(sc, {"kind": kind})
    config = tw.c.compiled.config
    assert config["est_body"] == 1 and "omega_low" not in tw.c.compiled.channels
    assert tw.c.compiled.estimates[0] == "omega_low"
    _check(tw, r, kind)
    assert max(a.u["f_pin"] for a, _ in tw.rows) > 1.0                    # it acted


@pytest.mark.parametrize("kind", ["brake", "doskil"])
def test_no_estimate_is_the_same_counted_fallback_in_c_and_python(tmp_path, kind):
    sc = _scenario(_no_encoder(tmp_path), kind, rpm=20, force=20.0, duration=2.0, start=1.0)
    ctx = context_for(sc, 0)
    y = {"omega_mot": 2.0, "theta_mot": 0.0, "torque_drive": 0.1}
    for impl in ("c", "python"):
        law = make_controller({"kind": kind, "implementation": impl}, ctx)
        assert (law.compiled is not None) == (impl == "c")
        a = law.step(1.0, y, None)
        assert a.status is Status.FALLBACK and "no estimate of 'omega_low' in this call" in a.message, a.message
        assert law.counts.failures == law.counts.fallbacks == 1


def test_the_c_core_refuses_an_estimated_body_it_has_no_config_for():
    from mitigate.controllers.compiled import law_config
    ok = law_config("doskil", n_ch=1, ch_drive=0, est_body=1, period=0.01, gain=5.0, n_max=25.0)
    law = CompiledLaw(ok, ("omega_mot",), ("omega_low",))
    assert law.step(0.0, {"omega_mot": 1.0}, None, 1.0) is None and law.missing_estimate() == "omega_low"
    with pytest.raises(SolverFailure, match="refused its configuration"):
        CompiledLaw({**ok, "est_body": 0}, ("omega_mot",))


def test_doskil_on_an_estimated_speed_suppresses_the_stick_slip(tmp_path):
    """No encoder on the lower disc: D-OSKIL reads the EKF's speed of it (from the motor's encoder and
    torque) and holds the disc within 5 % of 20 rpm over the last 10 s (PI: stuck, see above)."""
    _, r = _run(_scenario(_no_encoder(tmp_path), "doskil", rpm=20, force=20.0, duration=30.0, start=10.0))
    assert r.status is Status.OK, r.message
    w = np.asarray(r.to_log()["true_omega_low"])[-1000:]
    target = 20 * math.pi / 30
    assert np.all(np.abs(w - target) < 0.05 * target), (w.min(), w.max())


# ------------------------------------------------------------------ a field string read at the surface
def _surface_only(tmp_path):
    """The lab drill string without a bit encoder and without the motor's load cell: the top's encoder,
    the torque sub in the pipe, the weight on bit."""
    text = (ROOT / "models" / "rigs" / "drillstring_motor.toml").read_text()
    start = text.index("[sensors.enc_bit]")
    text = text[:start] + text[text.index("[sensors.torque_bit]"):]
    text = text.replace('name = "drillstring_motor"', 'name = "surface_string"')
    rig = tmp_path / "surface_string.toml"
    rig.write_text(text)
    return rig


@pytest.mark.slow
def test_a_string_read_at_the_surface_runs_every_industry_law(tmp_path):
    """SoftSpeed and Z-Torque read the torque sub in the pipe, D-OSKIL the EKF's bit speed; each runs
    its 4 s under control, compiled, with no fallback."""
    rig = _surface_only(tmp_path)
    m = get_model(str(rig))
    assert m.speed_channel("bit") is None and m.drive_load_sensor().channel == "torque_bit"
    text = DRILL.read_text().replace('model = "drillstring_motor"', f'model = "{rig}"')
    for kind in ("softspeed", "ztorque", "doskil"):
        (tmp_path / "sc.toml").write_text(text + f'\n[[controllers]]\nname = "{kind}"\nkind = "{kind}"\n')
        sc = replace(load_scenario(tmp_path / "sc.toml"), duration=12.0)
        c, r = _run(sc)
        assert r.status is Status.OK and c.compiled is not None, (kind, r.message)
        assert c.counts.fallbacks == 0 and c.counts.steps > 1900
