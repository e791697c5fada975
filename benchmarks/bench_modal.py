"""Benchmark: time of the modal analysis (models.modal) and of the stability map.

Usage: python benchmarks/bench_modal.py [--repeats 7] [--out benchmarks/results/simulate_modal.md]
       python benchmarks/bench_modal.py --quick        # 1 repeat, a 3 x 3 map (CI smoke run)
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from models import get_model
from models.modal import linearise, modes
from models.stability import stability_map

from _results import publish


def timeit(fn, repeats):
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), float(np.percentile(ts, 95))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog="example: python benchmarks/bench_modal.py "
                                 "--repeats 7 --out benchmarks/results/simulate_modal.md")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", default=None)
    ap.add_argument("--quick", action="store_true", help="1 repeat and a 3 x 3 stability map (a smoke run for CI)")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeats = 1
    m = get_model("rig3")
    p = m.published()
    n1, om = (np.linspace(0, 40, 3), np.linspace(0.5, 6.0, 3)) if args.quick else (np.linspace(0, 40, 21),
                                                                                  np.linspace(0.5, 6.0, 23))
    cases = [
        ("modes rig3 free (3-DOF chain, scipy eig)", lambda: modes(m, p, "free")),
        ("modes rig3 clamped", lambda: modes(m, p, "clamped")),
        ("modes rig3 closed (CasADi Jacobian + Newton + eig)", lambda: modes(m, p, "closed")),
        ("linearise rig3 at steady sliding", lambda: linearise(m, p, [np.pi, 20.0, 0.0])),
        (f"stability_map rig3 {n1.size} x {om.size} points", lambda: stability_map(m, p, n1, om, input="n1")),
    ]
    rows = [(name, *timeit(fn, args.repeats if "map" not in name else max(1, args.repeats // 3))) for name, fn in cases]
    lines = ["| task | median [ms] | p95 [ms] |", "|---|---|---|"]
    lines += [f"| {n} | {a * 1e3:.1f} | {b * 1e3:.1f} |" for n, a, b in rows]
    text = (f"### Modal analysis\n\nCommand: `python benchmarks/bench_modal.py --repeats {args.repeats}`  \n"
            f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start\n\n" + "\n".join(lines) + "\n")
    publish(text, args.out, append=True)


if __name__ == "__main__":
    main()
