"""Benchmark: the integration rule's implicit step (models.sdirk) against explicit RK4.

Three parts:

1. **Accuracy at tiny regularisations**: one disc on an undamped spring (the ``disc`` rig, a Stribeck
   fall over 1e-3 rad/s) with the regularised model at eps = 1e-4 ... 1e-7 rad/s, stepped at 10 ms by
   the rule (which picks the implicit step), against the exact Coulomb cycle (period, peak speed):
   the errors, the substeps, and the substeps explicit RK4 would have needed.
2. **Cost of one sample with sensitivities** (identification's ``sample_function``, gcc -O1): rig3 at
   its identification eps (the rule keeps RK4) and the paper-on-paper slider of
   ``tests/data/paper_slider`` at its default eps (the rule takes the implicit step), median of many
   mapped evaluations per sample.
3. **Identification of the measured slider** (``mitigate identify`` on ``tests/data/paper_slider/k1002Nm_v42.csv``
   and ``k168Nm_v42.csv``, free mu_s, mu_k, v_s, hold-out 0.5): wall time, status, estimates, the
   held-out period (skipped with --quick).

Usage: python benchmarks/bench_implicit.py [--quick] [--out benchmarks/results/implicit.md]

``--quick`` (CI; prints only): part 1 at eps = 1e-4 only over 6 s, part 2 with 2 timed evaluations per rig,
no part 3.
"""

from __future__ import annotations

import argparse
import math
import platform
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from estimators.identify.functions import shooting_functions  # noqa: E402
from estimators.identify.outputs import plan_channels  # noqa: E402
from estimators.identify.options import IdentifyOptions, default_eps  # noqa: E402
from models import get_model, read_csv  # noqa: E402
from models.discretise import integration  # noqa: E402

SLIDER = ROOT / "tests" / "data" / "paper_slider"


def coulomb_cycle(eps_list, duration):
    m = get_model("disc")
    p = m.published().replace(d=0.0, v_s=1e-3)
    N, W = 20.0, math.pi
    u = np.array([W, N])
    delta = N * p["r"] * (p["mu_s"] - p["mu_k"])
    wn = math.sqrt(p["k"] / p["J"])
    period = 2 * delta / (p["k"] * W) + (2 * math.pi - 2 * math.atan(wn * delta / (p["k"] * W))) / wn
    wmax = W + math.sqrt(W ** 2 + (wn * delta / p["k"]) ** 2)
    rows = []
    for eps in eps_list:
        integ = integration(m, p, 0.01, u=u, eps=eps)
        f = m.ode(eps)
        x, uu, pp = ca.SX.sym("x", 2), ca.SX.sym("u", 2), ca.SX.sym("p", m.n_p)
        F = ca.Function("F", [x, uu, pp], [integ.advance(lambda a, b, c: f(a, b, c), x, uu, pp)])
        t0 = time.perf_counter()
        xs, X = np.zeros(2), []
        for _ in range(int(duration / 0.01)):
            xs = np.array(F(xs, u, p.vector())).ravel()
            X.append(xs)
        wall = time.perf_counter() - t0
        X = np.array(X)
        t = 0.01 * np.arange(1, len(X) + 1)
        w = X[:, 1]
        slip = np.abs(w) > 0.1
        on = t[1:][slip[1:] & ~slip[:-1]]
        per = float(np.mean(np.diff(on)[1:])) if len(on) > 2 else float("nan")
        rk4 = integration(m, p, 0.01, u=u, eps=eps, method="rk4", max_nsub=None).nsub
        rows.append((eps, integ.method, integ.nsub, rk4, per / period - 1, w[t > 2].max() / wmax - 1, wall))
    return rows, period, wmax


