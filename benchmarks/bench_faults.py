"""What the fault handling costs: the guarded plug-in call, the worker pool, the main job.

1. **Guarded call** (:func:`models.plugins.call`, used for every ``step``/``update``/``reset``): the
   wall time of a trivial call through the guard against a direct call, median over many calls, under
   a :func:`models.plugins.watchdog` as in a closed loop and alone (a one-shot timer per call); and
   per closed loop (``calls per run x overhead``).
2. **Worker pool** (:class:`mitigate.workers.WorkerPool`): the time from creating the pool to the result
   of two trivial tasks in two spawned workers (the start-up every ``run``/``sweep``/``benchmark`` pays).
3. **Main job** (``mitigate run scenarios/stick_slip_30rpm.toml --out DIR --force``): the command's wall
   time, and the CPU time of it and its workers (less sensitive to other load), with this tree against a
   reference tree (``--reference``, e.g. an export of ``main``:
   ``git archive main | tar -x -C /tmp/main_src``), alternating the two so that machine load hits
   both alike; medians and their ratio.

Usage::

    python benchmarks/bench_faults.py --quick                          # 1 and 2 only, a few seconds
    python benchmarks/bench_faults.py --reference /tmp/main_src --repeats 5
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def guarded_call(n: int) -> dict:
    from models import plugins

    def f(x):
        return x

    direct, guarded, watched = [], [], []
    for _ in range(n):
        t0 = time.perf_counter()
        f(1.0)
        direct.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        plugins.call(f, 1.0, timeout=2.0, what="step")
        guarded.append(time.perf_counter() - t0)
    with plugins.watchdog(2.0):            # as in a closed loop: one periodic alarm, no timer per call
        for _ in range(n):
            t0 = time.perf_counter()
            plugins.call(f, 1.0, timeout=2.0, what="step")
            watched.append(time.perf_counter() - t0)
    return {"direct_us": 1e6 * statistics.median(direct), "guarded_us": 1e6 * statistics.median(guarded),
            "watched_us": 1e6 * statistics.median(watched)}


def _noop(x):
    return x


def pool_startup(repeats: int) -> list[float]:
    from mitigate.workers import WorkerPool

    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        with WorkerPool(2) as pool:
            list(pool.map(_noop, [(1,), (2,)]))
        times.append(time.perf_counter() - t0)
    return times


def main_job(tree: Path, out: Path) -> tuple[float, float]:
    """``(wall time, CPU time of the command and its workers)`` [s] of one main job."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "mitigate.cli", "run", str(ROOT / "scenarios/stick_slip_30rpm.toml"),
                        "--out", str(out), "--force", "--json"], env=env, cwd=tree, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise SystemExit(f"{tree}: the main job failed: {p.stderr.strip()[-300:]}")
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("Usage::")[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the guarded call and the pool only (CI)")
    ap.add_argument("--reference", type=Path, help="a source tree to compare the main job with (e.g. main)")
    ap.add_argument("--repeats", type=int, default=3, help="main-job runs per tree (default 3)")
    a = ap.parse_args(argv)

    g = guarded_call(2000 if a.quick else 20000)
    calls = 3001 + 2001                      # one 60 s run at 10 ms: estimator updates + controller steps
    print(f"guarded call: {g['watched_us']:.2f} us in a closed loop (watchdog), {g['guarded_us']:.2f} us alone "
          f"(one-shot timer), against {g['direct_us']:.2f} us direct (medians); about "
          f"{1e-3 * calls * (g['watched_us'] - g['direct_us']):.1f} ms per 60 s closed loop")
    ps = pool_startup(1 if a.quick else 3)
    print(f"worker pool, 2 spawned workers, 2 trivial tasks: median {statistics.median(ps):.2f} s "
          f"({', '.join(f'{x:.2f}' for x in ps)})")
    if a.quick:
        return 0
    trees = [("this tree", ROOT)] + ([("reference", a.reference.resolve())] if a.reference else [])
    times: dict[str, list[tuple[float, float]]] = {name: [] for name, _ in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(a.repeats):
            for name, tree in trees:
                times[name].append(main_job(tree, Path(tmp) / name.replace(" ", "_")))
    med = {}
    for name, ts in times.items():
        med[name] = (statistics.median(w for w, _ in ts), statistics.median(c for _, c in ts))
        print(f"main job, {name}: wall median {med[name][0]:.1f} s ({', '.join(f'{w:.1f}' for w, _ in ts)}); "
              f"CPU median {med[name][1]:.1f} s ({', '.join(f'{c:.1f}' for _, c in ts)})")
    if a.reference:
        print(f"ratio this tree / reference: wall {med['this tree'][0] / med['reference'][0]:.2f}, "
              f"CPU {med['this tree'][1] / med['reference'][1]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
