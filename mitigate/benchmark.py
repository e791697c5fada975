"""The open benchmark: every controller on a fixed suite of scenarios, one ranked table.

A suite is a TOML file (``scenarios/benchmark/suite.toml``)::

    [suite]
    name = "stickslip-benchmark-1"
    scenarios = ["established.toml", "bistable.toml", ...]   # relative to the suite file

    [[controllers]]                    # run on every scenario (as a scenario's [[controllers]])
    name = "SoftSpeed"
    kind = "softspeed"

A scenario of the suite may list ``[[controllers]]`` of its own: they are replaced by the suite's.
A controller whose actuator or channel a scenario's rig lacks (D-OSKIL on a rig without a servo)
is reported as not applicable there, not as a failure.

The ranking: in each scenario the controllers are ranked by the severity after the control start
(``sss``; ties by ``time_to_suppress``); a run that diverged or failed ranks last.  The table gives,
per controller, the mean rank, the fraction of scenarios where its severity is the lowest, then over
the runs that did not fail: the mean severity, the mean severity over the last 5 s, the mean
fraction of time stuck, the median time to suppress, the mean speed error, the mean pin work and
drive energy; and over every run: the number of failed runs and controller fallbacks, and the 95th
percentile of its planning-call times.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from models.checks import read_toml
from models.errors import ConfigError, PluginError
from models.files import OutputSet, output_set
from models.status import Status
from mitigate.scenario import ControllerSpec, Scenario, parse_scenario

__all__ = ["Suite", "load_suite", "BenchmarkResult", "run_benchmark", "write_benchmark", "RANK_COLUMNS"]

#: (key, header, unit, aggregate) of the ranked table
RANK_COLUMNS = (
    ("mean_rank", "mean rank", "-", None),
    ("lowest_fraction", "lowest SSS", "-", None),
    ("sss", "SSS", "-", "mean"),
    ("sss_final", "SSS last 5 s", "-", "mean"),
    ("stuck_fraction", "stuck", "-", "mean"),
    ("time_to_suppress", "t suppress [s]", "s", "median"),
    ("speed_error_rms", "speed err [rad/s]", "rad/s", "mean"),
    ("pin_work", "pin work [J]", "J", "mean"),
    ("drive_energy", "drive energy [J]", "J", "mean"),
    ("failed", "failed runs", "-", "sum"),
    ("controller_fallbacks", "fallbacks", "-", "sum"),
    ("plan_p95_ms", "plan p95 [ms]", "ms", "max"),
)


#: the files :func:`write_benchmark` writes, by key
BENCHMARK_FILES = {"ranking": "ranking.md", "csv": "results.csv", "json": "results.json", "png": "benchmark.png"}


@dataclass(frozen=True)
class Suite:
    """A benchmark suite: its scenarios (with the suite's controllers) and the controllers."""

    name: str
    description: str
    scenarios: tuple[Scenario, ...]
    controllers: tuple[ControllerSpec, ...]
    path: str = ""


def _controller_specs(raw, where: str) -> list[ControllerSpec]:
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{where}: controllers: list at least one [[controllers]] table")
    out, seen = [], set()
    for i, c in enumerate(raw):
        if not isinstance(c, Mapping) or not isinstance(c.get("name"), str) or not isinstance(c.get("kind"), str):
            raise ConfigError(f"{where}: controllers[{i}] must be a table with a name and a kind, got {c!r}")
        if c["name"] in seen:
            raise ConfigError(f"{where}: controllers[{i}].name: duplicate controller name {c['name']!r}")
        seen.add(c["name"])
        out.append(ControllerSpec(c["name"], c["kind"], {k: v for k, v in c.items() if k not in ("name", "kind")}))
    return out


def load_suite(path, *, extra_controllers=(), only=None) -> Suite:
    """Read a suite file; ``extra_controllers`` (ControllerSpec or mappings) are added to its
    controllers, ``only`` restricts it to those scenario names."""
    path = Path(path)
    data = read_toml(path, "benchmark suite")
    where = path.name
    for k in data:
        if k not in ("suite", "controllers"):
            raise ConfigError(f"{where}: {k}: unknown section; expected suite and controllers")
    s = data.get("suite", {})
    if not isinstance(s, Mapping):
        raise ConfigError(f"{where}: suite must be a table")
    for k in s:
        if k not in ("name", "description", "scenarios"):
            raise ConfigError(f"{where}: suite.{k}: unknown key; expected name, description, scenarios")
    files = s.get("scenarios")
    if not isinstance(files, list) or not files or not all(isinstance(f, str) for f in files):
        raise ConfigError(f"{where}: suite.scenarios must be a list of scenario files, got {files!r}")
    ctrls = _controller_specs(data.get("controllers"), where)
    n_suite = len(ctrls)
    for c in extra_controllers:
        spec = c if isinstance(c, ControllerSpec) else ControllerSpec(c["name"], c["kind"],
                                                                      {k: v for k, v in c.items()
                                                                       if k not in ("name", "kind")})
        if spec.name in [x.name for x in ctrls]:
            raise ConfigError(f"controller name {spec.name!r} is already in the suite")
        ctrls.append(spec)
    # a wrong kind or option is an error of the suite, found before anything runs; only what a
    # scenario's rig lacks (a servo, a channel) makes a controller "not applicable" there
    from dataclasses import is_dataclass

    from mitigate.controllers.factory import controller_class, parse_options
    for i, c in enumerate(ctrls):
        cw = f"{where}: controllers[{i}]" if i < n_suite else f"controller {c.name!r}"
        cls = controller_class(c.kind, cw)
        oc = getattr(cls, "options_class", None)
        if oc is not None and is_dataclass(oc):
            parse_options(oc, dict(c.options), cw)
    raw_ctrls = [{"name": c.name, "kind": c.kind, **c.options} for c in ctrls]
    scenarios = []
    for f in files:
        p = path.parent / f
        sd = dict(read_toml(p, "scenario file"))
        sd["controllers"] = raw_ctrls
        if isinstance(sd.get("control", {}), Mapping):     # a real-time budget: one control period per call
            sd["control"] = {"deadline": "period", **sd.get("control", {})}
        scenarios.append(parse_scenario(sd, str(p)))
    if only:
        names = [sc.name for sc in scenarios]
        bad = [o for o in only if o not in names]
        if bad:
            raise ConfigError(f"scenario {bad[0]!r} is not in the suite ({', '.join(names)})")
        scenarios = [sc for sc in scenarios if sc.name in only]
    return Suite(str(s.get("name", path.stem)), str(s.get("description", "")), tuple(scenarios), tuple(ctrls),
                 str(path))


@dataclass(frozen=True)
class BenchmarkResult:
    """The benchmark's results.

    Attributes
    ----------
    suite : the Suite
    cells : ``{(scenario, controller): {metrics..., "status", "message", "applicable"}}``
    ranks : ``{(scenario, controller): rank}`` (1 = lowest severity)
    table : one row per controller, ordered by mean rank (keys of :data:`RANK_COLUMNS`)
    status : :meth:`Status.worst` of the runs (FAILED if some runs failed, WARNING if some warned)
    """

    suite: Suite = field(repr=False)
    cells: dict = field(repr=False)
    ranks: dict = field(repr=False)
    table: list = field(repr=False)
    elapsed: float = 0.0
    status: Status = Status.OK
    message: str = "ok"
    files: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        from mitigate.cliutil import to_jsonable
        return to_jsonable({
            "suite": self.suite.name, "status": self.status.value, "message": self.message, "elapsed_s": self.elapsed,
            "scenarios": [sc.name for sc in self.suite.scenarios], "controllers": [c.name for c in self.suite.controllers],
            "table": self.table,
            "cells": [{"scenario": s, "controller": c, "rank": self.ranks.get((s, c)), **v}
                      for (s, c), v in self.cells.items()],
            "files": {k: str(v) for k, v in self.files.items()}})


def _job(sc, i):
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.runner import failed_run, run_one
    try:
        make_controller(sc.controllers[i], context_for(sc, i))
    except ConfigError as exc:     # the rig lacks what the controller needs: not applicable here
        return sc.name, sc.controllers[i].name, None, str(exc)
    except PluginError as exc:     # a broken plug-in: its run FAILED
        return sc.name, sc.controllers[i].name, failed_run(sc.controllers[i], f"controller failed to build: {exc}"), ""
    r = run_one(sc, i)
    return sc.name, r.name, r, ""


def run_benchmark(suite: Suite, *, jobs: int = 2, progress: bool = False) -> BenchmarkResult:
    """Run every controller of ``suite`` on every scenario (in ``jobs`` processes) and rank them."""
    from mitigate.runner import STALL_TIMEOUT, failed_run
    from mitigate.workers import WorkerPool

    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    t0 = time.perf_counter()
    tasks = [(sc, i) for sc in suite.scenarios for i in range(len(sc.controllers))]
    results: list = [None] * len(tasks)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(tasks), desc=f"benchmark {suite.name}", unit="run")
    try:
        with WorkerPool(jobs, stall_timeout=STALL_TIMEOUT) as pool:   # a run that fails (its worker dies, hangs) fails alone
            for out in pool.map(_job, tasks):
                sc, i = tasks[out.index]
                results[out.index] = out.value if out.ok else (sc.name, sc.controllers[i].name,
                                                               failed_run(sc.controllers[i], out.error), "")
                if bar is not None:
                    bar.update()
    finally:
        if bar is not None:
            bar.close()
    cells = {}
    for sname, cname, run, why in results:
        if run is None:
            cells[(sname, cname)] = {"applicable": False, "status": "not applicable", "message": why}
        else:
            cells[(sname, cname)] = {"applicable": True, "status": run.status.value, "message": run.message,
                                     "failed": int(not run.success), **run.metrics}
    ranks = {}
    for sc in suite.scenarios:
        rows = [(c.name, cells[(sc.name, c.name)]) for c in suite.controllers if cells[(sc.name, c.name)]["applicable"]]
        key = lambda r: (r[1]["failed"], r[1]["sss"] if math.isfinite(r[1]["sss"]) else 1e9,  # noqa: E731
                         r[1]["time_to_suppress"] if math.isfinite(r[1]["time_to_suppress"]) else 1e9)
        for k, (name, _) in enumerate(sorted(rows, key=key), start=1):
            ranks[(sc.name, name)] = k
    table = []
    for c in suite.controllers:
        mine = [(s.name, cells[(s.name, c.name)]) for s in suite.scenarios if cells[(s.name, c.name)]["applicable"]]
        row: dict[str, Any] = {"controller": c.name, "kind": c.kind, "scenarios": len(mine)}
        if not mine:
            table.append(row | {k: float("nan") for k, *_ in RANK_COLUMNS})
            continue
        row["mean_rank"] = float(np.mean([ranks[(s, c.name)] for s, _ in mine]))
        row["lowest_fraction"] = float(np.mean([ranks[(s, c.name)] == 1 for s, _ in mine]))
        ran = [(s, v) for s, v in mine if not v["failed"]]
        for key, _h, _u, agg in RANK_COLUMNS[2:]:
            # counts and worst times over every run; the physical metrics over the runs that finished
            # (a diverged run's partial record is counted in "failed runs" and ranked last instead)
            vals = np.array([float(v.get(key, np.nan)) for _, v in (mine if agg in ("sum", "max") else ran)], float)
            fin = vals[np.isfinite(vals)]
            if agg == "sum":
                row[key] = float(np.nansum(vals))
            elif agg == "max":
                row[key] = float(np.max(fin)) if fin.size else float("nan")
            elif agg == "median":
                row[key] = float(np.median(vals)) if vals.size else float("nan")   # inf counts: not suppressed
            else:
                row[key] = float(np.mean(fin)) if fin.size else float("nan")
        table.append(row)
    table.sort(key=lambda r: (r.get("mean_rank", math.inf) if math.isfinite(r.get("mean_rank", math.inf)) else math.inf))
    failed = sum(v.get("failed", 0) for v in cells.values())
    status = Status.worst(run.status for _, _, run, _ in results if run is not None)
    return BenchmarkResult(suite, cells, ranks, table, time.perf_counter() - t0, status,
                           "ok" if failed == 0 else f"{failed} run(s) failed or diverged")


