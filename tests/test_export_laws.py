"""The industry's laws leave the workbench too (issue 26): ``mitigate export`` writes SoftSpeed,
Z-Torque, D-OSKIL and the brake of the main scenario with its EKF through the same glue as the NMPC
(mitigate/export/glue.py; the law's core is the workbench's own csrc/ss_laws.c).  Built with CMake,
each replays the workbench's own 60 s run bit for bit without allocating after ``create``; loaded
back as ``kind = "exported"`` it gives the workbench law's commands exactly; its gains are runtime
parameters."""

from __future__ import annotations

import math
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mitigate.controllers.exported import ExportedLibrary
from mitigate.export import build_export, export_controller
from mitigate.scenario import ControllerSpec, load_scenario
from models.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
MAIN = ROOT / "scenarios" / "stick_slip_30rpm.toml"
DRILL = ROOT / "scenarios" / "benchmark" / "drillstring.toml"
#: the main scenario's laws by name, with a runtime parameter and a value that changes their commands
LAWS = {"SoftSpeed": ("Kp", 0.5), "Z-Torque": ("gain", 1.0), "D-OSKIL": ("gain", 5.0),
        "R2 brake": ("gain_overspeed", 20.0)}

pytestmark = pytest.mark.skipif(shutil.which("cmake") is None or shutil.which("cc") is None,
                                reason="needs a C compiler and cmake")


