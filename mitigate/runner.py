"""Run every controller of a scenario, in parallel processes, and write the comparison.

:func:`run_scenario` validates the scenario completely (file, every controller's
options, the estimator) and checks that no output file exists (unless ``force``)
BEFORE any simulation starts.  Each controller runs in its own worker process
(``concurrent.futures.ProcessPoolExecutor``, spawn context): CasADi objects cannot be
pickled, so a worker rebuilds the scenario, estimator and controller from the scenario
PATH and the controller index.  Outputs (all written atomically) in ``out``:

- ``metrics.csv``, ``metrics.json``: :func:`mitigate.metrics.closed_loop_metrics` per controller;
- ``log_<controller>.csv``: the run in the CSV log format (measured channels + true twists);
- ``timeseries_<controller>.png`` (per controller), ``comparison.png`` (overlaid),
  ``phase.png`` (omega1 vs twist12), ``metrics.png`` (bars);
- ``report.md`` linking them.
"""

from __future__ import annotations

import csv
import io
import json
import multiprocessing as mp
import re
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from queue import Empty

import numpy as np

from mitigate.cliutil import check_outputs, to_jsonable
from mitigate.metrics import METRIC_UNITS, closed_loop_metrics
from mitigate.scenario import Scenario, load_scenario
from models.errors import ConfigError
from models.logs import atomic_write_text

__all__ = ["ControllerRun", "RunSummary", "validate_scenario", "output_paths", "run_one", "run_scenario",
           "slugs", "TABLE_COLUMNS"]

#: (metric key, column header) of the terminal table
TABLE_COLUMNS = (
    ("sss", "SSS"), ("sss_final", "SSS last"), ("stuck_fraction", "stuck"), ("mean_omega1", "mean w1"),
    ("rms_twist12", "rms twist"), ("motor_torque_std", "torque std"), ("friction_work_pin2", "W pin2 [J]"),
    ("plan_median_ms", "plan med [ms]"), ("plan_p95_ms", "plan p95 [ms]"), ("controller_fallbacks", "fallbacks"),
    ("estimator_fallbacks", "est fb"),
)


@dataclass(frozen=True)
class ControllerRun:
    """One controller's run: its closed-loop result and metrics."""

    name: str
    kind: str
    result: object = field(repr=False)
    metrics: dict = field(default_factory=dict)
    elapsed: float = 0.0
    status: str = "ok"
    success: bool = True


@dataclass(frozen=True)
class RunSummary:
    """All runs of a scenario and the files written."""

    scenario: str
    out: str
    runs: tuple
    files: dict
    elapsed: float
    status: str = "ok"
    success: bool = True

    def as_dict(self) -> dict:
        return {"scenario": self.scenario, "out": self.out, "status": self.status, "success": self.success,
                "elapsed_s": self.elapsed, "files": {k: str(v) for k, v in self.files.items()},
                "controllers": [{"name": r.name, "kind": r.kind, "status": r.status, "success": r.success,
                                 "elapsed_s": r.elapsed, "metrics": r.metrics} for r in self.runs]}


def slugs(names) -> list[str]:
    """File-name-safe, unique versions of the controller names."""
    out = []
    for i, n in enumerate(names):
        s = re.sub(r"[^a-z0-9]+", "_", n.lower()).strip("_") or f"controller{i}"
        if s in out:
            s = f"{s}_{i}"
        out.append(s)
    return out


def validate_scenario(path) -> Scenario:
    """Load the scenario and build every controller and the estimator once (raises ConfigError)."""
    from estimators.factory import make_estimator
    from mitigate.controllers.factory import make_controller

    sc = load_scenario(path)
    src = Path(sc.path).name
    if sc.model != "rig3":
        raise ConfigError(f"{src}: scenario.model must be 'rig3' for 'mitigate run', got {sc.model!r}")
    if not sc.controllers:
        raise ConfigError(f"{src}: controllers: missing; list at least one [[controllers]] table")
    make_estimator(sc.estimator, sc.model_params, sc.sensors, sc.dt, where=f"{src}: estimator")
    for i, spec in enumerate(sc.controllers):
        make_controller(spec, sc, i)
    return sc


def output_paths(scenario: Scenario, out) -> dict[str, Path]:
    """Every file :func:`run_scenario` writes, by key."""
    out = Path(out)
    files = {"metrics_csv": out / "metrics.csv", "metrics_json": out / "metrics.json", "report": out / "report.md",
             "comparison_png": out / "comparison.png", "phase_png": out / "phase.png",
             "metrics_png": out / "metrics.png"}
    for s in slugs([c.name for c in scenario.controllers]):
        files[f"log_{s}"] = out / f"log_{s}.csv"
        files[f"timeseries_{s}"] = out / f"timeseries_{s}.png"
    return files


