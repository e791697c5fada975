"""Tuning any controller's declared tunables on a scenario, with a fixed budget (Optuna).

From Python::

    from mitigate import tune
    r = tune("scenarios/benchmark/established.toml", "softspeed", budget=30, out="out/tune")
    r.best_options            # the controller's options table with the tuned values
    r.held_out                # the score and ranked metrics of the defaults and of the tuned values on other seeds

A trial runs the controller with one set of values at ``phases`` TUNING switch-on phases and
``seeds`` TUNING noise seeds, and scores the mean of the declared score that follows the ranking's
order (:func:`mitigate.benchmark.score.run_score`: whether the run did the job, then what the rig
sees, the time to suppress, the hardware loads and the effort).  The tuning phases lie halfway
between the benchmark's (``grid`` phases at ``k T / grid``: the tuning's are at ``(m + 1/2) T / grid``),
and its seeds are other seeds (:data:`TUNING_SEED_OFFSET`): a tuned controller is scored on phases
and seeds it never saw.  The first trial is the shipped options.  Optuna's TPE sampler (seeded,
multivariate, its random start-up trials a fifth of the budget: :func:`startup_trials`) proposes the
rest; a median pruner stops a trial whose running mean is worse than the median of earlier trials at
the same run.  The study lives in a journal file under ``out``
(:class:`optuna.storages.JournalStorage`): an interrupted tuning continues where it stopped, and
``n_jobs`` processes share it (each with its own sampler seed; with one process the study is
reproducible, with several the order of the trials depends on timing).  With one process the
sampler is seeded again before every trial by the seed and the trials finished so far, so a study
that was interrupted and continued proposes what it would have proposed uninterrupted.
:func:`tune_suite` (``mitigate benchmark --tuned``) runs every study in one process, and several
studies at a time: its tuned values are the same on any machine and load.  The result is then reported on HELD-OUT seeds that neither the
tuning nor the benchmark (seeds 0 .. S-1) uses, at the benchmark's own phases.

With ``validate = V > 0`` the choice is not the best tuning score: the :data:`VALIDATION_CANDIDATES`
best trials and the shipped options are run at ``V`` VALIDATION phases (quarter points of the grid,
:func:`validation_phases`, disjoint from the benchmark's and the tuning's) on their own seeds
(:data:`VALIDATION_SEED_OFFSET`), and the candidate with the lowest mean score there wins; a tie keeps
the shipped options.  Tuning on two runs over-fits: a law that beats the shipped one only in the
score's tie-break terms can sit at the edge of the speed band.  The validation runs see more of
that edge (measured on the suite's SoftSpeed: job done on 10 of 14 scenarios against 8 without it,
13 with the shipped options; BENCHMARKS.md): it helps, it does not close the gap, because the score's
job-done term is binary and cannot see how close to the band a run came.

Each tunable is a multiple of its natural unit on the rig (:mod:`mitigate.tunables`); the tuned
options are stored in SI, the multiples beside them.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from models.errors import ConfigError
from models.status import Outcome, Status
from mitigate.benchmark.plan import Reference, RunTask, reference_run, run_seed, slug
from mitigate.metrics import MetricOptions, ranked
from mitigate.record import RunRecord
from mitigate.tunables import set_option

__all__ = ["TuneResult", "tune", "tune_suite", "startup_trials", "tuning_phases", "settings", "TUNING_SEED_OFFSET",
           "HELD_OUT_SEED_OFFSET", "FAILED_SCORE", "DEFAULT_GRID", "validation_phases", "VALIDATION_SEED_OFFSET",
           "VALIDATION_CANDIDATES"]

#: seed indices of the tuning runs and of the held-out report (the benchmark uses 0 .. S-1)
TUNING_SEED_OFFSET = 100
HELD_OUT_SEED_OFFSET = 200
VALIDATION_SEED_OFFSET = 150
#: the best trials (by tuning score) that the validation runs beside the shipped options
VALIDATION_CANDIDATES = 3
#: the score of a run the rig cannot host (:data:`mitigate.benchmark.score.NOT_APPLICABLE`)
FAILED_SCORE = 10.0
#: the benchmark's switch-on phases the tuning keeps away from when none are given (the suite's default)
DEFAULT_GRID = 6


def startup_trials(budget: int) -> int:
    """TPE's random start-up trials for a budget: a fifth of it, 2 to 20 (Optuna's default of 10 made a
    budget of 12 a seeded random search)."""
    return max(2, min(20, round(budget / 5)))


def tuning_phases(phases: int, grid: int) -> list[float]:
    """The tuning's switch-on phases as fractions of the stick-slip period: ``phases`` of the midpoints
    ``(m + 1/2) / grid`` between the benchmark's ``grid`` phases ``k / grid``, spread evenly.

    Raises
    ------
    ConfigError : more tuning phases than the grid has midpoints.
    """
    if phases > grid:
        raise ConfigError(f"phases must be <= the benchmark's {grid} phases (the tuning's lie between them), "
                          f"got {phases}")
    return [(math.floor(k * grid / phases) + 0.5) / grid for k in range(phases)]


def validation_phases(n: int, grid: int, what: str = "validate") -> list[float]:
    """The validation's switch-on phases as fractions of the stick-slip period: ``n`` of the quarter
    points ``(m + 1/4) / grid`` and ``(m + 3/4) / grid``, spread evenly (never a benchmark phase
    ``k / grid`` nor a tuning phase ``(m + 1/2) / grid``).

    Raises
    ------
    ConfigError : more validation phases than the grid has quarter points (``2 grid``); ``what``
        names the argument in the message.
    """
    pts = sorted((m + q) / grid for m in range(grid) for q in (0.25, 0.75))
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= len(pts):
        raise ConfigError(f"{what} must be an integer from 0 to {len(pts)} (twice the benchmark's {grid} phases), "
                          f"got {n!r}")
    return [pts[math.floor(k * len(pts) / n)] for k in range(n)]


def settings(budget: int, phases: int, seeds: int, grid: int, seed: int = 0, validate: int = 0) -> dict:
    """How a suite was tuned (stored with the results)."""
    from mitigate.benchmark.score import describe
    out = {"budget": budget, "sampler": f"Optuna TPE (seed {seed}, multivariate, {startup_trials(budget)} random "
                                        f"start-up trials; the first trial the shipped options; median pruning)",
           "phases": phases, "seeds": seeds, "phase_fractions": tuning_phases(phases, grid),
           "seed_offset": TUNING_SEED_OFFSET, "score": describe()}
    if validate:
        out["validation"] = {"phases": validate, "phase_fractions": validation_phases(validate, grid),
                             "seed_offset": VALIDATION_SEED_OFFSET, "candidates": VALIDATION_CANDIDATES,
                             "rule": "the best candidates by tuning score and the shipped options, run at the "
                                     "validation phases; the lowest mean score there wins, a tie keeps the shipped"}
    return out


@dataclass(frozen=True)
class TuneResult(Outcome):
    """A tuning's outcome.

    Attributes
    ----------
    scenario, controller, kind : what was tuned where
    budget : trials asked for; n_trials / n_complete / n_pruned : what the study holds
    tunables : ``{name: {"low", "high", "log", "unit"}}`` (range in multiples of ``unit`` on this rig)
    best_params : ``{name: multiple}``; best_options : the options table with the tuned values (SI)
    best_value, default_value : mean score on the tuning runs, tuned (the chosen trial) and shipped
    validation : ``{"phases": [fractions], "candidates": [{"trial", "params", "tuning", "validation"}],
        "chosen": trial}`` when the choice was validated (``validate > 0``), else empty
    held_out : ``{"defaults" | "tuned": {"n_runs", "failed", "violations", "score", <ranked metric>:
        {"median", "ci_low", "ci_high"}}}`` on held-out seeds at the benchmark's phases (medians over
        the runs that did the job)
    study : the journal file ("" in memory)
    """

    scenario: str
    controller: str
    kind: str
    budget: int
    tunables: dict
    best_params: dict
    best_options: dict
    best_value: float
    default_value: float
    held_out: dict = field(default_factory=dict)
    validation: dict = field(default_factory=dict)
    n_trials: int = 0
    n_complete: int = 0
    n_pruned: int = 0
    study: str = ""
    elapsed: float = 0.0
    status: Status = Status.OK
    message: str = "ok"

    def as_dict(self) -> dict[str, Any]:
        from mitigate.cliutil import to_jsonable
        return to_jsonable(dataclasses.asdict(self))


def _optuna():
    """Optuna, or a one-line ConfigError saying how to install it (it is an optional dependency)."""
    try:
        import optuna
    except ImportError:
        raise ConfigError("tuning needs Optuna (pip install 'stickslip-workbench[tune]')") from None
    return optuna


def _score(rec: RunRecord) -> float:
    """:func:`mitigate.benchmark.score.run_score`: the ranking's order in one number."""
    from mitigate.benchmark.score import run_score
    return run_score(rec)