@pytest.fixture(scope="module", params=list(LAWS))
def exported(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("laws") / request.param.replace(" ", "_").replace("-", "_").lower()
    res = export_controller(MAIN, request.param, out, reference=60.0)
    return request.param, res, build_export(out, build_type="Debug")   # as tests/test_export.py


def _replay(exe: Path, csv: Path) -> tuple[int, dict]:
    r = subprocess.run([str(exe), str(csv)], capture_output=True, text=True)
    words = r.stdout.split()
    return r.returncode, {words[i]: words[i + 1] for i in range(0, len(words) - 1, 2)}


@pytest.mark.slow
def test_each_exported_law_replays_the_workbench_bit_for_bit_without_allocating(exported):
    name, res, so = exported
    assert res.reference_rows == 6001
    assert not any(f.startswith("vendor/") for f in res.files)        # a law needs no QP solver
    outs = [p.name for p in res.interface.outputs]
    assert outs[0] in ("omega_ref", "n2") and all(n.startswith("estimate:") for n in outs[1:]) and len(outs) > 5
    code, out = _replay(so.parent / f"{res.prefix}_replay", res.out / "test" / "reference.csv")
    assert code == 0, out
    assert out["rows"] == "6001" and out["mismatches"] == "0" and out["worst_relative"] == "0"
    assert out["allocations_after_create"] == "0" and out["failed"] == "0"


@pytest.mark.slow
def test_the_replay_notices_a_changed_command(exported, tmp_path):
    name, res, so = exported
    lines = (res.out / "test" / "reference.csv").read_text().splitlines()
    col = 1 + len(res.interface.inputs)                      # out[0], the command (D-OSKIL's n2 is also a channel)
    row = lines[4000].split(",")
    row[col] = repr(float(row[col]) + 1e-6 * max(1.0, abs(float(row[col]))))
    lines[4000] = ",".join(row)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    code, out = _replay(so.parent / f"{res.prefix}_replay", bad)
    assert code == 1 and out["mismatches"] == "1"


@pytest.mark.slow
def test_each_exported_law_in_the_workbench_gives_the_laws_commands_exactly(exported):
    from mitigate import run
    name, res, _ = exported
    sc = load_scenario(MAIN)
    law = next(c for c in sc.controllers if c.name == name)
    sc = replace(sc, duration=30.0, controllers=(law, ControllerSpec("exported", "exported", {"path": str(res.out)})))
    a, b = run(sc).runs
    assert a.status.success and b.status.success
    assert b.result.controller_counts["fallbacks"] == a.result.controller_counts["fallbacks"] == 0
    assert set(a.result.commands) == set(b.result.commands)
    for k, v in a.result.commands.items():
        np.testing.assert_array_equal(v, b.result.commands[k])
    (cmd,) = [p.name for p in res.interface.outputs if not p.name.startswith("estimate:")]
    active = a.result.t >= 20.0
    assert np.ptp(a.result.commands[cmd][active]) > 0          # the law acted: the comparison is not vacuous


@pytest.mark.slow
def test_a_laws_gains_are_runtime_parameters(exported):
    name, res, _ = exported
    par, value = LAWS[name]
    p = {q.name: q for q in res.interface.params}
    assert par in p and p[par].unit and p[par].value != value
    rig = [q.name.startswith("rig:") for q in res.interface.params]
    assert rig == sorted(rig, reverse=True) and 0 < sum(rig) < len(rig)     # the rig's first, then the law's
    lib, other = ExportedLibrary(res.out), ExportedLibrary(res.out, {par: value})
    data = np.loadtxt(res.out / "test" / "reference.csv", delimiter=",", skiprows=1)
    n_in = len(res.interface.inputs)
    moved = []
    for row in data[2000:2600]:
        for lb in (lib, other):
            lb.in_buf[:] = row[1:1 + n_in]
            lb.step(row[0])
        moved.append(abs(lib.out_buf[0] - other.out_buf[0]))
    assert max(moved) > 1e-6
    with pytest.raises(ConfigError, match=r"params\.%s must be a finite number" % par):
        ExportedLibrary(res.out, {par: math.inf})


@pytest.mark.slow
def test_an_exported_law_refuses_parameters_its_core_cannot_run(tmp_path):
    """SoftSpeed's virtual drive needs an inertia: create() returns NULL for J_v = 0 (one line)."""
    res = export_controller(MAIN, "SoftSpeed", tmp_path / "ss", reference=None)
    names = [p.name for p in res.interface.params]
    assert names[-6:] == ["Kp", "Ki", "J_v", "band", "tau_torque", "tau_acc"]
    assert "SoftSpeed (omega_ref) with an EKF on rig 'rig3'" in (res.out / "include" / "softspeed.h").read_text()
    readme = (res.out / "README.md").read_text()
    assert "no solver library" in readme and "Z = 0.1099" in readme
    build_export(res.out, tool="make", build_type="Debug")
    ExportedLibrary(res.out)
    with pytest.raises(ConfigError, match=r"create\(\) refused its parameters"):
        ExportedLibrary(res.out, {"J_v": 0.0})


@pytest.mark.slow
def test_a_law_on_the_drill_string_exports_and_replays(tmp_path):
    """Another rig: D-OSKIL on the lab drill string read at the surface only (no bit encoder: the bit's
    speed is the exported EKF's; the weight on bit modulated around 200 N, a 2 ms DAQ), 12 s of which
    4 s under control."""
    from test_bench_sensors import _surface_only
    rig = _surface_only(tmp_path)
    (tmp_path / "sc.toml").write_text(DRILL.read_text().replace('model = "drillstring_motor"', f'model = "{rig}"'))
    sc = load_scenario(tmp_path / "sc.toml")
    sc = replace(sc, controllers=(ControllerSpec("D-OSKIL", "doskil", {}),))
    res = export_controller(sc, "D-OSKIL", tmp_path / "dk", reference=12.0)
    so = build_export(res.out, build_type="Debug")
    code, out = _replay(so.parent / f"{res.prefix}_replay", res.out / "test" / "reference.csv")
    assert code == 0 and out["rows"] == "6001" and out["mismatches"] == "0", out
    data = np.loadtxt(res.out / "test" / "reference.csv", delimiter=",", skiprows=1)
    wob = data[:, 1 + len(res.interface.inputs)]
    assert np.ptp(wob[data[:, 0] >= 8.0]) > 1.0                # it modulated the weight on bit
    assert "omega_bit" not in [p.name for p in res.interface.inputs]
    assert "and the estimate's omega_bit" in (res.out / "README.md").read_text()
