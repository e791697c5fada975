"""NMPC time per plan in closed loop on the stick-slip case (N1 = 20 N, 30 rpm).

The exact stick/slip plant (models.plant.Plant, hybrid) starts from established
stick-slip (10 s from rest, no control), then the NMPC runs on the true state for
``--duration`` seconds, planning every OCP interval dt = 0.05 s (every 5th DAQ sample;
held in between).  Timed: wall time of each plan (``Controller.step`` calls that
solve), after a warm-up plan that is excluded.  Reported against the 10 ms DAQ period.

Usage::

    python benchmarks/bench_nmpc.py                       # N = 20, 50; rti, sqp, ipopt
    python benchmarks/bench_nmpc.py --horizons 50 --solvers rti --out benchmarks/results/nmpc.md
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from estimators.base import Estimate
from mitigate.controllers.nmpc import make_nmpc
from mitigate.metrics import severity
from models import get_model
from models.actuators import ServoOptions
from models.plant import Plant, SimOptions

W0 = np.pi
DO_MPC_MS = 15.5  # do-mpc's own smaller 3-disc example, ms per step (issue 5)


def run(solver: str, horizon: int, duration: float, extra: dict) -> dict:
    m = get_model("rig3")
    p = m.published()
    servo = ServoOptions()
    base = Plant(m, p, SimOptions(seed=0), sensors=None, servo=servo)
    for _ in range(1000):
        base.step([W0, 20.0, 0.0])
    t_build = time.perf_counter()
    c = make_nmpc({"horizon": horizon, "solver": solver, **extra}, p, 0.01, W0, servo, "bench")
    t_build = time.perf_counter() - t_build
    plant = Plant(m, p, SimOptions(seed=0), sensors=None, servo=servo, x0=base.x)
    times, prep, allc, w1, n2 = [], [], [], [], []
    after_plan = False
    n = int(round(duration / 0.01))
    for k in range(n):
        t = base.t + k * 0.01
        est = Estimate(t=t, x=plant.x.copy(), P=None, names=m.states, status="ok", success=True)
        a = c.step(t, est, plant.measure())
        if not a.status.startswith("hold"):
            times.append(a.solve_time)
            after_plan = True
        elif after_plan:
            prep.append(a.solve_time)  # RTI preparation phase runs in this held sample
            after_plan = False
        allc.append(a.solve_time)
        plant.step([a.omega_ref, 20.0, a.n2])
        w1.append(plant.x[2])
        n2.append(plant.u_applied[2])
    ts = 1e3 * np.array(times[1:])  # first plan (warm-up, cold caches) excluded
    tp = 1e3 * np.array(prep[1:]) if len(prep) > 1 else np.array([np.nan])
    busy = 1e3 * np.array(allc[1:])
    w1 = np.array(w1)
    tail = w1[-int(2.0 / 0.01):]
    return dict(solver=solver, N=horizon, median=np.median(ts), p95=np.percentile(ts, 95), max=ts.max(),
                prep_median=np.median(tp), prep_p95=np.percentile(tp, 95), call_max=busy.max(),
                per_sample=busy.mean(),
                plans=len(ts), failures=c.counts.failures, nsub=c.nsub, build=t_build,
                sev=severity(tail), pin_work=float(np.sum(np.array(n2)) * 0.01))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--horizons", type=int, nargs="+", default=[20, 50])
    ap.add_argument("--solvers", nargs="+", default=["rti", "sqp", "ipopt"])
    ap.add_argument("--duration", type=float, default=6.0, help="closed-loop seconds per case")
    ap.add_argument("--eps", type=float, default=0.05)
    ap.add_argument("--no-prepare", action="store_true", help="RTI without the preparation/feedback split")
    ap.add_argument("--out", default="")
    ap.add_argument("--append", action="store_true", help="append the table to --out instead of replacing it")
    args = ap.parse_args(argv)
    rows = []
    for N in args.horizons:
        for s in args.solvers:
            r = run(s, N, args.duration, {"eps": args.eps, "prepare_ahead": not args.no_prepare})
            rows.append(r)
            print(f"{s:6s} N={N:3d} median {r['median']:7.2f} ms  p95 {r['p95']:7.2f}  max {r['max']:7.2f}  "
                  f"plans {r['plans']}  fail {r['failures']}  sev(last 2 s) {r['sev']:.3f}  build {r['build']:.1f} s",
                  flush=True)
    head = ("| solver | N | plan call median [ms] | p95 [ms] | max [ms] | prep call median / p95 [ms] "
            "| max of any call [ms] | mean per DAQ sample [ms] | plan median / 10 ms DAQ | do-mpc 15.5 ms / plan median "
            "| plans | failures | severity R1 (last 2 s) |\n|" + "---|" * 13 + "\n")
    body = "".join(
        f"| {r['solver']} | {r['N']} | {r['median']:.2f} | {r['p95']:.2f} | {r['max']:.2f} "
        f"| {r['prep_median']:.2f} / {r['prep_p95']:.2f} | {r['call_max']:.2f} | {r['per_sample']:.2f} "
        f"| {r['median'] / 10:.2f} | {DO_MPC_MS / r['median']:.1f}x | {r['plans']} | {r['failures']} | {r['sev']:.3f} |\n"
        for r in rows)
    cmd = "python " + " ".join([os.path.relpath(__file__)] + (argv if argv is not None else sys.argv[1:]))
    info = (f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
            f"dt_ocp = 0.05 s, RK4 substeps {rows[0]['nsub']} (eps = {args.eps} rad/s), "
            f"{args.duration} s closed loop per case; preparation/feedback split "
            f"{'off' if args.no_prepare else 'on'}; load average at the end "
            f"{os.getloadavg()[0]:.1f} (shared machine: other jobs were running)\n")
    table = head + body
    print(table)
    if args.out:
        from models.logs import atomic_write_text
        text = f"Command: `{cmd}`\n\n{info}\n{table}\n"
        if args.append and os.path.exists(args.out):
            text = open(args.out).read() + "\n" + text
        else:
            text = "# NMPC time per plan\n\n" + text
        atomic_write_text(args.out, text, overwrite=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
