"""Closed-loop logs carry the drive's current and voltage (or torque), and the report checks the
drive's limit (issue 28, item 5).

The drive registry says what a drive reports (:meth:`models.rig.drives.Drive.signals`) and what the
rig limits (:meth:`~models.rig.drives.Drive.limit`); the closed loop logs the first as ``true_*``
columns with units, the metric ``drive_load_peak`` is the second's peak over its limit, and the
report's verdict says when a run reached or exceeded it.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from mitigate.closedloop import run_closed_loop
from mitigate.controllers.factory import context_for, make_controller
from mitigate.metrics import closed_loop_metrics, get
from mitigate.report import drive_limit_note
from mitigate.scenario import make_scenario
from models import get_model
from models.logs import read_csv

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


def _run(sc):
    return run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))


def test_dc_motor_log_carries_current_and_voltage_that_obey_the_armature_circuit(tmp_path):
    """rig3 sliding steadily at 30 rpm, N1 = 20 N (a stable point): the log's current and voltage are
    the plant's, and in steady state they satisfy the armature's own equation V = R i + KE ratio w3
    (L di/dt = 0), which the closed loop never evaluates (it logs the PI loop's limited voltage)."""
    sc = make_scenario(name="steady", model="rig3", duration=6.0, controllers=["pi"], estimator="fd",
                       control_start=1.0, plant={"start": "sliding"})
    r = _run(sc)
    assert r.success, r.message
    log = r.to_log()
    assert log.units["true_current"] == "A" and log.units["true_voltage"] == "V"
    np.testing.assert_array_equal(log["true_current"], r.state("current"))
    p = sc.plant_params
    i, V, w3 = log["true_current"][-100:], log["true_voltage"][-100:], r.state("omega_R3")[-100:]
    np.testing.assert_allclose(V, p.R * i + p.KE * p.eta * w3, rtol=1e-3)
    assert 1.0 < float(np.mean(i)) < 5.0                       # the thesis' operating point draws about 2.2 A
    # written and read back with its units
    back = read_csv(log.write_csv(tmp_path / "log.csv"))
    np.testing.assert_allclose(back["true_voltage"], log["true_voltage"], rtol=1e-8)
    # the metric: the peak current after the switch-on over rig3's i_max = 10 A, and the energy from the same V i
    met = closed_loop_metrics(r, sc)
    after = r.t >= sc.control.start - 1e-12
    assert met["drive_load_peak"] == pytest.approx(np.max(np.abs(r.state("current")[after])) / p.i_max, rel=1e-12)
    assert met["drive_energy"] == pytest.approx(np.sum(np.abs(log["true_voltage"] * log["true_current"])[after])
                                                * sc.dt, rel=1e-9)
    note = drive_limit_note(sc, met)
    assert note.startswith("Drive: peak |current| ") and "% of the rig's limit of 10 A" in note


def _rig2(tmp_path, extra: str = "") -> str:
    text = (ROOT / "models/rigs/rig2.toml").read_text()
    old = 'input = "motor_torque"      # tau_m [N m], disc side'
    assert old in text
    p = tmp_path / "rig2_limited.toml"
    p.write_text(text.replace(old, old + "\n" + extra, 1))
    return str(p)


def test_torque_drive_logs_its_torque_and_a_saturated_run_is_at_its_limit(tmp_path):
    """rig2 (a torque drive) with torque_max = 0.3 N m under a 0.4 N m programme: the plant applies
    0.3 N m (it clips its input), the log carries that torque, the ratio is 1 and the verdict says the
    drive was at its limit; without torque_max the ratio is NaN and the verdict says nothing."""
    rig = get_model(_rig2(tmp_path, 'torque_max = "0.3 N m"'))
    sc = make_scenario(name="sat", model=rig, duration=3.0, inputs={"motor_torque": 0.4}, controllers=["pi"],
                       estimator="fd", control_start=1.0)
    r = _run(sc)
    assert r.success, r.message
    log = r.to_log()
    assert log.units["true_drive_torque"] == "N m"
    np.testing.assert_allclose(log["true_drive_torque"][:-1], 0.3)          # applied, not the 0.4 commanded
    np.testing.assert_allclose(log["command_motor_torque"], 0.4)            # the command column
    # the channel of the same name keeps what the DAQ measured (not overwritten by the command)
    np.testing.assert_array_equal(log["motor_torque"], r.y["motor_torque"])
    assert not np.array_equal(log["motor_torque"], log["command_motor_torque"])
    met = closed_loop_metrics(r, sc)
    assert met["drive_load_peak"] == pytest.approx(1.0, abs=1e-12)
    assert drive_limit_note(sc, met) == "Drive: at its limit: peak |drive_torque| 0.3 N m (the rig's limit 0.3 N m)."

    free = make_scenario(name="free", model="rig2", duration=3.0, inputs={"motor_torque": 0.4}, controllers=["pi"],
                         estimator="fd", control_start=1.0)
    met_free = closed_loop_metrics(_run(free), free)
    assert math.isnan(met_free["drive_load_peak"]) and drive_limit_note(free, met_free) == ""


def test_a_run_beyond_the_limit_says_so():
    """The verdict's words for a peak above the limit (a drive whose model does not enforce its
    rating), at it and below it, with the peak in the drive's unit."""
    sc = SimpleNamespace(plant_model=get_model("rig3"), plant_params=get_model("rig3").published())
    assert drive_limit_note(sc, {"drive_load_peak": 1.25}) == (
        "Drive: the run EXCEEDED its drive's limit: peak |current| 12.5 A, 1.25 x the rig's limit of 10 A.")
    assert drive_limit_note(sc, {"drive_load_peak": 0.9999}).startswith("Drive: at its limit")
    assert drive_limit_note(sc, {"drive_load_peak": 0.5}) == "Drive: peak |current| 5 A, 50 % of the rig's limit of 10 A."
    assert drive_limit_note(sc, {}) == ""


def test_the_metric_is_one_plain_declaration():
    m = get("drive_load_peak")
    assert m.unit == "-" and m.rank == 4 and m.kind == "value" and "closed_loop" in m.runs


def test_a_speed_drive_reports_nothing_and_the_drive_kinds_declare_their_units():
    """A prescribed speed: the model does not know its torque, so nothing is logged and no limit is
    checked; the other kinds declare a unit for every signal they give."""
    disc = get_model("disc")
    assert disc.drive.signal_units() == {} and disc.drive.limit(disc.published().as_dict()) is None
    rig3 = get_model("rig3")
    p = rig3.published()
    X = np.tile(rig3.steady_sliding(np.array([math.pi, 20.0, 0.0]), p), (3, 1))
    U = np.tile([math.pi, 20.0, 0.0], (3, 1))
    sig = rig3.drive.signals(rig3, p, X, U)
    assert set(sig) == set(rig3.drive.signal_units()) == {"current", "voltage"}
    assert rig3.drive.limit(p.as_dict()) == ("current", 10.0)
    assert rig3.drive.signals(rig3, p, X[:0], U[:0])["voltage"].shape == (0,)


def test_a_closed_loop_log_keeps_the_load_cells_and_the_servos_applied_force(tmp_path):
    """rig3 under the brake: the n2 column is what the DAQ read (its load cell), the brake's command
    is command_n2 and the force the servo applied (lagged, rate-limited) is true_n2; written and read
    back as CSV, the three stay apart."""
    sc = make_scenario(name="brk", model="rig3", duration=3.0, inputs={"omega_ref": "30 rpm", "n1": 20.0},
                       controllers=["brake"], estimator="fd", control_start=1.0)
    r = _run(sc)
    assert r.success, r.message
    log = r.to_log()
    j = r.inputs.index("n2")
    np.testing.assert_array_equal(log["n2"], r.y["n2"])
    np.testing.assert_array_equal(log["command_n2"], r.commands["n2"])
    np.testing.assert_array_equal(log["true_n2"], r.u[:, j])
    assert np.max(np.abs(log["command_n2"] - log["true_n2"])) > 0.1          # the servo lags its command
    assert log.units["command_n2"] == log.units["true_n2"] == "N"
    log.write_csv(tmp_path / "log.csv")
    back = read_csv(tmp_path / "log.csv")
    np.testing.assert_allclose(back["true_n2"], r.u[:, j], rtol=1e-8, atol=1e-9)
