"""Benchmark: the integration rule on a small DC gear motor, L/R from 0.05 to 5 ms.

Rig: two discs on a shaft, a small gear motor (R = 2 ohm, L = 0.1 / 1 / 10 mH, i.e. L/R =
0.05 / 0.5 / 5 ms) with its PI speed loop on disc A, a Stribeck brake pin on disc B whose
normal force is a freely named input (``brake_force``).  Input programme over 3 s: the
set-point steps 0 -> 3 -> 6 rad/s (t = 0, 1 s), the brake 10 -> 25 N (t = 2 s).

For each L/R and each step (10 ms: the DAQ period of the plant and the estimators; 50 ms: the
NMPC's interval) it compares

- ``rule``: what :func:`models.discretise.integration` decides (RK4 substeps, the current
  quasi-static when L/R is far below the substep), and
- ``explicit``: RK4 on the full model with the substeps its fastest rate needs
  (``h |lambda| <= 2.5``, what the old per-consumer rules would have had to use),

against a fine reference: CVODES (1e-10) on the full regularised model (eps = 0.05 rad/s), input
held over each step.  Errors are the largest deviation of the disc speeds over the run, relative
to the largest speed, and of the current relative to its largest value; cost is the median
wall time of one call of the step and its state Jacobian (what the EKF and the NMPC's stage
evaluate; CasADi SX, not compiled), median of many calls.

It also checks the exact stick/slip plant (``models.plant``, hybrid stepping) with its rule
against the same plant with 400 substeps per 10 ms sample.

Usage: python benchmarks/bench_stiff_drive.py [--quick] [--out benchmarks/results/stiff_drive.md]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from models import get_model
from models.discretise import RHO, Integration, integration
from models.rates import stiff_rates
from models.plant import SimOptions, hybrid_step_function, plant_integration

from _results import publish

#: the rig (L = 1 mH in the file; this script varies L)
RIG = Path(__file__).resolve().parents[1] / "tests" / "data" / "small_motor.toml"

EPS = 0.05
DURATION = 3.0


def write_rig(folder: Path, lr_ms: float) -> Path:
    """The benchmark's rig file with L/R = ``lr_ms`` [ms] (R = 2 ohm)."""
    tag = f"{lr_ms:g}".replace(".", "p")
    path = folder / f"tworig_{tag}.toml"
    text = RIG.read_text().replace('name = "tworig"', f'name = "tworig_{tag}"')
    path.write_text(text.replace('L = { value = 1.0, unit = "mH" }', f'L = {{ value = {lr_ms * 2.0!r}, unit = "mH" }}'))
    return path


def programme(t: float) -> np.ndarray:
    """omega_ref [rad/s], brake_force [N] at time ``t`` [s]."""
    return np.array([3.0 if t < 1.0 else 6.0, 10.0 if t < 2.0 else 25.0])


def step_function(model, integ: Integration) -> ca.Function:
    f = model.ode(EPS)
    x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
    xn = integ.advance(lambda a, b, c: f(a, b, c), x, u, p,
                       lambda a, b, c: model.quasi_static_current(a, b, model.unpack(c)))
    return ca.Function("F", [x, u, p], [xn, ca.jacobian(xn, x)])


def reference(model, dt: float) -> ca.Function:
    x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
    return ca.integrator("ref", "cvodes", {"x": x, "p": ca.vertcat(u, p), "ode": model.ode(EPS)(x, u, p)}, 0.0, dt,
                         {"abstol": 1e-10, "reltol": 1e-10})


def trajectory(F, model, p, dt: float, ref: bool = False) -> np.ndarray:
    n = int(round(DURATION / dt))
    X = np.zeros((n + 1, model.nx))
    for k in range(n):
        u = programme(k * dt)
        if ref:
            X[k + 1] = np.array(F(x0=X[k], p=np.concatenate([u, p]))["xf"]).ravel()
        else:
            X[k + 1] = np.array(F(X[k], u, p)).ravel()
    return X


def cost_us(F, model, p, calls: int) -> float:
    x, u = np.zeros(model.nx), programme(0.0)
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        F(x, u, p)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e6)


def errors(X, Xr, model) -> tuple[float, float]:
    spd = [model.speed_index(b) for b in model.bodies]
    ws = float(np.max(np.abs(Xr[:, spd])))
    e_w = float(np.max(np.abs(X[:, spd] - Xr[:, spd]))) / ws
    ic = model.current_index
    e_i = float(np.max(np.abs(X[:, ic] - Xr[:, ic]))) / max(float(np.max(np.abs(Xr[:, ic]))), 1e-12)
    return e_w, e_i


