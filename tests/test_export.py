"""The controller leaves the workbench (issue 26): ``mitigate export`` writes a C library of the
main scenario's NMPC with its EKF; built with CMake (and with make), it reproduces the workbench's
own 30 s run step by step to 1e-9 without allocating after ``create`` (the export of the one command,
shared with tests/test_fmu.py: tests/conftest.py ``nmpc_export``); loaded back into the
workbench as ``kind = "exported"`` it gives the NMPC's commands exactly."""

from __future__ import annotations

import math
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mitigate.cli import main as cli_main
from mitigate.export import build_export, export_controller
from mitigate.scenario import ControllerSpec, load_scenario
from models.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
MAIN = ROOT / "scenarios" / "stick_slip_30rpm.toml"

#: the tests build unoptimised (about 4x faster to compile, the same results: docs/export.md);
#: benchmarks/bench_export.py builds Release (-O2), checks that it replays the reference, and times it
BUILD = "Debug"

pytestmark = [pytest.mark.skipif(shutil.which("cmake") is None or shutil.which("cc") is None,
                                 reason="needs a C compiler and cmake"),
              pytest.mark.xdist_group("nmpc_export")]


@pytest.fixture(scope="module")
def exported(nmpc_export):
    return nmpc_export, nmpc_export.library


def _replay(exe: Path, csv: Path) -> tuple[int, dict]:
    r = subprocess.run([str(exe), str(csv)], capture_output=True, text=True)
    words = r.stdout.split()
    return r.returncode, {words[i]: words[i + 1] for i in range(0, len(words) - 1, 2)}


@pytest.mark.slow
def test_the_exported_library_replays_the_workbench_bit_for_bit_without_allocating(exported):
    res, so = exported
    assert res.reference_rows == 3001                                  # 30 s at 10 ms
    code, out = _replay(so.parent / f"{res.prefix}_replay", res.out / "test" / "reference.csv")
    assert code == 0, out
    assert out["rows"] == "3001" and out["mismatches"] == "0" and float(out["worst_relative"]) <= 1e-9
    assert out["allocations_after_create"] == "0"
    assert int(out["ok"]) > 0 and int(out["hold"]) > 0 and out["failed"] == "0"   # it planned and held
    doc = res.cli                 # the command's --json: the replay's line as numbers too, no hint
    assert doc["replay_values"]["rows"] == 3001 and doc["replay_values"]["mismatches"] == 0
    assert doc["replay_values"]["allocations_after_create"] == 0 and doc["hints"] == []


@pytest.mark.slow
def test_the_replay_notices_a_changed_output(exported, tmp_path):
    """The check can fail: one command of one sample moved by 1e-6 (relative) is one mismatch."""
    res, so = exported
    lines = (res.out / "test" / "reference.csv").read_text().splitlines()
    head = lines[0].split(",")
    col = head.index(res.interface.outputs[0].name)
    row = lines[3000].split(",")
    row[col] = repr(float(row[col]) * (1 + 1e-6))
    lines[3000] = ",".join(row)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    code, out = _replay(so.parent / f"{res.prefix}_replay", bad)
    assert code == 1 and out["mismatches"] == "1"


@pytest.mark.slow
def test_make_builds_the_same_library(exported, tmp_path):
    res, _ = exported
    copy = tmp_path / "copy"
    shutil.copytree(res.out, copy, symlinks=True, ignore=shutil.ignore_patterns("build"))
    so = build_export(copy, tool="make", build_type=BUILD)
    code, out = _replay(so.parent / f"{res.prefix}_replay", copy / "test" / "reference.csv")
    assert code == 0 and out["mismatches"] == "0" and out["allocations_after_create"] == "0"


@pytest.mark.slow
def test_the_exported_library_in_the_workbench_equals_the_nmpc(exported):
    from mitigate import run
    res, _ = exported
    sc = load_scenario(MAIN)
    nmpc = next(c for c in sc.controllers if c.name == "NMPC")
    sc = replace(sc, duration=25.0, controllers=(nmpc, ControllerSpec("exported", "exported", {"path": str(res.out)})))
    a, b = run(sc).runs
    assert b.status.success and b.result.controller_counts["fallbacks"] == 0
    for k, v in a.result.commands.items():
        np.testing.assert_array_equal(v, b.result.commands[k])


