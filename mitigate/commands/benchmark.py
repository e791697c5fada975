"""``mitigate benchmark``: every controller on the open benchmark suite, over switch-on phases and
noise seeds, ranked like for like with intervals; ``mitigate benchmark leaderboard DIR``: the
leaderboard of every submitted entry."""

from __future__ import annotations

import shlex
import sys

from mitigate.cliutil import add_command, add_common, emit_json, format_table, quantity
from models.errors import ConfigError

EPILOG = """\
The suite file lists the scenarios and the controllers (scenarios/benchmark/suite.toml, suite v1,
frozen by suite.lock.json). Each controller runs on each scenario at --phases switch-on instants
spread over one stick-slip period (measured on the scenario's uncontrolled run) and --seeds noise
seeds; every number is a median, over the runs that did the job, with a 95 % bootstrap interval.
Ranked per actuator class (the drive's set-point; normal forces; both) and overall, in this order:
the job done (every run kept the programme's speed and force bands, over the last periods and over
every one-period window, did not stall and did not fail), what the rig's sensors see of the
oscillation (ties below their resolution), the time to suppress, the hardware loads (string torque,
drive current, set-point excursion), the effort; ties where the intervals overlap.

The compute model: every controller answer is applied one control period late and no call has a
wall-clock deadline, so results.json is the same on any machine and load apart from its timing and
provenance fields (the latency scenario, each answer applied after its measured time, is reported
apart). Every finished run is kept in DIR/runs/: a killed benchmark, started again with the same
command, redoes only the unfinished runs. DIR is locked while it runs; the report is written as one
set: ranking.md, results.csv (one row per run), entries.csv, results.json (the entry: every run's
record, the suite version, the commit; its JSON Schema is mitigate/benchmark/results.schema.json),
benchmark.png, distribution.png. With --tuned, every controller is first tuned on every scenario
with the same --budget (Optuna TPE; studies in DIR/tuning/) on phases and seeds the ranking does not
use, scored in the ranking's order, and the tuned values are stored with the results; --validate V
chooses each tuned value on V validation phases (the 3 best trials and the shipped options). With
--generated N --seed S the suite's scenarios are replaced by N scenarios generated from S (rig zoo
rigs, operating points, mismatches; written to DIR/generated/); with --slipping only draws whose
uncontrolled body does not stall (where a drive-only controller can do the job).

Submit your own controller (a Controller subclass in an importable module) with --controller
module:Class (or NAME=KIND[,option=value,...]) and --alone: DIR/results.json is your entry.
mitigate benchmark leaderboard DIR ranks every entry under DIR beside the reference entries
(benchmarks/results/reference/) and writes leaderboard.md and leaderboard.html to --out.
Exit code 1 when a run failed.

examples:
  mitigate benchmark scenarios/benchmark/suite.toml --out out/benchmark              # 6 phases x 3 seeds
  mitigate benchmark scenarios/benchmark/suite.toml --quick --out out/quick          # 1 phase, 1 seed
  mitigate benchmark scenarios/benchmark/suite.toml --phases 3 --seeds 2 --only established --json
  mitigate benchmark scenarios/benchmark/suite.toml --controller my_module:MyController --alone --out entries/mine
  mitigate benchmark leaderboard entries --out out/leaderboard
  mitigate benchmark scenarios/benchmark/suite.toml --tuned --budget 50 --out out/tuned
  mitigate benchmark scenarios/benchmark/suite.toml --tuned --validate 4 --phases 3 --out out/tuned_v
  mitigate benchmark scenarios/benchmark/suite.toml --generated 10 --seed 1 --out out/generated
  mitigate benchmark scenarios/benchmark/suite.toml --generated 10 --seed 1 --slipping --out out/slipping
  mitigate benchmark scenarios/benchmark/suite.toml --scheduler tcp://10.0.0.5:8786 --out out/benchmark
"""


