"""Stick-slip mitigation: controllers, the closed loop, the scenario runner, metrics, sweeps, the benchmark.

The Python API (the ``mitigate`` CLI is a thin layer over it)::

    from mitigate import make_scenario, run
    sc = make_scenario(name="demo", model="rig3", duration=60, inputs={"omega_ref": "30 rpm", "n1": 20},
                       controllers=["pi", {"name": "NMPC", "kind": "nmpc"}], control_start=20)
    result = run(sc)                                  # objects; nothing is written
    result.run("NMPC").metrics["sss"]
"""

import models.portable  # noqa: F401 - first: it pins OpenBLAS's kernels before numpy loads them

from mitigate.benchmark import BenchmarkResult, Suite, load_suite, run_benchmark, write_benchmark
from mitigate.closedloop import ClosedLoopResult, run_closed_loop
from mitigate.controllers.base import Action, ControlContext, Controller
from mitigate.controllers.factory import CONTROLLER_KINDS, context_for, make_controller
from mitigate.metrics import MetricOptions, closed_loop_metrics, moving_severity, severity, time_to_suppress
from mitigate.runner import ControllerRun, RunResult, run, run_scenario
from mitigate.scenario import ControllerSpec, Scenario, load_scenario, make_scenario, parse_scenario
from mitigate.sweep import SweepResult, sweep
from mitigate.tune import TuneResult, tune

__all__ = [
    "Action", "ControlContext", "Controller", "CONTROLLER_KINDS", "context_for", "make_controller",
    "ClosedLoopResult", "run_closed_loop",
    "MetricOptions", "closed_loop_metrics", "moving_severity", "severity", "time_to_suppress",
    "ControllerRun", "RunResult", "run", "run_scenario",
    "ControllerSpec", "Scenario", "load_scenario", "make_scenario", "parse_scenario",
    "SweepResult", "sweep",
    "BenchmarkResult", "Suite", "load_suite", "run_benchmark", "write_benchmark",
    "TuneResult", "tune",
]
