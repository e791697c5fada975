"""Run every controller of a scenario and compare them.

From Python::

    from mitigate import run, make_scenario
    result = run("scenarios/stick_slip_30rpm.toml")            # or a Scenario object; writes nothing
    result.runs[0].metrics["sss"], result.runs[0].result.objective_speed
    result = run(scenario, out="out/")                         # also writes the report

:func:`run` validates the scenario completely (every controller's options, the estimator) and,
when ``out`` is given, checks that no output file exists (unless ``force``) BEFORE any
simulation starts.  Each controller runs in its own worker process
(``concurrent.futures.ProcessPoolExecutor``, spawn context; the scenario is pickled, the
CasADi Functions are rebuilt in the worker).  Files written to ``out`` (atomically):

- ``metrics.csv``, ``metrics.json``: :func:`mitigate.metrics.closed_loop_metrics` per controller;
- ``log_<controller>.csv``: the run as a log (measured channels, commands, true twists and speeds);
- ``timeseries_<controller>.png``, ``comparison.png``, ``phase.png``, ``metrics.png``;
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

from models.errors import ConfigError
from models.files import atomic_write_text, refuse_overwrite
from models.status import Status
from mitigate.metrics import METRIC_UNITS, closed_loop_metrics
from mitigate.scenario import Scenario, load_scenario

__all__ = ["ControllerRun", "RunResult", "run", "run_scenario", "validate_scenario", "output_paths", "slugs",
           "TABLE_COLUMNS"]

#: (metric key, column header) of the terminal table
TABLE_COLUMNS = (
    ("sss", "SSS"), ("sss_final", "SSS last"), ("time_to_suppress", "t supp [s]"), ("stuck_fraction", "stuck"),
    ("mean_speed", "mean w"), ("speed_error_rms", "w err rms"), ("pin_work", "pin W [J]"),
    ("plan_median_ms", "plan med [ms]"), ("plan_p95_ms", "plan p95 [ms]"), ("controller_fallbacks", "fallbacks"),
    ("estimator_fallbacks", "est fb"),
)


@dataclass(frozen=True)
class ControllerRun:
    """One controller's run: its closed-loop result (:class:`mitigate.closedloop.ClosedLoopResult`)
    and metrics."""

    name: str
    kind: str
    result: object = field(repr=False)
    metrics: dict = field(default_factory=dict)
    elapsed: float = 0.0
    status: Status = Status.OK
    message: str = "ok"

    @property
    def success(self) -> bool:
        return self.status.success


@dataclass(frozen=True)
class RunResult:
    """Every run of a scenario, and the files written (empty if none were asked for)."""

    scenario: Scenario = field(repr=False)
    runs: tuple
    files: dict
    elapsed: float
    status: Status = Status.OK
    message: str = "ok"

    @property
    def success(self) -> bool:
        return self.status.success

    def run(self, name: str) -> ControllerRun:
        """The run of the controller named ``name``."""
        for r in self.runs:
            if r.name == name:
                return r
        raise ConfigError(f"no controller named {name!r}; controllers: {', '.join(r.name for r in self.runs)}")

    def table(self) -> list[dict]:
        """One row per controller: name, kind, status and every metric."""
        return [{"controller": r.name, "kind": r.kind, "status": r.status.value, **r.metrics} for r in self.runs]

    def as_dict(self) -> dict:
        from mitigate.cliutil import to_jsonable
        obs = None
        if self.runs and getattr(self.runs[0].result, "observability", None) is not None:
            o = self.runs[0].result.observability
            obs = o.as_dict() if hasattr(o, "as_dict") else str(o)
        return to_jsonable({
            "scenario": self.scenario.name, "status": self.status.value, "message": self.message,
            "elapsed_s": self.elapsed, "files": {k: str(v) for k, v in self.files.items()},
            "observability": obs, "messages": list(self.scenario.messages),
            "controllers": [{"name": r.name, "kind": r.kind, "status": r.status.value, "message": r.message,
                             "elapsed_s": r.elapsed, "metrics": r.metrics} for r in self.runs]})


def slugs(names) -> list[str]:
    """File-name-safe, unique versions of the controller names."""
    out = []
    for i, n in enumerate(names):
        s = re.sub(r"[^a-z0-9]+", "_", n.lower()).strip("_") or f"controller{i}"
        if s in out:
            s = f"{s}_{i}"
        out.append(s)
    return out


def validate_scenario(scenario) -> Scenario:
    """The scenario (loaded if a path), with every controller and the estimator built once
    (raises ConfigError naming the field of the first problem)."""
    from estimators.base import EstimatorContext
    from estimators.online.factory import make_estimator
    from mitigate.controllers.factory import make_controller

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    if not sc.controllers:
        raise ConfigError(f"{sc.where}: controllers: missing; list at least one [[controllers]] table")
    make_estimator(sc.estimator, EstimatorContext(sc.model, sc.model_params, sc.dt, sc.sensors, None,
                                                  f"{sc.where}: estimator"))
    for i, spec in enumerate(sc.controllers):
        make_controller(spec, sc, i)
    return sc


def output_paths(scenario: Scenario, out) -> dict[str, Path]:
    """Every file :func:`run` writes to ``out``, by key."""
    out = Path(out)
    files = {"metrics_csv": out / "metrics.csv", "metrics_json": out / "metrics.json", "report": out / "report.md",
             "comparison_png": out / "comparison.png", "phase_png": out / "phase.png",
             "metrics_png": out / "metrics.png"}
    for s in slugs([c.name for c in scenario.controllers]):
        files[f"log_{s}"] = out / f"log_{s}.csv"
        files[f"timeseries_{s}"] = out / f"timeseries_{s}.png"
    return files


def run_one(scenario: Scenario, index: int, queue=None) -> ControllerRun:
    """Run controller ``index`` of ``scenario`` in closed loop (a worker's job)."""
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import make_controller

    t0 = time.perf_counter()
    spec = scenario.controllers[index]
    ctrl = make_controller(spec, scenario, index)
    cb = (lambda k: queue.put((index, k))) if queue is not None else None
    res = run_closed_loop(scenario, ctrl, progress=cb)
    met = closed_loop_metrics(res, scenario)
    return ControllerRun(spec.name, spec.kind, res, met, time.perf_counter() - t0, res.status, res.message)


def _init_worker():
    import os
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def _execute(sc: Scenario, jobs: int, progress: bool) -> list[ControllerRun]:
    from tqdm import tqdm

    n_ctrl = len(sc.controllers)
    bar = tqdm(total=n_ctrl * sc.samples, desc=f"run {sc.name}", unit="step", disable=None if progress else True,
               leave=False)
    done, last = {}, {}

    def tick(i, k):
        bar.update(k - last.get(i, 0))
        last[i] = k

    try:
        if jobs <= 1 or n_ctrl == 1:
            class _Q:
                def put(self, item):
                    tick(*item)
            for i in range(n_ctrl):
                done[i] = run_one(sc, i, _Q())
        else:
            ctx = mp.get_context("spawn")
            with ctx.Manager() as mgr, ProcessPoolExecutor(max_workers=min(jobs, n_ctrl), mp_context=ctx,
                                                            initializer=_init_worker) as ex:
                q = mgr.Queue()
                futs = {ex.submit(run_one, sc, i, q): i for i in range(n_ctrl)}
                while True:
                    try:
                        tick(*q.get(timeout=0.2))
                    except Empty:
                        pass
                    if all(f.done() for f in futs):
                        break
                for f, i in futs.items():
                    done[i] = f.result()   # a worker exception (a bug) propagates
    finally:
        bar.close()
    return [done[i] for i in range(n_ctrl)]


def _metrics_csv(runs) -> str:
    keys = list(METRIC_UNITS)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["controller", "kind", "status", "message"] + [f"{k} [{METRIC_UNITS[k]}]" for k in keys])
    for r in runs:
        w.writerow([r.name, r.kind, r.status.value, r.message] + [f"{float(r.metrics[k]):.6g}" for k in keys])
    return buf.getvalue()