@pytest.mark.slow
def test_runtime_parameters_change_the_controller_without_a_rebuild(exported):
    from mitigate.controllers.exported import ExportedLibrary
    res, _ = exported
    names = [p.name for p in res.interface.params]
    assert "rig:J1" in names and "weight:speed" in names and "setpoint_band" in names
    lib = ExportedLibrary(res.out)
    slow = ExportedLibrary(res.out, {"setpoint_rate": 0.1})
    data = np.loadtxt(res.out / "test" / "reference.csv", delimiter=",", skiprows=1)
    n_in = len(res.interface.inputs)
    moved = []
    for row in data[2000:2300]:
        for lb in (lib, slow):
            lb.in_buf[:] = row[1:1 + n_in]
            lb.step(row[0])
        moved.append(abs(lib.out_buf[0] - slow.out_buf[0]))
    assert max(moved) > 1e-3                          # a rate limit of 0.1 rad/s^2 moves the set-point less
    with pytest.raises(ConfigError, match=r"params: the library has no parameter 'rig:nope'"):
        ExportedLibrary(res.out, {"rig:nope": 1.0})
    with pytest.raises(ConfigError, match=r"params\.weight:speed must be a finite number"):
        ExportedLibrary(res.out, {"weight:speed": math.nan})


def test_bad_exports_are_one_line_refusals_and_write_nothing(tmp_path, capsys):
    out = tmp_path / "x"
    with pytest.raises(ConfigError, match=r"controller 'Nope' is not in the scenario"):
        export_controller(MAIN, "Nope", out)
    with pytest.raises(ConfigError, match=r"of kind 'supervisor'; export supports nmpc, softspeed, ztorque, doskil, "
                                          r"brake$"):
        export_controller(MAIN, "speed supervisor", out)
    sc = load_scenario(MAIN)
    with pytest.raises(ConfigError, match=r"estimator.kind = 'fd'; export supports the EKF and the MHE$"):
        export_controller(replace(sc, estimator={"kind": "fd"}), "NMPC", out)
    with pytest.raises(ConfigError, match=r"the MHE did not compile its update .*; export needs a C compiler and "
                                          r"qpsol = 'ldl'$"):
        export_controller(replace(sc, estimator={"kind": "mhe", "qpsol": "osqp"}), "NMPC", out)
    with pytest.raises(ConfigError, match=r"^build_type: expected one of Release, Debug; got 'Fast'$"):
        export_controller(MAIN, "NMPC", out, build_type="Fast")
    assert not out.exists()
    out.mkdir()
    with pytest.raises(ConfigError, match=r"exists; refusing to overwrite"):
        export_controller(MAIN, "NMPC", out, reference=None)
    assert cli_main(["export", str(MAIN), "--controller", "Nope", "--out", str(tmp_path / "y")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


@pytest.mark.slow
@pytest.mark.parametrize("inputs", ["motor", "pin", "both_full", "both_none"])
def test_every_input_set_exports_and_replays(inputs, tmp_path):
    """The motor-only and the pin-only NMPC export too (issue 26): 25 s of the main scenario (5 s of
    control) replay bit for bit without allocation.  The pin-only one with N2 programmed at 10 N (a
    job, like a weight on bit) and a force window of rig3's period, so the band on the moving mean
    runs in the library too.  The main scenario's QP is the partially condensed one (its NMPC table:
    hpipm's "speed" preset from a small mu0, docs/export.md); "both_full" / "both_none": both inputs
    with ``qp_condensing = "full"`` (the QP condensed in the preparation, hpipm's dense IPM in the
    feedback) or the options' defaults (the structured QP, hpipm's "speed_abs" from its own mu0)
    replay the workbench's run of the same options bit for bit too, and only the structured one
    gets the export's hint."""
    path = MAIN
    if inputs == "pin":
        path = tmp_path / "pin10.toml"
        path.write_text(MAIN.read_text().replace("n2 = 0.0", "n2 = 10.0"))
    sc = load_scenario(path)
    assert sc.inputs["n2"](0.0) == (10.0 if inputs == "pin" else 0.0)
    extra = {"force_window": 2.33} if inputs == "pin" else {}
    structured = inputs == "both_none"
    if inputs.startswith("both_"):
        inputs, extra = "both", {"qp_condensing": inputs[5:]}
        if structured:
            extra.update(qp_mode="speed_abs", qp_mu0=None)
    ctrls = tuple(replace(c, options={**dict(c.options), "inputs": inputs, **extra}) if c.name == "NMPC" else c
                  for c in sc.controllers)
    res = export_controller(replace(sc, controllers=ctrls), "NMPC", tmp_path / inputs, reference=25.0,
                            prefix=f"nmpc_{inputs}")
    assert [p.name for p in res.interface.outputs][:1] == (["n2"] if inputs == "pin" else ["omega_ref"])
    assert bool(res.hints) is structured and all("qp_condensing = 'partial'" in h for h in res.hints), res.hints
    so = build_export(res.out, build_type=BUILD)
    code, out = _replay(so.parent / f"{res.prefix}_replay", res.out / "test" / "reference.csv")
    assert code == 0 and out["rows"] == "2501" and out["mismatches"] == "0", out
    assert out["allocations_after_create"] == "0" and int(out["ok"]) > 0
    if inputs == "pin":
        par = {p.name: p for p in res.interface.params}
        assert par["force_window"].value == pytest.approx(2.33)
