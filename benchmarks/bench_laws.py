"""Per-call cost of the industry's laws and the brake: the compiled step as the exported library
runs it (timed inside C), the same step in the workbench (through ctypes), and the Python reference.

For each law of the main scenario (``scenarios/stick_slip_30rpm.toml``: SoftSpeed, Z-Torque,
D-OSKIL, the R2 brake):

- ``mitigate export`` writes it with its EKF (``--duration`` s of reference run) into a temporary
  folder, CMake builds it, and the recorded in[] rows run through the library (ctypes); after each
  step with the controller on, the library's own clock says how long the law's call took
  (``last_solve_time``: ``ss_clock()`` around ``ssl_step``, so the clock's own ~20-30 ns are in it)
  and the whole step (``last_step_time``: the EKF's update and the law);
- the same samples (the channels and the estimate the library logged) go through the workbench's
  law, ``Controller.step`` with ``implementation = "c"`` and ``"python"``, timed with
  ``time.perf_counter`` (the Python around the call included: argument checks, counts, the Action).

Medians and 95th percentiles over the calls after the first 50 with the controller on.

Usage::

    python benchmarks/bench_laws.py [--duration 60] [--out benchmarks/results/export.md]
    python benchmarks/bench_laws.py --quick     # SoftSpeed only, 21 s, a Debug build, prints (CI)

``--out`` replaces only this script's section of the file (between its markers).
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MAIN = ROOT / "scenarios" / "stick_slip_30rpm.toml"
LAWS = ("SoftSpeed", "Z-Torque", "D-OSKIL", "R2 brake")
BEGIN, END = "<!-- bench_laws: begin -->", "<!-- bench_laws: end -->"


def _stats(x) -> tuple[float, float]:
    x = np.asarray(x, float)
    return float(np.median(x)), float(np.percentile(x, 95))


def measure(name: str, duration: float, folder: Path, build_type: str = "Release") -> dict:
    """The three timings of one law [us] (``build_type``: the library's, Release as measured)."""
    from estimators.base import Estimate
    from mitigate.controllers.exported import ExportedLibrary
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.export import build_export, export_controller
    from mitigate.scenario import load_scenario

    res = export_controller(MAIN, name, folder / "x", reference=duration)
    build_export(res.out, build_type=build_type)
    lib = ExportedLibrary(res.out)
    data = np.loadtxt(res.out / "test" / "reference.csv", delimiter=",", skiprows=1)
    n_in = len(res.interface.inputs)
    ins = [p.name for p in res.interface.inputs]
    enable = ins.index("enable")
    law_c, step_c = [], []
    for row in data:
        lib.in_buf[:] = row[1:1 + n_in]
        lib.step(row[0])
        if row[1 + enable]:
            law_c.append(lib.last_solve_time)
            step_c.append(lib.last_step_time)
    sc = load_scenario(MAIN)
    i = [c.name for c in sc.controllers].index(name)
    outs = [p.name for p in res.interface.outputs]
    states = tuple(n.partition(":")[2] for n in outs if n.startswith("estimate:"))
    k_est = [outs.index(f"estimate:{n}") for n in states]
    chans = [(j, n) for j, n in enumerate(ins) if not n.startswith("programme:") and n not in ("enable", "target_speed")]
    rows = [r for r in data if r[1 + enable]]
    samples = [({n: float(r[1 + j]) for j, n in chans},
                Estimate(float(r[0]), r[1 + n_in + np.array(k_est)], np.eye(len(states)), states)) for r in rows]
    py = {}
    for impl in ("c", "python"):
        law = make_controller(dict(sc.controllers[i].options, kind=sc.controllers[i].kind, implementation=impl),
                              context_for(sc, i))
        law.reset()
        times = []
        for r, (y, est) in zip(rows, samples):
            t0 = time.perf_counter()
            law.step(float(r[0]), y, est)
            times.append(time.perf_counter() - t0)
        py[impl] = times
    skip = 50
    return {"law": name, "calls": len(law_c) - skip,
            "law_c": _stats(1e6 * np.array(law_c[skip:])), "step_c": _stats(1e6 * np.array(step_c[skip:])),
            "wb_c": _stats(1e6 * np.array(py["c"][skip:])), "wb_py": _stats(1e6 * np.array(py["python"][skip:]))}


def table(rows: list[dict], command: str, duration: float, build: str = "-O2") -> str:
    head = ("| law | calls | C: the law's call, median / p95 [us] | C: exported step (EKF + law) [us] | "
            "workbench, compiled (ctypes) [us] | workbench, Python reference [us] |\n|---|---|---|---|---|---|\n")
    body = "".join(f"| {r['law']} | {r['calls']} | {r['law_c'][0]:.3f} / {r['law_c'][1]:.3f} | "
                   f"{r['step_c'][0]:.2f} / {r['step_c'][1]:.2f} | {r['wb_c'][0]:.1f} / {r['wb_c'][1]:.1f} | "
                   f"{r['wb_py'][0]:.1f} / {r['wb_py'][1]:.1f} |\n" for r in rows)
    return (f"{BEGIN}\n## The laws' compiled steps (SoftSpeed, Z-Torque, D-OSKIL, brake)\n\n"
            f"Command: `{command}`\n\n"
            f"The main scenario's laws exported with its EKF (rig3, 10 ms DAQ), {duration:g} s of the workbench's run "
            f"replayed through each library built with CMake ({build}); the calls with the controller on, the first 50 "
            f"left out.  \"C\" columns: timed inside the library by its own clock (`last_solve_time`: the clock "
            f"around `ssl_step`, the clock's own cost included; `last_step_time`: the whole step).  Workbench "
            f"columns: `Controller.step` on the same samples, timed with `time.perf_counter` (its Python included).  "
            f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, load "
            f"average {os.getloadavg()[0]:.1f} at the end (shared with other jobs: the medians are the fair figure)."
            f"\n\n"
            + head + body + f"{END}\n")


def write_section(path: Path, text: str) -> None:
    old = path.read_text() if path.exists() else "# The exported controllers' timings\n\n"
    if BEGIN in old and END in old:
        new = old[:old.index(BEGIN)] + text + old[old.index(END) + len(END) + 1:]
    else:
        new = old.rstrip("\n") + "\n\n" + text
    path.write_text(new)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="Example: python benchmarks/bench_laws.py --out benchmarks/results/export.md",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=60.0, help="seconds of the scenario replayed (default 60)")
    p.add_argument("--laws", nargs="+", default=list(LAWS), choices=LAWS, help="the laws (default: all)")
    p.add_argument("--out", default=None, help="markdown file whose section to (re)write (default: print only)")
    p.add_argument("--quick", action="store_true",
                   help="SoftSpeed only, 21 s, a Debug build (-O0 -g: compiles faster; its times are not the "
                        "Release ones) on all cores, print (CI smoke run)")
    a = p.parse_args(argv)
    if shutil.which("cmake") is None:
        print("bench_laws: needs cmake and a C compiler", file=sys.stderr)
        return 2
    laws, duration = (["SoftSpeed"], 21.0) if a.quick else (a.laws, a.duration)
    build_type = "Debug" if a.quick else "Release"
    if a.quick:
        os.environ.setdefault("CMAKE_BUILD_PARALLEL_LEVEL", str(os.cpu_count() or 1))  # its files side by side
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_laws_") as tmp:
        for k, name in enumerate(laws):
            folder = Path(tmp) / str(k)
            folder.mkdir()
            rows.append(measure(name, duration, folder, build_type))
            print(f"{name}: {rows[-1]}", flush=True)
    command = "python benchmarks/bench_laws.py" + (" --quick" if a.quick else "") + \
        ("" if a.duration == 60.0 else f" --duration {a.duration:g}") + \
        (f" --laws {' '.join(repr(x) for x in a.laws)}" if tuple(a.laws) != LAWS else "") + \
        (f" --out {a.out}" if a.out else "")
    text = table(rows, command, duration, "-O0 -g, Debug: --quick" if a.quick else "-O2")
    print(text)
    if a.out and not a.quick:
        write_section(Path(a.out), text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