class _Objective:
    """A picklable Optuna objective: run the tasks with the trial's values, report as it goes."""

    def __init__(self, tasks: list[RunTask], base: Mapping, space: Mapping[str, tuple]):
        self.tasks, self.base, self.space = tasks, dict(base), dict(space)

    def options(self, params: Mapping[str, float]) -> dict:
        opts = dict(self.base)
        for name, (lo, hi, log, integer, unit) in self.space.items():
            v = params[name] * unit
            opts = set_option(opts, name, int(round(v)) if integer else float(v))
        return opts

    def __call__(self, trial) -> float:
        import optuna

        from mitigate.benchmark.execute import run_task
        params = {n: trial.suggest_float(n, lo, hi, log=log) for n, (lo, hi, log, _i, _u) in self.space.items()}
        opts = self.options(params)
        total = 0.0
        for i, t in enumerate(self.tasks):
            total += _score(run_task(dataclasses.replace(t, options=opts)))
            trial.report(total / (i + 1), i)
            if trial.should_prune():
                raise optuna.TrialPruned()
        return total / len(self.tasks)


def _sampler(seed: int, finished: int, budget: int):
    """Optuna's TPE sampler for the next trial of a study that has ``finished`` trials: multivariate,
    a fifth of the budget random start-up trials (:func:`startup_trials`), seeded by ``seed`` and
    ``finished`` (the same proposals whether or not the study was interrupted)."""
    optuna = _optuna()
    return optuna.samplers.TPESampler(seed=(int(seed) * 100003 + int(finished)) & 0xFFFFFFFF,
                                      n_startup_trials=startup_trials(budget), multivariate=True)


