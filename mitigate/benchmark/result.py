"""The benchmark run end to end: uncontrolled references, the runs, their statistics.

From Python::

    from mitigate.benchmark import load_suite, run_benchmark, write_benchmark
    suite = load_suite("scenarios/benchmark/suite.toml", only=["established"])
    res = run_benchmark(suite, phases=3, seeds=2, jobs=2)        # objects; nothing is written
    res.entry("established", "NMPC").metrics["residual_severity"]   # {"median", "ci_low", "ci_high"}
    res.tables["drive"]                                           # like for like: the drive's set-point only
    write_benchmark(res, "out/benchmark")                         # ranking.md, results.*, PNGs
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from models.errors import ConfigError, DataError
from models.status import Outcome, Status
from mitigate.benchmark.execute import RunStore, execute
from mitigate.benchmark.plan import Reference, make_tasks, reference_run
from mitigate.benchmark.stats import Entry, class_tables, rank, summarise
from mitigate.benchmark.suite import Suite

__all__ = ["BenchmarkResult", "run_benchmark", "assemble", "references", "definition"]


@dataclass(frozen=True)
class BenchmarkResult(Outcome):
    """The benchmark's results.

    Attributes
    ----------
    suite : the Suite
    references : ``{scenario: Reference}`` (the uncontrolled runs: periods, stick-slip at switch-on)
    records : every run's :class:`mitigate.record.RunRecord` (:func:`mitigate.benchmark.execute.run_task`)
    entries : ``{(scenario, controller): Entry}`` (n_runs, medians and intervals, ranks)
    tables : ``{"overall" | "drive" | "force" | "both": rows}`` (:func:`mitigate.benchmark.stats.class_tables`)
    phases, seeds : per (scenario, controller)
    tuned : ``{(scenario, controller): options}`` when the controllers were tuned (``mode == "tuned"``)
    tuning : how they were tuned (budget, sampler, tuning phases and seeds; empty for the defaults)
    metrics_version : :data:`mitigate.metrics.METRICS_VERSION` of the code that scored the runs
    provenance : where the runs were made (:func:`mitigate.benchmark.entry.provenance`), taken when the
        benchmark STARTED: the commit whose code the workers imported, not the one when it wrote
    status : :meth:`Status.worst` of the runs (FAILED if a run failed -- the others' results stand --,
        WARNING if a run warned), and WARNING when a suppression scenario has no stick-slip at its switch-on
    """

    suite: Suite = field(repr=False)
    references: dict = field(repr=False)
    records: list = field(repr=False)
    entries: dict = field(repr=False)
    tables: dict = field(repr=False)
    phases: int = 1
    seeds: int = 1
    mode: str = "defaults"
    tuned: dict = field(default_factory=dict, repr=False)
    elapsed: float = 0.0
    status: Status = Status.OK
    message: str = "ok"
    files: dict = field(default_factory=dict)
    computed: int = 0
    tuning: dict = field(default_factory=dict)
    metrics_version: str = ""
    provenance: dict = field(default_factory=dict, repr=False)

    def entry(self, scenario: str, controller: str) -> Entry:
        try:
            return self.entries[(scenario, controller)]
        except KeyError:
            raise ConfigError(f"no entry for controller {controller!r} on scenario {scenario!r}") from None

    def as_dict(self, provenance: Mapping | None = None) -> dict[str, Any]:
        """The results as a submittable entry (:func:`mitigate.benchmark.entry.entry_document`: every
        run's record, the suite's version and compute model, ``provenance``), which the results' JSON
        Schema accepts; everything but its ``timing`` and ``provenance`` is the same on any machine.
        ``provenance`` None: the one taken when the runs started (:attr:`provenance`)."""
        from mitigate.benchmark.entry import entry_document
        return entry_document(self, provenance if provenance is not None else (self.provenance or None))


def references(suite: Suite, jobs: int = 1) -> dict[str, Reference]:
    """The uncontrolled run of every scenario (:func:`mitigate.benchmark.plan.reference_run`), in
    ``jobs`` worker processes."""
    from mitigate.benchmark.execute import pool
    if jobs <= 1 or len(suite.scenarios) == 1:
        return {sc.name: reference_run(sc, suite.metrics) for sc in suite.scenarios}
    refs = {}
    with pool(min(jobs, len(suite.scenarios))) as p:
        for out in p.map(reference_run, [(sc, suite.metrics) for sc in suite.scenarios]):
            if not out.ok:
                sc = suite.scenarios[out.index]
                raise DataError(f"{sc.where}: the uncontrolled reference run failed: {out.error}")
            refs[out.value.scenario] = out.value
    return {sc.name: refs[sc.name] for sc in suite.scenarios}


#: modules that only present results (a change to them does not change a run)
_PRESENTATION = ("mitigate/benchmark/render.py", "mitigate/benchmark/figures.py", "mitigate/benchmark/write.py",
                 "mitigate/benchmark/entry.py", "mitigate/benchmark/leaderboard.py", "mitigate/benchmark/freeze.py",
                 "mitigate/benchmark/generate.py", "mitigate/benchmark/score.py", "mitigate/benchmark/schema",
                 "mitigate/benchmark/stats.py", "mitigate/benchmark/result.py", "mitigate/benchmark/__init__.py",
                 "mitigate/report.py", "mitigate/plots.py", "mitigate/timeplots.py", "mitigate/cliutil.py",
                 "mitigate/cli.py", "mitigate/tune.py", "mitigate/commands/")


def code_hash() -> str:
    """Hash of the workbench's source that computes a run (``models``, ``estimators``, ``mitigate``
    but its presentation modules): runs made by other code are not reused."""
    import hashlib

    import estimators
    import models
    import mitigate
    h = hashlib.sha256()
    for pkg in (models, estimators, mitigate):
        root = Path(pkg.__file__).parent
        for p in sorted(root.rglob("*.py")):
            rel = p.relative_to(root.parent).as_posix()
            if rel.startswith(_PRESENTATION):
                continue
            h.update(rel.encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def definition(suite: Suite, phases: int, seeds: int, tuned: Mapping | None = None) -> dict:
    """What identifies a benchmark's runs on disk: the suite and scenario files, the controllers and
    their options, phases, seeds, tuned values and the code (a change to any is a new benchmark)."""
    from mitigate.sweep.store import definition_hash
    files = [Path(suite.path)] + [Path(sc.path) for sc in suite.scenarios if sc.path]
    text = {str(p.name): p.read_text() for p in files if p.is_file()}
    return {"suite": suite.name, "files": definition_hash(text), "code": code_hash(), "phases": phases, "seeds": seeds,
            "controllers": [[c.name, c.kind, dict(c.options)] for c in suite.controllers],
            "scenarios": [sc.name for sc in suite.scenarios],
            "tuned": sorted([[s, c, o] for (s, c), o in (tuned or {}).items()], key=str)}


def run_benchmark(suite: Suite, *, phases: int | None = None, seeds: int | None = None, jobs: int = 2,
                  store: str | Path | None = None, force: bool = False, scheduler: str | None = None, client=None,
                  progress: bool = False, tuned: Mapping | None = None, refs: Mapping | None = None,
                  tuning: Mapping | None = None, provenance: Mapping | None = None) -> BenchmarkResult:
    """Run every controller of ``suite`` on every scenario at ``phases`` switch-on instants and
    ``seeds`` noise seeds, and rank them.

    Parameters
    ----------
    phases, seeds : per (scenario, controller) (None: the suite's; ``--quick``: 1 and 1)
    jobs : local worker processes (1: in this process); scheduler / client: a Dask cluster instead
    store : a folder to keep every finished run in (resumable; :class:`RunStore`); None: memory only
    force : discard a store holding a different benchmark
    tuned : ``{(scenario, controller): options}`` replacing the suite's options (the tuned mode)
    refs : precomputed ``{scenario: Reference}``
    tuning : how ``tuned`` was made (:func:`mitigate.tune.tune_suite`'s ``settings``), stored with the results
    provenance : where the runs are made (None: :func:`mitigate.benchmark.entry.provenance` now, before
        the first run; a caller that tuned first passes the one it took before tuning)

    Returns
    -------
    BenchmarkResult
    """
    from mitigate.benchmark.entry import provenance as where_made
    t0 = time.perf_counter()
    prov = dict(provenance) if provenance is not None else where_made()
    phases = suite.phases if phases is None else phases
    seeds = suite.seeds if seeds is None else seeds
    refs = dict(refs) if refs is not None else references(suite, jobs if client is None and not scheduler else 1)
    tasks = make_tasks(suite, refs, phases=phases, seeds=seeds, options=tuned)
    st = RunStore(store, definition(suite, phases, seeds, tuned), force=force) if store is not None else None
    computed: list = []
    recs = execute(tasks, store=st, jobs=jobs, scheduler=scheduler, client=client, progress=progress,
                   desc=f"benchmark {suite.name}", on_record=computed.append)
    return assemble(suite, refs, list(recs.values()), phases=phases, seeds=seeds, tuned=tuned, tuning=tuning,
                    elapsed=time.perf_counter() - t0, computed=len(computed), provenance=prov)


def assemble(suite: Suite, refs: Mapping, records: list, *, phases: int, seeds: int, tuned: Mapping | None = None,
             tuning: Mapping | None = None, elapsed: float = 0.0, computed: int = 0,
             provenance: Mapping | None = None) -> BenchmarkResult:
    """A :class:`BenchmarkResult` from every run's record (:func:`run_benchmark` once its runs are done,
    or a store's records read back): the entries, their ranks, the class tables, the status."""
    from mitigate.metrics import METRICS_VERSION
    kinds = {c.name: c.kind for c in suite.controllers}
    entries = summarise(records, kinds)
    scen = [sc.name for sc in suite.scenarios]
    names = [c.name for c in suite.controllers]
    for s in scen:
        for c, r in rank([entries[(s, c)] for c in names]).items():
            entries[(s, c)].rank = r
    # the class tables rank on the machine-independent scenarios only (the suite's timing ones apart)
    tables = class_tables(entries, [s for s in scen if s not in suite.timing], names)
    for klass, rows in tables.items():
        if klass == "overall":
            continue
        for row in rows:
            for s, r in row["ranks"].items():
                if entries[(s, row["controller"])].klass == klass:
                    entries[(s, row["controller"])].class_rank = r
    failed = sum(r.failed for r in records)
    no_slip = [k for k, v in refs.items() if not v.prevention and not v.stick_slip]
    notes = []
    if failed:
        notes.append(f"{failed} run(s) failed or diverged")
    if no_slip:
        notes.append(f"no stick-slip at the switch-on of {', '.join(no_slip)}")
    runs = [r.status for r in records if r.applicable]
    warned = sum(s is Status.WARNING for s in runs)
    if warned:
        notes.append(f"{warned} run(s) with warnings")
    # the whole is as good as its worst run (Status.worst); a suppression scenario without stick-slip warns
    status = Status.worst(runs + ([Status.WARNING] if no_slip else []))
    return BenchmarkResult(suite, dict(refs), records, entries, tables, phases, seeds,
                           "tuned" if tuned else "defaults", dict(tuned or {}), elapsed, status, "; ".join(notes) or "ok",
                           computed=computed, tuning=dict(tuning or {}), metrics_version=METRICS_VERSION,
                           provenance=dict(provenance or {}))

