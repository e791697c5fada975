"""The results of the scenarios a benchmark has finished so far, from its run store.

A benchmark keeps every finished run in ``DIR/runs/`` (``mitigate benchmark ... --out DIR``) and writes
its report only when every run is done.  On a loaded machine the reference size (6 phases x 3 seeds,
2,700 runs) may take longer than one sitting; this script reads the runs done so far, keeps the
scenarios whose runs are ALL done (the tasks go scenario by scenario), and writes the same output set
(``ranking.md``, ``results.csv``, ``entries.csv``, ``results.json``, the figures) for them, its status
message saying how many scenarios of the suite it holds.  The runs are read, never recomputed; only
the uncontrolled reference runs of the kept scenarios are (they are not stored).

It refuses a store made for another definition (suite and scenario files, controllers, phases,
seeds); when the code that computed the runs differs from this checkout's, the status message says
so, with both code hashes.

Examples::

    python benchmarks/benchmark_partial.py scenarios/benchmark/suite.toml /tmp/bench_ref --out /tmp/partial
    python benchmarks/benchmark_partial.py --quick      # a 1-scenario benchmark, then its partial results (CI)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def partial(suite_path, store, out, *, phases: int | None = None, seeds: int | None = None, jobs: int = 1,
            force: bool = False, command: str = "", only=None) -> dict:
    """Write the output set of the finished scenarios of ``store`` to ``out``; returns its files.  ``only``:
    the scenarios the benchmark was run on (its ``--only``), None: the whole suite."""
    from mitigate.benchmark import load_suite, references, write_benchmark
    from mitigate.benchmark.result import assemble, code_hash, definition
    from mitigate.record import RunRecord
    from models.errors import ConfigError

    suite = load_suite(suite_path, only=only)
    phases = phases or suite.phases
    seeds = seeds or suite.seeds
    man = json.loads((Path(store) / "manifest.json").read_text())
    want = definition(suite, phases, seeds)
    made = man.get("definition", {})
    differ = [k for k in want if k != "code" and json.dumps(want[k], default=str) != json.dumps(made.get(k), default=str)]
    if differ:
        raise ConfigError(f"{store}: its runs were made for another benchmark ({', '.join(differ)} differ); "
                          f"not mixing them")
    runs = Path(store) / "runs"
    records = [RunRecord.from_json(json.loads(p.read_text()), str(p)) for p in sorted(runs.rglob("*.json"))]
    per = Counter(r.run.scenario for r in records)
    full = len(suite.controllers) * phases * seeds
    keep = [sc for sc in suite.scenarios if per.get(sc.name, 0) == full]
    if not keep:
        raise ConfigError(f"{store}: no scenario has all its {full} runs yet ({dict(per)})")
    sub = dataclasses.replace(suite, scenarios=tuple(keep), timing=tuple(n for n in suite.timing
                                                                         if n in {sc.name for sc in keep}))
    refs = references(sub, jobs)
    names = {sc.name for sc in keep}
    res = assemble(sub, refs, [r for r in records if r.run.scenario in names], phases=phases, seeds=seeds)
    note = (f"from the run store: all {len(keep)} scenarios" if len(keep) == len(suite.scenarios) else
            f"partial: {len(keep)} of {len(suite.scenarios)} scenarios ({', '.join(sc.name for sc in keep)})")
    if made.get("code") != code_hash():
        note += f"; runs computed by code {made.get('code')} (this checkout: {code_hash()})"
    res = dataclasses.replace(res, message=f"{note}; {res.message}")
    return write_benchmark(res, out, force=force, command=command)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("suite", nargs="?", help="the suite file the store was made with")
    ap.add_argument("store", nargs="?", help="the benchmark's --out folder (its runs/)")
    ap.add_argument("--out", help="where to write the partial output set")
    ap.add_argument("--phases", type=int, default=None)
    ap.add_argument("--seeds", type=int, default=None)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--only", default=None, help="the scenarios the benchmark ran on (its --only), comma-separated")
    ap.add_argument("--force", action="store_true")
    ap.add_argument("--quick", action="store_true", help="run a 1-scenario --quick benchmark first, then this")
    args = ap.parse_args(argv)
    from models.errors import ConfigError, DataError
    try:
        if args.quick:
            from _results import QUICK_ONLY, quick_benchmark
            with tempfile.TemporaryDirectory() as d:
                r = quick_benchmark(f"{d}/b")
                if r.returncode not in (0, 1):
                    sys.stderr.write(r.stderr)
                    return r.returncode
                files = partial(ROOT / "scenarios/benchmark/suite.toml", f"{d}/b", f"{d}/p", phases=1, seeds=1,
                                only=[QUICK_ONLY])
                print(json.loads(Path(files["json"]).read_text())["message"])
            return 0
        if not (args.suite and args.store and args.out):
            ap.error("give SUITE STORE --out OUT, or --quick")
        files = partial(args.suite, args.store, args.out, phases=args.phases, seeds=args.seeds, jobs=args.jobs,
                        force=args.force, only=args.only.split(",") if args.only else None, command="python benchmarks/benchmark_partial.py " + " ".join(sys.argv[1:]))
    except (ConfigError, DataError) as exc:
        sys.stderr.write(f"benchmark_partial: {exc}\n")
        return 2
    print(json.loads(Path(files["json"]).read_text())["message"])
    print("\n".join(f"{k}: {v}" for k, v in files.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