def run_case(path: Path, lr_ms: float, dts, calls: int) -> list[dict]:
    model = get_model(path)
    params = model.published()
    p = np.asarray(params.vector(), float)
    u_max = np.array([6.0, 25.0])
    rows = []
    for dt in dts:
        Xr = trajectory(reference(model, dt), model, p, dt, ref=True)
        rule = integration(model, params, dt, u=u_max, eps=EPS)
        full = integration(model, params, dt, u=u_max, eps=EPS, min_nsub=1)
        if full.quasi_static:     # the explicit alternative: the full model's own substep count
            lam = stiff_rates(model, params, u_max, eps=EPS)
            n_full = max(int(np.ceil(dt * lam / RHO)), 1)
            full = Integration(dt, n_full, None, lam, 0.0, f"RK4, {n_full} substeps (full model)")
        for label, integ in (("rule", rule), ("explicit", full)):
            F = step_function(model, integ)
            X = trajectory(lambda a, b, c: F(a, b, c)[0], model, p, dt)
            e_w, e_i = errors(X, Xr, model) if np.all(np.isfinite(X)) else (float("inf"), float("inf"))
            rows.append({"lr_ms": lr_ms, "dt": dt, "method": label, "nsub": integ.nsub, "qs": integ.quasi_static,
                         "err_w": e_w, "err_i": e_i, "cost_us": cost_us(F, model, p, calls), "note": integ.note})
    return rows


def plant_case(path: Path, lr_ms: float) -> dict:
    """The exact stick/slip plant with its rule (nsub = 10 asked) against 400 explicit substeps per sample."""
    model = get_model(path)
    params = model.published()
    p = np.asarray(params.vector(), float)
    integ = plant_integration(model, params, SimOptions(dt=0.01, nsub=10), programme(0.0))
    runs = []
    for F in (hybrid_step_function(model, 0.01, integ.nsub, quasi_static=integ.quasi_static),
              hybrid_step_function(model, 0.01, 400)):
        x, th = np.zeros(model.nx), 0.0
        X = [x]
        for k in range(int(round(DURATION / 0.01))):
            xn, thn = F(x, th, programme(k * 0.01), p)
            x, th = np.array(xn).ravel(), float(thn)
            X.append(x)
        runs.append(np.array(X))
    a, b = runs
    spd = [model.speed_index(bb) for bb in model.bodies]
    err = float(np.max(np.abs(a[:, spd] - b[:, spd]))) / float(np.max(np.abs(b[:, spd])))
    return {"lr_ms": lr_ms, "err_w": err, "ok": bool(np.all(np.isfinite(a))), "note": integ.note}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="example: python benchmarks/bench_stiff_drive.py --quick")
    ap.add_argument("--quick", action="store_true", help="L/R = 0.5 ms only, fewer timing calls (CI)")
    ap.add_argument("--calls", type=int, default=2000, help="timing calls per step Function (default 2000)")
    ap.add_argument("--out", default=None, help="write the markdown report to this file")
    args = ap.parse_args(argv)
    lrs = (0.5,) if args.quick else (0.05, 0.5, 5.0)
    calls = 200 if args.quick else args.calls
    rows, plants = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for lr in lrs:
            path = write_rig(Path(tmp), lr)
            rows += run_case(path, lr, (0.01, 0.05), calls)
            plants.append(plant_case(path, lr))
    lines = [f"### Stiff drives: the integration rule against CVODES (1e-10), two-disc rig, {DURATION:g} s programme",
             "", f"Command: `python benchmarks/bench_stiff_drive.py{' --quick' if args.quick else ''}`  ",
             f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, load average "
             f"{os.getloadavg()[0]:.1f} at the start", "",
             "| L/R [ms] | step [ms] | method | substeps | current | speed error | current error | cost/step [us] |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['lr_ms']:g} | {r['dt'] * 1e3:g} | {r['method']} | {r['nsub']} | "
                     f"{'quasi-static' if r['qs'] else 'state'} | {r['err_w']:.2e} | {r['err_i']:.2e} | "
                     f"{r['cost_us']:.0f} |")
    lines += ["", "Rule decisions (as every consumer states them):", ""]
    lines += [f"- L/R {r['lr_ms']:g} ms, step {r['dt'] * 1e3:g} ms: {r['note']}" for r in rows if r["method"] == "rule"]
    lines += ["", "Exact stick/slip plant (hybrid, nsub = 10 asked) against 400 substeps per 10 ms sample:", "",
              "| L/R [ms] | speed error | finite | rule |", "|---|---|---|---|"]
    lines += [f"| {p['lr_ms']:g} | {p['err_w']:.2e} | {p['ok']} | {p['note']} |" for p in plants]
    text = "\n".join(lines) + "\n"
    publish(text, args.out)
    bad = [r for r in rows if r["method"] == "rule" and not r["err_w"] < 0.05]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
