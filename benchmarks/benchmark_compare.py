"""Where the NMPC wins and where the industry's laws win, per actuator class, and by how much.

Reads a benchmark's ``results.json`` (``mitigate benchmark ... --out DIR``) and prints, per scenario
and like for like, the NMPC variant's median residual severity against the best industry law of
its class (ratio < 1: the NMPC leaves less), with both intervals, whether the intervals separate
(a win or a loss) or overlap (a tie), the times to suppress and the effort (set-point variation).

- drive set-point only: "NMPC motor only" against SoftSpeed and Z-Torque;
- normal force only: "NMPC pin only" against the brake and D-OSKIL;
- both: "NMPC" against every industry law (SoftSpeed, Z-Torque, the brake, D-OSKIL).

Examples::

    python benchmarks/benchmark_compare.py out/benchmark/results.json
    python benchmarks/benchmark_compare.py --quick          # runs a 1-scenario --quick benchmark first (CI)
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLASSES = (("drive set-point only", "NMPC motor only", ("SoftSpeed", "Z-Torque")),
           ("normal force only", "NMPC pin only", ("brake", "D-OSKIL")),
           ("both", "NMPC", ("SoftSpeed", "Z-Torque", "brake", "D-OSKIL")))


def _m(e, key, what="median"):
    v = e["metrics"].get(key, {}).get(what)
    return math.inf if v is None and what != "median" else (math.nan if v is None else float(v))


def _pct(v):
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:.3g}"


def _s(v):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return "never" if math.isinf(v) else f"{v:.3g}"


def _misses(e) -> str:
    """Deadline misses summed over the entry's runs (the controller's fallback acted instead)."""
    v = e.get("counts", {}).get("controller_deadline_misses")
    return "-" if v is None else str(v)


def compare(doc: dict) -> str:
    entries = {(e["scenario"], e["controller"]): e for e in doc["entries"]}
    L = [f"Benchmark `{doc['suite']}` ({doc['mode']}, {doc['phases']} phase(s) x {doc['seeds']} seed(s)).", ""]
    for title, nmpc, laws in CLASSES:
        L += [f"### {title}: {nmpc} against the best of {', '.join(laws)}", "",
              "| scenario | best law | law: what stays [%] | NMPC: what stays [%] | ratio NMPC/law | verdict | "
              "t suppress law / NMPC [s] | set-point var. law / NMPC [1/s] | deadline misses law / NMPC |",
              "|---|---|---|---|---|---|---|---|---|"]
        wins = losses = ties = lower = higher = 0
        ratios = []
        for s in doc["scenarios"]:
            n = entries.get((s, nmpc))
            cand = [entries[(s, c)] for c in laws if (s, c) in entries and entries[(s, c)]["applicable"]
                    and entries[(s, c)]["job_done"]]
            if n is None or not n["applicable"] or not cand:
                continue
            best = min(cand, key=lambda e: _m(e, "residual_severity"))
            rn, rb = _m(n, "residual_severity"), _m(best, "residual_severity")
            ratio = rn / rb if rb > 0 else math.nan
            if not n["job_done"]:
                verdict, losses = "NMPC: job NOT done", losses + 1
            elif min(n["n_runs"], best["n_runs"]) < 2:       # one run: no interval, nothing separates
                if rn < rb:
                    verdict, lower = "NMPC lower (1 run, unproven)", lower + 1
                else:
                    verdict, higher = "law lower (1 run, unproven)", higher + 1
            elif _m(n, "residual_severity", "ci_high") < _m(best, "residual_severity", "ci_low"):
                verdict, wins = "NMPC wins", wins + 1
            elif _m(best, "residual_severity", "ci_high") < _m(n, "residual_severity", "ci_low"):
                verdict, losses = "law wins", losses + 1
            else:
                verdict, ties = "tie", ties + 1
            if math.isfinite(ratio):
                ratios.append(ratio)
            L.append(f"| {s} | {best['controller']} | {_pct(rb)} [{_pct(_m(best, 'residual_severity', 'ci_low'))}, "
                     f"{_pct(_m(best, 'residual_severity', 'ci_high'))}] | {_pct(rn)} "
                     f"[{_pct(_m(n, 'residual_severity', 'ci_low'))}, {_pct(_m(n, 'residual_severity', 'ci_high'))}] | "
                     f"{ratio:.2f} | {verdict} | {_s(_m(best, 'time_to_suppress'))} / {_s(_m(n, 'time_to_suppress'))} | "
                     f"{_s(_m(best, 'setpoint_variation'))} / {_s(_m(n, 'setpoint_variation'))} | "
                     f"{_misses(best)} / {_misses(n)} |")
        if ratios:
            g = math.exp(sum(math.log(r) for r in ratios) / len(ratios))
            single = f"; single runs (no interval): NMPC lower {lower}, law lower {higher}" if lower + higher else ""
            L += ["", f"{nmpc}: wins {wins}, ties {ties}, loses {losses} (job not done included){single}; geometric "
                      f"mean ratio of what stays {g:.2f} (range {min(ratios):.2f}-{max(ratios):.2f}).", ""]
        else:
            L += ["", "(no comparable entries)", ""]
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", nargs="?", help="a benchmark's results.json")
    ap.add_argument("--quick", action="store_true",
                    help="run `mitigate benchmark --quick --only drillstring` into a temporary folder first and time it")
    args = ap.parse_args(argv)
    if args.quick:
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            cmd = [sys.executable, "-m", "mitigate.cli", "benchmark", str(ROOT / "scenarios/benchmark/suite.toml"),
                   "--quick", "--only", "drillstring", "--json", "--out", d]
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode not in (0, 1):
                sys.stderr.write(r.stderr)
                return r.returncode
            print(f"`mitigate benchmark --quick --only drillstring`: {time.perf_counter() - t0:.1f} s\n")
            print(compare(json.loads(r.stdout)))
        return 0
    if not args.results:
        ap.error("give a results.json or --quick")
    try:
        doc = json.loads(Path(args.results).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        sys.stderr.write(f"benchmark_compare: {args.results}: {exc}\n")
        return 2
    print(compare(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
