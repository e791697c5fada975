"""The exported controller's step in C, and the workbench's NMPC calling the same compiled step.

For each horizon N, the main scenario's NMPC (``scenarios/stick_slip_30rpm.toml``, inputs "both",
EKF) is exported (``mitigate export``), built with CMake, and its logged reference run
(``test/reference.csv``: the workbench's own closed loop) is replayed through:

- the exported library, from a small C program compiled here that times every ``step`` with
  ``CLOCK_MONOTONIC``: a *feedback* call is one that returned a new plan (status OK: the EKF's update,
  the supervision, the initial-value embedding and one QP), a *preparation* call the first held call
  after it (the EKF's update, the shift and the linearisation of all stages), a *hold* any other held
  call; *EKF* is the step with the controller off (``enable`` = 0: the estimator alone);
- the workbench's NMPC (``kind = "nmpc"``, ``implementation = "c"``) through Python, fed the same
  measurements and the same estimates (the reference's estimate columns): the same compiled NMPC step
  plus the ctypes call.

Medians and 95th percentiles in microseconds.  "Python around it" is, call by call, the workbench's
wall time less the compiled step's own timer inside it: the Python call's cost, which a slow period of
a shared machine moves far less than the two sides' medians (measured minutes apart).  Usage::

    python benchmarks/bench_export.py --quick                 # N = 20, 21 s of the run, one round (CI)
    python benchmarks/bench_export.py --horizons 20 50 --rounds 3
    python benchmarks/bench_export.py --horizons 20 --qp-condensing full   # the condensed QP exported
    python benchmarks/bench_export.py --qp-condensing none --qp-mode speed_abs --qp-mu0 preset   # NMPCOptions' defaults

The QP setting is the main scenario's (partial condensing, hpipm's "speed" preset from mu0 = 1e-4)
unless the options above replace it.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

MAIN = ROOT / "scenarios" / "stick_slip_30rpm.toml"

TIMER = r"""
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "PFX.h"
static double now(void) { struct timespec ts; clock_gettime(CLOCK_MONOTONIC, &ts); return ts.tv_sec + 1e-9 * ts.tv_nsec; }
int main(int argc, char** argv) {
    FILE* f = fopen(argv[1], "r"); FILE* o = fopen(argv[2], "w");
    char* line = NULL; size_t cap = 0;
    double row[1 + UPFX_N_IN + UPFX_N_OUT], out[UPFX_N_OUT];
    PFX* s = PFX_create(NULL);
    if (!f || !o || !s || getline(&line, &cap, f) < 0) return 2;
    while (getline(&line, &cap, f) > 0) {
        char* p = line; int i, st; double t0, dt;
        for (i = 0; i < 1 + UPFX_N_IN + UPFX_N_OUT; i++) { char* e; row[i] = strtod(p, &e); p = e; while (*p == ',') p++; }
        t0 = now(); st = PFX_step(s, row[0], row + 1, out); dt = now() - t0;
        fprintf(o, "%d %d %.9e\n", (int)row[1 + UPFX_IN_ENABLE], st, dt);
    }
    PFX_destroy(s); fclose(o); return 0;
}
"""


def export_horizon(N: int, seconds: float, work: Path, qp: dict | None = None):
    """Export and build the main scenario's NMPC at horizon ``N``; ``qp``: NMPC options replacing the
    scenario's QP setting (``qp_condensing``, ``qp_mode``, ``qp_mu0``; None: as the scenario declares)."""
    from mitigate.export import build_export, export_controller
    from mitigate.scenario import load_scenario
    sc = load_scenario(MAIN)
    extra = dict(qp or {})
    ctrls = tuple(replace(c, options={**dict(c.options), "horizon": N, **extra}) if c.name == "NMPC" else c
                  for c in sc.controllers)
    sc = replace(sc, controllers=ctrls)
    out = work / f"nmpc_N{N}"
    res = export_controller(sc, "NMPC", out, reference=seconds, prefix=f"nmpc{N}", force=True)
    so = build_export(out)                       # Release (-O2): the build measured here
    # what is timed must be what the workbench computes: the Release build replays its reference
    r = subprocess.run([str(so.parent / f"{res.prefix}_replay"), str(out / "test" / "reference.csv")],
                       capture_output=True, text=True)
    if r.returncode or " mismatches 0 " not in f" {r.stdout} ":
        raise SystemExit(f"bench_export: the Release build of N = {N} does not replay the workbench: {r.stdout.strip()}")
    return sc, res, so


