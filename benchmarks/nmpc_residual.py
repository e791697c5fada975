"""What stays: the NMPC against the industry's laws over switch-on phases and noise seeds.

For every scenario (the benchmark suite ``scenarios/benchmark/*.toml`` and the held-out files
``benchmarks/heldout/*.toml``) and every controller it runs the closed loop at ``--phases``
switch-on instants spread over one stick-slip period and at ``--seeds`` noise seeds, and
reports, from the TRUE plant:

- ``residual``: the severity ``(max - min) / (2 mean)`` of the objective body's speed over the
  last ``max(5 s, 3 stick-slip periods)`` of the run (what stays once transients are over; at
  most half of the controlled time);
- ``speed_ratio``: mean objective speed over that window / the programme's mean there (a
  controller that runs the body fast lowers the severity by cheating);
- ``force_ratio``: per actuated normal force (a servo input), its applied mean after the switch-
  on / the programme's mean (drilling: the weight on bit is the driller's programme);
- ``overshoot``: ``max(w - w_prog) / w_prog`` of the objective body after the switch-on
  (meaningful from rest; after a mid-cycle switch-on it includes the slip under way);
- ``fallbacks``, ``failures``: the controller's counts; ``status``: the run's.

The stick-slip period is measured from the uncontrolled run (the programme alone) over the
max(10 s, 40 %) of the time before the scenario's control start; the phases are ``start + k T / K``.  A scenario whose
control starts at 0 s (prevention from rest) runs at one phase.

The estimator is the one a user would pick (``--estimator user``, the default): each file's own,
except that the finite-difference baseline becomes the EKF (the suite's drill string has the
FD estimator, which holds the motor current and the PI integral at their initial values);
``--estimator scenario`` keeps every file's own, ``--estimator ekf`` forces the default EKF.

Summary rows: per (scenario, controller) the median and the maximum over runs; per scenario the
NMPC variants' median residual over the better of SoftSpeed and Z-Torque (target <= 1.5).

Usage::

    python benchmarks/nmpc_residual.py --quick                       # established, cut at 26 s; 1 phase, 1 seed
    python benchmarks/nmpc_residual.py --phases 3 --seeds 2          # suite + held-out
    python benchmarks/nmpc_residual.py --only suite --controllers nmpc nmpc_motor softspeed ztorque
    python benchmarks/nmpc_residual.py --scenarios scenarios/benchmark/drillstring.toml --nmpc horizon=40
    python benchmarks/nmpc_residual.py --json > out/residual.json
    python benchmarks/nmpc_residual.py --only suite --latency measured   # answers applied after their time
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from multiprocessing import get_context
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from _results import publish  # noqa: E402
SUITE = ROOT / "scenarios" / "benchmark"
HELDOUT = ROOT / "benchmarks" / "heldout"

#: name -> (kind, options) of the controllers this harness knows
CONTROLLERS = {
    "nmpc": ("nmpc", {}),
    "nmpc_motor": ("nmpc", {"inputs": "motor"}),
    "nmpc_pin": ("nmpc", {"inputs": "pin"}),
    "softspeed": ("softspeed", {}),
    "ztorque": ("ztorque", {}),
    "doskil": ("doskil", {}),
    "brake": ("brake", {"gain_overspeed": 80.0, "filter_tau": 0.0}),
}
INDUSTRY = ("softspeed", "ztorque")
NMPCS = ("nmpc", "nmpc_motor", "nmpc_pin")
#: residual window: max(RESIDUAL_MIN_S, RESIDUAL_PERIODS periods), at most half the controlled time
RESIDUAL_MIN_S = 5.0
RESIDUAL_PERIODS = 3.0


def _read(path: Path) -> dict:
    import tomllib
    with open(path, "rb") as f:
        return tomllib.load(f)


def scenario_files(only: str) -> list[Path]:
    suite = [SUITE / n for n in _read(SUITE / "suite.toml")["suite"]["scenarios"]]
    held = sorted(HELDOUT.glob("*.toml")) if HELDOUT.is_dir() else []
    return {"suite": suite, "heldout": held, "all": suite + held}[only]


def build(path: Path, *, seed: int | None = None, start: float | None = None, estimator="user",
          controller: tuple | None = None, duration: float | None = None, latency=None):
    """The scenario of ``path`` with another seed, control start, estimator, duration or
    ``[control] latency`` (``"measured"`` or seconds), and one controller ``(name, kind, options)``."""
    from mitigate.scenario import parse_scenario
    data = _read(path)
    data.pop("controllers", None)
    sc = data.setdefault("scenario", {})
    if seed is not None:
        sc["seed"] = int(seed)
    if duration is not None:
        sc["duration"] = float(duration)
    if start is not None:
        data.setdefault("control", {})["start"] = float(start)
    if latency is not None:
        data.setdefault("control", {})["latency"] = latency
    if isinstance(estimator, dict):
        data["estimator"] = dict(estimator)
    elif estimator == "user":
        if data.get("estimator", {}).get("kind", "ekf") == "fd":
            data["estimator"] = {"kind": "ekf"}
    elif estimator != "scenario":
        data["estimator"] = {"kind": estimator}
    if controller is not None:
        name, kind, opts = controller
        data["controllers"] = [{"name": name, "kind": kind, **opts}]
    return parse_scenario(data, str(path))


def stick_slip_period(path: Path, duration: float | None = None) -> tuple[float, float]:
    """(period [s] of the uncontrolled stick-slip before the control start, control start [s]);
    ``duration`` cuts the uncontrolled run of a scenario whose control starts after 0 s (``--quick``)."""
    import numpy as np

    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from models.signals import dominant_frequency, stick_slip_cycles

    base = build(path, estimator="fd", controller=("PI only", "pi", {}), duration=duration)
    start = base.control.start
    if start <= 0:
        # prevention from rest: the stick-slip the uncontrolled run develops over 30 s
        base = build(path, estimator="fd", controller=("PI only", "pi", {}), start=0.0,
                     duration=max(30.0, base.duration))
    res = run_closed_loop(base, make_controller(base.controllers[0], context_for(base, 0)))
    w = res.objective_speed
    t1 = start if start > 0 else res.t[-1]
    m = (res.t >= max(0.0, t1 - max(10.0, 0.4 * t1))) & (res.t < t1)
    cyc = stick_slip_cycles(w[m], base.dt, 1e-3)
    if cyc is not None:
        return cyc.period, start
    f = dominant_frequency(w[m], base.dt)   # no stick in the window (unstable sliding): the spectrum
    if not f > 0:
        from models import modes
        f = float(np.min([v for v in modes(base.model, base.model_params, "clamped").freq_hz if v > 0]))
    return 1.0 / f, start


def run_metrics(res, sc, period: float) -> dict:
    """The harness's metrics of one closed-loop run (module docstring)."""
    import numpy as np

    from mitigate.metrics import severity, time_to_suppress
    t, dt = res.t, sc.dt
    m = t >= res.control_start - 1e-12
    w = res.objective_speed
    model = sc.model
    j = model.inputs.index(model.drive_input)
    prog = np.array([sc.programme(tk) for tk in t])
    after = max(t[-1] - res.control_start, dt)
    win = min(max(RESIDUAL_MIN_S, RESIDUAL_PERIODS * period), 0.5 * after)
    last = t >= t[-1] - win + 0.5 * dt
    if not model.drive.sets_speed:
        nominal = float(model.spec.extra.get("operating_point", {}).get("speed", float("nan")))
        w_prog = np.full(len(t), nominal)
    else:
        w_prog = prog[:, j]
    out = {
        "residual": severity(w[last]),
        "speed_ratio": float(np.mean(w[last]) / np.mean(w_prog[last])),
        "overshoot": float(np.max((w[m] - w_prog[m]) / np.abs(w_prog[m]))),
        "t_suppress": time_to_suppress(w[m], dt, max(3.0, RESIDUAL_PERIODS * period), 0.1),
        "fallbacks": int(res.controller_counts.get("fallbacks", 0)),
        "failures": int(res.controller_counts.get("failures", 0)),
        "status": res.status.value,
        "success": bool(res.success),
        "window_s": float(win),
    }
    for name in sc.plant_model.servo_inputs:
        k = sc.plant_model.inputs.index(name)
        pm = float(np.mean(prog[m, model.inputs.index(name)]))
        out[f"force_ratio:{name}"] = float(np.mean(res.u[m, k]) / pm) if pm > 0 else float("nan")
        out[f"force_mean:{name}"] = float(np.mean(res.u[m, k]))
    if len(res.solve_times):
        st = np.asarray(res.solve_times)[np.asarray(res.plan_calls, bool)]
        out["plan_median_ms"] = 1e3 * float(np.median(st)) if st.size else float("nan")
    return out


