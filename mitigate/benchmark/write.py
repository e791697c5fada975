"""Writing a benchmark's output set: ``ranking.md``, ``results.csv`` (one row per run),
``entries.csv`` (one row per scenario and controller: medians and intervals), ``results.json``,
``benchmark.png`` and ``distribution.png``.  :func:`write_benchmark` is the one function that
writes them; :func:`output_paths` says which they are, so a caller can refuse before any work."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
from pathlib import Path

from models.files import atomic_write_text, refuse_overwrite
from mitigate.benchmark.render import render_ranking
from mitigate.benchmark.stats import EFFORT, RANKED
from mitigate.metrics import metric_unit

__all__ = ["write_benchmark", "output_paths"]


def output_paths(out) -> dict[str, Path]:
    """Every file :func:`write_benchmark` writes to ``out``, by key."""
    out = Path(out)
    return {"ranking": out / "ranking.md", "csv": out / "results.csv", "entries": out / "entries.csv",
            "json": out / "results.json", "png": out / "benchmark.png", "distribution": out / "distribution.png"}


def _runs_csv(res) -> str:
    keys = sorted({k for r in res.records for k in r.get("metrics", {})})
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scenario", "controller", "class", "phase", "seed", "switch_on [s]", "run_seed", "applicable",
                "status", "failed"] + [f"{k} [{metric_unit(k) or '-'}]" for k in keys])
    for r in res.records:
        m = r.get("metrics", {})
        w.writerow([r["scenario"], r["controller"], r.get("class", ""), r["phase"], r["seed"], r["switch_on"],
                    r["run_seed"], r.get("applicable", True), r.get("status", ""), r.get("failed", 0)]
                   + [f"{float(m[k]):.6g}" if k in m else "" for k in keys])
    return buf.getvalue()


def _entries_csv(res) -> str:
    keys = RANKED + EFFORT
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scenario", "controller", "kind", "class", "applicable", "n_runs", "n_failed", "n_violations",
                "job_done", "rank", "class_rank"]
               + [f"{k}_{s} [{metric_unit(k) or '-'}]" for k in keys for s in ("median", "ci_low", "ci_high")])
    for e in res.entries.values():
        w.writerow([e.scenario, e.controller, e.kind, e.klass, e.applicable, e.n_runs, e.n_failed, e.n_violations,
                    e.job_done, e.rank if e.rank is not None else "", e.class_rank if e.class_rank is not None else ""]
                   + [f"{e.value(k, s):.6g}" for k in keys for s in ("median", "ci_low", "ci_high")])
    return buf.getvalue()


def write_benchmark(res, out, *, force: bool = False, command: str = "") -> dict[str, Path]:
    """Write the output set of :class:`mitigate.benchmark.BenchmarkResult` ``res`` to ``out``
    (refusing to replace a file unless ``force``); returns ``{key: path}``."""
    from mitigate.benchmark.figures import plot_distribution, plot_heatmap

    files = output_paths(out)
    for p in files.values():
        refuse_overwrite(p, force, "force")
    Path(out).mkdir(parents=True, exist_ok=True)
    atomic_write_text(files["ranking"], render_ranking(res, command), overwrite=True)
    atomic_write_text(files["csv"], _runs_csv(res), overwrite=True)
    atomic_write_text(files["entries"], _entries_csv(res), overwrite=True)
    res = dataclasses.replace(res, files=files)
    atomic_write_text(files["json"], json.dumps(res.as_dict(), indent=2) + "\n", overwrite=True)
    plot_heatmap(res, files["png"])
    plot_distribution(res, files["distribution"])
    return files
