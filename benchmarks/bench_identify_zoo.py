"""Identification speed on any rig: the rig zoo and a user's rig (writes a section of benchmarks/results/identify.md).

Run from the repository root::

    PYTHONPATH=. python benchmarks/bench_identify_zoo.py            # 4 corners + 6 examples + the user rig
    PYTHONPATH=. python benchmarks/bench_identify_zoo.py --quick    # CI: 1 corner + the user rig, 10 s logs, prints
    PYTHONPATH=. python benchmarks/bench_identify_zoo.py --profile user_pin_rig   # where the time goes
    PYTHONPATH=. python benchmarks/bench_identify_zoo.py --help

Cases (``benchmarks/_zoo_rigs.py``): the zoo's four CI corners and its first derandomised rigs of up
to 3 bodies (``tests/rig_zoo.py``: speed, torque and DC-motor drives, every friction law, lab to
field scale), and the student's rig ``tests/data/userrig/pin_rig.toml``.  Each: a 60 s log of the
exact plant from rest at the operating point (the rig's sensors and noise), up to 6 free parameters
started 20 % off, the log's encoders untwisted at its start.

Per case: a warm-up fit on the first 2 s (builds or loads the compiled functions; its wall time is
the "compile" column), then the timed fit of the whole log: wall and CPU time (``time.process_time``:
this process and its threads, not the other sessions on the shared cores), iterations (all solves),
how it ended, the largest error in stated total errors (``|estimate - truth| / fit.error``) and the
largest relative error.  Targets (issue 28): median <= 20 s, worst <= 60 s, <= 30 iterations.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_identify as bi  # noqa: E402 - the results file's section writer
from _zoo_rigs import cases, errors_in_bars, rel_errors  # noqa: E402

from estimators.identify import IdentifyOptions, identify  # noqa: E402


def run_case(c, duration: float):
    try:
        log = c.log(seed=3, duration=duration)
    except Exception as exc:  # noqa: BLE001 - e.g. the exact plant ran off: no log to fit
        return dict(error=f"no log: {type(exc).__name__}: {str(exc).splitlines()[0][:100]}")
    o = IdentifyOptions(free=c.free, encoder_zero=c.encoder_zero)
    t0 = time.perf_counter()
    try:
        identify(log.slice(0.0, 2.0), c.model, c.start, o)
    except Exception as exc:  # noqa: BLE001 - a benchmark reports every outcome
        return dict(error=f"warm-up: {type(exc).__name__}: {str(exc).splitlines()[0][:100]}")
    compile_s = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        fit = identify(log, c.model, c.start, o, holdout=c.holdout)
    except Exception as exc:  # noqa: BLE001
        return dict(error=f"{type(exc).__name__}: {str(exc).splitlines()[0][:100]}", compile=compile_s)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    z = errors_in_bars(fit, c.truth)
    rel = rel_errors(fit, c.truth)
    worst = max(z, key=z.get)
    worst_rel = max(rel, key=lambda n: abs(rel[n]))
    if fit.validation is not None:
        from mitigate.commands.identify import holdout_line
        print(f"  {c.name}: {holdout_line(fit.validation, {ch.name: ch.unit for ch in fit.problem.channels})}")
    return dict(fit=fit, wall=wall, cpu=cpu, compile=compile_s, iters=fit.iterations, nsub=fit.nsub,
                worst=f"{worst} {z[worst]:.2g}", worst_rel=f"{worst_rel} {100 * rel[worst_rel]:+.2g} %",
                solves=" + ".join(f"{a.iterations}" for a in fit.attempts))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="1 corner (lab_speed_drive) and the user rig, 10 s logs; prints only")
    ap.add_argument("--examples", type=int, default=6, help="derandomised zoo rigs besides the corners (default 6)")
    ap.add_argument("--duration", type=float, default=None, help="log length [s] (default 60, --quick 10)")
    ap.add_argument("--only", nargs="*", default=None, metavar="CASE", help="run these cases only")
    ap.add_argument("--out", type=Path, default=None, help=f"results file (default {bi.RESULTS.relative_to(bi.ROOT)})")
    ap.add_argument("--no-write", action="store_true", help="print the section only")
    ap.add_argument("--profile", metavar="CASE", default=None,
                    help="profile the timed fit of one case (cProfile, 30 entries by cumulative time); writes nothing")
    args = ap.parse_args(argv)
    duration = args.duration or (10.0 if args.quick else 60.0)
    if not duration > 2.0:
        ap.error(f"--duration must be > 2 s, got {duration}")
    warnings.simplefilter("ignore")
    todo = cases(0 if args.quick else args.examples)
    if args.quick:
        todo = [c for c in todo if c.name in ("lab_speed_drive", "user_pin_rig")]
    if args.only:
        todo = [c for c in todo if c.name in args.only]
    if args.profile:
        import cProfile
        import pstats
        todo = [c for c in cases(args.examples) if c.name == args.profile]
        if not todo:
            ap.error(f"--profile: no case {args.profile!r}")
        prof = cProfile.Profile()
        prof.enable()
        r = run_case(todo[0], duration)
        prof.disable()
        print({k: v for k, v in r.items() if k != "fit"})
        pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
        return 0
    cmd = "benchmarks/bench_identify_zoo.py" + (" --quick" if args.quick else "") + \
        (f" --duration {duration:g}" if args.duration else "")
    lines = ["## Speed on any rig: the rig zoo and a user's rig", "",
             f"Command: `PYTHONPATH=. python {cmd}` ({duration:g} s logs; 2 cores shared with other sessions, "
             f"1-min load average at start {os.getloadavg()[0]:.1f}: wall times vary with it, CPU times much less).",
             "", "| case | rig | free | nsub | compile [s] | wall [s] | CPU [s] | iterations (per solve) | status | "
             "worst error / stated error | worst relative error |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    walls, iters = [], []
    for c in todo:
        r = run_case(c, duration)
        if "error" in r:
            lines.append(f"| {c.name} | {c.describe} | {', '.join(c.free)} | - | {r.get('compile', float('nan')):.1f} "
                         f"| - | - | - | {r['error']} | - | - |")
        else:
            f = r["fit"]
            walls.append(r["wall"])
            iters.append(r["iters"])
            lines.append(f"| {c.name} | {c.describe} | {', '.join(c.free)} | {r['nsub']} | {r['compile']:.1f} | "
                         f"{r['wall']:.1f} | {r['cpu']:.1f} | {r['iters']} ({r['solves']}) | {f.status.value}: "
                         f"{f.message.split(';')[0].split('. Try')[0][:70]} | {r['worst']} | {r['worst_rel']} |")
        print(lines[-1], flush=True)
    if walls:
        lines += ["", f"Wall time: median {np.median(walls):.1f} s, worst {max(walls):.1f} s; iterations: median "
                      f"{np.median(iters):.0f}, worst {max(iters)} ({len(walls)} of {len(todo)} cases fitted).  "
                      f"Targets: median <= 20 s, worst <= 60 s, <= 30 iterations."]
    print("\n".join(lines[-1:]))
    bi.S.results = None if args.no_write or (args.quick and args.out is None) else (args.out or bi.RESULTS)
    bi.replace_section("zoo" + ("_quick" if args.quick else ""), lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