def register(sub) -> None:
    p = add_command(sub, "benchmark", help="rank every controller on the open benchmark suite",
                    description=__doc__, epilog=EPILOG)
    p.add_argument("suite", metavar="SUITE.toml", help="benchmark suite (scenarios/benchmark/suite.toml), or the word "
                   "leaderboard followed by DIR")
    p.add_argument("entries", nargs="?", default=None, metavar="DIR",
                   help="(leaderboard) a folder of entries: every results.json under it")
    p.add_argument("--controller", action="append", default=[], metavar="module:Class|NAME=KIND[,opt=val]",
                   help="add a controller to the suite's (repeatable)")
    p.add_argument("--alone", action="store_true",
                   help="run only the --controller ones, not the suite's (a submission: DIR/results.json is its entry)")
    p.add_argument("--generated", type=int, default=None, metavar="N",
                   help="replace the suite's scenarios by N generated from --seed (written to DIR/generated/)")
    p.add_argument("--seed", type=int, default=None, metavar="S", help="the seed of --generated")
    p.add_argument("--slipping", action="store_true",
                   help="(--generated) only scenarios whose uncontrolled body does not stall (stuck beyond the "
                   "suite's stuck_limit; up to 40 draws a scenario): every class can do the job")
    p.add_argument("--reference", action="append", default=None, metavar="DIR",
                   help="(leaderboard) folders of reference entries (default: benchmarks/results/reference if it "
                        "exists; repeatable)")
    p.add_argument("--no-reference", action="store_true", help="(leaderboard) leave the reference entries out")
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
    p.add_argument("--budget", type=int, default=50, metavar="N",
                   help="trials per controller and scenario (--tuned; default 50, the reference's)")
    p.add_argument("--validate", type=int, default=0, metavar="V",
                   help="(--tuned) choose each tuned value on V validation phases (the 3 best trials and the shipped "
                        "options; default 0: the best tuning score)")
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
    """``NAME=KIND[,option=value,...]`` or ``module:Class`` (named after the class) -> a [[controllers]] table."""
    if "=" not in text and ":" in text and "," not in text:
        cls = text.rpartition(":")[2].strip()
        if not cls or not text.partition(":")[0].strip():
            raise ConfigError(f"--controller must be module:Class or NAME=KIND[,option=value,...], got {text!r}")
        return {"name": cls, "kind": text.strip()}
    name, sep, rest = text.partition("=")
    if not sep or not name.strip() or not rest.strip():
        raise ConfigError(f"--controller must be module:Class or NAME=KIND[,option=value,...], got {text!r}")
    parts = rest.split(",")
    out = {"name": name.strip(), "kind": parts[0].strip()}
    for p in parts[1:]:
        k, s2, v = p.partition("=")
        if not s2 or not k.strip():
            raise ConfigError(f"--controller {name}: options must be option=value, got {p!r}")
        out[k.strip()] = _value(v.strip())
    return out


def leaderboard(args) -> int:
    """``mitigate benchmark leaderboard DIR``."""
    from pathlib import Path

    from mitigate.benchmark.leaderboard import write_leaderboard
    from models.files import check_output_dir
    if not args.entries:
        raise ConfigError("leaderboard needs DIR: mitigate benchmark leaderboard DIR [--out OUT]")
    out = check_output_dir(args.out)
    refs = [] if args.no_reference else (args.reference if args.reference is not None else
                                         [p for p in ["benchmarks/results/reference"] if Path(p).is_dir()])
    files = write_leaderboard([args.entries, *refs], out, force=args.force)
    if args.json:
        emit_json({k: str(v) for k, v in files.items()})
    else:
        print(f"leaderboard of {args.entries}" + (f" and {', '.join(refs)}" if refs else "")
              + f": {files['markdown']}, {files['html']}")
    return 0


