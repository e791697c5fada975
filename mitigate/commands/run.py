"""``mitigate run``: compare the controllers of a scenario in closed loop."""

from __future__ import annotations

import argparse
import sys

from mitigate.cliutil import add_common, emit_json, format_table

EPILOG = """\
Runs every [[controllers]] entry of the scenario against the same plant (exact stick/slip,
sensors, servo, mismatch), each in its own process, and writes to DIR: a terminal table,
metrics.csv, metrics.json, log_<controller>.csv (measured channels + true twists),
timeseries_<controller>.png, comparison.png, phase.png, metrics.png and report.md.
Nothing is run or written if the scenario is invalid or an output exists (use --force).

Example:
  mitigate run scenarios/stick_slip_30rpm.toml --out out/
  mitigate run scenarios/mismatch_20pct.toml --out out/mismatch --jobs 2 --json
"""


def register(sub) -> None:
    p = sub.add_parser("run", help="compare controllers on a scenario in closed loop",
                       description=__doc__, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", metavar="SCENARIO.toml", help="scenario file (see scenarios/)")
    p.add_argument("--jobs", type=int, default=2, metavar="N", help="worker processes (default: 2)")
    add_common(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from mitigate.runner import TABLE_COLUMNS, run_scenario

    summary = run_scenario(args.scenario, args.out, force=args.force, jobs=args.jobs, progress=not args.json)
    if args.json:
        emit_json(summary.as_dict())
    else:
        rows = [[r.name, r.kind] + [r.metrics[k] for k, _ in TABLE_COLUMNS] + [r.status] for r in summary.runs]
        print(format_table(["controller", "kind"] + [h for _, h in TABLE_COLUMNS] + ["status"], rows))
        print(f"\n{summary.status}; {summary.elapsed:.1f} s; outputs in {summary.out} (report: "
              f"{summary.files['report']})")
    return 0 if summary.success else 1