def sample_cost(model, eps, log, u, free, reps):
    """Median wall time per sample of the compiled sensitivity function, mapped over 2000 samples."""
    o = IdentifyOptions(free=free, eps=eps)
    chans = plan_channels(model, log, o)
    integ = integration(model, model.published(), log.dt, eps=eps)
    S, _, _, compiled = shooting_functions(model, integ, chans, [c.kind == "speed" for c in chans],
                                           [model.param_names.index(n) for n in free], False, True)
    n = 2000
    Sm = S.map(n)
    x = np.zeros((model.nx, n))
    uu = np.tile(np.asarray(u, float)[:, None], (1, n))
    th = np.tile(model.published().vector(free)[:, None], (1, n))
    p = np.tile(model.published().vector()[:, None], (1, n))
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        Sm(x, uu, th, p, log.dt, eps)
        times.append((time.perf_counter() - t0) / n)
    return integ, float(np.median(times)), compiled


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="the implicit step against explicit RK4: accuracy and cost",
                                 epilog="example: python benchmarks/bench_implicit.py --quick   (CI; prints only)\n"
                                        "         python benchmarks/bench_implicit.py          "
                                        "(writes benchmarks/results/implicit.md)",
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="part 1 at eps = 1e-4 only over 6 s, part 2 with 2 timed evaluations per rig, no "
                         "identification (part 3); prints, writes nothing")
    ap.add_argument("--out", default=None, help="the report (default: benchmarks/results/implicit.md; "
                                                "--quick writes none unless given)")
    a = ap.parse_args(argv)
    lines = ["# The implicit step (SDIRK2) against explicit RK4", "",
             f"`python benchmarks/bench_implicit.py{' --quick' if a.quick else ''}`; {platform.node()}, "
             f"{time.strftime('%Y-%m-%d %H:%M')}; the machine is shared (medians; +-30-50 % run to run)", ""]

    eps_list = (1e-4,) if a.quick else (1e-4, 1e-5, 1e-6, 1e-7)
    rows, period, wmax = coulomb_cycle(eps_list, 6.0 if a.quick else 12.0)
    lines += ["## 1. The exact Coulomb cycle of a disc at tiny regularisations (10 ms steps)", "",
              f"analytic period {period:.4f} s, peak speed {wmax:.4f} rad/s", "",
              "| eps [rad/s] | method | substeps | RK4 would need | period error | peak error | wall [s] |",
              "|---|---|---|---|---|---|---|"]
    lines += [f"| {e:g} | {mth} | {n} | {n4} | {100 * pe:+.2f} % | {100 * we:+.2f} % | {w:.2f} |"
              for e, mth, n, n4, pe, we, w in rows]

    lines += ["", "## 2. One identification sample with its sensitivities (compiled, median per sample)", "",
              "| rig | eps [rad/s] | integration | time per sample |", "|---|---|---|---|"]
    r3 = get_model("rig3")
    from models.plant import SimOptions, simulate
    sim_log = simulate(r3, r3.published(), np.array([math.pi, 20.0, 0.0]), 1.0, SimOptions()).to_log()
    for model, log, free, u in (
            (r3, sim_log, ("k1", "mu_k"), [math.pi, 20.0, 0.0]),
            (get_model(SLIDER / "slider_k1002.toml"), read_csv(SLIDER / "k1002Nm_v42.csv"), ("mu_s", "mu_k", "v_s"),
             [4.2e-5])):
        eps = default_eps(model)
        integ, tps, compiled = sample_cost(model, eps, log, u, free, 2 if a.quick else 20)
        lines.append(f"| {model.name} | {eps:.3g} | {integ.note} | {1e6 * tps:.1f} us{'' if compiled else ' (not compiled)'} |")

    for k, seconds in (() if a.quick else ((1002, 8), (168, 16))):
        lines += ["", f"## 3. `mitigate identify` on the measured slider (k = {k} N/m, {seconds} s at 2 kHz, hold-out 0.5)",
                  "", "Target (issue 28): exit 0, converged or best fit, the held-out stick-slip period within 15 % "
                  "of the measured one, 0.2 <= mu_k < mu_s <= 0.6, no flag beyond the README's command.", ""]
        cmd = [sys.executable, "-m", "mitigate.cli", "identify", str(SLIDER / f"k{k}Nm_v42.csv"), "--model",
               str(SLIDER / f"slider_k{k}.toml"), "--free", "mu_s,mu_k,v_s", "--holdout", "0.5", "--out",
               f"/tmp/bench_implicit_fit_{k}.toml", "--force", "--no-plot"]
        t0 = time.perf_counter()
        out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=3600,
                             env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
        lines += [f"exit {out.returncode}, {time.perf_counter() - t0:.0f} s wall", "", "```",
                  out.stdout.strip()[-3000:], "```"]
    text = "\n".join(lines) + "\n"
    print(text)
    out = a.out or (None if a.quick else str(ROOT / "benchmarks" / "results" / "implicit.md"))
    if out:
        Path(out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
