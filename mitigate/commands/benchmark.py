"""``mitigate benchmark``: every controller on the open benchmark suite, one ranked table and one figure."""

from __future__ import annotations

import argparse
import shlex
import sys

from mitigate.cliutil import add_common, emit_json, format_table
from models.errors import ConfigError

EPILOG = """\
The suite file lists the scenarios and the controllers (scenarios/benchmark/suite.toml). Each
controller runs on each scenario (in --jobs processes); the table ranks them by the severity
after the control start and shows the stuck fraction, the time to suppress, speed tracking,
actuator work, failures and planning-call times. Written to DIR: ranking.md, results.csv,
results.json, benchmark.png.

Add your own controller (a Controller subclass in an importable module) beside the reference
ones with --controller NAME=KIND[,option=value,...].

examples:
  mitigate benchmark scenarios/benchmark/suite.toml --out out/benchmark
  mitigate benchmark scenarios/benchmark/suite.toml --out out/mine --controller "Mine=my_module:MyController,gain=2"
  mitigate benchmark scenarios/benchmark/suite.toml --only established --only realistic --json
"""


def register(sub) -> None:
    p = sub.add_parser("benchmark", help="rank every controller on the open benchmark suite",
                       description=__doc__, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("suite", metavar="SUITE.toml", help="benchmark suite (scenarios/benchmark/suite.toml)")
    p.add_argument("--controller", action="append", default=[], metavar="NAME=KIND[,opt=val]",
                   help="add a controller to the suite's (repeatable)")
    p.add_argument("--only", action="append", default=None, metavar="SCENARIO",
                   help="run only this scenario of the suite (repeatable)")
    p.add_argument("--jobs", type=int, default=2, metavar="N", help="worker processes (default: 2)")
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
    from mitigate.benchmark import BENCHMARK_FILES, load_suite, run_benchmark, write_benchmark
    from mitigate.controllers.factory import controller_class, options_of
    from models.files import check_output_dir, output_set

    out = check_output_dir(args.out)                 # before anything: a usable folder
    if isinstance(args.jobs, int) and args.jobs < 1:
        raise ConfigError(f"--jobs must be an integer >= 1, got {args.jobs}")
    extra = [parse_controller(c) for c in args.controller]
    suite = load_suite(args.suite, extra_controllers=extra, only=args.only)
    for sc in suite.scenarios:                       # every controller's options, before anything runs
        for i, c in enumerate(sc.controllers):
            where = f"{sc.where}: controllers[{i}]"
            options_of(controller_class(c.kind, where), c.options, where)
    command = "mitigate benchmark " + " ".join(shlex.quote(a) for a in sys.argv[2:]) if len(sys.argv) > 2 else ""
    with output_set(out, BENCHMARK_FILES.values(), force=args.force) as w:   # locked, written as one set
        res = run_benchmark(suite, jobs=args.jobs, progress=not args.json)
        files = write_benchmark(res, w, command=command)
    if args.json:
        d = res.as_dict()
        d["files"] = {k: str(v) for k, v in files.items()}
        emit_json(d)
    else:
        from mitigate.benchmark import RANK_COLUMNS
        rows = [[r["controller"]] + [r.get(k, float("nan")) for k, *_ in RANK_COLUMNS] for r in res.table]
        print(format_table(["controller"] + [h for _k, h, *_ in RANK_COLUMNS], rows))
        print(f"\n{res.message}; {res.elapsed:.0f} s; ranking in {files['ranking']}")
    return 0 if res.status.success else 1
