"""Run every controller of a scenario and compare them.

From Python::

    from mitigate import run, make_scenario
    result = run("scenarios/stick_slip_30rpm.toml")            # or a Scenario object; writes nothing
    result.runs[0].metrics["sss"], result.runs[0].result.objective_speed
    result = run(scenario, out="out/")                         # also writes the report

:func:`run` validates the scenario completely (every controller's options, the estimator) and,
when ``out`` is given, checks the output folder (a usable folder, not in use by another command,
no output file existing unless ``force``) BEFORE any simulation starts.  Each controller runs in
its own worker process (:class:`mitigate.workers.WorkerPool`, spawn context; the scenario is
pickled, the CasADi Functions are rebuilt in the worker).

Failures are failures: a controller or estimator that raises (in its constructor, ``reset``,
``step`` or ``update``; also ``SystemExit``), returns NaN or the wrong type, or hangs past
``[control] timeout`` makes ITS run ``Status.FAILED`` with the reason (the exception's type and
first line) in the table, the JSON and the report; the other controllers' runs complete, and the
result's status is FAILED (the CLI exits 1).  A bad option is a ConfigError before anything runs
(exit 2).  Fallbacks on more than 1 % of a run's calls, or set-point chatter, make that run a
WARNING (``mitigate.closedloop``).

Files written to ``out`` as one set (:func:`models.files.output_set`: staged, then moved into
place; a killed run leaves ``out`` as it was):

- ``metrics.csv``, ``metrics.json``: :func:`mitigate.metrics.closed_loop_metrics` per controller;
- ``log_<controller>.csv``: the run as a log (measured channels, commands, true twists and speeds, the
  drive's current and voltage or its torque);
- ``timeseries_<controller>.png``, ``comparison.png``, ``phase.png``, ``metrics.png``;
- ``report.md`` linking them.
(A run that failed before its first sample has no log and no time series.)
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

from models.errors import ConfigError, PluginError, SolverFailure
from models.files import check_output_dir, output_set
from models.status import Outcome, Status
from mitigate.metrics import closed_loop_metrics, is_count, units
from mitigate.scenario import Scenario, load_scenario

__all__ = ["ControllerRun", "RunResult", "run", "run_scenario", "validate_scenario", "output_paths", "slugs"]


@dataclass(frozen=True)
class ControllerRun(Outcome):
    """One controller's run: its closed-loop result (:class:`mitigate.closedloop.ClosedLoopResult`;
    None when the run failed before its first sample) and metrics (NaN where there is nothing to measure)."""

    name: str
    kind: str
    result: object = field(repr=False)
    metrics: dict = field(default_factory=dict)
    elapsed: float = 0.0
    status: Status = Status.OK
    message: str = "ok"
    #: the tuning values the controller runs with, by name (:meth:`Controller.tuning_values`: SoftSpeed's
    #: Z, J_v, Kp, Ki, f_t; Z-Torque's gain, tau_hp; D-OSKIL's gain; the brake's gains), empty if none
    tuning: dict = field(default_factory=dict)
    #: the unit of each tuning value, by name (the controller's ``derived_units``)
    tuning_units: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RunResult(Outcome):
    """Every run of a scenario, and the files written (empty if none were asked for)."""

    scenario: Scenario = field(repr=False)
    runs: tuple
    files: dict
    elapsed: float
    status: Status = Status.OK
    message: str = "ok"

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
                             "elapsed_s": r.elapsed, "tuning": r.tuning,
                             "tuning_units": {k: r.tuning_units.get(k, "") for k in r.tuning},
                             "metrics": r.metrics} for r in self.runs]})


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
    (raises ConfigError naming the field of the first problem; a plug-in whose constructor
    fails otherwise is not a ConfigError: :func:`run` reports its run as FAILED)."""
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    _build_all(sc)
    return sc


