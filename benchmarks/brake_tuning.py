"""Grid search of the semi-active R2 brake gains on the stick-slip scenario.

Criterion: overall severity SSS of the TRUE R1 speed after the control start (lower is
better); ties (within 0.01) are broken by the friction work at pin 2 (wear, energy).
Prints a table and writes benchmarks/results/brake_tuning.md.

    python benchmarks/brake_tuning.py [scenarios/stick_slip_30rpm.toml]
"""

from __future__ import annotations

import itertools
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

GAINS_OVER = (2.0, 5.0, 10.0, 20.0, 40.0, 80.0, 160.0)
GAINS_REL = (0.0, 10.0, 40.0)
TAUS = (0.0, 0.03)


def _one(args):
    path, go, gr, tau = args
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.brake import BrakeController, BrakeOptions
    from mitigate.metrics import closed_loop_metrics
    from mitigate.scenario import load_scenario

    sc = load_scenario(path)
    c = BrakeController(BrakeOptions(gain_overspeed=go, gain_relative=gr, filter_tau=tau), sc.inputs["omega_ref"](0.0),
                        sc.dt * sc.control_every)
    r = run_closed_loop(sc, c)
    return (go, gr, tau), closed_loop_metrics(r, sc.plant_params)


def main(path="scenarios/stick_slip_30rpm.toml"):
    t0 = time.perf_counter()
    grid = [(path, go, gr, tau) for go, gr, tau in itertools.product(GAINS_OVER, GAINS_REL, TAUS)]
    with ProcessPoolExecutor(2) as ex:
        rows = list(ex.map(_one, grid))
    rows.sort(key=lambda r: (round(r[1]["sss"], 2), r[1]["friction_work_pin2"]))
    lines = ["# Brake tuning (grid search)", "",
             f"Scenario `{path}`; estimator as in the scenario; metrics after the control start (true states).",
             "Sorted by SSS (rounded to 0.01), then by friction work at pin 2.", "",
             "| gain_overspeed [N s/rad] | gain_relative [N s/rad] | filter_tau [s] | SSS | SSS last 5 s | stuck | "
             "friction work pin 2 [J] | mean N2 [N] |", "|---|---|---|---|---|---|---|---|"]
    for (go, gr, tau), m in rows:
        lines.append(f"| {go:g} | {gr:g} | {tau:g} | {m['sss']:.3f} | {m['sss_final']:.3f} | "
                     f"{m['stuck_fraction']:.3f} | {m['friction_work_pin2']:.3f} | {m['mean_n2']:.3f} |")
    lines += ["", f"Command: `python benchmarks/brake_tuning.py {path}` ({time.perf_counter() - t0:.0f} s on 2 workers)."]
    text = "\n".join(lines) + "\n"
    print(text)
    Path("benchmarks/results").mkdir(parents=True, exist_ok=True)
    Path("benchmarks/results/brake_tuning.md").write_text(text)


if __name__ == "__main__":
    main(*sys.argv[1:])
