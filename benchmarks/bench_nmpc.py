"""NMPC time per call and closed-loop effect on the stick-slip case (rig3, N1 = 20 N, 30 rpm).

The exact stick/slip plant (:class:`models.plant.Plant`, hybrid, ideal sensors) starts from
established stick-slip (10 s from rest, no control), then the NMPC runs on the true state for
``--duration`` seconds, planning every OCP interval dt = 0.05 s (every 5th DAQ sample; held in
between).  Timed: the wall time of every ``Controller.step`` call.  A *plan* call is the
feedback phase (embed the state, one QP); the first held call after a plan is the RTI
*preparation* phase (shift the plan, evaluate the compiled stages); the first plan is a warm-up
and excluded.  Reported against the 10 ms DAQ period.

Effect: the severity of R1's speed ``(max - min) / (2 mean)`` over the whole controlled window
and over its last 2 s, the time after which R1 stays within 10 % of 30 rpm ("settled"), and
the friction work at pin 2 [J] (``mitigate.metrics.contact_work``).

Usage::

    python benchmarks/bench_nmpc.py --quick                           # N = 20, rti, 2 s (CI)
    python benchmarks/bench_nmpc.py                                   # N = 20, 50; rti, sqp, ipopt
    python benchmarks/bench_nmpc.py --horizons 50 --solvers rti --duration 8
    python benchmarks/bench_nmpc.py --horizons 50 --solvers rti --inputs both pin motor
    python benchmarks/bench_nmpc.py --horizons 50 --inputs motor --weights ref=0.05 d_ref=0.1
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from estimators.base import Estimate
from mitigate.controllers.base import ControlContext
from mitigate.controllers.nmpc import NMPC, NMPCOptions, NMPCWeights
from mitigate.controllers.nmpc.options import WEIGHT_NAMES
from mitigate.metrics import contact_work, severity
from models import get_model
from models.plant import Plant, SimOptions
from models.status import Status

W0 = np.pi        # 30 rpm [rad/s]
N1 = 20.0         # [N]
DT = 0.01         # DAQ period [s]
DO_MPC_MS = 15.5  # do-mpc's own smaller 3-disc example, ms per step (issue 5)


#: plant = nominal x factor with --mismatch (scenarios/mismatch_20pct.toml); the NMPC keeps the nominal
MISMATCH = {"mu_k": 1.2, "k1": 0.8, "J1": 1.2}


def plant_params(mismatch: bool):
    p = get_model("rig3").published()
    return p.replace(**{k: p[k] * f for k, f in MISMATCH.items()}) if mismatch else p


def stick_slip_start(mismatch: bool = False):
    """The plant state after 10 s from rest at 30 rpm, N1 = 20 N (established stick-slip)."""
    m = get_model("rig3")
    base = Plant(m, plant_params(mismatch), SimOptions(seed=0), sensors=None)
    for _ in range(1000):
        base.step([W0, N1, 0.0])
    return base.x.copy(), base.t


def run(solver: str, horizon: int, duration: float, inputs: str, extra: dict, weights: dict | None = None,
        mismatch: bool = False, state_noise: float = 0.0, load_factor: float | None = None) -> dict:
    m = get_model("rig3")
    p = m.published()
    pp = plant_params(mismatch)
    x0, t0 = stick_slip_start(mismatch)
    u_prog = np.array([W0, N1, 0.0])
    ctx = ControlContext(m, p, DT, lambda t: u_prog, where="bench")
    opts = NMPCOptions(horizon=horizon, solver=solver, inputs=inputs,
                       weights=NMPCWeights(**(weights or {})), **extra)
    t_build = time.perf_counter()
    c = NMPC(opts, ctx)
    t_build = time.perf_counter() - t_build
    plant = Plant(m, pp, SimOptions(seed=0), sensors=None, x0=x0, u0=u_prog)
    plans, prep, allc, w1, wref, X, U = [], [], [], [], [], [], []
    after_plan = False
    rng = np.random.default_rng(1)
    speeds = [m.speed_index(b) for b in m.bodies]
    for k in range(int(round(duration / DT))):
        t = t0 + k * DT
        x = plant.x.copy()
        x[speeds] += state_noise * rng.standard_normal(len(speeds))   # a stand-in for an estimator's error
        if load_factor is None:
            est = Estimate(t, x, None, m.states)
        else:   # what an estimator's friction factor on R1's pin would say
            est = Estimate(t, np.append(x, load_factor), None, m.states + ("load:pin1",))
        a = c.step(t, plant.measure(), est)
        if a.status is not Status.HOLD:
            plans.append(a.solve_time)
            after_plan = True
        elif after_plan:
            prep.append(a.solve_time)   # the RTI preparation phase runs in this held sample
            after_plan = False
        allc.append(a.solve_time)
        u = u_prog.copy()
        for name, v in a.u.items():
            u[m.inputs.index(name)] = v
        x_before = plant.x.copy()
        plant.step(u)
        X.append(x_before)
        U.append(plant.u_applied.copy())   # what the servo applied over the sample
        wref.append(u[0])
        w1.append(plant.x[2])
    tf = 1e3 * np.array(plans[1:])      # the first plan (warm-up, cold caches) is excluded
    tp = 1e3 * np.array(prep[1:]) if len(prep) > 1 else np.array([np.nan])
    busy = 1e3 * np.array(allc[1:])
    w1 = np.array(w1)
    off = np.nonzero(np.abs(w1 - W0) > 0.1 * W0)[0]
    # from then on R1 stays within 10 % of 30 rpm (inf: it is outside at the end of the run)
    settle = float("inf") if off.size and off[-1] == len(w1) - 1 else ((off[-1] + 1) * DT if off.size else 0.0)
    return dict(settle=settle, solver=solver, N=horizon, inputs=inputs, median=np.median(tf), p95=np.percentile(tf, 95),
                max=tf.max(), prep_median=np.median(tp), prep_p95=np.percentile(tp, 95), call_max=busy.max(),
                per_sample=busy.mean(), plans=len(tf), failures=c.counts.failures, nsub=c.nsub, build=t_build,
                sev=severity(w1), sev_final=severity(w1[-int(2.0 / DT):]), mean_final=float(np.mean(w1[-int(2.0 / DT):])),
                work=contact_work(m, pp, np.array(X), np.array(U), "pin2", DT),
                wref_lo=min(wref), wref_hi=max(wref), weights=c.weights)


QP_FIELDS = ("A", "B", "b", "Q", "S", "R", "q", "r", "lbx0", "ubx0", "lbx", "ubx", "lbu", "ubu", "lg", "ug")


def qp_study(horizon: int, duration: float, repeats: int = 3) -> list[dict]:
    """The QPs of a closed loop out of stick-slip, solved again by hpipm in each mode and tolerance
    and by the exact active-set qrqp: median time and iterations, and the first move's error."""
    from mitigate.controllers.nmpc.qp import ConicQP, HpipmQP
    m = get_model("rig3")
    p = m.published()
    x0, t0 = stick_slip_start()
    u_prog = np.array([W0, N1, 0.0])
    c = NMPC(NMPCOptions(horizon=horizon), ControlContext(m, p, DT, lambda t: u_prog, where="bench"))
    qp = c.ocp.qp
    recorded = []
    solve = qp.solve

    def record():
        recorded.append({f: getattr(qp, f).copy() for f in QP_FIELDS})
        solve()
    qp.solve = record
    plant = Plant(m, p, SimOptions(seed=0), sensors=None, x0=x0, u0=u_prog)
    for k in range(int(round(duration / DT))):
        t = t0 + k * DT
        a = c.step(t, plant.measure(), Estimate(t, plant.x.copy(), None, m.states))
        u = u_prog.copy()
        for name, v in a.u.items():
            u[m.inputs.index(name)] = v
        plant.step(u)
    dims = (qp.N, qp.nx, qp.nu, qp.idxbx, qp.idxbu, qp.C, qp.D)
    exact = ConicQP(*dims, solver="qrqp")
    ref = []
    for data in recorded:
        for f in QP_FIELDS:
            getattr(exact, f)[...] = data[f]
        exact.solve()
        ref.append(exact.u[0].copy())
    rows = []
    for mode, tol in (("speed", 1e-5), ("speed", 1e-6), ("speed_abs", 1e-6), ("speed_abs", 1e-7), ("speed_abs", 1e-8)):
        h = HpipmQP(*dims, tol=tol, mode=mode)
        ts, its, err = [], [], []
        for rep in range(repeats):
            for data, u_ref in zip(recorded, ref):
                for f in QP_FIELDS:
                    getattr(h, f)[...] = data[f]
                t_0 = time.perf_counter()
                h.solve()
                ts.append(time.perf_counter() - t_0)
                its.append(h.iterations)
                if rep == 0:
                    err.append(np.abs(h.u[0] - u_ref))
        err = np.array(err)
        rows.append(dict(mode=mode, tol=tol, median=1e3 * np.median(ts), iters=np.mean(its), its_max=max(its),
                         err95=np.percentile(err, 95, axis=0), errmax=err.max(axis=0), n=len(recorded)))
    return rows