def _build_all(sc: Scenario) -> dict[int, str]:
    """Build the estimator and every controller once: ConfigError for bad input; ``{index: why}``
    for the controllers whose run cannot start (a broken plug-in: PluginError)."""
    from estimators.base import EstimatorContext
    from estimators.online.factory import make_estimator
    from mitigate.controllers.factory import context_for, controller_class, make_controller

    if not sc.controllers:
        raise ConfigError(f"{sc.where}: controllers: missing; list at least one [[controllers]] table")
    # what every controller needs of the rig, all of it at once (not one run at a time)
    lacks: dict[str, list[str]] = {}
    for i, spec in enumerate(sc.controllers):
        ctx = context_for(sc, i)
        for item in ctx.missing(getattr(controller_class(spec.kind, ctx.where), "needs", ())):
            lacks.setdefault(item, []).append(ctx.where.removeprefix(f"{sc.where}: "))
    if lacks:
        raise ConfigError(f"{sc.where}: rig {sc.model.name!r} lacks what the controllers need: "
                          + "; ".join(f"{item}, for {', '.join(who)}" for item, who in lacks.items()))
    broken: dict[int, str] = {}
    try:
        make_estimator(sc.estimator, EstimatorContext(sc.model, sc.model_params, sc.dt, sc.sensors, None,
                                                      f"{sc.where}: estimator", sc.control.timeout))
    except PluginError as exc:
        broken = {i: f"estimator failed to build: {exc}" for i in range(len(sc.controllers))}
    for i, spec in enumerate(sc.controllers):
        try:
            make_controller(spec, context_for(sc, i))
        except PluginError as exc:
            broken.setdefault(i, f"controller failed to build: {exc}")
    return broken


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


def run_one(scenario: Scenario, index: int) -> ControllerRun:
    """Run controller ``index`` of ``scenario`` in closed loop (a worker's job): never raises for a
    failing controller or estimator -- the run is FAILED with the reason."""
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.workers import report

    t0 = time.perf_counter()
    spec = scenario.controllers[index]
    try:
        ctrl = make_controller(spec, context_for(scenario, index))
        res = run_closed_loop(scenario, ctrl, progress=report)
    except PluginError as exc:
        return failed_run(spec, f"{exc}", time.perf_counter() - t0)
    if len(res.t) < 2:                 # failed at its first sample (in reset): nothing to measure or log
        return failed_run(spec, res.message, time.perf_counter() - t0)
    met = closed_loop_metrics(res, scenario)
    if res.status is Status.FAILED:    # what it did until it failed is no result: only the counts stay
        met = {k: (v if is_count(k) else float("nan")) for k, v in met.items()}
    return ControllerRun(spec.name, spec.kind, res, met, time.perf_counter() - t0, res.status, res.message,
                         *tuning_of(ctrl))


def tuning_of(ctrl) -> tuple[dict[str, float], dict[str, str]]:
    """The controller's tuning values (:meth:`Controller.tuning_values`) and their units (its
    ``derived_units``); ({}, {}) for a plug-in that has none or whose method fails (a report line is
    not worth a FAILED run)."""
    from models import plugins
    timeout = getattr(getattr(ctrl, "context", None), "timeout", None)
    try:
        tv = dict(plugins.call(ctrl.tuning_values, timeout=timeout, what="tuning_values")) \
            if hasattr(ctrl, "tuning_values") else {}
        values = {str(k): float(v) for k, v in tv.items()}
        units = dict(getattr(ctrl, "derived_units", None) or {})
        return values, {k: str(units[k]) for k in values if k in units}
    except (PluginError, SolverFailure, TypeError, ValueError):
        return {}, {}


#: a worker that reports nothing for this long [s] (it reports every 100 samples; a controller stuck in C
#: code that the per-call timeout cannot interrupt) is killed and its run FAILED (mitigate.workers)
STALL_TIMEOUT = 600.0

def failed_run(spec, why: str, elapsed: float = 0.0) -> ControllerRun:
    """The FAILED run of a controller that could not run at all (no result; NaN metrics)."""
    return ControllerRun(spec.name, spec.kind, None, {k: float("nan") for k in units()}, elapsed,
                         Status.FAILED, why)


def _execute(sc: Scenario, jobs: int, progress: bool, broken: dict[int, str] | None = None) -> list[ControllerRun]:
    from tqdm import tqdm

    from mitigate.workers import WorkerPool

    broken = broken or {}
    n_ctrl = len(sc.controllers)
    todo = [i for i in range(n_ctrl) if i not in broken]
    done = {i: failed_run(sc.controllers[i], why) for i, why in broken.items()}
    bar = tqdm(total=len(todo) * sc.samples, desc=f"run {sc.name}", unit="step", disable=None if progress else True,
               leave=False)
    last: dict[int, int] = {}

    def tick(j, k):
        bar.update(k - last.get(j, 0))
        last[j] = k

    try:
        with WorkerPool(min(jobs, max(len(todo), 1)), stall_timeout=STALL_TIMEOUT) as pool:
            for out in pool.map(run_one, [(sc, i) for i in todo], on_progress=tick):
                i = todo[out.index]
                done[i] = out.value if out.ok else failed_run(sc.controllers[i], out.error)
    finally:
        bar.close()
    return [done[i] for i in range(n_ctrl)]


