"""Benchmark: the per-step cost on rig3 of the plant, the EKF and the NMPC (no loss of speed).

Runs one closed loop of rig3 (30 rpm, N1 = 20 N, from rest, control from 2 s) with the EKF and
the NMPC, and times separately 2000 plant steps.  Reports medians [us]: plant step
(``Plant.step``, sensors on), EKF update (``estimator_times``), NMPC feedback calls and
preparation (plan) calls (``solve_times`` split by ``plan_calls``).  Uses only the public API
that every version of the workbench has, so the same script measures another checkout
(``PYTHONPATH=/path/to/checkout python benchmarks/bench_rig3_steps.py``) for a before/after ratio.

Usage: python benchmarks/bench_rig3_steps.py [--quick] [--duration 12] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np


def measure(duration: float, plant_steps: int) -> dict:
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import make_controller
    from mitigate.scenario import make_scenario
    from models import get_model
    from models.plant import Plant, SimOptions

    m = get_model("rig3")
    plant = Plant(m, m.published(), SimOptions(), u0=np.array([np.pi, 20.0, 0.0]))
    u = np.array([np.pi, 20.0, 0.0])
    for _ in range(50):
        plant.step(u)
    times = []
    for _ in range(plant_steps):
        t0 = time.perf_counter()
        plant.step(u)
        times.append(time.perf_counter() - t0)
    sc = make_scenario(name="steps", duration=duration, inputs={"omega_ref": "30 rpm", "n1": 20.0, "n2": 0.0},
                       controllers=[{"name": "NMPC", "kind": "nmpc"}], estimator="ekf", control_start=2.0)
    try:                             # make_controller(spec, context) since the faults branch; (spec, scenario, i) before
        from mitigate.controllers.factory import context_for
        ctrl = make_controller(sc.controllers[0], context_for(sc, 0))
    except (TypeError, AttributeError):
        ctrl = make_controller(sc.controllers[0], sc, 0)
    r = run_closed_loop(sc, ctrl)
    st, plan = np.asarray(r.solve_times, float), np.asarray(r.plan_calls, bool)
    return {"module": __import__("models").__file__, "status": r.status.value,
            "plant_us": float(np.median(times) * 1e6),
            "ekf_us": float(np.median(np.asarray(r.estimator_times, float)[1:]) * 1e6),
            "nmpc_feedback_us": float(np.median(st[~plan]) * 1e6) if np.any(~plan) else float("nan"),
            "nmpc_plan_us": float(np.median(st[plan]) * 1e6) if np.any(plan) else float("nan"),
            "nsub_nmpc": int(getattr(ctrl, "nsub", 0)), "fallbacks": int(r.controller_counts.get("fallbacks", 0)),
            "load": os.getloadavg()[0]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="example: python benchmarks/bench_rig3_steps.py --quick --json")
    ap.add_argument("--quick", action="store_true", help="4 s closed loop, 500 plant steps (CI)")
    ap.add_argument("--duration", type=float, default=12.0, help="closed-loop duration [s] (default 12)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    res = measure(4.0 if args.quick else args.duration, 500 if args.quick else 2000)
    if args.json:
        print(json.dumps(res))
    else:
        for k, v in res.items():
            print(f"{k:18s} {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
