"""Benchmark: one 60 s open-loop run of the published 3-disc rig at the 10 ms DAQ rate.

Case: N1 = 20 N, omega_ref = 30 rpm, from rest (stick-slip), sensors on.  For each plant
method (hybrid = exact stick/slip, smooth = regularised RK4, cvodes) the wall time of
``models.plant.simulate`` is measured after one warm-up run (which also builds and
caches the CasADi step function); median and p95 over the repeats, real-time factor =
simulated time / wall time.

Usage: python benchmarks/bench_simulate.py [--repeats 5] [--out benchmarks/results/simulate_modal.md]
       python benchmarks/bench_simulate.py --quick     # 5 s, 1 repeat, hybrid and smooth (CI smoke run)
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

import numpy as np

from models import get_model
from models.plant import SimOptions, simulate

from _results import publish

DURATION = 60.0


def bench(method: str, repeats: int, duration: float = DURATION) -> dict:
    m = get_model("rig3")
    p = m.published()
    u = np.array([math.pi, 20.0, 0.0])
    opts = SimOptions(method=method)
    simulate(m, p, u, duration, opts)  # warm-up (builds the step function)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = simulate(m, p, u, duration, opts)
        times.append(time.perf_counter() - t0)
    stuck = float(np.mean(r.state("omega_R1") == 0.0))
    return {"method": method, "median": float(np.median(times)), "p95": float(np.percentile(times, 95)),
            "stuck": stuck}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog="example: python benchmarks/"
                                 "bench_simulate.py --repeats 5 --out benchmarks/results/simulate_modal.md")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=None, help="append the markdown table to this file")
    ap.add_argument("--quick", action="store_true", help="5 s simulated, 1 repeat, hybrid and smooth (CI smoke run)")
    args = ap.parse_args(argv)
    global DURATION
    if args.quick:
        args.repeats, DURATION = 1, 5.0
    rows = [bench(mth, args.repeats, DURATION) for mth in (("hybrid", "smooth") if args.quick
                                                           else ("hybrid", "smooth", "cvodes"))]
    base = rows[0]["median"]
    lines = ["| method | median wall [s] | p95 wall [s] | real-time factor | ratio to hybrid | R1 stuck fraction (true speed == 0) |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['median']:.3f} | {r['p95']:.3f} | {DURATION / r['median']:.1f} x | "
                     f"{r['median'] / base:.2f} | {r['stuck']:.3f} |")
    head = (f"### Open-loop simulation, rig3, 60 s at dt = 10 ms (6000 samples, nsub = 10), "
            f"{args.repeats} repeats after warm-up\n\nCommand: `python benchmarks/bench_simulate.py --repeats "
            f"{args.repeats}`  \nMachine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
            f"load average {os.getloadavg()[0]:.1f} at the start of the table\n")
    text = head + "\n" + "\n".join(lines) + "\n"
    publish(text, args.out, append=True)


if __name__ == "__main__":
    main()