def job(args) -> dict:
    path, cname, kind, opts, seed, start, estimator, period, latency, duration = args
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    t0 = time.perf_counter()
    try:
        sc = build(Path(path), seed=seed, start=start, estimator=estimator, controller=(cname, kind, opts),
                   latency=latency, duration=duration)
        res = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
        met = run_metrics(res, sc, period)
    except Exception as exc:  # noqa: BLE001 - a failed build or run is a result of its own
        met = {"status": "failed", "message": f"{type(exc).__name__}: {exc}", "residual": float("nan")}
    met.update(scenario=Path(path).stem, controller=cname, seed=seed, start=start, elapsed=time.perf_counter() - t0)
    return met


def applicable(path: Path, name: str) -> bool:
    """Whether controller ``name`` can act on the scenario's rig (the pin class needs a servo)."""
    from models import get_model
    data = _read(path)
    m = get_model(data["scenario"]["model"] if "/" not in data["scenario"]["model"]
                  else str((path.parent / data["scenario"]["model"]).resolve()))
    kind, opts = CONTROLLERS[name]
    if kind in ("doskil", "brake") or opts.get("inputs") == "pin":
        return bool(m.servo_inputs)
    if name == "nmpc" and not m.servo_inputs:
        return False   # "both" is the motor-only NMPC on a rig without a servo
    return True


