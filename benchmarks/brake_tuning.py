"""Grid search of the semi-active R2 brake gains on the stick-slip scenario.

Criterion: overall severity SSS of the TRUE R1 speed after the control start (lower is
better); ties (within 0.01) are broken by the friction work at the servo pin (wear, energy).
Prints a table and writes benchmarks/results/brake_tuning.md.

    PYTHONPATH=. python benchmarks/brake_tuning.py [scenarios/stick_slip_30rpm.toml] [--estimator fd]
    PYTHONPATH=. python benchmarks/brake_tuning.py --quick     # 1 gain, 25 s, prints only (CI smoke run)

The estimator is the scenario's unless ``--estimator`` names another kind; a kind this checkout
does not have (the EKF lands from another branch) falls back to ``fd``, and the output says so.
"""

from __future__ import annotations

import argparse
import itertools
import os
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
GAINS_OVER = (2.0, 5.0, 10.0, 20.0, 40.0, 80.0, 160.0)
GAINS_REL = (0.0, 10.0, 40.0)
TAUS = (0.0, 0.03)


def _scenario(path: str, estimator: str | None):
    from estimators.base import EstimatorContext
    from estimators.online.factory import make_estimator
    from mitigate.scenario import load_scenario
    from models.errors import ConfigError

    sc = load_scenario(path)
    if estimator:
        sc = sc.replace(estimator={"kind": estimator})
    try:
        make_estimator(sc.estimator, EstimatorContext(sc.model, sc.model_params, sc.dt, sc.sensors))
        note = ""
    except ConfigError as exc:
        note = f"estimator {sc.estimator.get('kind')!r} not available here ({exc}); used 'fd'"
        sc = sc.replace(estimator={"kind": "fd"})
    return sc, note


def _one(args):
    path, estimator, go, gr, tau, duration = args
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.brake import BrakeController, BrakeOptions
    from mitigate.controllers.factory import context_for
    from mitigate.metrics import closed_loop_metrics

    sc, _ = _scenario(path, estimator)
    if duration:
        sc = sc.replace(duration=duration)
    c = BrakeController(BrakeOptions(gain_overspeed=go, gain_relative=gr, filter_tau=tau), context_for(sc))
    r = run_closed_loop(sc, c)
    return (go, gr, tau), closed_loop_metrics(r, sc)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog="example: PYTHONPATH=. python "
                                 "benchmarks/brake_tuning.py scenarios/stick_slip_30rpm.toml --estimator fd --jobs 2")
    ap.add_argument("scenario", nargs="?", default=str(ROOT / "scenarios" / "stick_slip_30rpm.toml"))
    ap.add_argument("--estimator", default=None, help="estimator kind (default: the scenario's)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--quick", action="store_true",
                    help="1 gain (gain_overspeed 80), the scenario cut to 25 s, in this process; prints only (a "
                         "smoke run for CI)")
    args = ap.parse_args(argv)
    path = args.scenario
    sc, note = _scenario(path, args.estimator)
    t0 = time.perf_counter()
    if args.quick:
        grid = [(path, args.estimator, go, 0.0, 0.03, 25.0) for go in (80.0,)]
        rows = [_one(g) for g in grid]
    else:
        grid = [(path, args.estimator, go, gr, tau, None)
                for go, gr, tau in itertools.product(GAINS_OVER, GAINS_REL, TAUS)]
        with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as ex:
            rows = list(ex.map(_one, grid))
    rows.sort(key=lambda r: (round(r[1]["sss"], 2), r[1]["pin_work"]))
    lines = ["# Brake tuning (grid search)", "",
             f"Scenario `{path}`; estimator `{sc.estimator['kind']}`"
             + (f" ({note})" if note else "") + "; metrics after the control start (true states).",
             "Sorted by SSS (rounded to 0.01), then by the friction work at the servo pin.", "",
             "| gain_overspeed [N s/rad] | gain_relative [N s/rad] | filter_tau [s] | SSS | SSS last 5 s | stuck | "
             "pin work [J] | mean pin force [N] |", "|---|---|---|---|---|---|---|---|"]
    for (go, gr, tau), m in rows:
        lines.append(f"| {go:g} | {gr:g} | {tau:g} | {m['sss']:.3f} | {m['sss_final']:.3f} | "
                     f"{m['stuck_fraction']:.3f} | {m['pin_work']:.3f} | {m['mean_pin_force']:.3f} |")
    cmd = f"PYTHONPATH=. python benchmarks/brake_tuning.py {path}" + (f" --estimator {args.estimator}"
                                                                       if args.estimator else "")
    where = "in this process" if args.quick else f"on {args.jobs} workers"
    lines += ["", f"Command: `{cmd}{' --quick' if args.quick else ''}` ({time.perf_counter() - t0:.0f} s {where})."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.quick:
        return
    (ROOT / "benchmarks" / "results").mkdir(parents=True, exist_ok=True)
    (ROOT / "benchmarks" / "results" / "brake_tuning.md").write_text(text)


if __name__ == "__main__":
    main()
