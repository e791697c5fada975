"""``mitigate benchmark``: every controller on the open benchmark suite, over switch-on phases and
noise seeds, ranked like for like with intervals."""

from __future__ import annotations

import shlex
import sys

from mitigate.cliutil import add_command, add_common, emit_json, format_table, quantity
from models.errors import ConfigError

EPILOG = """\
The suite file lists the scenarios and the controllers (scenarios/benchmark/suite.toml). Each
controller runs on each scenario at --phases switch-on instants spread over one stick-slip period
(measured on the scenario's uncontrolled run) and --seeds noise seeds; every number is a median
with a 95 % bootstrap interval; controllers are ranked on what stays (the residual severity), then
on how fast they suppress, with ties where the intervals overlap, per actuator class (the drive's
set-point; normal forces; both) and overall, with their effort beside. A controller that leaves
the programme's band of a normal force (the weight on bit) has not done the job.

Every finished run is kept in DIR/runs/: a killed benchmark, started again with the same command,
redoes only the unfinished runs. DIR is locked while it runs; the report is written as one set:
ranking.md, results.csv (one row per run), entries.csv, results.json, benchmark.png,
distribution.png. Each controller call has one control period (a later answer is a counted
deadline miss and the fallback acts). With --tuned, every controller is first
tuned on every scenario with the same --budget (mitigate tune; studies in DIR/tuning/), and the
benchmark runs the tuned values on seeds the tuning did not see.

Add your own controller (a Controller subclass in an importable module) beside the reference
ones with --controller NAME=KIND[,option=value,...].  Exit code 1 when a run failed.

examples:
  mitigate benchmark scenarios/benchmark/suite.toml --out out/benchmark              # 6 phases x 3 seeds
  mitigate benchmark scenarios/benchmark/suite.toml --quick --out out/quick          # 1 phase, 1 seed
  mitigate benchmark scenarios/benchmark/suite.toml --phases 3 --seeds 2 --only established --json
  mitigate benchmark scenarios/benchmark/suite.toml --out out/mine --controller "Mine=my_module:MyController,gain=2"
  mitigate benchmark scenarios/benchmark/suite.toml --scheduler tcp://10.0.0.5:8786 --out out/benchmark
  mitigate benchmark scenarios/benchmark/suite.toml --tuned --budget 30 --out out/tuned
"""


def register(sub) -> None:
    p = add_command(sub, "benchmark", help="rank every controller on the open benchmark suite",
                    description=__doc__, epilog=EPILOG)
    p.add_argument("suite", metavar="SUITE.toml", help="benchmark suite (scenarios/benchmark/suite.toml)")
    p.add_argument("--controller", action="append", default=[], metavar="NAME=KIND[,opt=val]",
                   help="add a controller to the suite's (repeatable)")
    p.add_argument("--only", action="append", default=None, metavar="SCENARIO",
                   help="run only this scenario of the suite (repeatable)")
    p.add_argument("--phases", type=int, default=None, metavar="K",
                   help="switch-on instants per scenario, spread over one stick-slip period (default: the suite's)")
    p.add_argument("--seeds", type=int, default=None, metavar="S", help="noise seeds per phase (default: the suite's)")
    p.add_argument("--quick", action="store_true", help="1 phase and 1 seed (a first look, not a ranking)")
    p.add_argument("--jobs", type=int, default=2, metavar="N", help="local worker processes (default: 2)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler (tcp://host:port) to send the runs to; default: local processes")
    p.add_argument("--scheduler-timeout", type=quantity("time", lo=0.0, lo_open=True), default=10.0, metavar="TIME",
                   help="how long to wait for the Dask scheduler, in s or with a unit (default 10 s)")
    p.add_argument("--tuned", action="store_true", help="tune every controller per scenario first (same --budget)")
    p.add_argument("--budget", type=int, default=20, metavar="N", help="trials per controller and scenario (--tuned)")
    add_common(p, default_out="out/benchmark")
    p.set_defaults(func=run)