def time_c(res, so, work: Path, rounds: int) -> dict:
    p = res.prefix
    src = work / f"timer_{p}.c"
    src.write_text(TIMER.replace("UPFX", p.upper()).replace("PFX", p))
    exe = work / f"timer_{p}"
    subprocess.run(["cc", "-O2", f"-I{res.out / 'include'}", str(src), "-o", str(exe), f"-L{so.parent}", f"-l{p}",
                    f"-Wl,-rpath,{so.parent}", "-lm"], check=True)
    groups: dict[str, list] = {"feedback": [], "preparation": [], "hold": [], "ekf": []}
    for _ in range(rounds):
        log = work / f"times_{p}.txt"
        subprocess.run([str(exe), str(res.out / "test" / "reference.csv"), str(log)], check=True)
        d = np.loadtxt(log)
        en, st, dt = d[:, 0].astype(int), d[:, 1].astype(int), d[:, 2]
        prev = -1
        for e, s_, t in zip(en, st, dt):
            if not e:
                groups["ekf"].append(t)
                prev = -1
                continue
            if s_ == 0:
                groups["feedback"].append(t)
            elif s_ == 1 and prev == 0:
                groups["preparation"].append(t)
            elif s_ == 1:
                groups["hold"].append(t)
            prev = s_
    return {k: np.array(v) for k, v in groups.items()}


def time_python(sc, res, rounds: int) -> dict:
    """The workbench's NMPC (compiled step through ctypes) on the reference's measurements and estimates: the
    wall time of each call and, in ``*_c``, the compiled step's own C timer inside it (the difference is
    the Python call).  The calls run under :func:`models.plugins.watchdog`, as a closed loop of the workbench
    runs them (one periodic alarm instead of a timer armed per call: 5 us less per call)."""
    from estimators.base import Estimate
    from mitigate.controllers.factory import context_for, make_controller
    from models import plugins
    i = [c.name for c in sc.controllers].index("NMPC")
    data = np.loadtxt(res.out / "test" / "reference.csv", delimiter=",", skiprows=1)
    ins = [p.name for p in res.interface.inputs]
    outs = [p.name for p in res.interface.outputs]
    chans = [(k, n) for k, n in enumerate(ins) if not n.startswith("programme:") and n not in ("enable", "target_speed")]
    est_cols = [k for k, n in enumerate(outs) if n.startswith("estimate:")]
    names = tuple(outs[k].partition(":")[2] for k in est_cols)
    en = ins.index("enable")
    groups: dict[str, list] = {k: [] for k in ("feedback", "preparation", "hold", "feedback_c", "preparation_c",
                                                "hold_c")}
    for _ in range(rounds):
        c = make_controller(sc.controllers[i], context_for(sc, i))
        c.reset()
        prev = None
        with plugins.watchdog(c.context.timeout):
            for row in data:
                if not row[1 + en]:
                    continue
                t = row[0]
                meas = {n: row[1 + k] for k, n in chans}
                x = row[1 + len(ins) + np.array(est_cols)]
                est = Estimate(t, x, None, names)
                t0 = time.perf_counter()
                a = c.step(t, meas, est)
                dt = time.perf_counter() - t0
                s = a.status.value
                kind = ("feedback" if s == "ok" else "preparation" if s == "hold" and prev == "ok" else
                        "hold" if s == "hold" else None)
                if kind:
                    groups[kind].append(dt)
                    groups[kind + "_c"].append(c.compiled.info.step_time)
                prev = s
    return {k: np.array(v) for k, v in groups.items()}