def write_outputs(result: RunResult, out, *, force: bool = False) -> dict[str, Path]:
    """Write the logs, plots, metrics and report of a run to ``out`` (see module docstring)."""
    from mitigate.plots import plot_comparison, plot_metric_bars, plot_phase_portraits
    from mitigate.report import write_report
    from mitigate.timeplots import plot_run

    sc = result.scenario
    files = output_paths(sc, out)
    for p in files.values():
        refuse_overwrite(p, force, "force")
    Path(out).mkdir(parents=True, exist_ok=True)
    names = slugs([r.name for r in result.runs])
    for s, r in zip(names, result.runs):
        r.result.to_log().write_csv(files[f"log_{s}"], overwrite=True)
        plot_run(sc, r.result, f"{sc.name}: {r.name} (true speeds and twists, applied inputs)",
                 files[f"timeseries_{s}"])
    results = {r.name: r.result for r in result.runs}
    plot_comparison(sc, results, f"{sc.name}: controllers compared", files["comparison_png"])
    plot_phase_portraits(sc, results, f"{sc.name}: phase portraits (true states)", files["phase_png"])
    plot_metric_bars({r.name: r.metrics for r in result.runs}, f"{sc.name}: metrics after control start",
                     files["metrics_png"])
    atomic_write_text(files["metrics_csv"], _metrics_csv(result.runs), overwrite=True)
    payload = result.as_dict()
    payload["files"] = {k: str(v) for k, v in files.items()}
    payload["metric_units"] = METRIC_UNITS
    atomic_write_text(files["metrics_json"], json.dumps(payload, indent=2) + "\n", overwrite=True)
    write_report(sc, result, files, names, files["report"])
    return files


