"""``mitigate run``: compare the controllers of a scenario in closed loop."""

from __future__ import annotations

import math
import sys

from mitigate.cliutil import add_command, add_common, emit_json, format_table
from models.errors import ConfigError

EPILOG = """\
Runs every [[controllers]] entry of the scenario against the same plant (exact stick/slip,
its sensors and servos, parameter mismatch and [structure]), each in its own process, and
writes to DIR: a terminal table, metrics.csv, metrics.json, log_<controller>.csv (measured
channels, commands, true twists and speeds, the drive's current and voltage or its torque),
timeseries_<controller>.png, comparison.png, phase.png, metrics.png and report.md (whose verdict
says when a run exceeded the drive's limit: a DC motor's i_max, a torque drive's torque_max).
Nothing is run or written if the scenario is invalid, DIR cannot be a folder, another command is
writing into DIR, or an output exists (use --force); the outputs are written as one set (a killed
run leaves DIR as it was). Exit codes: 0 every run ok (or with warnings), 1 a run FAILED or diverged
(a controller or estimator that raised, returned NaN or hung past [control] timeout; the reason is
in the table, metrics.json and report.md), 2 bad input.

Example:
  mitigate run scenarios/stick_slip_30rpm.toml --out out/
  mitigate run scenarios/mismatch_20pct.toml --out out/mismatch --jobs 2 --json
  mitigate run scenarios/realistic.toml --out out/realistic
"""


def register(sub) -> None:
    p = add_command(sub, "run", help="compare controllers on a scenario in closed loop",
                    description=__doc__, epilog=EPILOG)
    p.add_argument("scenario", metavar="SCENARIO.toml", help="scenario file (see scenarios/)")
    p.add_argument("--jobs", type=int, default=2, metavar="N", help="worker processes (default: 2)")
    add_common(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from mitigate.report import drive_limit_note, summary_rows
    from mitigate.runner import run_scenario

    if isinstance(args.jobs, int) and args.jobs < 1:
        raise ConfigError(f"--jobs must be an integer >= 1, got {args.jobs}")
    res = run_scenario(args.scenario, args.out, force=args.force, jobs=args.jobs, progress=not args.json)
    if args.json:
        emit_json(res.as_dict())
    else:
        for note in res.scenario.messages:
            print(f"note: {note}")
        obs = next((r.result.observability for r in res.runs if getattr(r.result, "observability", None)), None)
        if obs is not None:
            print(f"observability: {getattr(obs, 'message', obs)}")
        print(format_table(*summary_rows(res.scenario, res.runs)))
        for r in res.runs:           # a run at or beyond its drive's limit (NaN: the rig declares none)
            if float(r.metrics.get("drive_load_peak", math.nan)) >= 1 - 1e-3:
                print(f"{r.name}: {drive_limit_note(res.scenario, r.metrics)}")
        print(f"\n{res.message}; {res.elapsed:.1f} s; outputs in {args.out} (report: {res.files['report']})")
    return 0 if res.success else 1