def _metrics_csv(runs) -> str:
    keys = units()
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["controller", "kind", "status", "message"] + [f"{k} [{u}]" for k, u in keys.items()])
    for r in runs:
        w.writerow([r.name, r.kind, r.status.value, r.message]
                   + [f"{float(r.metrics.get(k, math.nan)):.6g}" for k in keys])
    return buf.getvalue()


def write_outputs(result: RunResult, out, *, force: bool = False) -> dict[str, Path]:
    """Write the logs, plots, metrics and report of a run to ``out`` as one set (module docstring)."""
    sc = result.scenario
    files = output_paths(sc, out)
    with output_set(out, [p.name for p in files.values()], force=force) as w:
        _write_set(result, w)
    return _existing(files)


def _existing(files: dict[str, Path]) -> dict[str, Path]:
    return {k: p for k, p in files.items() if p.exists()}


def _write_set(result: RunResult, w) -> None:
    """Every file of a run into the output set ``w`` (:class:`models.files.OutputSet`)."""
    from mitigate.plots import plot_comparison, plot_metric_bars, plot_phase_portraits
    from mitigate.report import write_report
    from mitigate.timeplots import plot_run

    sc = result.scenario
    files = output_paths(sc, w.root)
    staged = {k: w.path(p.name) for k, p in files.items()}
    names = slugs([r.name for r in result.runs])
    for s, r in zip(names, result.runs):
        if r.result is None:      # failed before it ran: nothing to log or plot
            continue
        r.result.to_log().write_csv(staged[f"log_{s}"], overwrite=True)
        plot_run(sc, r.result, f"{sc.name}: {r.name} (true speeds and twists, applied inputs)",
                 staged[f"timeseries_{s}"])
    results = {r.name: r.result for r in result.runs if r.result is not None}
    plot_comparison(sc, results, f"{sc.name}: controllers compared", staged["comparison_png"])
    plot_phase_portraits(sc, results, f"{sc.name}: phase portraits (true states)", staged["phase_png"])
    plot_metric_bars({r.name: r.metrics for r in result.runs}, f"{sc.name}: metrics after control start",
                     staged["metrics_png"])
    w.write_text("metrics.csv", _metrics_csv(result.runs))
    payload = result.as_dict()
    payload["files"] = {k: str(v) for k, v in files.items()
                        if not (k.startswith(("log_", "timeseries_")) and not staged[k].exists())}
    payload["metric_units"] = units()
    w.write_text("metrics.json", json.dumps(payload, indent=2) + "\n")
    write_report(sc, result, files, names, staged["report"])


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
    ``files`` written, ``status`` (Status.OK; Status.WARNING when a run has warnings; Status.FAILED
    when a run failed or diverged, ``message`` naming each with its reason).

    Raises
    ------
    ConfigError : a bad scenario, a bad ``jobs``, an output folder that cannot be used (a file, not
        writable, in use by another command) or an existing output without ``force`` (nothing has
        been run or written then).
    """
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    t0 = time.perf_counter()
    if out is not None:
        check_output_dir(out)
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    broken = _build_all(sc)
    if out is None:
        return _summarise(sc, _execute(sc, jobs, progress, broken), {}, t0)
    files = output_paths(sc, out)
    with output_set(out, [p.name for p in files.values()], force=force) as w:
        result = _summarise(sc, _execute(sc, jobs, progress, broken), {}, t0)
        _write_set(result, w)
    return _summarise(sc, list(result.runs), _existing(files), t0, notes=w.notes)


def _summarise(sc, runs, files, t0, notes=()) -> RunResult:
    bad = [r for r in runs if not r.success]
    warn = [r for r in runs if r.status is Status.WARNING]
    status = Status.worst(runs)
    message = "; ".join(f"{r.name}: {r.message}" for r in bad + warn) or "ok"
    if notes:
        message = f"{message} ({'; '.join(notes)})"
    return RunResult(sc, tuple(runs), files, time.perf_counter() - t0, status, message)


def run_scenario(path, out, *, force: bool = False, jobs: int = 2, progress: bool = True) -> RunResult:
    """:func:`run` that always writes to ``out`` (the ``mitigate run`` command)."""
    return run(path, out=out, force=force, jobs=jobs, progress=progress)
