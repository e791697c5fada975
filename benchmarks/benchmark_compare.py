"""Where the NMPC wins and where the industry's laws win, per actuator class, on the benchmark's order.

Reads a benchmark's ``results.json`` (``mitigate benchmark ... --out DIR``) and prints, per scenario
and like for like, the NMPC variant against the best industry law of its class by the benchmark's
own ranking (the job done in every run, then what the rig sees, the time to suppress, the string's
peak torque, the drive's peak load, the set-point's excursion, the effort, each with its interval):
a win when the NMPC is clearly better, a loss when the law is, a tie otherwise, and the ranked
column that decided it.

- drive set-point only: "NMPC motor only" against SoftSpeed and Z-Torque;
- normal force only: "NMPC pin only" against the brake and D-OSKIL;
- both: "NMPC" against "Z-Torque + D-OSKIL" (the two-actuator industry baseline).

Examples::

    python benchmarks/benchmark_compare.py out/benchmark/results.json
    python benchmarks/benchmark_compare.py benchmarks/results/reference/results.json.gz
    python benchmarks/benchmark_compare.py --quick          # runs a 1-scenario --quick benchmark first (CI)
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CLASSES = (("drive set-point only", "NMPC motor only", ("SoftSpeed", "Z-Torque")),
           ("normal force only", "NMPC pin only", ("brake", "D-OSKIL")),
           ("both", "NMPC", ("Z-Torque + D-OSKIL",)))


def _entry(d: dict):
    """A :class:`mitigate.benchmark.stats.Entry` from an entry of results.json."""
    from mitigate.benchmark.entry import finite
    from mitigate.benchmark.stats import Entry
    e = Entry(d["scenario"], d["controller"], d["kind"], d["class"], d["applicable"], d["n_runs"], d["n_failed"],
              d["n_violations"], d.get("n_force_violations", 0), d.get("n_speed_violations", 0), d["n_suppressed"],
              d.get("n_stalled", 0))
    e.metrics = {k: {w: finite(v[w]) for w in ("median", "ci_low", "ci_high")} for k, v in d["metrics"].items()}
    e.rank, e.class_rank = d.get("rank"), d.get("class_rank")
    return e


def _v(e, key, what="median", pct=False) -> str:
    v = e.value(key, what)
    if math.isnan(v):
        return "-"
    if math.isinf(v):
        return "never"
    return f"{100 * v:.3g}" if pct else f"{v:.3g}"


def _ci(e, key, pct=False) -> str:
    lo, hi = _v(e, key, "ci_low", pct), _v(e, key, "ci_high", pct)
    return _v(e, key, pct=pct) if lo == hi else f"{_v(e, key, pct=pct)} [{lo}, {hi}]"


def _best(cands):
    """The law ranked best among ``cands`` by the benchmark's order (ties: the first listed)."""
    from mitigate.benchmark.stats import clearly_better
    return min(cands, key=lambda e: sum(clearly_better(o, e) for o in cands if o is not e))


def compare(doc: dict) -> str:
    from mitigate.benchmark.render import job_words
    from mitigate.benchmark.stats import clearly_better, deciding
    entries = {(e["scenario"], e["controller"]): _entry(e) for e in doc["entries"]}
    s = doc["suite"]
    L = [f"Benchmark `{s['name']}` v{s['version']} ({doc['mode']}, {s['phases']} phase(s) x {s['seeds']} seed(s)); "
         f"compute model: {s['compute_model']}.", ""]
    for title, nmpc, laws in CLASSES:
        L += [f"### {title}: {nmpc} against the best of {', '.join(laws)}", "",
              "| scenario | best law | verdict | decided by | NMPC: job | law: job | rig sees NMPC / law [%] | "
              "t suppress NMPC / law [s] | string torque peak NMPC / law | drive load NMPC / law [%] | "
              "set-point excursion NMPC / law [%] | set-point var. NMPC / law [1/s] | true what stays NMPC / law [%] |",
              "|" + "---|" * 13]
        wins = losses = ties = 0
        where = {"win": [], "tie": [], "loss": []}
        for sc in s["scenarios"]:
            n = entries.get((sc, nmpc))
            cand = [entries[(sc, c)] for c in laws if (sc, c) in entries and entries[(sc, c)].applicable]
            if n is None or not n.applicable or not cand:
                continue
            best = _best(cand)
            if clearly_better(n, best):
                verdict, wins = "NMPC wins", wins + 1
                where["win"].append(sc)
            elif clearly_better(best, n):
                verdict, losses = "law wins", losses + 1
                where["loss"].append(sc)
            else:
                verdict, ties = "tie", ties + 1
                where["tie"].append(sc)
            L.append(f"| {sc} | {best.controller} | {verdict} | {deciding(n, best)} | {job_words(n)} | "
                     f"{job_words(best)} | {_ci(n, 'measured_severity', True)} / {_ci(best, 'measured_severity', True)} | "
                     f"{_ci(n, 'measured_time_to_suppress')} / {_ci(best, 'measured_time_to_suppress')} | "
                     f"{_v(n, 'string_torque_peak')} / {_v(best, 'string_torque_peak')} | "
                     f"{_v(n, 'drive_load_peak', pct=True)} / {_v(best, 'drive_load_peak', pct=True)} | "
                     f"{_v(n, 'setpoint_excursion', pct=True)} / {_v(best, 'setpoint_excursion', pct=True)} | "
                     f"{_v(n, 'setpoint_variation')} / {_v(best, 'setpoint_variation')} | "
                     f"{_v(n, 'residual_severity', pct=True)} / {_v(best, 'residual_severity', pct=True)} |")
        detail = "; ".join(f"{k}: {', '.join(v)}" for k, v in where.items() if v)
        L += ["", f"{nmpc}: wins {wins}, ties {ties}, loses {losses}" + (f" ({detail})" if detail else "") + ".", ""]
    return "\n".join(L)


def _load(path: Path) -> dict:
    from mitigate.benchmark.entry import read_entry
    return read_entry(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", nargs="?", help="a benchmark's results.json (or .json.gz)")
    ap.add_argument("--quick", action="store_true",
                    help="run `mitigate benchmark --quick --only drillstring` into a temporary folder first and time it")
    args = ap.parse_args(argv)
    if args.quick:
        from _results import QUICK_ONLY, quick_benchmark
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            r = quick_benchmark(d)
            if r.returncode not in (0, 1):
                sys.stderr.write(r.stderr)
                return r.returncode
            print(f"`mitigate benchmark --quick --only {QUICK_ONLY}`: {time.perf_counter() - t0:.1f} s\n")
            print(compare(json.loads(r.stdout)))
        return 0
    if not args.results:
        ap.error("give a results.json or --quick")
    from models.errors import DataError
    try:
        doc = _load(Path(args.results))
    except DataError as exc:
        sys.stderr.write(f"benchmark_compare: {exc}\n")
        return 2
    print(compare(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