def _study(storage_path: str | None, name: str, seed: int, definition_hash: str, force: bool, budget: int = 50):
    optuna = _optuna()
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(storage_path)) if storage_path else None
    sampler = _sampler(seed, 0, budget)
    pruner = optuna.pruners.MedianPruner(n_startup_trials=5, n_warmup_steps=0)
    study = optuna.create_study(storage=storage, study_name=name, sampler=sampler, pruner=pruner,
                                direction="minimize", load_if_exists=True)
    old = study.user_attrs.get("definition")
    if old is not None and old != definition_hash:
        if not force:
            raise ConfigError(f"{storage_path}: the study {name!r} was made for other options or another scenario "
                              f"(pass force=True to start it again)")
        optuna.delete_study(study_name=name, storage=storage)
        study = optuna.create_study(storage=storage, study_name=name, sampler=sampler, pruner=pruner,
                                    direction="minimize")
    study.set_user_attr("definition", definition_hash)
    return study


def _finished(study) -> int:
    from optuna.trial import TrialState
    return sum(t.state in (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL) for t in study.trials)


def _optimize(args) -> int:
    """A worker: load the study and run ``n`` trials (the pool's job)."""
    storage_path, name, seed, h, objective, n, budget = args
    from mitigate.workers import report
    study = _study(storage_path, name, seed, h, False, budget)
    done = [0]

    def tick(_s, _t):            # a heartbeat per trial (the pool's stall watchdog) and the progress
        done[0] += 1
        report(done[0])

    study.optimize(objective, n_trials=n, callbacks=[tick])
    return n


def _resolve(scenario, controller):
    from mitigate.scenario import ControllerSpec, Scenario, load_scenario
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    if isinstance(controller, ControllerSpec):
        spec = controller
    elif isinstance(controller, Mapping):
        from mitigate.benchmark.suite import controller_spec
        spec = controller_spec(controller, "controller")
    elif isinstance(controller, str) and any(c.name == controller for c in sc.controllers):
        spec = next(c for c in sc.controllers if c.name == controller)
    elif isinstance(controller, str) and controller:
        spec = ControllerSpec(controller, controller, {})
    else:
        raise ConfigError(f"controller must be a controller name of the scenario, a kind or a table, got {controller!r}")
    return sc.replace(controllers=(spec,)), spec