def _value(text: str):
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def parse_controller(text: str) -> dict:
    """``NAME=KIND[,option=value,...]`` -> a [[controllers]] table."""
    name, sep, rest = text.partition("=")
    if not sep or not name.strip() or not rest.strip():
        raise ConfigError(f"--controller must be NAME=KIND[,option=value,...], got {text!r}")
    parts = rest.split(",")
    out = {"name": name.strip(), "kind": parts[0].strip()}
    for p in parts[1:]:
        k, s2, v = p.partition("=")
        if not s2 or not k.strip():
            raise ConfigError(f"--controller {name}: options must be option=value, got {p!r}")
        out[k.strip()] = _value(v.strip())
    return out


def run(args) -> int:
    from mitigate.benchmark import BENCHMARK_FILES, load_suite, references, run_benchmark, write_benchmark
    from mitigate.controllers.factory import controller_class, options_of
    from models.files import check_output_dir, output_set

    out = check_output_dir(args.out)                 # before anything: a usable folder
    for flag in ("phases", "seeds", "jobs", "budget"):
        v = getattr(args, flag)
        if v is not None and v < 1:
            raise ConfigError(f"--{flag} must be an integer >= 1, got {v}")
    if args.quick and (args.phases is not None or args.seeds is not None):
        raise ConfigError("--quick is 1 phase and 1 seed; give either --quick or --phases/--seeds")
    extra = [parse_controller(c) for c in args.controller]
    suite = load_suite(args.suite, extra_controllers=extra, only=args.only)
    for sc in suite.scenarios:                       # every controller's options, before anything runs
        for i, c in enumerate(sc.controllers):
            where = f"{sc.where}: controllers[{i}]"
            options_of(controller_class(c.kind, where), c.options, where)
    command = "mitigate benchmark " + " ".join(shlex.quote(a) for a in sys.argv[2:]) if len(sys.argv) > 2 else ""
    phases, seeds = (1, 1) if args.quick else (args.phases, args.seeds)
    # locked for the whole benchmark (the run store in DIR/runs/ too), the report written as one set
    with output_set(out, BENCHMARK_FILES.values(), force=args.force) as w:
        client = None
        if args.scheduler:
            from mitigate.sweep import connect_scheduler
            client = connect_scheduler(args.scheduler, args.scheduler_timeout)
        try:
            refs = references(suite, args.jobs)
            tuned = None
            if args.tuned:
                from mitigate.tune import tune_suite
                tuned = tune_suite(suite, budget=args.budget, out=out / "tuning", refs=refs, jobs=args.jobs,
                                   progress=not args.json)
            res = run_benchmark(suite, phases=phases, seeds=seeds, jobs=args.jobs, store=out, force=args.force,
                                client=client, progress=not args.json, tuned=tuned, refs=refs)
        finally:
            if client is not None:
                client.close()
        files = write_benchmark(res, w, command=command)
    if args.json:
        d = res.as_dict()
        d["files"] = {k: str(v) for k, v in files.items()}
        emit_json(d)
    else:
        from mitigate.benchmark.render import CLASS_TITLES, table_header
        from mitigate.metrics import shown
        cols = shown("terminal")
        for klass, rows in res.tables.items():
            print(f"\n{CLASS_TITLES[klass]}")
            print(format_table(["controller", "class", "mean rank", "first", "job done"]
                               + [table_header(m) for m in cols] + ["failed", "left force band", "left speed band"],
                               [[r["controller"], r["class"], r["mean_rank"], f"{r['first']}/{r['scenarios']}",
                                 f"{r['job_done']}/{r['scenarios']}"]
                                + [(100 if m.percent else 1) * r[m.name] for m in cols]
                                + [r["failed"], r["force_violations"], r["speed_violations"]] for r in rows]))
        print(f"\n{res.status.value} ({res.message}); {len(res.records)} runs, {res.computed} computed now; "
              f"{res.elapsed:.0f} s; ranking in {files['ranking']}")
    return 0 if res.success else 1
