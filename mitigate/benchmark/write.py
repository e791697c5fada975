"""Writing a benchmark's output set: ``ranking.md``, ``results.csv`` (one row per run),
``entries.csv`` (one row per scenario and controller: medians and intervals), ``results.json``,
``benchmark.png`` and ``distribution.png``.  :func:`write_benchmark` is the one function that
writes them, as one output set (:func:`models.files.output_set`: locked, staged, committed together);
:data:`BENCHMARK_FILES` and :func:`output_paths` say which they are."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
from pathlib import Path

from models.files import OutputSet, output_set
from mitigate.benchmark.render import render_ranking
from mitigate.benchmark.stats import did_job, entry_metrics
from mitigate.metrics import in_order, unit

__all__ = ["write_benchmark", "output_paths", "BENCHMARK_FILES"]

#: the files :func:`write_benchmark` writes, by key
BENCHMARK_FILES = {"ranking": "ranking.md", "csv": "results.csv", "entries": "entries.csv", "json": "results.json",
                   "png": "benchmark.png", "distribution": "distribution.png"}


def output_paths(out) -> dict[str, Path]:
    """Every file :func:`write_benchmark` writes to ``out``, by key."""
    out = Path(out)
    return {k: out / n for k, n in BENCHMARK_FILES.items()}


def _runs_csv(res) -> str:
    """One row per run: its identity, status and message, every result, then every timing."""
    keys = in_order({k for r in res.records for k in r.metrics})
    times = in_order({k for r in res.records for k in r.timings})
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scenario", "controller", "class", "phase", "seed", "switch_on [s]", "run_seed", "applicable",
                "status", "did the job", "message"]
               + [f"{k} [{unit(k) or ('s' if k == 'elapsed_s' else '-')}]" for k in keys + times])
    for r in res.records:
        q = r.run
        w.writerow([q.scenario, q.controller, r.actuator_class, q.phase, q.seed, q.switch_on, q.run_seed, r.applicable,
                    r.status.value if r.applicable else "not applicable", did_job(r), r.message]
                   + [f"{float(r.metrics[k]):.6g}" if k in r.metrics else "" for k in keys]
                   + [f"{float(r.timings[k]):.6g}" if k in r.timings else "" for k in times])
    return buf.getvalue()


def _entries_csv(res) -> str:
    keys = entry_metrics()
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scenario", "controller", "kind", "class", "applicable", "n_runs", "n_failed", "n_violations",
                "job_done", "rank", "class_rank"]
               + [f"{k}_{s} [{unit(k) or '-'}]" for k in keys for s in ("median", "ci_low", "ci_high")])
    for e in res.entries.values():
        w.writerow([e.scenario, e.controller, e.kind, e.klass, e.applicable, e.n_runs, e.n_failed, e.n_violations,
                    e.job_done, e.rank if e.rank is not None else "", e.class_rank if e.class_rank is not None else ""]
                   + [f"{e.value(k, s):.6g}" for k in keys for s in ("median", "ci_low", "ci_high")])
    return buf.getvalue()


def write_benchmark(res, out, *, force: bool = False, command: str = "") -> dict[str, Path]:
    """Write the output set of :class:`mitigate.benchmark.BenchmarkResult` ``res`` to ``out`` as one
    set (:func:`models.files.output_set`, refusing to replace a file unless ``force``; ``out`` may be
    an open :class:`models.files.OutputSet`); returns ``{key: final path}``."""
    from mitigate.benchmark.figures import plot_distribution, plot_heatmap

    if not isinstance(out, OutputSet):
        with output_set(out, BENCHMARK_FILES.values(), force=force) as w:
            return write_benchmark(res, w, command=command)
    w, n = out, BENCHMARK_FILES
    files = {k: w.final(v) for k, v in n.items()}
    w.write_text(n["ranking"], render_ranking(res, command))
    w.write_text(n["csv"], _runs_csv(res))
    w.write_text(n["entries"], _entries_csv(res))
    res = dataclasses.replace(res, files=files)
    from mitigate.benchmark.entry import provenance
    prov = dict(res.provenance) if res.provenance else provenance()     # taken when the runs started
    prov["command"] = command
    w.write_text(n["json"], json.dumps(res.as_dict(prov), indent=2) + "\n")
    plot_heatmap(res, w.path(n["png"]))
    plot_distribution(res, w.path(n["distribution"]))
    return files
