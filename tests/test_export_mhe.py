"""The MHE leaves the workbench too (issue 26): a scenario whose ``[estimator]`` is the MHE exports
its controller (here the NMPC, both inputs) with the MHE's compiled update (csrc/ss_mhe.c with its
EKF alongside: the C the workbench's MHE runs with ``compile = true``).  Built with CMake, the
library replays the workbench's own run -- commands and the MHE's estimates -- bit for bit, without
allocating after ``create``; its FMU (the same sources) passes fmpy's validation and gives the
library's outputs on that run."""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mitigate.export import build_export, export_controller
from mitigate.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
MAIN = ROOT / "scenarios" / "stick_slip_30rpm.toml"

pytestmark = pytest.mark.skipif(shutil.which("cmake") is None or shutil.which("cc") is None,
                                reason="needs a C compiler and cmake")


@pytest.mark.slow
def test_nmpc_with_the_mhe_exports_replays_the_workbench_bit_for_bit_and_its_fmu_agrees(tmp_path):
    sc = load_scenario(MAIN)
    sc = replace(sc, estimator={"kind": "mhe", "window": 10})
    # 24 s of the main scenario: stick-slip, the MHE's window filling and running, the NMPC from 20 s
    res = export_controller(sc, "NMPC", tmp_path / "x", reference=24.0, fmu=True, build_type="Debug")
    assert "ss_mhe.c" in " ".join(res.files) and "an MHE (window 10)" in (res.out / "README.md").read_text()
    so = build_export(res.out, build_type="Debug")
    r = subprocess.run([str(so.parent / f"{res.prefix}_replay"), str(res.out / "test" / "reference.csv")],
                       capture_output=True, text=True)
    words = r.stdout.split()
    out = {words[i]: words[i + 1] for i in range(0, len(words) - 1, 2)}
    assert r.returncode == 0, r.stdout + r.stderr
    assert out["rows"] == "2401" and out["mismatches"] == "0" and out["worst_relative"] == "0"
    assert out["allocations_after_create"] == "0" and out["failed"] == "0"
    outs = [p.name for p in res.interface.outputs]
    assert outs[:2] == ["omega_ref", "n2"] and any(n.startswith("estimate:twist") for n in outs)
    # the FMU: validated and simulated by fmpy on the reference run's inputs (tests/test_fmu.py's reading)
    fmpy = pytest.importorskip("fmpy")
    from fmpy.validation import validate_fmu
    from test_fmu import _fmu_outputs, _inputs
    fmu = res.out / f"{res.prefix}.fmu"
    assert validate_fmu(str(fmu)) == []
    ref = np.loadtxt(res.out / "test" / "reference.csv", delimiter=",", skiprows=1)
    r = fmpy.simulate_fmu(str(fmu), start_time=0.0, stop_time=ref[-1, 0], output_interval=sc.dt,
                          input=_inputs(res, ref), output=_fmu_outputs(res))
    n_in = len(res.interface.inputs)
    want = ref[:-1, 1 + n_in:]
    worst = max(float(np.max(np.abs(r[name][1:] - want[:, j]) / np.maximum(np.abs(want[:, j]), 1.0)))
                for j, name in enumerate(_fmu_outputs(res)))
    assert len(r) == len(ref) and worst <= 1e-9, worst