def summarise(rows: list[dict]) -> tuple[list[dict], list[dict]]:
    import numpy as np
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["scenario"], r["controller"]), []).append(r)
    summ = []
    for (s, c), rs in groups.items():
        res = np.array([r.get("residual", np.nan) for r in rs], float)
        row = {"scenario": s, "controller": c, "n_runs": len(rs),
               "residual_median": float(np.median(res)), "residual_max": float(np.max(res)),
               "speed_ratio": float(np.median([r.get("speed_ratio", np.nan) for r in rs])),
               "overshoot_max": float(np.max([r.get("overshoot", np.nan) for r in rs])),
               "fallbacks": int(sum(r.get("fallbacks", 0) for r in rs)),
               "failed": int(sum(not r.get("success", False) for r in rs))}
        forces = sorted({k for r in rs for k in r if k.startswith("force_ratio:")})
        for k in forces:
            row[k] = float(np.median([r.get(k, np.nan) for r in rs]))
        summ.append(row)
    verdict = []
    for s in dict.fromkeys(r["scenario"] for r in summ):
        by = {r["controller"]: r for r in summ if r["scenario"] == s}
        ind = [by[c]["residual_median"] for c in INDUSTRY if c in by]
        best = min(ind) if ind else float("nan")
        for c in NMPCS:
            if c in by:
                ratio = by[c]["residual_median"] / best if best > 0 else float("nan")
                verdict.append({"scenario": s, "controller": c, "residual": by[c]["residual_median"],
                                "best_industry": best, "ratio": ratio,
                                "meets_1_5x": bool(ratio <= 1.5) if math.isfinite(ratio) else None})
    return summ, verdict