def run_one(path: str, index: int, queue=None) -> ControllerRun:
    """Worker: rebuild the scenario and controller ``index`` from ``path`` and run the closed loop."""
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import make_controller

    t0 = time.perf_counter()
    sc = load_scenario(path)
    spec = sc.controllers[index]
    ctrl = make_controller(spec, sc, index)
    cb = (lambda k: queue.put((index, k))) if queue is not None else None
    res = run_closed_loop(sc, ctrl, progress=cb)
    met = closed_loop_metrics(res, sc.plant_params)
    return ControllerRun(spec.name, spec.kind, res, met, time.perf_counter() - t0, res.status, res.success)


def _execute(sc: Scenario, jobs: int, progress: bool) -> list[ControllerRun]:
    from tqdm import tqdm

    n_ctrl = len(sc.controllers)
    total = n_ctrl * int(round(sc.duration / sc.dt))
    bar = tqdm(total=total, desc=f"run {sc.name}", unit="step", disable=None if progress else True, leave=False)
    done = {}
    try:
        if jobs <= 1 or n_ctrl == 1:
            last = {}

            class _Q:
                def put(self, item):
                    i, k = item
                    bar.update(k - last.get(i, 0))
                    last[i] = k
            for i in range(n_ctrl):
                done[i] = run_one(sc.path, i, _Q())
        else:
            ctx = mp.get_context("spawn")
            with ctx.Manager() as mgr, ProcessPoolExecutor(max_workers=min(jobs, n_ctrl), mp_context=ctx) as ex:
                q = mgr.Queue()
                futs = {ex.submit(run_one, sc.path, i, q): i for i in range(n_ctrl)}
                last = {}
                while True:
                    try:
                        i, k = q.get(timeout=0.2)
                        bar.update(k - last.get(i, 0))
                        last[i] = k
                    except Empty:
                        pass
                    if all(f.done() for f in futs):
                        break
                for f, i in futs.items():
                    done[i] = f.result()   # a worker exception (a bug) propagates to the CLI
    finally:
        bar.close()
    return [done[i] for i in range(n_ctrl)]


def _metrics_csv(runs) -> str:
    keys = list(METRIC_UNITS)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["controller", "kind", "success", "status"] + [f"{k} [{METRIC_UNITS[k]}]" for k in keys])
    for r in runs:
        w.writerow([r.name, r.kind, r.success, r.status] + [f"{float(r.metrics[k]):.6g}" for k in keys])
    return buf.getvalue()


def run_scenario(path, out, *, force: bool = False, jobs: int = 2, progress: bool = True) -> RunSummary:
    """Validate, check outputs, run all controllers and write every output (see module docstring).

    Parameters
    ----------
    path : scenario TOML path
    out : output folder
    force : overwrite existing outputs
    jobs : worker processes (1: run in this process)
    progress : show a tqdm progress bar (on stderr, only on a terminal)

    Raises
    ------
    ConfigError : bad scenario or existing outputs (nothing has been run or written then).
    """
    from mitigate.plots import plot_comparison, plot_metric_bars, plot_phase_portraits
    from mitigate.report import write_report
    from mitigate.timeplots import plot_time_histories

    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"--jobs must be an integer >= 1, got {jobs!r}")
    t0 = time.perf_counter()
    sc = validate_scenario(path)
    files = output_paths(sc, out)
    check_outputs(files.values(), force)
    runs = _execute(sc, jobs, progress)
    Path(out).mkdir(parents=True, exist_ok=True)
    names = [r.name for r in runs]
    for s, r in zip(slugs(names), runs):
        r.result.to_log().write_csv(files[f"log_{s}"], overwrite=True)
        res = r.result
        ch = {c: res.y[c] for c in ("omega1", "omega2", "omega3", "motor_torque", "n1", "n2") if c in res.y}
        ch.update(omega1=res.state("omega1"), omega2=res.state("omega2"), omega3=res.state("omega3"),
                  omega_ref=res.action_omega_ref, twist12=res.state("phi12"), twist23=res.state("phi23"),
                  n2=res.input("n2"))
        plot_time_histories(res.t, ch, f"{sc.name}: {r.name} (true speeds/twists, applied N2, measured torque)",
                            files[f"timeseries_{s}"])
    results = {r.name: r.result for r in runs}
    mets = {r.name: r.metrics for r in runs}
    plot_comparison(results, f"{sc.name}: controllers compared", files["comparison_png"])
    plot_phase_portraits(results, f"{sc.name}: phase portraits (true states)", files["phase_png"])
    plot_metric_bars(mets, f"{sc.name}: metrics after control start", files["metrics_png"])
    atomic_write_text(files["metrics_csv"], _metrics_csv(runs), overwrite=True)
    ok = all(r.success for r in runs)
    summary = RunSummary(sc.name, str(out), tuple(runs), files, time.perf_counter() - t0,
                         "ok" if ok else "some runs failed: " + "; ".join(f"{r.name}: {r.status}" for r in runs
                                                                          if not r.success), ok)
    payload = summary.as_dict()
    payload["metric_units"] = METRIC_UNITS
    atomic_write_text(files["metrics_json"], json.dumps(to_jsonable(payload), indent=2) + "\n", overwrite=True)
    write_report(sc, summary, files, files["report"])
    return summary
