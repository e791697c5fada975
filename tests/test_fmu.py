"""The exported controller as an FMI 2.0 co-simulation FMU and in a real-time loop (issue 26).

The main scenario's NMPC is exported once with ``fmu=True`` (30 s of reference: 20 s of stick-slip,
10 s of control).  fmpy (the reader Simulink, Dymola and OpenModelica users validate FMUs with)
validates its model description and simulates it on the reference run's inputs: its outputs equal
the library's (the reference outputs) to 1e-9.  The real-time driver runs against the scenario's
plant in another process over UDP; in lockstep it reproduces the workbench's own run sample by
sample, so the stick-slip it suppresses is the workbench's, and its deadline counts agree with its
own per-period log.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mitigate.cli import main as cli_main
from mitigate.export.driver import parse_summary
from mitigate.export.fmu import unit_definition
from models.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
MAIN = ROOT / "scenarios" / "stick_slip_30rpm.toml"
REFERENCE = 30.0             # the shared export's (tests/conftest.py nmpc_export)
pytestmark = pytest.mark.xdist_group("nmpc_export")
needs_tools = pytest.mark.skipif(shutil.which("cmake") is None or shutil.which("cc") is None,
                                 reason="needs a C compiler and cmake")


@pytest.fixture(scope="module")
def exported(nmpc_export):
    """The one command's export with the FMU (tests/conftest.py: export, build, replay, and 3 s of the
    real-time driver), shared with tests/test_export.py."""
    pytest.importorskip("fmpy")
    return nmpc_export, nmpc_export.fmu, nmpc_export.ref


def _env():
    return dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _inputs(res, ref, until=None):
    """The reference's in[] columns as fmpy's ``input=`` structured array."""
    names = [p.name for p in res.interface.inputs]
    rows = ref if until is None else ref[ref[:, 0] <= until + 1e-9]
    sig = np.zeros(len(rows), dtype=[("time", float)] + [(n, float) for n in names])
    sig["time"] = rows[:, 0]
    for j, n in enumerate(names):
        sig[n] = rows[:, 1 + j]
    return sig


def _fmu_outputs(res):
    return [p.name if p.name.startswith("estimate:") else f"command:{p.name}" for p in res.interface.outputs]


@pytest.fixture(scope="module")
def simulated(exported):
    """fmpy's run of the FMU over the whole reference at the DAQ period."""
    from fmpy import simulate_fmu
    res, fmu, ref = exported
    dt = 0.01
    return simulate_fmu(str(fmu), start_time=0.0, stop_time=ref[-1, 0], output_interval=dt,
                        input=_inputs(res, ref), output=_fmu_outputs(res) + ["status"])


def test_units_are_written_in_modelica_syntax_with_their_si_base_units():
    assert unit_definition("N m s/rad") == ("N.m.s/rad", {"kg": "1", "m": "2", "s": "-1", "rad": "-1"})
    assert unit_definition("kg m^2") == ("kg.m2", {"kg": "1", "m": "2"})
    assert unit_definition("rad/s/s") == ("rad/s2", {"s": "-2", "rad": "1"})
    assert unit_definition("ohm") == ("Ohm", {"kg": "1", "m": "2", "s": "-3", "A": "-2"})
    assert unit_definition("V/(rad/s)") == unit_definition("V s/rad") == \
        ("V.s/rad", {"kg": "1", "m": "2", "s": "-2", "A": "-1", "rad": "-1"})
    name, attrs = unit_definition("rpm")
    assert name == "rpm" and float(attrs["factor"]) == pytest.approx(2 * np.pi / 60, rel=1e-15)
    assert unit_definition("-") is None and unit_definition("") is None
    with pytest.raises(ConfigError, match=r"unit \[furlong\] does not convert"):
        unit_definition("furlong", "export: x")


def test_bad_rt_and_fmu_requests_are_one_line_refusals(tmp_path, capsys):
    assert cli_main(["export", str(MAIN), "--controller", "NMPC", "--out", str(tmp_path / "x"), "--rt", "0"]) == 2
    err = capsys.readouterr().err
    assert "--rt must be a number of seconds > 0, got 0.0" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
    from mitigate.export.plant_server import PlantServer
    from mitigate.scenario import load_scenario
    sc = load_scenario(MAIN)
    with pytest.raises(ConfigError, match=r"is not a folder written by `mitigate export`"):
        PlantServer(sc, tmp_path)
    (tmp_path / "export.json").write_text('{"rig": "rig2", "dt": 0.01, "inputs": [], "outputs": []}')
    with pytest.raises(ConfigError, match=r"exported for rig 'rig2' at 0.01 s, the scenario is rig 'rig3'"):
        PlantServer(sc, tmp_path)