def run(scenario, *, out=None, force: bool = False, jobs: int = 2, progress: bool = False) -> RunResult:
    """Run every controller of a scenario in closed loop and compare them.

    Parameters
    ----------
    scenario : a :class:`mitigate.scenario.Scenario` or the path of a scenario TOML file
    out : folder to write the report, plots, logs and metrics into (None: write nothing)
    force : replace existing output files
    jobs : worker processes (1: run in this process)
    progress : show a progress bar (on stderr, only on a terminal)

    Returns
    -------
    RunResult : ``runs`` (one :class:`ControllerRun` each: ``result``, ``metrics``, ``status``),
    ``files`` written, ``status`` (Status.OK, or Status.FAILED when a run diverged or failed).

    Raises
    ------
    ConfigError : a bad scenario, a bad ``jobs``, or an existing output without ``force``
        (nothing has been run or written then).
    """
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    t0 = time.perf_counter()
    sc = validate_scenario(scenario)
    if out is not None:
        for p in output_paths(sc, out).values():
            refuse_overwrite(p, force, "force")
    runs = _execute(sc, jobs, progress)
    bad = [r for r in runs if not r.success]
    status = Status.OK if not bad else Status.FAILED
    message = "ok" if not bad else "; ".join(f"{r.name}: {r.message}" for r in bad)
    result = RunResult(sc, tuple(runs), {}, time.perf_counter() - t0, status, message)
    if out is not None:
        files = write_outputs(result, out, force=True)
        result = RunResult(sc, tuple(runs), files, time.perf_counter() - t0, status, message)
    return result


def run_scenario(path, out, *, force: bool = False, jobs: int = 2, progress: bool = True) -> RunResult:
    """:func:`run` that always writes to ``out`` (the ``mitigate run`` command)."""
    return run(path, out=out, force=force, jobs=jobs, progress=progress)