def _kv(items) -> dict:
    out = {}
    for it in items or []:
        k, _, v = it.partition("=")
        if not _ or not k:
            raise SystemExit(f"nmpc_residual: --nmpc expects NAME=VALUE, got {it!r}")
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", choices=("suite", "heldout", "all"), default="all", help="which scenario set")
    ap.add_argument("--scenarios", nargs="+", type=Path, help="scenario files instead of --only")
    ap.add_argument("--controllers", nargs="+", default=list(CONTROLLERS), choices=list(CONTROLLERS))
    ap.add_argument("--phases", type=int, default=3, help="switch-on instants over one stick-slip period")
    ap.add_argument("--seeds", type=int, default=2, help="noise seeds (scenario seed + 0, 1, ...)")
    ap.add_argument("--estimator", default="user",
                    help="'user' (each file's own, FD replaced by the EKF), 'scenario', or a kind for every scenario")
    ap.add_argument("--nmpc", nargs="*", metavar="NAME=VALUE", help="options for every NMPC variant (JSON values)")
    ap.add_argument("--latency", help="[control] latency for every run: 'measured' (each answer applied after "
                                      "its measured computation time) or a time such as '3 ms'")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--quick", action="store_true",
                    help="established only, cut at 26 s (control from 20 s), 1 phase, 1 seed, NMPC motor vs "
                         "SoftSpeed, one worker process")
    ap.add_argument("--json", action="store_true", help="one JSON document on stdout")
    ap.add_argument("--out", type=Path, help="write the markdown tables here")
    args = ap.parse_args(argv)
    if args.phases < 1 or args.seeds < 1 or args.jobs < 1:
        print("nmpc_residual: --phases, --seeds and --jobs must be >= 1", file=sys.stderr)
        return 2
    files = args.scenarios or scenario_files(args.only)
    ctrls = args.controllers
    duration = None   # each file's own
    if args.quick:
        files, ctrls, args.phases, args.seeds = [SUITE / "established.toml"], ["nmpc_motor", "softspeed"], 1, 1
        duration = 26.0   # control from 20 s: 6 s of it (a 3 s residual window)
        args.jobs = 1     # one worker process: one start-up instead of two for three runs
    for f in files:
        if not Path(f).is_file():
            print(f"nmpc_residual: scenario file {f} not found", file=sys.stderr)
            return 2
    extra = _kv(args.nmpc)
    t0 = time.perf_counter()
    ctx = get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=ctx) as ex:
        periods = dict(zip(files, ex.map(partial(stick_slip_period, duration=duration), files)))
        jobs = []
        for f in files:
            T, start = periods[f]
            base_seed = _read(f)["scenario"].get("seed", 0)
            starts = [start] if start <= 0 else [start + k * T / args.phases for k in range(args.phases)]
            for name in ctrls:
                if not applicable(f, name):
                    continue
                kind, opts = CONTROLLERS[name]
                opts = {**opts, **extra} if kind == "nmpc" else opts
                for s in range(args.seeds):
                    for st in starts:
                        jobs.append((str(f), name, kind, opts, base_seed + s, round(st, 6), args.estimator, T,
                                     args.latency, duration))
        from tqdm import tqdm
        rows = list(tqdm(ex.map(job, jobs), total=len(jobs), desc="runs", disable=args.json or None, leave=False))
    elapsed = time.perf_counter() - t0
    summ, verdict = summarise(rows)
    if args.json:
        print(json.dumps({"periods": {Path(f).stem: p[0] for f, p in periods.items()}, "runs": rows,
                          "summary": summ, "verdict": verdict, "elapsed_s": elapsed}, indent=1, default=float))
        return 0
    text = render(summ, verdict, periods, args, elapsed, argv)
    publish(text, args.out)
    for r in rows:
        if not r.get("success", False):
            print(f"FAILED {r['scenario']} {r['controller']} seed {r['seed']} start {r['start']}: "
                  f"{r.get('message', r.get('status'))}")
    return 0


def _verdict(meets) -> str:
    return "-" if meets is None else ("yes" if meets else "**no**")   # -: no industry run to compare


def render(summ, verdict, periods, args, elapsed, argv) -> str:
    forces = sorted({k for r in summ for k in r if k.startswith("force_ratio:")})
    cmd = "python benchmarks/nmpc_residual.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = [f"Command: `{cmd.strip()}`", "",
             f"{args.phases} phase(s) x {args.seeds} seed(s); estimator {args.estimator}; latency "
             f"{args.latency or 0}; {elapsed:.0f} s on "
             f"{os.cpu_count()} cores ({platform.machine()}); stick-slip periods: "
             + ", ".join(f"{Path(f).stem} {p[0]:.2f} s" for f, p in periods.items()), "",
             "| scenario | controller | runs | residual median | residual max | mean speed / programme "
             "| peak overshoot | " + " | ".join(f"mean {k[12:]} / programme" for k in forces)
             + (" | " if forces else "") + "fallbacks | failed |",
             "|---|---|---|---|---|---|---|" + "---|" * len(forces) + "---|---|"]
    for r in summ:
        fs = " | ".join("-" if k not in r or not math.isfinite(r[k]) else f"{r[k]:.2f}" for k in forces)
        lines.append(f"| {r['scenario']} | {r['controller']} | {r['n_runs']} | {r['residual_median']:.4f} "
                     f"| {r['residual_max']:.4f} | {r['speed_ratio']:.3f} | {r['overshoot_max']:.2f} | "
                     + (fs + " | " if forces else "") + f"{r['fallbacks']} | {r['failed']} |")
    lines += ["", "| scenario | NMPC variant | residual | best of SoftSpeed, Z-Torque | ratio | <= 1.5x |",
              "|---|---|---|---|---|---|"]
    for v in verdict:
        lines.append(f"| {v['scenario']} | {v['controller']} | {v['residual']:.4f} | {v['best_industry']:.4f} "
                     f"| {v['ratio']:.2f} | {_verdict(v['meets_1_5x'])} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