def _fmt(v) -> str:
    if isinstance(v, str):
        return v
    v = float(v)
    return "-" if math.isnan(v) else ("inf" if math.isinf(v) else f"{v:.3g}")


def render_ranking(res: BenchmarkResult, command: str = "") -> str:
    """The ranked table and the per-scenario severities as markdown."""
    su = res.suite
    L = [f"# Benchmark `{su.name}`", "", su.description, ""]
    if command:
        L += ["Made with:", "", "```bash", command, "```", ""]
    hdr = ["controller", "kind"] + [h for _k, h, _u, _a in RANK_COLUMNS]
    L += ["## Ranking (by severity after the control start, per scenario)", "",
          "| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
    for r in res.table:
        L.append("| " + " | ".join([r["controller"], r["kind"]] + [_fmt(r.get(k, float("nan"))) for k, *_ in RANK_COLUMNS])
                 + " |")
    names = [c.name for c in su.controllers]
    L += ["", "## Severity SSS after the control start (rank), per scenario", "",
          "| scenario | " + " | ".join(names) + " |", "|" + "---|" * (len(names) + 1)]
    for sc in su.scenarios:
        cells = []
        for n in names:
            v = res.cells[(sc.name, n)]
            if not v["applicable"]:
                cells.append("n/a")
            elif v.get("failed"):
                cells.append(f"FAILED ({v['status']})")
            else:
                cells.append(f"{_fmt(v['sss'])} ({res.ranks[(sc.name, n)]})")
        L.append(f"| {sc.name} | " + " | ".join(cells) + " |")
    na = [(s, c, v["message"]) for (s, c), v in res.cells.items() if not v["applicable"]]
    if na:
        L += ["", "Not applicable (the rig lacks what the controller needs):", ""]
        L += [f"- {c} on {s}: {m}" for s, c, m in na]
    bad = [(s, c, v["message"]) for (s, c), v in res.cells.items() if v.get("failed")]
    if bad:
        L += ["", "Failed or diverged runs:", ""] + [f"- {c} on {s}: {m}" for s, c, m in bad]
    L += ["", f"Status: {res.status.value} ({res.message}); wall time {res.elapsed:.0f} s.", ""]
    return "\n".join(L) + "\n"


def write_benchmark(res: BenchmarkResult, out, *, force: bool = False, command: str = "") -> dict:
    """Write ``ranking.md``, ``results.csv``, ``results.json`` and ``benchmark.png`` to ``out`` as one
    set (:func:`models.files.output_set`; ``out`` may be an open :class:`models.files.OutputSet`)."""
    import csv
    import io

    if not isinstance(out, OutputSet):
        with output_set(out, BENCHMARK_FILES.values(), force=force) as w:
            return write_benchmark(res, w, command=command)
    w = out
    files = {k: w.final(n) for k, n in BENCHMARK_FILES.items()}
    w.write_text(BENCHMARK_FILES["ranking"], render_ranking(res, command))
    keys = sorted({k for v in res.cells.values() for k in v if k not in ("applicable", "status", "message")})
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(["scenario", "controller", "applicable", "status", "rank"] + keys)
    for (s, c), v in res.cells.items():
        wr.writerow([s, c, v["applicable"], v["status"], res.ranks.get((s, c), "")] + [v.get(k, "") for k in keys])
    w.write_text(BENCHMARK_FILES["csv"], buf.getvalue())
    res = dataclasses.replace(res, files=files)
    w.write_text(BENCHMARK_FILES["json"], json.dumps(res.as_dict(), indent=2) + "\n")
    _plot(res, w.path(BENCHMARK_FILES["png"]))
    return files


def _plot(res: BenchmarkResult, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mitigate.cliutil import finish_figure

    su = res.suite
    names = [c.name for c in su.controllers]
    scen = [sc.name for sc in su.scenarios]
    S = np.full((len(scen), len(names)), np.nan)
    for i, s in enumerate(scen):
        for j, n in enumerate(names):
            v = res.cells[(s, n)]
            if v["applicable"] and not v.get("failed"):
                S[i, j] = v["sss"]
    fig, ax = plt.subplots(figsize=(1.3 * len(names) + 3, 0.55 * len(scen) + 2.5))
    im = ax.imshow(S, cmap="viridis_r", aspect="auto", vmin=0, vmax=max(1.2, float(np.nanmax(S)) if np.isfinite(S).any() else 1.2))
    for i, s in enumerate(scen):
        for j, n in enumerate(names):
            v = res.cells[(s, n)]
            txt = "n/a" if not v["applicable"] else ("fail" if v.get("failed") else f"{S[i, j]:.2f}\n#{res.ranks[(s, n)]}")
            ax.text(j, i, txt, ha="center", va="center", fontsize=7,
                    color="w" if np.isfinite(S[i, j]) and S[i, j] > 0.6 else "k")
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(scen)), scen, fontsize=8)
    fig.colorbar(im, ax=ax, label="severity SSS after control start [-] (lower is better)")
    finish_figure(fig, path, f"{su.name}: severity and rank per scenario")
