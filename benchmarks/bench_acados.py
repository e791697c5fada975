"""The NMPC's RTI beside acados' SQP_RTI on the same OCP (issue 26): feedback and preparation
times at N = 20 and 50, measured side by side, interleaved, on this machine.

The problem: the main scenario of ``benchmarks/bench_nmpc.py`` (rig3, 30 rpm, N1 = 20 N, inputs
"both": the drive's set-point and the pin servo n2; the default NMPC options as the workbench
resolves them; the exact stick/slip plant on the TRUE state from established stick-slip, planning
every dt = 0.05 s, ``--duration`` seconds).

**Ours** (this venv): the closed loop as ``bench_nmpc.py`` times it.  Feedback = a plan call of
``NMPC.step`` (embed the state, one QP); preparation = the first held call after a plan (shift,
evaluate the compiled stages).  Also reported: the OCP solver's own calls inside them
(``OCPSolver.solve`` and ``prepare``, wall time), i.e. without the controller's layers.

**acados** (its own venv): the workbench's OCP passed across as its own SX expressions: the
discrete dynamics ``F(xa, v, q)`` (RK4 with the rig's substeps), the stage residual ``r`` and
linear servo term ``l`` and the terminal residual (:func:`mitigate.controllers.nmpc.stage_functions`),
dumped as version-neutral instruction lists and rebuilt op by op in acados' casadi 3.6 (CasADi
3.8's serialisation cannot be read there), each checked against the workbench's evaluations.
acados then gets: ``integrator_type = DISCRETE`` with ``disc_dyn_expr = F``; cost ``EXTERNAL``
``0.5 |r|^2 + l`` with the custom Hessian ``J'J`` and ``hessian_approx = GAUSS_NEWTON`` (exactly
the workbench's Gauss-Newton Hessian and gradient; ``--cost conl``: the same as
convex-over-nonlinear); acados' per-stage cost scaling by dt is undone (the workbench's cost is
not scaled); the same boxes (the input boxes, the box on the previous set-point at stages 1..N,
the servo-rate rows); hpipm in the same mode with the same tolerance and iteration limit;
``PARTIAL_CONDENSING_HPIPM`` with ``qp_solver_cond_N = N`` (no condensing: the QP ours solves) and/or
``FULL_CONDENSING_HPIPM`` (``--qp``).  It replays the closed loop's plans: for every plan the
state, the linearisation's parameters and the bounds that our RTI solved with; its own iterate,
shifted after every plan as ours is (the tail holds the last input with no set-point change).
Timed: acados' own C timer ``time_tot`` of ``rti_phase = 2`` (feedback) and ``rti_phase = 1``
(preparation), and the wall time of the same phases called through acados' C API by ctypes
(bounds, parameters and the shift included).  The first plan of each side is a warm-up and excluded.

Agreement: acados' first move against ours at every plan, relative to the input's scale (the
set-point's speed scale, the servo's n_max).

Create acados' venv (one command; never in the workbench's venv; with a Python 3.12, which the
wheel's casadi is built for: on these machines pyenv's 3.12.1)::

    PYENV_VERSION=3.12.1 python3.12 -m venv /work/venv-acados && /work/venv-acados/bin/pip install comma-deps-acados numpy

acados generates and compiles its solver once per OCP structure and variant (about 2.5-3 min each
on this machine), cached by content under ``~/.cache/stickslip/acados``.

Examples::

    python benchmarks/bench_acados.py --quick                       # N = 20, 0.5 s, 1 round (acados if found)
    python benchmarks/bench_acados.py --out benchmarks/results/nmpc_acados.md
    python benchmarks/bench_acados.py --horizons 20 --rounds 3 --qp partial full --cost external conl
    python benchmarks/bench_acados.py --side ours                   # the workbench's side only
    python benchmarks/bench_acados.py --qp partial full --ours-qp none full partial   # ours condensed too

``--acados-python`` (default ``$ACADOS_PYTHON`` or /work/venv-acados/bin/python) names acados'
interpreter; without it, the acados side is skipped with a one-line note.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
SIDE = HERE / "_acados_side.py"
DEFAULT_ACADOS_PYTHON = os.environ.get("ACADOS_PYTHON", "/work/venv-acados/bin/python")


# ----------------------------------------------------------------------------- the closed loop
def _nmpc(horizon: int, qp_tol=None, implementation: str = "c", qp_condensing: str = "none", hpipm=("speed_abs", None)):
    """The rig, the programme and the NMPC of the main scenario (``bench_nmpc.py``'s); the default
    options but ``qp_tol`` if given.  ``implementation``: "c" (the compiled step, what is timed) or
    "python" (the reference of the same step, whose OCP calls the recording reads; the two agree to
    2e-15 on this loop, tests/test_nmpc.py); ``hpipm``: ``(qp_mode, qp_mu0)``."""
    from bench_nmpc import DT, N1, W0
    from mitigate.controllers.base import ControlContext
    from mitigate.controllers.nmpc import NMPC, NMPCOptions
    from models import get_model
    m = get_model("rig3")
    u_prog = np.array([W0, N1, 0.0])
    ctx = ControlContext(m, m.published(), DT, lambda t: u_prog, where="bench")
    extra = {} if qp_tol is None else {"qp_tol": float(qp_tol)}
    if qp_condensing != "none":
        extra["qp_condensing"] = qp_condensing
    extra["qp_mode"], extra["qp_mu0"] = hpipm
    return m, u_prog, NMPC(NMPCOptions(horizon=horizon, inputs="both", implementation=implementation, **extra), ctx)


def _loop(m, u_prog, c, duration: float):
    """``bench_nmpc.run``'s closed loop from established stick-slip on the true state; the wall
    and thread CPU times [s] of the plan calls and of the first held call after each plan."""
    from bench_nmpc import DT, stick_slip_start
    from estimators.base import Estimate
    from models.plant import Plant, SimOptions
    from models.status import Status
    x0, t0 = stick_slip_start()
    plant = Plant(m, m.published(), SimOptions(seed=0), sensors=None, x0=x0, u0=u_prog)
    plans, prep, plans_cpu, prep_cpu, c_plans, c_prep = [], [], [], [], [], []
    after_plan = False
    info = c.compiled.info if getattr(c, "compiled", None) is not None else None
    for k in range(int(round(duration / DT))):
        t = t0 + k * DT
        meas, est = plant.measure(), Estimate(t, plant.x.copy(), None, m.states)
        c0 = time.thread_time()
        a = c.step(t, meas, est)
        cpu = time.thread_time() - c0
        if a.status is not Status.HOLD:
            plans.append(a.solve_time)
            plans_cpu.append(cpu)
            c_plans.append(info.step_time if info is not None else np.nan)
            after_plan = True
        elif after_plan:
            prep.append(a.solve_time)
            prep_cpu.append(cpu)
            c_prep.append(info.step_time if info is not None else np.nan)
            after_plan = False
        u = u_prog.copy()
        for name, v in a.u.items():
            u[m.inputs.index(name)] = v
        plant.step(u)
    return plans, prep, plans_cpu, prep_cpu, c_plans, c_prep


def time_ours(horizon: int, duration: float, qp_tol=None, qp_condensing: str = "none", hpipm=("speed_abs", None)) -> dict:
    """Our side, timed: the workbench NMPC's plan (feedback) and first held (preparation) calls,
    through Python (``Action.solve_time``, wall) and inside C (the compiled step's own
    ``step_time``: the whole NMPC step, supervision and fallbacks included) [s]."""
    m, u_prog, c = _nmpc(horizon, qp_tol, qp_condensing=qp_condensing, hpipm=hpipm)
    plans, prep, plans_cpu, prep_cpu, c_plans, c_prep = _loop(m, u_prog, c, duration)
    return dict(feedback=plans[1:], preparation=prep[1:], feedback_c=c_plans[1:], preparation_c=c_prep[1:],
                feedback_cpu=plans_cpu[1:], preparation_cpu=prep_cpu[1:], failures=c.counts.failures,
                plans=len(plans))


def record(horizon: int, duration: float, path: Path, qp_tol=None, hpipm=("speed_abs", None)) -> dict:
    """Run the closed loop once and write what acados needs to ``path`` (module docstring)."""
    import casadi as ca
    from _acados_side import dump_sx
    from mitigate.controllers.nmpc import stage_functions
    from mitigate.controllers.nmpc.qp import HpipmQP
    rows = {k: [] for k in ("xa0", "q_lin", "lbv", "ubv", "lbw", "ubw", "dg", "u_ours", "prepared", "init")}
    inits: list[tuple] = []
    m, u_prog, c = _nmpc(horizon, qp_tol, implementation="python", hpipm=hpipm)
    ocp = c.ocp
    solve, prepare = ocp.solve, ocp.prepare
    q_prep = {}

    def recorded_prepare(q):
        q_prep["q"] = np.array(q, float)
        prepare(q)

    def recorded_solve(xa0, q, lo, hi, rate):
        xa0, q = np.array(xa0, float), np.array(q, float)
        prepared, init = ocp.prepared, ocp.X is None
        if init:              # the plan ours starts from (hold the inputs, simulate): made here to keep it
            ocp.initialise(xa0, q)
            inits.append((ocp.X.copy(), ocp.V.copy()))
        res = solve(xa0, q, lo, hi, rate)
        rows["xa0"].append(xa0)
        rows["q_lin"].append(q_prep["q"] if prepared else q)
        for k, b in zip(("lbv", "ubv", "lbw", "ubw", "dg"), ocp.last_bounds):
            rows[k].append(np.zeros(0) if b is None else np.array(b, float))
        rows["u_ours"].append(np.array(res.u[0], float))
        rows["prepared"].append(prepared)
        rows["init"].append(init)
        return res
    ocp.solve, ocp.prepare = recorded_solve, recorded_prepare
    _loop(m, u_prog, c, duration)
    L, spec = c.layout, c.spec
    F, cost, _, term = stage_functions(m, spec)
    xa, v, q = ca.SX.sym("xa", L.nxa), ca.SX.sym("v", L.nv), ca.SX.sym("q", L.nq)
    co, te = cost(xa=xa, v=v, q=q), term(xa=xa, q=q)
    fns = {"F": F, "cost": ca.Function("cost", [xa, v, q], [co["r"], co["l"]], ["xa", "v", "q"], ["r", "l"]),
           "rN": ca.Function("rN", [xa, q], [te["r"]], ["xa", "q"], ["r"])}
    data = {}
    X0, V0 = inits[0]
    rng = np.random.default_rng(0)
    for name, f in fns.items():
        data.update(dump_sx(f, name))
        # a test point near the first plan, for the check after the transfer
        ins = {"xa": X0[3] * (1 + 0.1 * rng.standard_normal(L.nxa)), "v": V0[3] + rng.standard_normal(L.nv),
               "q": rows["q_lin"][0]}
        args = [ins[n] for n in f.name_in()]
        for i, a in enumerate(args):
            data[f"{name}.test_in{i}"] = np.asarray(a, float)
        for i, o in enumerate(f.call([ca.DM(a) for a in args])):
            data[f"{name}.test_out{i}"] = np.array(o).ravel(order="F")
    hp = inspect.signature(HpipmQP.__init__).parameters
    data.update(
        N=np.array(horizon), dt=np.array(spec.dt), nxa=np.array(L.nxa), nv=np.array(L.nv), nq=np.array(L.nq),
        i_wprev=np.array(-1 if L.i_wprev is None else L.i_wprev), C=L.C, D=L.D,
        tail_zero=np.array([0] if L.drive else [], dtype=np.int64),
        qp_tol=np.array(ocp.qp_tol), hpipm_mode=np.array(hpipm[0]),
        qp_mu0=np.array(np.nan if hpipm[1] is None else float(hpipm[1])),
        qp_iter_max=np.array(hp["iter_max"].default),
        u_scale=np.array(([spec.setpoint_scale] if L.drive else []) + list(spec.force_scales), float),
        X_init=np.array([x for x, _ in inits]), V_init=np.array([v_ for _, v_ in inits]),
        **{k: np.array(v) for k, v in rows.items()})
    np.savez(path, **data)
    return dict(plans=len(rows["xa0"]), inits=len(inits), prepared=int(np.sum(rows["prepared"])), nsub=spec.nsub,
                failures=c.counts.failures)


# ----------------------------------------------------------------------------- the driver
def _acados_ok(python: str, data: Path) -> str:
    """'' if acados' interpreter rebuilds and checks the OCP's functions, else why not (one line)."""
    if not Path(python).exists():
        return f"no acados interpreter at {python} (see --help: one command creates it)"
    r = subprocess.run([python, str(SIDE), str(data), "--check"], capture_output=True, text=True, timeout=600)
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["?"])[-1]
        return f"acados' interpreter {python} failed the function check: {last}"
    return ""


def _run_acados(python: str, data: Path, qp: str, cost: str, cflags: str, out: Path) -> dict:
    r = subprocess.run([python, str(SIDE), str(data), "--qp", qp, "--cost", cost, f"--cflags={cflags}", "--out", str(out)],
                       capture_output=True, text=True, timeout=3600)
    if r.returncode != 0:
        raise RuntimeError(f"acados side failed ({qp}, {cost}): {r.stderr.strip()[-2000:]}")
    return json.loads(out.read_text())


def _run_ours(horizon: int, duration: float, qp_tol, out: Path, cond: str = "none", hpipm=("speed_abs", None)) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE.parent)] + os.environ.get("PYTHONPATH", "").split(os.pathsep)))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker-ours", str(horizon), "--duration", str(duration),
           "--json", str(out), "--ours-qp", cond, "--qp-mode", hpipm[0]] + ([] if qp_tol is None else ["--qp-tol", str(qp_tol)])
    cmd += [] if hpipm[1] is None else ["--qp-mu0", str(hpipm[1])]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    if r.returncode != 0:
        raise RuntimeError(f"our side failed: {r.stderr.strip()[-2000:]}")
    return json.loads(out.read_text())


def _agreement(data: Path, moves) -> dict:
    with np.load(data) as z:
        u, scale = z["u_ours"], z["u_scale"]
    e = np.abs(np.asarray(moves) - u) / scale
    return dict(median=np.median(e, axis=0), p95=np.percentile(e, 95, axis=0), max=e.max(axis=0), n=len(e))


#: (side label, phase, measure label, key in a run's result)
def _series(kind: str, res: dict):
    """The timed series [ms] of one run: (phase, measure, samples)."""
    if kind == "ours":
        return [("feedback", "compiled NMPC step (C timer)", 1e3 * np.array(res["feedback_c"])),
                ("feedback", "workbench controller call (wall)", 1e3 * np.array(res["feedback"])),
                ("feedback", "workbench controller call (thread CPU)", 1e3 * np.array(res["feedback_cpu"])),
                ("preparation", "compiled NMPC step (C timer)", 1e3 * np.array(res["preparation_c"])),
                ("preparation", "workbench controller call (wall)", 1e3 * np.array(res["preparation"])),
                ("preparation", "workbench controller call (thread CPU)", 1e3 * np.array(res["preparation_cpu"]))]
    fb, pr = res["feedback"], res["preparation"]
    # plan 0 is the warm-up; plan 1's preparation is the first (excluded, as ours)
    f = lambda a: 1e3 * np.array(a)[1:]                   # noqa: E731
    p = lambda a: 1e3 * np.array(a, float)[2:]            # noqa: E731
    return [("feedback", "acados time_tot (C timer)", f(fb["time_tot"])),
            ("feedback", "of which the QP: time_qp (C timer)", f(fb["time_qp"])),
            ("feedback", "ctypes calls (wall)", f(fb["wall"])),
            ("feedback", "ctypes calls (thread CPU)", f(fb["cpu"])),
            ("preparation", "acados time_tot (C timer)", p(pr["time_tot"])),
            ("preparation", "ctypes calls (wall)", p(pr["wall"])),
            ("preparation", "ctypes calls (thread CPU)", p(pr["cpu"]))]


def _detail(res: dict) -> str:
    fb, pr = res["feedback"], res["preparation"]
    med = lambda a, s: 1e3 * float(np.nanmedian(np.array(a, float)[s:]))   # noqa: E731
    return (f"feedback: time_qp {med(fb['time_qp'], 1):.3f}, of which in hpipm {med(fb['time_qp_solver_call'], 1):.3f}; "
            f"preparation: time_lin {med(pr['time_lin'], 2):.3f}, time_qp_xcond {med(pr['time_qp_xcond'], 2):.3f}; "
            f"QP iterations median {np.median(res['qp_iter'][1:]):.0f}, max {max(res['qp_iter'][1:])}")


def _machine() -> str:
    cpu = "?"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="N = 20, 0.5 s (10 plans), 1 round, partial condensing (a smoke run for CI; acados only "
                         "if found)")
    ap.add_argument("--horizons", type=int, nargs="+", default=[20, 50])
    ap.add_argument("--duration", type=float, default=8.0, help="closed-loop seconds")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds (ours, acados; the order alternates)")
    ap.add_argument("--side", choices=("both", "ours", "acados"), default="both")
    ap.add_argument("--ours-qp", nargs="+", choices=("none", "full", "partial"), default=["none"],
                    help="our compiled step's QP (NMPCOptions.qp_condensing): none (hpipm's Riccati IPM on the OCP "
                         "QP, the default), full (condensed in the preparation, hpipm's dense IPM), partial (condensed "
                         "to ceil(N / 5) stages, Riccati on those)")
    ap.add_argument("--qp", nargs="+", choices=("partial", "full", "blocks"), default=["partial", "full"],
                    help="acados' QP: partial condensing with cond_N = N (hpipm's OCP QP, as ours by default), full "
                         "condensing (hpipm's dense QP) and/or blocks (partial condensing to ceil(N / 5) stages, as "
                         "ours with --ours-qp partial)")
    ap.add_argument("--cost", nargs="+", choices=("external", "conl"), default=["external"],
                    help="acados' cost module: EXTERNAL with the Gauss-Newton custom Hessian, or "
                         "CONVEX_OVER_NONLINEAR; both give our Gauss-Newton Hessian exactly")
    ap.add_argument("--cflags", default="-O2", help="acados' ext_fun_compile_flags (default: acados' -O2)")
    ap.add_argument("--qp-tol", type=float, default=None,
                    help="the QP tolerance on both sides (default: the NMPC's default; a diagnostic)")
    ap.add_argument("--qp-mode", default="speed_abs", choices=("speed_abs", "speed", "balance", "robust"),
                    help="hpipm's preset on both sides (NMPCOptions.qp_mode; default speed_abs, the NMPC's default)")
    ap.add_argument("--qp-mu0", type=float, default=None,
                    help="hpipm's initial complementarity on both sides (NMPCOptions.qp_mu0; acados' qp_mu0; "
                         "default: the preset's)")
    ap.add_argument("--acados-python", default=DEFAULT_ACADOS_PYTHON, help="acados' interpreter")
    ap.add_argument("--wait-load", type=float, default=None, metavar="L",
                    help="before each round wait (up to --wait-max s) until the 1-min load average is <= L")
    ap.add_argument("--wait-max", type=float, default=1800.0, help="longest wait for --wait-load [s]")
    ap.add_argument("--keep", default="", help="keep the recorded closed loops (.npz) in this folder")
    ap.add_argument("--out", default="", help="write the results (markdown) here")
    ap.add_argument("--append", action="store_true",
                    help="append to --out (a second measurement below the first, without the notes)")
    ap.add_argument("--worker-ours", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--json", default="", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker_ours is not None:
        Path(args.json).write_text(json.dumps(time_ours(args.worker_ours, args.duration, args.qp_tol, args.ours_qp[0],
                                                        (args.qp_mode, args.qp_mu0))))
        return 0
    if args.quick:
        args.horizons, args.duration, args.rounds, args.qp, args.cost = [20], 0.5, 1, ["partial"], ["external"]
    from mitigate.controllers.nmpc import MAX_HORIZON
    bad = ([f"--horizons must be 1..{MAX_HORIZON}, got {h}" for h in args.horizons if not 1 <= h <= MAX_HORIZON]
           + ([f"--duration must be >= 0.2 s (a few plans), got {args.duration:g}"] if not args.duration >= 0.2 else [])
           + ([f"--rounds must be >= 0, got {args.rounds}"] if args.rounds < 0 else [])
           + ([f"--qp-tol must be > 0, got {args.qp_tol:g}"] if args.qp_tol is not None and not args.qp_tol > 0 else [])
           + ([f"--qp-mu0 must be > 0, got {args.qp_mu0:g}"] if args.qp_mu0 is not None and not args.qp_mu0 > 0 else [])
           + (["--append needs --out"] if args.append and not args.out else []))
    if bad:
        ap.error(bad[0])
    import casadi as ca
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_acados."))
    work.mkdir(parents=True, exist_ok=True)
    load = [os.getloadavg()]
    t_start = time.time()
    data = {}
    for N in args.horizons:
        data[N] = work / f"closed_loop_N{N}.npz"
        info = record(N, args.duration, data[N], args.qp_tol, (args.qp_mode, args.qp_mu0))
        print(f"N = {N}: recorded {info['plans']} plans ({info['prepared']} prepared, {info['inits']} from scratch, "
              f"{info['failures']} failures; RK4 substeps {info['nsub']})", flush=True)
    variants = [(qp, cost) for qp in args.qp for cost in args.cost] if args.side != "ours" else []
    note = ""
    if variants:
        note = _acados_ok(args.acados_python, data[args.horizons[0]])
        if note:
            print(f"acados side skipped: {note}", flush=True)
            variants = []
    builds, versions = {}, {}
    for N in args.horizons:
        for qp, cost in variants:      # generate and compile once (cached), untimed
            res = _run_acados(args.acados_python, data[N], qp, cost, args.cflags, work / "warm.json")
            builds[(N, qp, cost)] = res["build"]
            versions = {k: res[k] for k in ("acados", "casadi", "python", "acados_dir")}
    runs = {}                          # (kind, N) -> list of results
    agree = {}
    for r in range(args.rounds):
        if args.wait_load is not None:
            t_wait = time.time()
            while os.getloadavg()[0] > args.wait_load and time.time() - t_wait < args.wait_max:
                time.sleep(15)
            load[-1] = os.getloadavg()
        for N in args.horizons:
            tasks = ([("ours", c) for c in args.ours_qp] if args.side != "acados" else []) + [("acados", v) for v in variants]
            for kind, v in (tasks if r % 2 == 0 else tasks[::-1]):
                out = work / f"round{r}_{kind}_N{N}_{v if kind == 'ours' else '_'.join(v)}.json"
                if kind == "ours":
                    res = _run_ours(N, args.duration, args.qp_tol, out, v, (args.qp_mode, args.qp_mu0))
                    key = ("ours" if v == "none" else f"ours, {v} condensing", N)
                else:
                    res = _run_acados(args.acados_python, data[N], v[0], v[1], args.cflags, out)
                    key = (f"acados {'partial condensing to ceil(N/5) stages' if v[0] == 'blocks' else v[0] + ' condensing'}"
                           f", {v[1]} cost", N)
                    agree.setdefault(key, _agreement(data[N], res["moves"]))
                runs.setdefault(key, []).append(res)
        load.append(os.getloadavg())
        print(f"round {r + 1}/{args.rounds} done; load average {load[-1][0]:.2f}", flush=True)
    text = _report(args, argv, runs, agree, builds, versions, note, load, time.time() - t_start, ca.__version__)
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    print(text)
    if args.out:
        from models.files import atomic_write_text
        if args.append and os.path.exists(args.out):
            text = Path(args.out).read_text() + "\n" + text.split("\n## What the comparison is")[0].replace(
                "# The NMPC's RTI beside", "## Also measured: the NMPC's RTI beside", 1) + "\n"
        atomic_write_text(args.out, text, overwrite=True)
    return 0


def _report(args, argv, runs, agree, builds, versions, note, load, took, ca_version) -> str:
    cmd = "python " + " ".join(["benchmarks/bench_acados.py"] + list(argv if argv is not None else sys.argv[1:]))
    from models.cbuild import blasfeo_override
    blas = blasfeo_override()
    lines = ["# The NMPC's RTI beside acados' SQP_RTI on the same OCP (issue 26)", "",
             f"Command: `{cmd}` ({took / 60:.1f} min)", "",
             f"Machine: {_machine()}; load average (1 min) before / after each round: "
             + " / ".join(f"{lv[0]:.2f}" for lv in load) + " (a shared machine: other engineers' jobs run beside)",
             f"Ours: Python {platform.python_version()}, casadi {ca_version}, numpy {np.__version__}; "
             + (f"hpipm as the casadi wheel ships it, blasfeo from {blas} (STICKSLIP_BLASFEO)."
                if blas is not None else "hpipm and blasfeo as the casadi wheel ships them."),
             ("acados: comma-deps-acados {acados} (its own venv, Python {python}, its vendored casadi {casadi}); "
              "libacados, hpipm and blasfeo as that wheel ships them ({acados_dir})".format(**versions)
              if versions else f"acados: not run ({note or 'side = ours'})"),
             f"Problem: bench_nmpc.py's main scenario, {args.duration:g} s closed loop from established stick-slip, "
             f"{args.rounds} interleaved round(s); the first plan of each run is a warm-up and excluded.", ""]
    if builds:
        lines.append("acados' code generation and build (cached by content; 0 = cached): "
                     + ", ".join(f"N = {N} {qp}/{cost} {t:.0f} s" for (N, qp, cost), t in builds.items()) + ".")
        lines.append("")
    lines += ["## Time per call [ms]", "",
              "Median, p10 and p95 over all samples of all rounds, and the range of the per-round medians. On a "
              "loaded machine the p10 is the better estimate of an undisturbed call (preemption and cache "
              "thrashing only ever add time).", "",
              "| side | N | phase | measure | median | per-round medians | p10 | p95 | samples |",
              "|---|---|---|---|---|---|---|---|---|"]
    for (kind, N), rs in sorted(runs.items(), key=lambda kv: (kv[0][1], not kv[0][0].startswith("ours"), kv[0][0])):
        series = {}
        for res in rs:
            for phase, measure, s in _series("ours" if kind.startswith("ours") else "acados", res):
                series.setdefault((phase, measure), []).append(s[np.isfinite(s)])
        for (phase, measure), ss in sorted(series.items(), key=lambda kv: kv[0][0] != "feedback"):
            allv = np.concatenate(ss)
            meds = [np.median(s) for s in ss]
            lines.append(f"| {kind} | {N} | {phase} | {measure} | {np.median(allv):.3f} | "
                         f"{min(meds):.3f} - {max(meds):.3f} | {np.percentile(allv, 10):.3f} "
                         f"| {np.percentile(allv, 95):.3f} | {allv.size} |")
    lines.append("")
    acad = [(k, rs) for k, rs in runs.items() if not k[0].startswith("ours")]
    if acad:
        lines += ["acados' C timers in detail (medians of the first round) and its status:", ""]
        for (kind, N), rs in sorted(acad, key=lambda kv: (kv[0][1], kv[0][0])):
            bad = sum(int(s != 0) for res in rs for s in res["status"])
            lines.append(f"- {kind}, N = {N}: {_detail(rs[0])}; feedback status != 0 in {bad} of "
                         f"{sum(len(res['status']) for res in rs)} plans")
        lines += ["", "## Agreement of the first moves", "",
                  "|acados' first move - ours| / the input's scale (set-point: the speed scale; servo: its n_max), "
                  "over every plan of the closed loop:", "",
                  "| acados variant | N | plans | set-point median / p95 / max | servo median / p95 / max |",
                  "|---|---|---|---|---|"]
        for (kind, N), a in sorted(agree.items(), key=lambda kv: (kv[0][1], kv[0][0])):
            cols = " | ".join(f"{a['median'][j]:.1e} / {a['p95'][j]:.1e} / {a['max'][j]:.1e}"
                              for j in range(len(a["median"])))
            lines.append(f"| {kind} | {N} | {a['n']} | {cols} |")
        lines.append("")
    lines += ["## What the comparison is, and what is not equal", "", NOTES]
    return "\n".join(lines) + "\n"


NOTES = """\
- Same OCP: acados gets the workbench's own SX expressions (dynamics F with RK4 substeps, stage
  residual and linear servo term, terminal residual), rebuilt op by op and checked to 1e-12;
  Gauss-Newton Hessian J'J exactly (EXTERNAL with the custom Hessian, or CONVEX_OVER_NONLINEAR);
  acados' per-stage cost scaling by dt set back to 1; the same boxes and servo-rate rows; hpipm
  in the same mode, tolerance and iteration limit, cold-started on both sides.
