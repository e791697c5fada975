"""Gain sweep of the drilling industry's stick-slip laws on the main scenario, and their step times.

The main scenario is ``scenarios/stick_slip_30rpm.toml`` (rig3, 30 rpm, N1 = 20 N, from rest,
control from 20 s, 60 s), with the finite-difference estimator (the laws use measured channels
only, never the estimate) and each law alone:

- SoftSpeed ``kp_factor`` (Kp = kp_factor Z, Z = sqrt(k J) = 0.110 N m s/rad; default 1);
- Z-Torque ``z`` (the torque-feedback factor; NORCE's default 0.25);
- D-OSKIL ``gain`` [N s/rad] (default derived from the rig: Z / (r2 mu_k) = 8.98).

Every metric is taken from the TRUE plant after the control start (mitigate.metrics): SSS over
the 40 s, SSS over the last 5 s, the time until the moving 3 s severity stays below 0.1, the
fraction of time R1 is stuck, the RMS speed error of R1 against the programme, the friction work
at the R2 pin, and the controller's mean wall time per step (``Controller.step``, guard included).
Then each law at its default runs once more in this process alone, for the per-step time
(median, p95, mean over the run; target <= 0.05 ms a step).

Prints the tables and writes ``benchmarks/results/industry_tuning.md``::

    PYTHONPATH=. python benchmarks/industry_tuning.py [--jobs 2] [--out benchmarks/results/industry_tuning.md]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "stick_slip_30rpm.toml"

#: (kind, option, values, default) of each law's sweep
GRIDS = (
    ("softspeed", "kp_factor", (0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 8.0), 1.0),
    ("ztorque", "z", (0.05, 0.1, 0.15, 0.25, 0.35, 0.5, 0.75, 1.0), 0.25),
    ("doskil", "gain", (2.0, 4.0, 6.0, 9.0, 12.0, 20.0, 40.0), None),   # None: derived from the rig (8.98)
)
COLUMNS = (("sss", "SSS", "{:.3f}"), ("sss_final", "SSS last 5 s", "{:.4f}"),
           ("time_to_suppress", "t suppress [s]", "{:.2f}"), ("stuck_fraction", "stuck", "{:.3f}"),
           ("speed_error_rms", "speed err [rad/s]", "{:.3f}"), ("pin_work", "pin work [J]", "{:.2f}"),
           ("step_mean_ms", "step mean [ms]", "{:.4f}"))


def scenario(kind: str, options: dict):
    """The main scenario with the FD estimator and one controller ``kind`` with ``options``."""
    from mitigate.scenario import ControllerSpec, load_scenario
    sc = load_scenario(SCENARIO)
    return sc.replace(estimator={"kind": "fd"}, controllers=(ControllerSpec(kind, kind, dict(options)),))


def run_one(args):
    """One closed-loop run; returns (kind, options, metrics with step-time statistics, derived gains)."""
    import numpy as np

    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.metrics import closed_loop_metrics

    kind, options = args
    sc = scenario(kind, options)
    ctrl = make_controller(sc.controllers[0], context_for(sc, 0))
    res = run_closed_loop(sc, ctrl)
    m = closed_loop_metrics(res, sc)
    st = np.asarray(res.solve_times) * 1e3
    m.update(step_mean_ms=float(np.mean(st)), step_median_ms=float(np.median(st)),
             step_p95_ms=float(np.percentile(st, 95)), status=res.status.value)
    derived = {"Kp": getattr(ctrl, "Kp", None), "gain": getattr(ctrl, "gain", None)}
    return kind, options, m, derived


def _fmt(fmt: str, v) -> str:
    v = float(v)
    return "inf" if math.isinf(v) else ("-" if math.isnan(v) else fmt.format(v))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "industry_tuning.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    tasks = [("pi", {})]
    for kind, opt, values, _ in GRIDS:
        tasks += [(kind, {opt: v}) for v in values]
    tasks += [(kind, {}) for kind, _opt, _values, default in GRIDS if default is None]   # the derived default
    with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as ex:
        rows = list(ex.map(run_one, tasks))
    sweep_s = time.perf_counter() - t0

    # the defaults once more, alone in this process, for the per-step time
    timing = [run_one((kind, {})) for kind, *_ in GRIDS]

    pi = rows[0][2]
    lines = ["# Industry laws: gain sweep on the main scenario", "",
             f"Scenario `{SCENARIO.relative_to(ROOT)}` (rig3, 30 rpm, N1 = 20 N, from rest, control from 20 s, "
             "60 s), finite-difference estimator (the laws read measured channels only), one law at a time. "
             "Metrics after the control start, from the TRUE plant; `step mean` is the controller's mean wall "
             "time per call (`Controller.step`), measured in the sweep's worker processes.", "",
             f"PI alone: SSS {pi['sss']:.3f}, SSS last 5 s {pi['sss_final']:.3f}, stuck {pi['stuck_fraction']:.3f}, "
             f"never suppressed.", ""]
    summary = []
    for kind, opt, values, default in GRIDS:
        mine = [r for r in rows[1:] if r[0] == kind]
        if default is None:
            dflt = next(r for r in mine if not r[1])
            default_value = dflt[3]["gain"]
        else:
            default_value = default
            dflt = next(r for r in mine if r[1] and r[1][opt] == default)
        lines += [f"## {kind}: `{opt}`", "",
                  "| " + " | ".join([opt] + [h for _, h, _ in COLUMNS]) + " |", "|" + "---|" * (len(COLUMNS) + 1)]
        for k, o, m, d in sorted(mine, key=lambda r: r[1].get(opt, default_value)):
            label = f"{o[opt]:g}" if o else f"{default_value:.3g} (derived default)"
            if o and default is not None and o[opt] == default:
                label += " (default)"
            lines.append("| " + " | ".join([label] + [_fmt(f, m[c]) for c, _, f in COLUMNS]) + " |")
        best = min(mine, key=lambda r: r[2]["sss"])
        rank = 1 + sum(r[2]["sss"] < dflt[2]["sss"] for r in mine)
        bv = best[1].get(opt, default_value)
        summary.append(f"- {kind}: the default ({opt} = {default_value:.3g}) gives SSS {dflt[2]['sss']:.3f}, "
                       f"rank {rank} of {len(mine)}; the best is {opt} = {bv:.3g} with SSS {best[2]['sss']:.3f} "
                       f"({100 * (dflt[2]['sss'] - best[2]['sss']) / best[2]['sss']:+.0f} % for the default), "
                       f"time to suppress {_fmt('{:.2f}', dflt[2]['time_to_suppress'])} s (default) vs "
                       f"{_fmt('{:.2f}', best[2]['time_to_suppress'])} s (best).")
        lines.append("")
    lines += ["## Where the defaults sit", ""] + summary + [""]
    lines += ["## Per-step controller time at the defaults (alone in one process)", "",
              "| law | median [ms] | p95 [ms] | mean [ms] | steps | target |", "|---|---|---|---|---|---|"]
    for kind, _o, m, _d in timing:
        ok = "met" if m["step_median_ms"] <= 0.05 else "NOT met"
        lines.append(f"| {kind} | {m['step_median_ms']:.4f} | {m['step_p95_ms']:.4f} | {m['step_mean_ms']:.4f} | "
                     f"{m['controller_steps']} | <= 0.05 ms: {ok} |")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines += ["", f"Command: `PYTHONPATH=. python benchmarks/industry_tuning.py --jobs {args.jobs}` "
              f"({sweep_s:.0f} s for the {len(tasks)} runs on {args.jobs} workers; {platform.machine()}, "
              f"{os.cpu_count()} cores, load average {load:.1f} at the end, Python {platform.python_version()}).", ""]
    text = "\n".join(lines)
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
