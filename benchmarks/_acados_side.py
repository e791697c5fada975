"""The acados side of ``benchmarks/bench_acados.py``: acados' SQP_RTI on the NMPC's own OCP,
replayed along the workbench's closed loop.  Runs in acados' own virtual environment (numpy,
acados' vendored casadi and ``acados_template``; nothing from this repository's packages), as::

    /work/venv-acados/bin/python benchmarks/_acados_side.py DATA.npz --qp partial --out RESULT.json

``DATA.npz`` is written by ``bench_acados.py`` in the workbench's venv: the OCP's functions as
version-neutral SX instruction lists (:func:`dump_sx`; CasADi 3.8's serialisation cannot be read
by acados' casadi 3.6), test evaluations of them, the OCP's dimensions and constraint structure,
and for every plan of the closed loop the data the workbench's RTI solved: the initial state, the
parameters of the linearisation, the bounds and the workbench's first move.

The first half of this module (:func:`dump_sx`, :func:`load_sx`) needs only casadi and numpy and
is imported by ``bench_acados.py`` too.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np

CACHE = Path(os.environ.get("STICKSLIP_CACHE", Path.home() / ".cache" / "stickslip")) / "acados"


# ----------------------------------------------------------------------------- SX transfer
def dump_sx(fn: ca.Function, prefix: str) -> dict[str, np.ndarray]:
    """An SX Function as plain arrays (op names, work-vector indices, constants, sparsities):
    rebuilt by :func:`load_sx` under any CasADi version that has the same operations."""
    if not fn.is_a("SXFunction"):
        fn = fn.expand()
    names = {getattr(ca, n): n for n in dir(ca) if n.startswith("OP_")}
    n = fn.n_instructions()
    ops = np.empty(n, dtype="<U24")
    arg = np.full((n, 2), -1, dtype=np.int64)
    res = np.full((n, 2), -1, dtype=np.int64)
    const = np.zeros(n)
    for k in range(n):
        op = names[fn.instruction_id(k)]
        if op == "OP_CALL":
            raise ValueError(f"{fn.name()}: calls to other Functions cannot be transferred (inline them)")
        ops[k] = op
        a, r = fn.instruction_input(k), fn.instruction_output(k)
        arg[k, :len(a)], res[k, :len(r)] = a, r
        if op == "OP_CONST":
            const[k] = fn.instruction_constant(k)

    def sparsity(sp: ca.Sparsity) -> np.ndarray:
        return np.array([sp.size1(), sp.size2()] + list(sp.colind()) + list(sp.row()), dtype=np.int64)
    out = {f"{prefix}.ops": ops, f"{prefix}.arg": arg, f"{prefix}.res": res, f"{prefix}.const": const,
           f"{prefix}.name": np.array(fn.name()),
           f"{prefix}.in": np.array(fn.name_in()), f"{prefix}.out": np.array(fn.name_out())}
    for i in range(fn.n_in()):
        out[f"{prefix}.sp_in{i}"] = sparsity(fn.sparsity_in(i))
    for i in range(fn.n_out()):
        out[f"{prefix}.sp_out{i}"] = sparsity(fn.sparsity_out(i))
    return out


def load_sx(data, prefix: str) -> ca.Function:
    """The Function :func:`dump_sx` wrote under ``prefix``, rebuilt operation by operation."""
    def sparsity(a) -> ca.Sparsity:
        nr, nc = int(a[0]), int(a[1])
        colind = [int(v) for v in a[2:3 + nc]]
        return ca.Sparsity(nr, nc, colind, [int(v) for v in a[3 + nc:]])
    name_in = [str(s) for s in data[f"{prefix}.in"]]
    name_out = [str(s) for s in data[f"{prefix}.out"]]
    syms = [ca.SX.sym(nm, sparsity(data[f"{prefix}.sp_in{i}"])) for i, nm in enumerate(name_in)]
    nz_in = [[s.nz[k] for k in range(s.nnz())] for s in syms]
    sp_out = [sparsity(data[f"{prefix}.sp_out{i}"]) for i in range(len(name_out))]
    nz_out = [[ca.SX(0)] * sp.nnz() for sp in sp_out]
    ops, arg, res, const = (data[f"{prefix}.{k}"] for k in ("ops", "arg", "res", "const"))
    code = {}
    w: dict[int, ca.SX] = {}
    for k in range(len(ops)):
        op = str(ops[k])
        a0, a1 = int(arg[k, 0]), int(arg[k, 1])
        r0, r1 = int(res[k, 0]), int(res[k, 1])
        if op == "OP_CONST":
            w[r0] = ca.SX(float(const[k]))
        elif op == "OP_INPUT":
            w[r0] = nz_in[a0][a1]
        elif op == "OP_OUTPUT":
            nz_out[r0][r1] = w[a0]
        else:
            c = code.get(op)
            if c is None:
                if not hasattr(ca, op):
                    raise ValueError(f"{prefix}: casadi {ca.__version__} has no operation {op}")
                c = code[op] = getattr(ca, op)
            w[r0] = ca.SX.unary(c, w[a0]) if a1 < 0 else ca.SX.binary(c, w[a0], w[a1])
    outs = [ca.SX(sp, ca.vertcat(*nz)) if nz else ca.SX(sp) for sp, nz in zip(sp_out, nz_out)]
    return ca.Function(str(data[f"{prefix}.name"]), syms, outs, name_in, name_out)


# ----------------------------------------------------------------------------- acados
def _template():
    """``AcadosModel, AcadosOcp, AcadosOcpSolver`` from the ``acados_template`` that
    comma-deps-acados ships inside its ``acados`` package, with acados' paths set and the
    libraries libacados needs loaded first (the wheel's libacados has no rpath to them)."""
    import ctypes

    import acados
    os.environ.setdefault("ACADOS_SOURCE_DIR", acados.DIR)
    os.environ.setdefault("TERA_PATH", acados.TERA_PATH)
    os.environ.setdefault("ACADOS_PYTHON_INTERFACE_PATH", acados.TEMPLATE_DIR)
    for lib in ("libblasfeo.so", "libhpipm.so", "libqpOASES_e.so.3.1"):
        path = Path(acados.LIB_DIR) / lib
        if path.exists():
            ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    sys.path.insert(0, str(Path(acados.__file__).parent))
    from acados_template import AcadosModel, AcadosOcp, AcadosOcpSolver
    return AcadosModel, AcadosOcp, AcadosOcpSolver


def check_functions(data) -> dict[str, ca.Function]:
    """The rebuilt functions, each checked against the workbench's own evaluations (max relative
    error; raises if above 1e-12)."""
    fns = {}
    for pre in ("F", "cost", "rN"):
        f = load_sx(data, pre)
        ins = [data[f"{pre}.test_in{i}"] for i in range(f.n_in())]
        for i, got in enumerate(f.call([ca.DM(x) for x in ins])):
            want = data[f"{pre}.test_out{i}"]
            err = np.max(np.abs(np.array(got).ravel(order="F") - want) / (1.0 + np.abs(want)))
            if not err <= 1e-12:
                raise RuntimeError(f"rebuilt {pre} output {i} differs from the workbench's by {err:.3g}")
        fns[pre] = f
    return fns


def formulate(data, fns, *, qp: str, cost: str, cflags: str):
    """acados' OCP: discrete dynamics F, the least-squares cost plus the linear servo term with
    the Gauss-Newton Hessian, the same boxes and general rows; SQP_RTI with hpipm."""
    AcadosModel, AcadosOcp, _ = _template()
    N, dt = int(data["N"]), float(data["dt"])
    nxa, nv, nq = int(data["nxa"]), int(data["nv"]), int(data["nq"])
    x, u, p = ca.SX.sym("xa", nxa), ca.SX.sym("v", nv), ca.SX.sym("q", nq)
    model = AcadosModel()
    model.name = "ss_" + data_hash(data, qp, cost, cflags)[:12]
    model.x, model.u, model.p = x, u, p
    model.xdot = ca.SX.sym("xdot", nxa)
    model.disc_dyn_expr = fns["F"](x, u, p)
    r, lin = fns["cost"](x, u, p)
    rN = fns["rN"](x, p)
    ocp = AcadosOcp()
    ocp.model = model
    ocp.dims.N = N
    if cost == "external":
        # 0.5 |r|^2 + l with the custom Hessian J'J (J = dr/d[u, x]: acados' ordering)
        J = ca.jacobian(r, ca.vertcat(u, x))
        ocp.cost.cost_type = ocp.cost.cost_type_e = "EXTERNAL"
        model.cost_expr_ext_cost = 0.5 * ca.sumsqr(r) + lin
        model.cost_expr_ext_cost_custom_hess = J.T @ J
        JN = ca.jacobian(rN, x)
        model.cost_expr_ext_cost_e = 0.5 * ca.sumsqr(rN)
        model.cost_expr_ext_cost_custom_hess_e = JN.T @ JN
    else:
        # convex-over-nonlinear: psi(y) = 0.5 |y[:-1]|^2 + y[-1] on y = [r; l]; its generalised
        # Gauss-Newton Hessian is J'J (psi is linear in l), the gradient J'r + dl
        ny = r.numel()
        y = ca.SX.sym("y", ny + 1)
        ocp.cost.cost_type = ocp.cost.cost_type_e = "CONVEX_OVER_NONLINEAR"
        model.cost_y_expr = ca.vertcat(r, lin)
        model.cost_r_in_psi_expr = y
        model.cost_psi_expr = 0.5 * ca.sumsqr(y[:ny]) + y[ny]
        ocp.cost.yref = np.zeros(ny + 1)
        yN = ca.SX.sym("yN", rN.numel())
        model.cost_y_expr_e = rN
        model.cost_r_in_psi_expr_e = yN
        model.cost_psi_expr_e = 0.5 * ca.sumsqr(yN)
        ocp.cost.yref_e = np.zeros(rN.numel())
    c = ocp.constraints
    c.x0 = data["xa0"][0]
    c.idxbu = np.arange(nv)
    c.lbu, c.ubu = data["lbv"][0], data["ubv"][0]
    iw = int(data["i_wprev"])
    if iw >= 0:
        c.idxbx, c.lbx, c.ubx = np.array([iw]), data["lbw"][0, :1], data["ubw"][0, :1]
        c.idxbx_e, c.lbx_e, c.ubx_e = np.array([iw]), data["lbw"][0, -1:], data["ubw"][0, -1:]
    if data["C"].shape[0]:
        c.C, c.D = data["C"], data["D"]
        c.lg, c.ug = -data["dg"][0], data["dg"][0]
    ocp.parameter_values = data["q_lin"][0]
    so = ocp.solver_options
    so.tf = N * dt
    so.integrator_type = "DISCRETE"
    so.nlp_solver_type = "SQP_RTI"
    so.hessian_approx = "GAUSS_NEWTON"
    so.regularize_method = "NO_REGULARIZE"
    so.qp_solver = "FULL_CONDENSING_HPIPM" if qp == "full" else "PARTIAL_CONDENSING_HPIPM"
    if qp == "partial":
        so.qp_solver_cond_N = N          # no condensing: hpipm's OCP QP on all N stages, as ours
    elif qp == "blocks":
        so.qp_solver_cond_N = -(-N // 5)  # condensed to ceil(N / 5) stages, as ours with qp_condensing "partial"
    so.hpipm_mode = str(data["hpipm_mode"]).upper()
    tol = float(data["qp_tol"])
    so.qp_solver_tol_stat = so.qp_solver_tol_eq = so.qp_solver_tol_ineq = so.qp_solver_tol_comp = tol
    so.qp_solver_iter_max = int(data["qp_iter_max"])
    so.qp_solver_warm_start = 0
    so.print_level = 0
    so.ext_fun_compile_flags = cflags
    return ocp


def data_hash(data, *options) -> str:
    h = hashlib.sha256()
    for k in sorted(data.files):
        if k.split(".")[0] in ("F", "cost", "rN") or k in ("N", "dt", "nxa", "nv", "nq", "i_wprev", "C", "D",
                                                            "hpipm_mode", "qp_tol", "qp_iter_max"):
            h.update(k.encode())
            h.update(np.ascontiguousarray(data[k]).tobytes())
    h.update(json.dumps([str(o) for o in options] + [ca.__version__]).encode())
    return h.hexdigest()


def build_solver(data, fns, *, qp: str, cost: str, cflags: str, rebuild: bool = False):
    """acados' solver for ``data``, generated and compiled once (cached by content under
    ``~/.cache/stickslip/acados``); returns the solver and the build time [s] (0: cached)."""
    _, _, AcadosOcpSolver = _template()
    ocp = formulate(data, fns, qp=qp, cost=cost, cflags=cflags)
    d = CACHE / ocp.model.name
    d.mkdir(parents=True, exist_ok=True)
    ocp.code_export_directory = str(d / "c_generated_code")
    json_file = str(d / "acados_ocp.json")
    built = (d / "c_generated_code" / f"libacados_ocp_solver_{ocp.model.name}.so").exists() and not rebuild
    t0 = time.perf_counter()
    cwd = os.getcwd()
    os.chdir(d)                      # acados writes beside its json
    try:
        solver = AcadosOcpSolver(ocp, json_file=json_file, build=not built, generate=not built, verbose=False)
    finally:
        os.chdir(cwd)
    unscale_cost(solver)
    return solver, (0.0 if built else time.perf_counter() - t0)


def unscale_cost(solver) -> None:
    """acados weights every stage cost (not the terminal one) by its time step; the workbench's
    OCP does not: set the scaling back to 1 at stages 0..N-1."""
    from ctypes import byref, c_char_p, c_double, c_int, c_void_p
    f = solver.shared_lib.ocp_nlp_cost_model_set
    f.argtypes = [c_void_p, c_void_p, c_void_p, c_int, c_char_p, c_void_p]
    one = c_double(1.0)
    for k in range(solver.N):
        f(solver.nlp_config, solver.nlp_dims, solver.nlp_in, k, b"scaling", byref(one))


class Driver:
    """acados' C API through ctypes with the argument types bound once (as the workbench calls
    hpipm): the least Python a caller of acados' shared library can put around it."""

    def __init__(self, solver):
        from ctypes import c_char_p, c_int, c_void_p
        lib, name = solver.shared_lib, solver.model_name
        self.solver, self.N = solver, solver.N
        self.cfg, self.dims, self.nin = c_void_p(solver.nlp_config), c_void_p(solver.nlp_dims), c_void_p(solver.nlp_in)
        self.nout, self.opts, self.nlp = c_void_p(solver.nlp_out), c_void_p(solver.nlp_opts), c_void_p(solver.nlp_solver)
        self.capsule = c_void_p(solver.capsule)
        five = [c_void_p, c_void_p, c_void_p, c_int, c_char_p, c_void_p]
        self._cset, self._oset, self._oget = (lib.ocp_nlp_constraints_model_set, lib.ocp_nlp_out_set,
                                              lib.ocp_nlp_out_get)
        for f in (self._cset, self._oset, self._oget):
            f.argtypes = five
        self._par = getattr(lib, f"{name}_acados_update_params")
        self._par.argtypes = [c_void_p, c_int, c_void_p, c_int]
        self._optset = lib.ocp_nlp_solver_opts_set
        self._optset.argtypes = [c_void_p, c_void_p, c_char_p, c_void_p]
        self._solve = getattr(lib, f"{name}_acados_solve")
        self._solve.argtypes = [c_void_p]
        self._solve.restype = c_int
        self._get = lib.ocp_nlp_get
        self._get.argtypes = [c_void_p, c_void_p, c_char_p, c_void_p]
        from ctypes import byref, c_double
        self._phase = c_int(0)
        self._phase_p = byref(self._phase)
        self._t = c_double(0.0)
        self._t_p = byref(self._t)

    def bound(self, stage: int, field: bytes, addr: int) -> None:
        self._cset(self.cfg, self.dims, self.nin, stage, field, addr)

    def put(self, stage: int, field: bytes, addr: int) -> None:
        self._oset(self.cfg, self.dims, self.nout, stage, field, addr)

    def take(self, stage: int, field: bytes, addr: int) -> None:
        self._oget(self.cfg, self.dims, self.nout, stage, field, addr)

    def params(self, stage: int, addr: int, n: int) -> None:
        self._par(self.capsule, stage, addr, n)

    def phase(self, k: int) -> int:
        """One SQP_RTI phase (1: preparation, 2: feedback); acados' status."""
        self._phase.value = k
        self._optset(self.cfg, self.opts, b"rti_phase", self._phase_p)
        return self._solve(self.capsule)

    def timer(self, field: bytes) -> float:
        """acados' own timer of the last call [s]."""
        self._get(self.cfg, self.nlp, field, self._t_p)
        return self._t.value


def replay(data, solver) -> dict:
    """Every plan of the recorded closed loop through acados' RTI: the preparation after a plan
    (shift the iterate as the workbench does, set the parameters, ``rti_phase = 1``) and the
    feedback at the next (embed the state, set the bounds, ``rti_phase = 2``)."""
    d = Driver(solver)
    N, nxa, nv, nq = d.N, int(data["nxa"]), int(data["nv"]), int(data["nq"])
    iw = int(data["i_wprev"])
    zero_tail = [int(j) for j in data["tail_zero"]]
    arr = {k: np.ascontiguousarray(data[k], dtype=float) for k in ("xa0", "lbv", "ubv", "lbw", "ubw", "dg", "q_lin")}
    xa0, lbv, ubv, lbw, ubw, dg, q_lin = (arr[k] for k in ("xa0", "lbv", "ubv", "lbw", "ubw", "dg", "q_lin"))
    lg = np.ascontiguousarray(-dg)
    prepared, init = data["prepared"].astype(bool), data["init"].astype(bool)
    X_init, V_init = np.ascontiguousarray(data["X_init"], float), np.ascontiguousarray(data["V_init"], float)
    P = xa0.shape[0]
    X, V = np.zeros((N + 1, nxa)), np.zeros((N, nv))
    u0 = np.zeros(nv)
    ax, av, au0 = X.ctypes.data, V.ctypes.data, u0.ctypes.data

    def row(a, i):
        return a.ctypes.data + i * a.shape[1] * 8

    def element(a, i, j):
        return a.ctypes.data + (i * a.shape[1] + j) * 8

    def prepare(i: int) -> tuple[float, float, int]:
        """Shift (as the workbench's OCPSolver.shift), parameters q_lin[i], phase 1; wall and thread
        CPU time [s], status."""
        c0, t0 = time.thread_time(), time.perf_counter()
        for k in range(N + 1):
            d.take(k, b"x", ax + k * nxa * 8)
        for k in range(N):
            d.take(k, b"u", av + k * nv * 8)
        for k in range(N):
            d.put(k, b"x", ax + (k + 1) * nxa * 8)      # x_N stays (the old last state)
        for k in range(N - 1):
            d.put(k, b"u", av + (k + 1) * nv * 8)
        for j in zero_tail:
            V[N - 1, j] = 0.0
        d.put(N - 1, b"u", av + (N - 1) * nv * 8)
        pq = row(q_lin, i)
        for k in range(N + 1):
            d.params(k, pq, nq)
        st = d.phase(1)
        return time.perf_counter() - t0, time.thread_time() - c0, st

    def initialise(i: int) -> int:
        j = int(np.count_nonzero(init[:i]))
        for k in range(N + 1):
            d.put(k, b"x", row(X_init[j], k))
        for k in range(N):
            d.put(k, b"u", row(V_init[j], k))
        for k in range(N + 1):
            d.params(k, row(q_lin, i), nq)
        return d.phase(1)

    def feedback(i: int) -> tuple[float, float, int]:
        c0, t0 = time.thread_time(), time.perf_counter()
        x0 = row(xa0, i)
        d.bound(0, b"lbx", x0)
        d.bound(0, b"ubx", x0)
        lo, hi = row(lbv, i), row(ubv, i)
        for k in range(N):
            d.bound(k, b"lbu", lo)
            d.bound(k, b"ubu", hi)
        if iw >= 0:
            for k in range(1, N + 1):
                d.bound(k, b"lbx", element(lbw, i, k - 1))
                d.bound(k, b"ubx", element(ubw, i, k - 1))
        if dg.shape[1]:
            lo, hi = row(lg, i), row(dg, i)
            for k in range(N):
                d.bound(k, b"lg", lo)
                d.bound(k, b"ug", hi)
        st = d.phase(2)
        d.take(0, b"u", au0)
        return time.perf_counter() - t0, time.thread_time() - c0, st

    # acados keeps a timer until the phase that sets it runs again: read each after its own phase
    fb = {k: np.full(P, np.nan) for k in ("wall", "cpu", "time_tot", "time_qp", "time_qp_solver_call")}
    pr = {k: np.full(P, np.nan) for k in ("wall", "cpu", "time_tot", "time_lin", "time_qp_xcond")}
    qp_iter = np.zeros(P, dtype=int)
    status = np.zeros(P, dtype=int)
    prep_status = np.zeros(P, dtype=int)
    moves = np.zeros((P, nv))
    inline = 0
    for i in range(P):
        if init[i]:
            prep_status[i] = initialise(i)
        elif not prepared[i] or i == 0:
            inline += 1
            _, _, prep_status[i] = prepare(i)
        fb["wall"][i], fb["cpu"][i], status[i] = feedback(i)
        for k in ("time_tot", "time_qp", "time_qp_solver_call"):
            fb[k][i] = d.timer(k.encode())
        qp_iter[i] = int(np.atleast_1d(solver.get_stats("qp_iter"))[-1])
        moves[i] = u0
        if iw >= 0:
            moves[i, 0] += xa0[i, iw]       # the applied set-point: w_prev + its change
        if i + 1 < P and prepared[i + 1] and not init[i + 1]:
            pr["wall"][i + 1], pr["cpu"][i + 1], prep_status[i + 1] = prepare(i + 1)
            for k in ("time_tot", "time_lin", "time_qp_xcond"):
                pr[k][i + 1] = d.timer(k.encode())
    return dict(feedback={k: v.tolist() for k, v in fb.items()}, preparation={k: v.tolist() for k, v in pr.items()},
                qp_iter=qp_iter.tolist(), status=status.tolist(), prep_status=prep_status.tolist(),
                moves=moves.tolist(), inline_preparations=inline)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", help="the .npz that bench_acados.py wrote")
    ap.add_argument("--qp", choices=("partial", "full", "blocks"), default="partial",
                    help="PARTIAL_CONDENSING_HPIPM with cond_N = N (no condensing), FULL_CONDENSING_HPIPM, or "
                         "PARTIAL_CONDENSING_HPIPM with cond_N = ceil(N / 5) (blocks)")
    ap.add_argument("--cost", choices=("external", "conl"), default="external")
    ap.add_argument("--cflags", default="-O2", help="acados' ext_fun_compile_flags (its default -O2)")
    ap.add_argument("--check", action="store_true", help="only rebuild and check the functions")
    ap.add_argument("--out", required=False, default="")
    args = ap.parse_args(argv)
    with np.load(args.data, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    fns = check_functions(_Files(data))
    if args.check:
        print("functions rebuilt and checked:", ", ".join(f"{k} ({f.n_instructions()} instructions)"
                                                          for k, f in fns.items()))
        return 0
    solver, t_build = build_solver(_Files(data), fns, qp=args.qp, cost=args.cost, cflags=args.cflags)
    mu0 = float(data["qp_mu0"]) if "qp_mu0" in data else float("nan")
    if np.isfinite(mu0):
        solver.options_set("qp_mu0", mu0)      # hpipm's initial complementarity, as ours (NMPCOptions.qp_mu0)
    import acados
    out = dict(replay(data, solver), build=t_build, qp=args.qp, cost=args.cost, cflags=args.cflags, casadi=ca.__version__,
               acados=_version("comma-deps-acados"), python=sys.version.split()[0], acados_dir=acados.DIR)
    text = json.dumps(out)
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text)
    return 0


class _Files(dict):
    """A dict of arrays that answers ``.files`` like an open npz."""

    @property
    def files(self):
        return list(self.keys())


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version(dist)
    except PackageNotFoundError:
        return "?"


if __name__ == "__main__":
    raise SystemExit(main())