@pytest.mark.slow
@needs_tools
def test_one_command_exports_builds_replays_and_runs_the_realtime_driver(exported):
    res, fmu, _ = exported
    doc = res.cli
    assert fmu.is_file() and f"{res.prefix}.fmu" in doc["files"] and "rt/driver.c" in doc["files"]
    assert " mismatches 0 " in doc["replay"] and "allocations_after_create 0" in doc["replay"]
    rt = doc["rt"]
    assert rt["status"] == "ok" and rt["driver"]["periods"] == 300 and rt["plant"]["samples"] == 300
    assert 0 <= rt["driver"]["missed"] <= 300 and rt["driver"]["step_p99_us"] >= rt["driver"]["step_median_us"] > 0
    text = doc["rt_text"]
    assert "deadlines: " in text and " missed (" in text and "step: median" in text and "plant: 300 samples" in text


@pytest.mark.slow
@needs_tools
def test_fmpy_validates_the_model_description(exported):
    from fmpy import dump, read_model_description
    from fmpy.validation import validate_fmu
    res, fmu, _ = exported
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu), validate=True)
    assert md.fmiVersion == "2.0" and md.coSimulation.modelIdentifier == res.prefix
    assert md.modelExchange is None and md.defaultExperiment.stepSize == "0.01"
    var = {v.name: v for v in md.modelVariables}
    units = {u.name: u for u in md.unitDefinitions}
    for p in res.interface.inputs:
        v = var[p.name]
        assert v.causality == "input" and v.start is not None
        assert v.variability == ("discrete" if p.name == "enable" else "continuous")
    assert float(var["programme:n1"].start) == 20.0 and float(var["programme:omega_ref"].start) == pytest.approx(np.pi)
    for name in _fmu_outputs(res) + ["solve_time", "status"]:
        assert var[name].causality == "output"
    for p in res.interface.params:
        v = var[p.name]
        assert v.causality == "parameter" and v.variability == "fixed" and float(v.start) == p.value
    assert var["rig:k1"].unit == "N.m/rad" and units["N.m/rad"].baseUnit.rad == -1
    assert var["omega3"].unit == "rad/s" and units["rad/s"].baseUnit.s == -1
    assert var["setpoint_rate"].unit == "rad/s2"
    assert all(v.unit in units for v in md.modelVariables if v.unit)
    dump(str(fmu))                                   # reads and prints it without an error


@pytest.mark.slow
@needs_tools
def test_the_fmu_gives_the_library_outputs_on_the_reference_run(exported, simulated):
    """fmpy records the outputs after each fmi2DoStep at its end time: the row at t_{k+1} holds the
    library's outputs of sample k (reference row k)."""
    res, _, ref = exported
    n_in = len(res.interface.inputs)
    r = simulated
    assert len(r) == len(ref) and np.allclose(r["time"], ref[:, 0], rtol=0, atol=1e-9)
    worst = 0.0
    for j, name in enumerate(_fmu_outputs(res)):
        want, got = ref[:-1, 1 + n_in + j], r[name][1:]
        worst = max(worst, float(np.max(np.abs(got - want) / np.maximum(np.abs(want), 1.0))))
    assert worst <= 1e-9
    assert np.count_nonzero(r["status"] == 0) > 0 and np.count_nonzero(r["status"] == 1) > 0
    assert not np.any(r["status"] >= 2)
    # before the first step: the commands pass the programme through
    assert r["command:omega_ref"][0] == pytest.approx(np.pi) and r["command:n2"][0] == 0.0
    # the controller acted: after 20 s the set-point left the programme
    k = ref[:, 0] > 21.0
    assert np.max(np.abs(r["command:omega_ref"][k] - np.pi)) > 0.05


@pytest.mark.slow
@needs_tools
def test_a_communication_step_must_be_whole_daq_periods(exported):
    """h = 1.5 DAQ periods is fmi2Error with a logged reason; h = 2 periods runs two steps."""
    from ctypes import byref
    from fmpy import extract, read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import (FMU2Slave, calloc, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, free)
    from fmpy.logging import addLoggerProxy
    res, fmu, ref = exported
    md = read_model_description(str(fmu))
    where = extract(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    ins = [vr[p.name] for p in res.interface.inputs]
    outs = [vr[n] for n in _fmu_outputs(res)]
    messages = []
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: messages.append((status, msg)))
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    addLoggerProxy(byref(cb))

    def new(name):
        s = FMU2Slave(guid=md.guid, unzipDirectory=where, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName=name)
        s.instantiate(callbacks=cb)
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.exitInitializationMode()
        return s

    a, b = new("a"), new("b")
    with pytest.raises(FMICallException, match=r"status 3 \(error\)"):
        a.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.015)
    assert any(st == 3 and b"not a whole number of DAQ periods" in m for st, m in messages)
    row = list(ref[0, 1:1 + len(ins)])
    a.setReal(ins, row)
    a.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.02)
    b.setReal(ins, row)
    b.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.01)
    one = b.getReal(outs)
    b.doStep(currentCommunicationPoint=0.01, communicationStepSize=0.01)
    assert a.getReal(outs) == b.getReal(outs) != one         # two steps, not one
    with pytest.raises(FMICallException):                       # a fixed parameter after initialisation
        a.setReal([vr["weight:speed"]], [2.0])
    assert any(b"weight:speed is a fixed parameter" in m for _, m in messages)
    for s in (a, b):
        s.terminate()
        s.freeInstance()
    shutil.rmtree(where, ignore_errors=True)


