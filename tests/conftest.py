"""Test tiers (docs/testing.md) and the fixtures several test files share.

Every test carries one tier mark:

- ``unit``: one module against an analytic result, a printed number or a hand computation (a
  friction law, a log parser, the modal analysis, the option checks); no closed loop, no command;
- ``integration``: layers together -- a closed loop, identification on a simulated log, a command
  line, the benchmark, worker processes, packaging.

and, independently, ``slow`` when it takes more than about 10 s on the 2-core development machine
(marked in its file, beside the test).  ``python -m pytest -m "not slow"`` is the quick loop (under
2 minutes); CI runs everything.

A file is one tier unless a test in it says otherwise (``@pytest.mark.unit`` or
``@pytest.mark.integration`` beside the test); a file not listed in :data:`UNIT_FILES` is
``integration``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

import mitigate.cli as cli

# The compiled steps the tests build (NMPC, EKF, laws) are Debug builds (models.codegen.BUILD_TYPES):
# the generated C of an NMPC's step compiles about 3x faster unoptimised (measured 12 s against 40 s
# for one step's C; a cold test of the NMPC on a new rig 26 s against 61 s) and gives the same bits.
# Set in the environment, so the commands and scripts the tests start build Debug too; a developer's
# own STICKSLIP_BUILD_TYPE wins.  The Release build stays checked: benchmarks/bench_export.py --quick
# builds the NMPC's export Release and replays the workbench's run with 0 mismatches.
os.environ.setdefault("STICKSLIP_BUILD_TYPE", "Debug")

#: the test files whose every test is a unit test (the rest are integration tests)
UNIT_FILES = frozenset({
    "test_checks.py", "test_coulomb_cycle.py", "test_independent_rig3.py", "test_logs.py", "test_metrics.py",
    "test_modal.py", "test_models.py", "test_params.py", "test_plots.py", "test_readme_commands.py",
    "test_rig_checks.py", "test_rig_files.py", "test_sensors.py", "test_status.py", "test_tdms.py",
    "test_thesis_id.py", "test_thesis_tables.py",
})
TIERS = ("unit", "integration")

#: the files whose tests share no costly module fixture and are spread over the workers one test at a
#: time (the benchmark scripts' --quick runs: about 15 min of work together); every other file's
#: tests stay on one worker, so its module fixtures (an export, a compiled library) are built once
SPREAD_FILES = frozenset({"test_benchmark_scripts.py", "test_fuzz_faults.py"})


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Give every test its file's tier unless it carries one of its own, and its file's xdist group
    (``--dist loadgroup``) unless the file is in :data:`SPREAD_FILES`."""
    for item in items:
        if not any(item.get_closest_marker(t) for t in TIERS):
            tier = "unit" if item.path.name in UNIT_FILES else "integration"
            item.add_marker(getattr(pytest.mark, tier))
        if item.path.name not in SPREAD_FILES and item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(item.path.stem))
        if config.getvalue("loadgroup") if hasattr(config.option, "loadgroup") else False:
            _group_node_id(item)


def _group_node_id(item) -> None:
    """Put the test's xdist group in its node id (``<id>@<group>``: what ``--dist loadgroup``
    schedules by).  pytest-xdist does it by assigning ``item._nodeid``, which pytest 9 no longer
    reads (its node id lives in ``item._id``): every group was ignored and every test scheduled
    alone, so a file's module fixtures were built on both workers (measured: the quick benchmark
    the two readers share was run twice).  Done here where pytest keeps ``_id``; xdist's own does
    it where it does not."""
    if not hasattr(item, "_id"):
        return
    marks = item.get_closest_marker("xdist_group")
    name = (marks.args[0] if marks.args else marks.kwargs.get("name", "default")) if marks else None
    if name is None or item.nodeid.rsplit("@", 1)[-1] == name:
        return
    from _pytest.nodeid import coerce_node_id
    item._id = coerce_node_id(f"{item.nodeid}@{name}")


@pytest.fixture
def main():
    """The command line's entry point, ``main(argv) -> exit code`` (:func:`mitigate.cli.main`)."""
    return cli.main


@pytest.fixture(scope="session")
def nmpc_export(tmp_path_factory):
    """The main scenario's NMPC exported by the one command (``mitigate export ... --fmu --rt 3
    --reference 30 --build-type Debug --json``: export with the FMU, build, replay the 30 s reference,
    3 s of the real-time driver), once for tests/test_export.py and tests/test_fmu.py (both in the
    xdist group ``nmpc_export``: one worker builds it once).

    Returns a namespace: ``out`` (the export folder), ``prefix``, ``interface``, ``cli`` (the
    command's JSON), ``library`` (the built library), ``fmu`` (the FMU's path), ``reference_rows`` and
    ``ref`` (``test/reference.csv`` as an array).
    """
    from mitigate.export.interface import Interface, Port
    root = Path(__file__).resolve().parent.parent
    out = tmp_path_factory.mktemp("nmpc_export") / "nmpc"
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-m", "mitigate.cli", "export", str(root / "scenarios" / "stick_slip_30rpm.toml"),
                        "--controller", "NMPC", "--out", str(out), "--reference", "30", "--fmu", "--rt", "3",
                        "--build-type", "Debug", "--json"],
                       capture_output=True, text=True, timeout=1800, env=env, cwd=str(root))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    doc = json.loads(r.stdout)
    itf = Interface(doc["prefix"], tuple(Port(n, u) for n, u in doc["inputs"]),
                    tuple(Port(n, u) for n, u in doc["outputs"]), tuple(Port(n, u, v) for n, u, v in doc["params"]))
    import numpy as np
    ref = np.loadtxt(out / "test" / "reference.csv", delimiter=",", skiprows=1)
    return SimpleNamespace(out=out, prefix=doc["prefix"], interface=itf, cli=doc, library=Path(doc["library"]),
                           fmu=out / f"{doc['prefix']}.fmu", reference_rows=doc["reference_rows"], ref=ref)