def fmt(v: np.ndarray) -> str:
    if v.size == 0:
        return "-"
    return f"{1e6 * np.median(v):.1f} / {1e6 * np.percentile(v, 95):.1f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="N = 20, 21 s of the run (1 s of control), one round; the Release build as measured, its "
                         "files compiled side by side (CI)")
    ap.add_argument("--horizons", type=int, nargs="+", default=[20, 50], metavar="N")
    ap.add_argument("--seconds", type=float, default=60.0, help="seconds of the reference run (default 60)")
    ap.add_argument("--rounds", type=int, default=3, help="replays per side, interleaved (default 3)")
    ap.add_argument("--keep", metavar="DIR", help="keep the exports in DIR")
    ap.add_argument("--qp-condensing", choices=("none", "full", "partial"), default=None,
                    help="the NMPC's qp_condensing (default: the scenario's, partial: condensed to ceil(N / 5) "
                         "stages; full: condensed in the preparation, hpipm's dense IPM; none: the OCP QP)")
    ap.add_argument("--qp-mode", choices=("speed_abs", "speed", "balance", "robust"), default=None,
                    help="the NMPC's qp_mode, hpipm's preset (default: the scenario's, speed)")
    ap.add_argument("--qp-mu0", default=None, metavar="MU0|preset",
                    help="the NMPC's qp_mu0 (default: the scenario's, 1e-4; preset: the preset's own, 10)")
    args = ap.parse_args(argv)
    qp = {}
    if args.qp_condensing is not None:
        qp["qp_condensing"] = args.qp_condensing
    if args.qp_mode is not None:
        qp["qp_mode"] = args.qp_mode
    if args.qp_mu0 is not None:
        if args.qp_mu0 == "preset":
            qp["qp_mu0"] = None
        else:
            try:
                mu0 = float(args.qp_mu0)
            except ValueError:
                mu0 = float("nan")
            if not mu0 > 0:
                ap.error(f"--qp-mu0 must be a number > 0 or 'preset', got {args.qp_mu0}")
            qp["qp_mu0"] = mu0
    if args.quick:
        args.horizons, args.seconds, args.rounds = [20], 21.0, 1
        os.environ.setdefault("CMAKE_BUILD_PARALLEL_LEVEL", str(os.cpu_count() or 1))  # its files side by side
    if shutil.which("cmake") is None or shutil.which("cc") is None:
        print("bench_export: needs a C compiler and cmake; skipped")
        return 0
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_export_"))
    work.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, load average {load:.2f}")
    print("median / p95 [us] per call       feedback        preparation     hold         EKF alone")
    for N in args.horizons:
        sc, res, so = export_horizon(N, args.seconds, work, qp)
        c, py = {}, {}
        for r in range(args.rounds):           # interleaved: C, Python, C, Python, ...
            for k, v in time_c(res, so, work, 1).items():
                c[k] = np.concatenate([c.get(k, np.zeros(0)), v])
            for k, v in time_python(sc, res, 1).items():
                py[k] = np.concatenate([py.get(k, np.zeros(0)), v])
        print(f"N = {N:<3} exported C step      {fmt(c['feedback']):>15} {fmt(c['preparation']):>15} "
              f"{fmt(c['hold']):>12} {fmt(c['ekf']):>12}")
        print(f"N = {N:<3} workbench NMPC (py)  {fmt(py['feedback']):>15} {fmt(py['preparation']):>15} "
              f"{fmt(py['hold']):>12}       (EKF separate)")
        print(f"N = {N:<3}   its C step inside  {fmt(py['feedback_c']):>15} {fmt(py['preparation_c']):>15} "
              f"{fmt(py['hold_c']):>12}       (the step's own timer)")
        d = {k: py[k] - py[k + "_c"] for k in ("feedback", "preparation", "hold")}
        print(f"N = {N:<3}   Python around it   {fmt(d['feedback']):>15} {fmt(d['preparation']):>15} "
              f"{fmt(d['hold']):>12}       (per call: wall - the step's timer)")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