@pytest.mark.slow
@needs_tools
def test_parameters_set_through_the_fmu_change_the_controller(exported, simulated):
    """A set-point rate limit of 0.1 rad/s^2 (exported: about 20) moves the set-point less."""
    from fmpy import simulate_fmu
    res, fmu, ref = exported
    r = simulate_fmu(str(fmu), start_time=0.0, stop_time=23.0, output_interval=0.01, input=_inputs(res, ref, 23.0),
                     output=["command:omega_ref"], start_values={"setpoint_rate": 0.1})
    base = simulated["command:omega_ref"][:len(r)]
    k = r["time"] > 20.0
    assert np.array_equal(r["command:omega_ref"][~k], base[~k])     # the programme until the switch-on
    moved = np.abs(r["command:omega_ref"][k] - np.pi)
    assert np.max(moved) <= 0.1 * 3.0 + 1e-9                         # 3 s at 0.1 rad/s^2 at most
    assert np.max(np.abs(base[k] - np.pi)) > 2 * np.max(moved)


def _lines(text):
    return {ln.split(":")[0]: ln for ln in text.splitlines()}


@pytest.mark.slow
@needs_tools
def test_the_realtime_driver_suppresses_stick_slip_against_the_plant_in_another_process(exported, tmp_path):
    """One command: the plant server with --run starts the driver.  24 s of samples: stick-slip until
    the switch-on at 20 s, then the NMPC.  The workbench's own NMPC run brings the objective speed's
    severity to 0.007 within 2 s of the switch-on (22-30 s of the main scenario), PI only stays at
    1.0-1.25 (stick-slip): the last stick-slip period (21.7-24 s) must be below 0.05, the one before
    the switch-on above 0.5.  In lockstep the samples the plant sent are the workbench's own
    (test/reference.csv) to 1e-9."""
    res, _, ref = exported
    log, dlog = tmp_path / "plant.csv", tmp_path / "driver.csv"
    r = subprocess.run([sys.executable, "-m", "mitigate.export.rt", str(MAIN), str(res.out), "--run", "24",
                        "--port", "0", "--log", str(log), "--driver-log", str(dlog)],
                       capture_output=True, text=True, timeout=600, env=_env(), cwd=str(ROOT))
    assert r.returncode == 0, r.stdout + r.stderr
    s = parse_summary(r.stdout)
    assert s["periods"] == 2400 and s["failed"] == 0 and s["ok"] + s["hold"] + s["fallback"] == 2400
    plant = _lines(r.stdout)["plant"]
    assert "2400 samples (24 s), control from 20 s" in plant
    data = np.loadtxt(log, delimiter=",", skiprows=1)
    n_in = len(res.interface.inputs)
    assert data.shape[0] == 2401
    sent, want = data[:, 1:1 + n_in], ref[:2401, 1:1 + n_in]
    assert np.max(np.abs(sent - want) / np.maximum(np.abs(want), 1.0)) <= 1e-9
    from mitigate.severity import severity
    w = data[:, -1]
    n = int(round(2.3334659 / 0.01))
    assert severity(w[2000 - n:2001]) > 0.5 and severity(w[-n - 1:]) < 0.05
    _check_counts(s, dlog)


def _check_counts(s, dlog):
    """The driver's printed counts agree with its own per-period log."""
    d = np.loadtxt(dlog, delimiter=",", skiprows=1)
    late = d[:, 5]
    assert len(d) == s["periods"]
    assert s["missed"] == np.count_nonzero(late > 0)
    assert s["max_lateness_us"] == pytest.approx(max(late.max(), 0.0), abs=2e-3)
    assert s["step_median_us"] == pytest.approx(np.sort(d[:, 3])[int(np.ceil(0.5 * len(d))) - 1], abs=2e-3)
    assert s["step_p99_us"] == pytest.approx(np.sort(d[:, 3])[int(np.ceil(0.99 * len(d))) - 1], abs=2e-3)
    assert np.all(np.diff(d[:, 1]) > 0)                           # releases move forward


@pytest.mark.slow
@needs_tools
def test_a_period_shorter_than_a_step_misses_every_deadline(exported, tmp_path):
    """--period 10 us: a step and an exchange with a Python plant take longer, so every period misses."""
    from mitigate.export.driver import run_realtime
    res, _, _ = exported
    dlog = tmp_path / "driver.csv"
    rt = run_realtime(MAIN, res.out, 0.5, period=1e-5, driver_log=dlog)
    assert rt.success, rt.message
    s = rt.driver
    assert s["periods"] == 50 and s["missed"] == 50 and s["max_lateness_us"] > 0 and s["skipped"] >= 50
    _check_counts(s, dlog)
    assert rt.plant.samples == 50
