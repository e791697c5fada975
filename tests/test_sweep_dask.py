"""The Dask path of ``mitigate sweep``: chunks sent to a (loopback) distributed cluster give the
same results as the local run, and the local path does not import Dask."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mitigate.scenario import load_scenario
from mitigate.sweep import SweepStore, options_from_scenario, parse_axis, plan_sweep, run_sweep

import distributed

ROOT = Path(__file__).resolve().parents[1]
LEAD = ROOT / "scenarios" / "sweep_leadscrew.toml"


def _plan():
    sc = load_scenario(LEAD)
    o = options_from_scenario(sc, duration=0.06, settle=0.03, start="both", chunk=3, backend="vm")
    return plan_sweep(sc, [parse_axis("omega_drive=30:60:2"), parse_axis("axial_force=80:320:4")], o)


def test_dask_cluster_matches_local(tmp_path):
    plan = _plan()
    local = run_sweep(plan, SweepStore(tmp_path / "local", plan.definition()), workers=1, progress=False,
                      stability=False)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        # through the --scheduler address, exactly as the CLI does
        remote = run_sweep(plan, SweepStore(tmp_path / "dask", plan.definition()),
                           scheduler=cluster.scheduler_address, progress=False, stability=False)
    assert remote.computed == local.computed == 6
    for start in ("rest", "sliding"):
        for k in ("amplitude", "severity", "stuck_fraction", "limit_cycle"):
            assert np.array_equal(remote.maps[start][k], local.maps[start][k], equal_nan=True), (start, k)
    assert np.any(local.maps["rest"]["limit_cycle"] == 1)  # the grid is not trivially quiet


@pytest.mark.slow
def test_local_sweep_does_not_import_dask(tmp_path):
    # only the sweep command is registered (the others are migrated in other branches)
    code = ("import sys; import mitigate.cli as cli; "
            f"rc = cli.main(['sweep', {str(LEAD)!r}, '--vary', 'axial_force=80:320:2', '--duration', '0.02', "
            f"'--workers', '1', '--backend', 'vm', '--no-stability', '--no-progress', '--start', 'rest', "
            f"'--out', {str(tmp_path / 'o')!r}]); "
            "assert rc == 0, rc; print('dask' in sys.modules, 'distributed' in sys.modules)")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().splitlines()[-1] == "False False"


def test_bad_scheduler_is_one_line_error(tmp_path, monkeypatch, capsys):
    import mitigate.cli as cli
    rc = cli.main(["sweep", str(LEAD), "--vary", "axial_force=80:320:2", "--duration", "0.02", "--no-stability",
               "--scheduler", "tcp://127.0.0.1:1", "--scheduler-timeout", "1", "--out", str(tmp_path / "o")])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "scheduler tcp://127.0.0.1:1: cannot connect" in err
    assert not (tmp_path / "o").exists()
