"""``mitigate sweep``: stick-slip maps over a grid of scenario fields (seed 002 Figs. 9.31-9.33)."""

from __future__ import annotations

import time
from pathlib import Path

from models.errors import ConfigError
from models.files import check_output_dir, file_stem, output_set
from mitigate.cliutil import add_command, add_common, emit_json, format_table, quantity

EPILOG = """\
axes: --vary name=start:stop:count (count linearly spaced values, both ends included); name is
  an input of the rig (n1, omega_ref, axial_force, omega_drive: the profile becomes a constant),
  a plant parameter (k1, d1, c, K, motor_torque_offset: replaced), <param>_scale (K_scale:
  multiplies the plant value) or mismatch.<param> (replaces the mismatch factor on the nominal value).
  start and stop are SI numbers or, for an input or a parameter, values with a unit as in rig files
  (--vary "omega_ref=10 rpm:60 rpm:6"). Without --vary the scenario's [sweep] vary list is used.
  --duration, --settle and --scheduler-timeout take seconds or a time with its unit ("2 min").

The sweep folder (--out) holds manifest.json, chunks/*.csv (one per finished chunk,
written atomically), results.csv and the PNG maps.  Rerunning the same command resumes
(finished chunks are not recomputed); a different grid into the same folder is refused
unless --force (which discards the old chunks).

examples:
  mitigate sweep scenarios/sweep_rig3.toml --out out/sweep_rig3
  mitigate sweep scenarios/sweep_rig3.toml --vary n1=5:40:50 --vary omega_ref=1:8:50 --start both
  mitigate sweep scenarios/sweep_rig3.toml --vary "omega_ref=10 rpm:75 rpm:20" --duration "1 min"
  mitigate sweep scenarios/sweep_leadscrew.toml --vary omega_drive=20:90:30 --vary axial_force=50:400:30
  mitigate sweep scenarios/sweep_rig3.toml --scheduler tcp://10.0.0.5:8786
"""


def register(sub) -> None:
    p = add_command(sub, "sweep", help="stick-slip maps over a grid of inputs/parameters (resumable, parallel)",
                    description=__doc__, epilog=EPILOG)
    p.add_argument("scenario", help="scenario TOML (its [sweep] table sets defaults)")
    p.add_argument("--vary", action="append", default=None, metavar="NAME=START:STOP:COUNT",
                   help="a sweep axis (repeatable; the first is the horizontal axis of the maps)")
    p.add_argument("--controller", default=None, metavar="NAME",
                   help="closed loop with this [[controllers]] entry of the scenario")
    p.add_argument("--start", choices=("rest", "sliding", "both"), default=None,
                   help="initial state of each run (default: sweep.start of the scenario, else rest)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler (tcp://host:port) to send chunks to; default: local processes")
    p.add_argument("--scheduler-timeout", type=quantity("time", lo=0.0, lo_open=True), default=10.0, metavar="TIME",
                   help="how long to wait for the Dask scheduler, in s or with a unit (default 10 s)")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: CPU count)")
    p.add_argument("--duration", type=quantity("time", lo=0.0, lo_open=True), default=None, metavar="TIME",
                   help="time per run, in s or with a unit (\"2 min\"; default: sweep/scenario)")
    p.add_argument("--settle", type=quantity("time", lo=0.0), default=None, metavar="TIME",
                   help="time discarded before the metrics, in s or with a unit (default: half the run)")
    p.add_argument("--chunk", type=int, default=None, help="points per chunk (unit of resuming)")
    p.add_argument("--backend", choices=("compiled", "vm"), default="compiled",
                   help="compiled: plant step compiled to C once (cached); vm: CasADi virtual machine")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-stability", action="store_true",
                   help="skip the linear stability of steady sliding (models.modal) and its boundary line")
    add_common(p, out=False)
    p.add_argument("--out", default=None, metavar="DIR", help="sweep folder (default: out/sweep-<scenario name>)")
    p.add_argument("--force", action="store_true", help="discard a different sweep already in --out")
    p.set_defaults(func=run)


def run(args) -> int:
    from mitigate.scenario import load_scenario
    from mitigate.sweep import (SweepStore, axis_units, closed_loop_controller, connect_scheduler, options_from_scenario, parse_axis,
                                plan_sweep, run_sweep)
    from mitigate.sweep.maps import plot_maps

    if args.out is not None:
        check_output_dir(args.out)
    sc = load_scenario(args.scenario)
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    opts = options_from_scenario(sc, start=args.start, duration=args.duration, settle=args.settle,
                                 chunk=args.chunk, backend=args.backend)
    vary = args.vary if args.vary else sc.sweep.get("vary", [])
    if not isinstance(vary, list) or not all(isinstance(v, str) for v in vary):
        raise ConfigError(f"sweep.vary must be a list of 'name=start:stop:count' strings, got {vary!r}")
    try:
        axes = [parse_axis(v, axis_units(sc)) for v in vary]
        plan = plan_sweep(sc, axes, opts)
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("axis ", "--vary ", 1).replace("axes:", "--vary:", 1)) from None
    try:
        closed_loop_controller(plan, args.controller)      # a known entry that switches on within the runs
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("controller must be", "--controller must be", 1)) from None
    out = check_output_dir(Path(args.out) if args.out else Path("out") / f"sweep-{file_stem(sc.name, 'scenario.name')}")
    t0 = time.perf_counter()
    model = sc.plant_model
    amp_unit = model.state_units[model.states.index(opts.amplitude_of)]
    client = connect_scheduler(args.scheduler, args.scheduler_timeout) if args.scheduler else None   # before any file is written
    try:
        # the store's hash guards a different sweep; the lock guards a second command into the same folder
        with output_set(out, [], force=True) as w:
            store = SweepStore(out, plan.definition(args.controller), force=args.force)
            res = run_sweep(plan, store, workers=args.workers, client=client, controller=args.controller,
                            progress=not (args.no_progress or args.json), stability=not args.no_stability)
            files = [w.final(f.name) for f in plot_maps(res, w.dir, title=f"{sc.name} ({opts.amplitude_of} amplitude)",
                                                        amp_unit=amp_unit, threshold=opts.threshold,
                                                        units=axis_units(sc))]
    finally:
        if client is not None:
            client.close()
    elapsed = time.perf_counter() - t0
    summary = []
    for start, maps in res.maps.items():
        lc = maps["limit_cycle"]
        summary.append([start, plan.n_points, float((lc > 0.5).sum()), float(maps["amplitude"].max()),
                        float(maps["severity"].max())])
    if args.json:
        emit_json({"scenario": sc.name, "out": str(out), "hash": store.hash, "points": plan.n_points,
                   "axes": [a.spec() for a in plan.axes], "starts": list(opts.starts),
                   "chunks_computed": res.computed, "chunks_reused": res.reused, "elapsed_s": elapsed,
                   "status": res.status.value, "message": res.message,
                   "limit_cycle_points": {r[0]: int(r[2]) for r in summary},
                   "files": [str(out / "results.csv")] + [str(f) for f in files]})
    else:
        print(f"sweep {sc.name}: {plan.n_points} points x {len(opts.starts)} start(s), "
              f"{res.computed} chunk(s) computed, {res.reused} reused, {elapsed:.1f} s -> {out}")
        print(format_table(["start", "points", "limit cycles", f"max amplitude [{amp_unit}]", "max severity"], summary))
        print(f"status: {res.message}")
    return 0 if res.success else 1