- Same QPs: acados replays the closed loop that ours ran (state, linearisation parameters and
  bounds at every plan) from the same initial plan, with its own iterate shifted as ours is. It
  does not close the loop itself; the agreement table shows how close its QPs' answers stay.
- Feedback / preparation: ours is the whole controller call (the layers around the OCP in
  Python included) and, inside it, the OCP solver's call; acados' C timer `time_tot` covers the
  phase inside libacados only (no Python); its ctypes wall time adds the per-stage C-API calls
  from Python (bounds at every stage; shift, parameters), which a C caller would do with memcpy.
  So compare a compiled step (issue 26's goal) against acados' C timer, and today's Python
  controller against either.
- Compiled code: acados' generated functions at `--cflags` (acados' default -O2); ours at -O2
  (the Release build, models.codegen; strict IEEE arithmetic). acados' wheel ships blasfeo built with AVX2/FMA kernels; the casadi wheel's
  blasfeo is the generic C target (its hpipm itself uses AVX); ours calls the wheel's unless
  STICKSLIP_BLASFEO names another (the "Ours:" line above says which).
- acados' preparation does the linearisation (and, with full condensing, the condensing); its
  feedback embeds x0 and solves the QP. With full condensing the QP is hpipm's dense solver.
"""


if __name__ == "__main__":
    raise SystemExit(main())