def run(args) -> int:
    from mitigate.benchmark import BENCHMARK_FILES, load_suite, references, run_benchmark, write_benchmark
    from mitigate.controllers.factory import controller_class, options_of
    from models.files import check_output_dir, output_set

    if args.suite == "leaderboard":
        return leaderboard(args)
    if args.entries is not None:
        raise ConfigError(f"unexpected argument {args.entries!r} (only leaderboard takes a DIR)")
    out = check_output_dir(args.out)                 # before anything: a usable folder
    for flag in ("phases", "seeds", "jobs", "budget", "generated"):
        v = getattr(args, flag)
        if v is not None and v < 1:
            raise ConfigError(f"--{flag} must be an integer >= 1, got {v}")
    if args.validate and not args.tuned:
        raise ConfigError("--validate chooses tuned values: give it with --tuned")
    if args.quick and (args.phases is not None or args.seeds is not None):
        raise ConfigError("--quick is 1 phase and 1 seed; give either --quick or --phases/--seeds")
    if (args.generated is None) != (args.seed is None):
        raise ConfigError("--generated N and --seed S go together")
    if args.slipping and args.generated is None:
        raise ConfigError("--slipping chooses generated scenarios: give it with --generated N --seed S")
    if args.seed is not None and args.seed < 0:
        raise ConfigError(f"--seed must be an integer >= 0, got {args.seed}")
    if args.alone and not args.controller:
        raise ConfigError("--alone runs only the --controller ones: give at least one --controller")
    extra = [parse_controller(c) for c in args.controller]
    suite_path = args.suite
    load_suite(suite_path, extra_controllers=extra, only=args.only)     # every problem before anything is drawn
    if args.generated is not None:
        from mitigate.benchmark.generate import generate
        suite_path = generate(suite_path, args.generated, args.seed, out / "generated", slipping=args.slipping)
    suite = load_suite(suite_path, extra_controllers=extra, only=args.only if args.generated is None else None)
    if args.alone:
        import dataclasses
        keep = {c["name"] for c in extra}
        suite = dataclasses.replace(suite, controllers=tuple(c for c in suite.controllers if c.name in keep),
                                    scenarios=tuple(sc.replace(controllers=tuple(c for c in sc.controllers
                                                                                 if c.name in keep))
                                                    for sc in suite.scenarios))
    for sc in suite.scenarios:                       # every controller's options, before anything runs
        for i, c in enumerate(sc.controllers):
            where = f"{sc.where}: controllers[{i}]"
            options_of(controller_class(c.kind, where), c.options, where)
    command = "mitigate benchmark " + " ".join(shlex.quote(a) for a in sys.argv[2:]) if len(sys.argv) > 2 else ""
    phases, seeds = (1, 1) if args.quick else (args.phases, args.seeds)
    if args.validate:
        from mitigate.tune import validation_phases
        validation_phases(args.validate, phases or suite.phases, "--validate")     # a bad one before anything runs
    # locked for the whole benchmark (the run store in DIR/runs/ too), the report written as one set
    from mitigate.benchmark.entry import provenance
    prov = provenance(command)                       # the code the workers import: before anything runs
    with output_set(out, BENCHMARK_FILES.values(), force=args.force) as w:
        client = None
        if args.scheduler:
            from mitigate.sweep import connect_scheduler
            client = connect_scheduler(args.scheduler, args.scheduler_timeout)
        try:
            refs = references(suite, args.jobs)
            tuned, how = None, None
            if args.tuned:
                from mitigate.tune import settings, tune_suite
                grid = phases or suite.phases
                tp = min(2, grid)            # tuning phases: between the benchmark's, at most one per gap
                tuned = tune_suite(suite, budget=args.budget, out=out / "tuning", refs=refs, jobs=args.jobs,
                                   progress=not args.json, grid=grid, phases=tp, validate=args.validate)
                how = settings(args.budget, tp, 1, grid, validate=args.validate)
            res = run_benchmark(suite, phases=phases, seeds=seeds, jobs=args.jobs, store=out, force=args.force,
                                client=client, progress=not args.json, tuned=tuned, refs=refs, tuning=how,
                                provenance=prov)
        finally:
            if client is not None:
                client.close()
        files = write_benchmark(res, w, command=command)
    if args.json:
        import json
        d = json.loads(files["json"].read_text())
        d["files"] = {k: str(v) for k, v in files.items()}
        emit_json(d)
    else:
        from mitigate.benchmark.render import CLASS_TITLES, table_header
        from mitigate.metrics import shown
        cols = shown("terminal")
        for klass, rows in res.tables.items():
            print(f"\n{CLASS_TITLES[klass]}")
            print(format_table(["controller", "class", "mean rank", "first", "job done"]
                               + [table_header(m) for m in cols] + ["failed", "left force band", "left speed band",
                                                                    "stalled"],
                               [[r["controller"], r["class"], r["mean_rank"], f"{r['first']}/{r['scenarios']}",
                                 f"{r['job_done']}/{r['scenarios']}"]
                                + [(100 if m.percent else 1) * r[m.name] for m in cols]
                                + [r["failed"], r["force_violations"], r["speed_violations"], r["stalled"]]
                                for r in rows]))
        print(f"\n{res.status.value} ({res.message}); {len(res.records)} runs, {res.computed} computed now; "
              f"{res.elapsed:.0f} s; ranking in {files['ranking']}")
    return 0 if res.success else 1