def _tasks(sc, spec, ref: Reference, mo: MetricOptions, fractions, seeds: int, offset: int) -> list[RunTask]:
    """Runs at the switch-on phases ``fractions`` of the stick-slip period and seeds ``offset + j``."""
    out = []
    for k, f in enumerate(fractions):
        t_on = sc.control.start + (0.0 if ref.prevention else f * ref.period)
        for j in range(seeds):
            s = run_seed(sc.seed, k, offset + j)
            out.append(RunTask(sc, spec.name, k, offset + j, round(t_on, 9), s, dict(spec.options), mo, "tune",
                               ref.speed))
    return out


def tune(scenario, controller, *, budget: int, phases: int = 2, seeds: int = 1, held_out_seeds: int = 2,
         metrics: MetricOptions | None = None, out=None, n_jobs: int = 1, seed: int = 0, force: bool = False,
         progress: bool = False, reference: Reference | None = None, grid: int = DEFAULT_GRID,
         on_trial=None, validate: int = 0) -> TuneResult:
    """Tune a controller's declared tunables on a scenario (module docstring).

    Parameters
    ----------
    scenario : a Scenario or a scenario file
    controller : a controller name of the scenario, a kind (``"softspeed"``), a ControllerSpec or a
        ``{name, kind, options...}`` table; its options are the starting point (the first trial)
    budget : trials (each ``phases x seeds`` runs, fewer when pruned)
    phases, seeds : tuning runs per trial (:func:`tuning_phases` of ``grid``); held_out_seeds : seeds per
        phase of the held-out report, at the benchmark's own ``grid`` phases
    grid : the benchmark's switch-on phases (the tuning's lie between them)
    metrics : MetricOptions (its period is set from the scenario's uncontrolled run)
    out : folder of the study's journal file (None: in memory)
    n_jobs : processes sharing the study (1: the trials one after another, reproducible)
    seed : the sampler's seed
    on_trial : called with the number of finished trials after each (``n_jobs = 1``; a heartbeat)
    validate : validation phases (0: the best tuning score wins; module docstring); each runs
        ``seeds`` seeds for each of the :data:`VALIDATION_CANDIDATES` best trials and the shipped options

    Raises
    ------
    ConfigError : a bad argument, a controller the scenario's rig cannot host, a controller with no
        tunables, or a study in ``out`` made for something else (without ``force``).
    """
    from mitigate.benchmark.execute import pool, run_task
    from mitigate.benchmark.stats import did_job, interval
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.sweep.store import definition_hash
    from mitigate.tunables import tunables_of

    for name, v, lo in (("budget", budget, 1), ("phases", phases, 1), ("seeds", seeds, 1),
                        ("held_out_seeds", held_out_seeds, 0), ("n_jobs", n_jobs, 1), ("grid", grid, 1)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ConfigError(f"{name} must be an integer >= {lo}, got {v!r}")
    vfractions = validation_phases(validate, grid)
    t0 = time.perf_counter()
    sc, spec = _resolve(scenario, controller)
    ctrl = make_controller(spec, context_for(sc, 0))
    tun = tunables_of(ctrl)
    if not tun:
        raise ConfigError(f"controller {spec.name!r} ({spec.kind}) declares no tunables")
    mo = metrics or MetricOptions()
    ref = reference or reference_run(sc, mo)
    mo = dataclasses.replace(mo, period=ref.period)
    space = {n: (t.low, t.high, t.log, t.integer, t.unit_value(ctrl.context)) for n, t in tun.items()}
    fractions = tuning_phases(phases, grid)
    objective = _Objective(_tasks(sc, spec, ref, mo, fractions, seeds, TUNING_SEED_OFFSET), spec.options, space)
    from mitigate.benchmark.score import describe
    h = definition_hash({"scenario": sc.name, "path": sc.path, "controller": [spec.kind, dict(spec.options)],
                         "space": space, "phases": fractions, "seeds": seeds, "period": ref.period,
                         "score": describe(), "startup": startup_trials(budget)})
    name = f"{slug(sc.name)}__{slug(spec.name)}"
    path = None
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        path = str(Path(out) / f"{name}.journal")
    elif n_jobs > 1:
        import tempfile
        path = str(Path(tempfile.mkdtemp(prefix="stickslip_tune_")) / f"{name}.journal")
    study = _study(path, name, seed, h, force, budget)
    if not study.trials:
        start = _start_params(ctrl, spec, space)
        if start:
            study.enqueue_trial(start, skip_if_exists=True)
    remaining = max(0, budget - _finished(study))
    from tqdm import tqdm
    bar = tqdm(total=budget, initial=budget - remaining, desc=f"tune {spec.name} on {sc.name}", unit="trial",
               disable=not progress)
    try:
        if remaining and n_jobs == 1:
            def tick(_s, _t):
                bar.update()
                if on_trial is not None:
                    on_trial(_finished(study))
            for _ in range(remaining):
                # the sampler seeded by the trials finished so far: a study interrupted and continued
                # proposes what it would have proposed uninterrupted (its history is the same)
                study.sampler = _sampler(seed, _finished(study), budget)
                study.optimize(objective, n_trials=1, callbacks=[tick])
        elif remaining:
            shares = [remaining // n_jobs + (i < remaining % n_jobs) for i in range(n_jobs)]
            jobs = [((path, name, seed + i, h, objective, n, budget),) for i, n in enumerate(shares) if n]
            counts = [0] * len(jobs)

            def progress_of(i, k):
                counts[i] = k
                bar.n = min(budget, budget - remaining + sum(counts))
                bar.refresh()

            with pool(len(jobs)) as p:
                for out in p.map(_optimize, jobs, on_progress=progress_of):
                    if not out.ok:
                        raise ConfigError(f"tuning {spec.name!r} on {sc.name!r}: a tuning worker failed: {out.error}")
            study = _study(path, name, seed, h, False, budget)
    finally:
        bar.close()
    from optuna.trial import TrialState
    complete = [t for t in study.trials if t.state is TrialState.COMPLETE]
    if not complete:
        raise ConfigError(f"tuning {spec.name!r} on {sc.name!r}: no trial completed out of {len(study.trials)}")
    best = min(complete, key=lambda t: t.value)
    first = next((t for t in complete if t.number == 0), None)
    validation = {}
    if vfractions:
        best, validation = _validate(objective, complete, first,
                                     _tasks(sc, spec, ref, mo, vfractions, seeds, VALIDATION_SEED_OFFSET))
        validation = {"phases": vfractions} | validation
    best_options = objective.options(best.params)
    held = {}
    if held_out_seeds:
        ho = _tasks(sc, spec, ref, mo, [k / grid for k in range(grid)] if not ref.prevention else [0.0],
                    held_out_seeds, HELD_OUT_SEED_OFFSET)
        for label, opts in (("defaults", dict(spec.options)), ("tuned", best_options)):
            recs = [run_task(dataclasses.replace(t, options=opts)) for t in ho]
            done = [r for r in recs if did_job(r)]
            held[label] = {"n_runs": len(recs), "failed": sum(r.failed for r in recs),
                           "violations": sum(int(r.metrics.get("band_violation", 0)) for r in recs),
                           "score": float(sum(_score(r) for r in recs) / len(recs))}
            for m in ranked():
                med, lo, hi = interval([r.value(m.name) for r in done])
                held[label][m.name] = {"median": med, "ci_low": lo, "ci_high": hi}
    n_pruned = sum(t.state is TrialState.PRUNED for t in study.trials)
    return TuneResult(sc.name, spec.name, spec.kind, budget,
                      {n: {"low": lo, "high": hi, "log": log, "unit": u} for n, (lo, hi, log, _i, u) in space.items()},
                      dict(best.params), best_options, float(best.value),
                      float(first.value) if first is not None else math.nan, held, validation, len(study.trials),
                      len(complete), n_pruned, path or "", time.perf_counter() - t0)


def _validate(objective: _Objective, complete: list, first, tasks: list[RunTask]):
    """The candidate the validation runs choose (module docstring) and the record of the choice."""
    from mitigate.benchmark.execute import run_task
    cands = sorted(complete, key=lambda t: (t.value, t.number))[:VALIDATION_CANDIDATES]
    if first is not None and first not in cands:
        cands.append(first)
    rows = []
    for t in cands:
        opts = objective.options(t.params)
        v = sum(_score(run_task(dataclasses.replace(task, options=opts))) for task in tasks) / len(tasks)
        rows.append({"trial": t.number, "params": dict(t.params), "tuning": float(t.value), "validation": float(v)})
    # lowest validation score; a tie keeps the shipped options (trial 0), then the better tuning score
    k = min(range(len(cands)), key=lambda i: (rows[i]["validation"], cands[i].number != 0, rows[i]["tuning"],
                                              cands[i].number))
    return cands[k], {"candidates": rows, "chosen": cands[k].number}


def _start_params(ctrl, spec, space) -> dict:
    """The shipped options as multiples (the first trial), clipped into the ranges; options left at 0
    ("derive from the rig") start from the derived value where the Tunable says it (``derived``)."""
    from mitigate.controllers.factory import parse_options
    oc = getattr(type(ctrl), "options_class", None)
    if oc is not None and isinstance(getattr(ctrl, "options", None), oc):
        opts = ctrl.options          # as the controller runs them (unset values derived from the rig)
    else:
        try:
            opts = parse_options(oc, dict(spec.options), "controller") if oc is not None else dict(spec.options)
        except ConfigError:
            return {}
    out = {}
    for name, (lo, hi, log, _i, unit) in space.items():
        v: Any = opts
        for part in name.split("."):
            v = v.get(part) if isinstance(v, Mapping) else getattr(v, part, None)
        tunable = type(ctrl).tunables[name]
        if isinstance(v, (int, float)) and v:
            x = float(v) / unit
        elif tunable.derived is not None:
            x = tunable.derived
        else:
            continue
        out[name] = min(max(x, lo), hi)
    return out


def _tune_study(sc, spec, kw) -> tuple[dict, dict]:
    """A worker's job: one study, its trials one after another (a heartbeat per trial)."""
    from mitigate.workers import report
    r = tune(sc, spec, n_jobs=1, progress=False, on_trial=report, **kw)
    return r.best_options, r.as_dict()


def tune_suite(suite, *, budget: int, out, refs: Mapping | None = None, jobs: int = 1, progress: bool = False,
               phases: int = 2, seeds: int = 1, grid: int | None = None, validate: int = 0) -> dict[tuple, dict]:
    """Tune every controller of a suite on every scenario with the same ``budget`` (controllers with
    no tunables, or that a rig cannot host, keep their options); ``{(scenario, controller): options}``.
    ``grid``: the benchmark's phases (the suite's by default; the tuning's phases lie between them);
    ``validate``: validation phases of each study's choice (:func:`tune`).
    Each study is kept under ``out``; ``out/tuning.json`` lists the results and :func:`settings`.

    Every study runs its trials one after another, so the tuned values are the same on any machine
    and load; ``jobs`` processes run that many studies at a time."""
    import json

    from mitigate.benchmark.execute import pool
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.tunables import tunables_of
    from models.files import atomic_write_text

    studies = []
    for sc in suite.scenarios:
        ref = (refs or {}).get(sc.name) or reference_run(sc, suite.metrics)
        for i, spec in enumerate(sc.controllers):
            try:
                has = bool(tunables_of(make_controller(spec, context_for(sc, i))))
            except ConfigError:
                has = False
            if has:
                # no held-out report here: the benchmark that follows scores the tuned values on its own seeds
                kw = dict(budget=budget, phases=phases, seeds=seeds, held_out_seeds=0, metrics=suite.metrics,
                          out=out, reference=ref, grid=grid or suite.phases, validate=validate)
                studies.append((sc, spec, kw))
    found: dict[int, tuple[dict, dict]] = {}
    if jobs <= 1 or len(studies) <= 1:
        for k, (sc, spec, kw) in enumerate(studies):
            r = tune(sc, spec, n_jobs=1, progress=progress, **kw)
            found[k] = (r.best_options, r.as_dict())
    else:
        from tqdm import tqdm
        bar = tqdm(total=len(studies), desc=f"tune {len(studies)} studies ({budget} trials each)", unit="study",
                   disable=not progress)
        try:
            with pool(min(jobs, len(studies))) as p:
                for done in p.map(_tune_study, studies):
                    sc, spec, _kw = studies[done.index]
                    if not done.ok:
                        raise ConfigError(f"tuning {spec.name!r} on {sc.name!r} failed: {done.error}")
                    found[done.index] = done.value
                    bar.update()
        finally:
            bar.close()
    tuned, results = {}, []
    for k, (sc, spec, _kw) in enumerate(studies):
        tuned[(sc.name, spec.name)] = found[k][0]
        results.append(found[k][1])
    how = settings(budget, phases, seeds, grid or suite.phases, validate=validate)
    atomic_write_text(Path(out) / "tuning.json", json.dumps({"settings": how, "studies": results}, indent=2) + "\n",
                      overwrite=True)
    return tuned