def _settled(t: float) -> str:
    return "never" if not np.isfinite(t) else f"{t:.2f} s"


def _kv(items):
    out = {}
    for it in items or []:
        k, _, v = it.partition("=")
        out[k] = float(v)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="N = 20, rti, 2 s (a smoke run for CI)")
    ap.add_argument("--horizons", type=int, nargs="+", default=[20, 50])
    ap.add_argument("--solvers", nargs="+", default=["rti", "sqp", "ipopt"])
    ap.add_argument("--inputs", nargs="+", default=["both"], help="both, pin and/or motor")
    ap.add_argument("--duration", type=float, default=6.0, help="closed-loop seconds per case")
    ap.add_argument("--eps", type=float, default=0.05)
    ap.add_argument("--qp-solver", default="hpipm")
    ap.add_argument("--weights", nargs="*", metavar="NAME=VALUE", help="NMPC weights (others: the defaults)")
    ap.add_argument("--mismatch", action="store_true",
                    help="plant mu_k x1.2, k1 x0.8, J1 x1.2 (the NMPC keeps the nominal model)")
    ap.add_argument("--state-noise", type=float, default=0.0, metavar="STD",
                    help="white noise [rad/s] on the speeds of the state handed to the NMPC (seeded)")
    ap.add_argument("--load-factor", type=float, default=None, metavar="F",
                    help="hand the NMPC an estimate with load:pin1 = F (an estimator's friction factor on R1)")
    ap.add_argument("--no-prepare", action="store_true", help="RTI without the preparation/feedback split")
    ap.add_argument("--qp-study", action="store_true",
                    help="re-solve the QPs of one closed loop with each hpipm mode and tolerance against qrqp")
    ap.add_argument("--out", default="")
    ap.add_argument("--append", action="store_true", help="append the table to --out instead of replacing it")
    args = ap.parse_args(argv)
    if args.quick:
        args.horizons, args.solvers, args.duration = [20], ["rti"], 2.0
    if args.qp_study:
        rows = qp_study(args.horizons[-1], args.duration)
        table = ("| hpipm mode | tol | median [ms] | iterations mean / max | first move error p95 "
                 "[rad/s, N] | max [rad/s, N] |\n|---|---|---|---|---|---|\n" + "".join(
                     f"| {r['mode']} | {r['tol']:g} | {r['median']:.3f} | {r['iters']:.2f} / {r['its_max']} "
                     f"| {r['err95'][0]:.1e}, {r['err95'][1]:.1e} | {r['errmax'][0]:.1e}, {r['errmax'][1]:.1e} |\n"
                     for r in rows))
        print(f"{rows[0]['n']} QPs of N = {args.horizons[-1]}, errors against qrqp\n" + table)
        return 0
    rows = []
    for N in args.horizons:
        for inp in args.inputs:
            for s in args.solvers:
                r = run(s, N, args.duration, inp, {"eps": args.eps, "dt": 0.05, "prepare_ahead": not args.no_prepare,
                                                   "qp_solver": args.qp_solver}, _kv(args.weights),
                      args.mismatch, args.state_noise, args.load_factor)
                rows.append(r)
                print(f"{s:5s} N={N:3d} {inp:5s} plan median {r['median']:6.2f} ms p95 {r['p95']:6.2f}  prep median "
                      f"{r['prep_median']:6.2f} p95 {r['prep_p95']:6.2f}  fail {r['failures']}  sev {r['sev']:.3f} "
                      f"final {r['sev_final']:.4f} mean {r['mean_final']:.3f}  settle {_settled(r['settle'])}  "
                      f"sp {r['wref_lo']:.2f}..{r['wref_hi']:.2f}  work {r['work']:.2f} J  build {r['build']:.1f} s",
                      flush=True)
    head = ("| solver | N | inputs | plan call median [ms] | p95 [ms] | max [ms] | prep call median / p95 [ms] "
            "| max of any call [ms] | mean per DAQ sample [ms] | do-mpc 15.5 ms / plan median | plans | failures "
            "| severity R1 (controlled / last 2 s) | mean R1 speed, last 2 s [rad/s] | settled [s] "
            "| friction work pin 2 [J] | set-point range [rad/s] |\n|"
            + "---|" * 17 + "\n")
    body = "".join(
        f"| {r['solver']} | {r['N']} | {r['inputs']} | {r['median']:.2f} | {r['p95']:.2f} | {r['max']:.2f} "
        f"| {r['prep_median']:.2f} / {r['prep_p95']:.2f} | {r['call_max']:.2f} | {r['per_sample']:.2f} "
        f"| {DO_MPC_MS / r['median']:.1f}x | {r['plans']} | {r['failures']} | {r['sev']:.3f} / {r['sev_final']:.4f} "
        f"| {r['mean_final']:.3f} | {_settled(r['settle'])} | {r['work']:.2f} "
        f"| {r['wref_lo']:.2f} .. {r['wref_hi']:.2f} |\n" for r in rows)
    cmd = "python " + " ".join([os.path.relpath(__file__)] + (argv if argv is not None else sys.argv[1:]))
    w = rows[0]["weights"]
    info = (f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
            f"dt_ocp = 0.05 s, RK4 substeps {rows[0]['nsub']} (eps = {args.eps} rad/s), QP {args.qp_solver}, "
            f"{args.duration} s closed loop per case; preparation/feedback split "
            f"{'off' if args.no_prepare else 'on'}; state noise {args.state_noise} rad/s on the speeds; "
            f"load:pin1 {'absent' if args.load_factor is None else args.load_factor}; "
            f"plant {'mismatched (mu_k x1.2, k1 x0.8, J1 x1.2)' if args.mismatch else 'nominal'}; weights "
            + ", ".join(f"{n}={getattr(w, n):g}" for n in WEIGHT_NAMES)
            + f"; load average at the end {os.getloadavg()[0]:.1f} (shared machine)\n")
    table = head + body
    print(table)
    if args.out:
        from models.files import atomic_write_text
        text = f"Command: `{cmd}`\n\n{info}\n{table}\n"
        if args.append and os.path.exists(args.out):
            text = open(args.out).read() + "\n" + text
        else:
            text = "# NMPC time per plan\n\n" + text
        atomic_write_text(args.out, text, overwrite=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
