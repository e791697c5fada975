"""The stage-wise QP of the NMPC and its solvers: hpipm called directly, or CasADi's ``conic``.

Every Gauss-Newton step of the OCP (:mod:`mitigate.controllers.nmpc.ocp`) is one QP in the
form hpipm solves natively::

    min  sum_{k=0}^{N} 0.5 x_k' Q_k x_k + u_k' S_k x_k + 0.5 u_k' R_k u_k + q_k' x_k + r_k' u_k
    s.t. x_{k+1} = A_k x_k + B_k u_k + b_k                       k = 0 .. N-1
         x_0 = lbx0 = ubx0                                      (initial-value embedding)
         lbx_k <= x_k[idxbx] <= ubx_k                           k = 1 .. N
         lbu_k <= u_k[idxbu] <= ubu_k                           k = 0 .. N-1
         lg_k  <= C x_k + D u_k <= ug_k                         k = 0 .. N-1

(stage ``N`` has no input).  Only the bounds that exist are passed, so hpipm's interior-point
iteration works on a handful of inequalities per stage instead of a (mostly infinite) bound on
every variable, and no general sparse QP is assembled and converted on every call.

The data live in numpy buffers with the stage on axis 0 and every matrix block flattened
column-major (the layout of a CasADi ``map`` output), so the compiled stage function's
outputs are copied in with one ``np.copyto`` each:

    A (N, nx nx), B (N, nx nu), b (N, nx), Q (N+1, nx nx), S (N, nu nx), R (N, nu nu),
    q (N+1, nx), r (N, nu), lbx0/ubx0 (nx,), lbx/ubx (N, nbx), lbu/ubu (N, nbu), lg/ug (N, ng)

and the solution is written to ``x`` (N+1, nx) and ``u`` (N, nu).

Solvers:

- :class:`HpipmQP`: hpipm's C API through ``ctypes`` on the ``libhpipm`` that CasADi ships.
  One call packs the data (``d_ocp_qp_set_all``), one solves, one unpacks; no allocation.
- :class:`ConicQP`: the same QP assembled as one sparse QP for CasADi's ``conic``
  ("qrqp", an exact active-set method, or "osqp"): the independent reference.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.sparse as sp

from models.errors import ConfigError, SolverFailure

__all__ = ["StageQP", "HpipmQP", "ConicQP", "make_qp", "QP_SOLVERS", "HPIPM_MODES"]

QP_SOLVERS = ("hpipm", "qrqp", "osqp")


class StageQP:
    """Buffers of the stage-wise QP (module docstring) and the solution.

    Parameters
    ----------
    N : intervals; nx, nu : states and inputs per stage
    idxbx : indices of the states bounded at stages 1..N
    idxbu : indices of the inputs bounded at stages 0..N-1
    C, D : (ng, nx), (ng, nu) constant general-constraint rows of stages 0..N-1
    """

    def __init__(self, N: int, nx: int, nu: int, idxbx, idxbu, C, D):
        self.N, self.nx, self.nu = int(N), int(nx), int(nu)
        self.idxbx = np.asarray(idxbx, dtype=np.int32).ravel()
        self.idxbu = np.asarray(idxbu, dtype=np.int32).ravel()
        self.C = np.asfortranarray(np.asarray(C, float).reshape(-1, nx))
        self.D = np.asfortranarray(np.asarray(D, float).reshape(-1, nu))
        self.ng = self.C.shape[0]
        nbx, nbu, ng = self.idxbx.size, self.idxbu.size, self.ng
        z = np.zeros
        self.A, self.B, self.b = z((N, nx * nx)), z((N, nx * nu)), z((N, nx))
        self.Q, self.S, self.R = z((N + 1, nx * nx)), z((N, nu * nx)), z((N, nu * nu))
        self.q, self.r = z((N + 1, nx)), z((N, nu))
        self.lbx0, self.ubx0 = z(nx), z(nx)
        self.lbx, self.ubx = z((N, nbx)), z((N, nbx))
        self.lbu, self.ubu = z((N, nbu)), z((N, nbu))
        self.lg, self.ug = z((N, ng)), z((N, ng))
        self.x, self.u = z((N + 1, nx)), z((N, nu))
        self.iterations = 0

    def solve(self) -> None:
        """Solve the QP in the buffers; the solution goes to ``x`` and ``u``.

        Raises
        ------
        SolverFailure : the solver did not converge.
        """
        raise NotImplementedError


# ----------------------------------------------------------------------------- hpipm
#: hpipm's presets (the NMPC's ``qp_mode``): the value is hpipm's ``enum hpipm_mode``
HPIPM_MODES = {"speed_abs": 0, "speed": 1, "balance": 2, "robust": 3}
HPIPM_STATUS = ("success", "maximum iterations", "minimum step length", "NaN in the solution",
                 "inconsistent equality constraints")
_LIB = None


def _hpipm():
    """hpipm's shared library as shipped with CasADi (loaded once)."""
    global _LIB
    if _LIB is None:
        path = Path(ca.__file__).resolve().parent / "libhpipm.so"
        if not path.exists():
            raise SolverFailure(f"hpipm: {path} not found (CasADi built without hpipm?)")
        lib = ctypes.CDLL(str(path))
        for name in ("d_ocp_qp_dim_strsize", "d_ocp_qp_strsize", "d_ocp_qp_sol_strsize",
                     "d_ocp_qp_ipm_arg_strsize", "d_ocp_qp_ipm_ws_strsize", "d_ocp_qp_dim_memsize",
                     "d_ocp_qp_memsize", "d_ocp_qp_sol_memsize", "d_ocp_qp_ipm_arg_memsize",
                     "d_ocp_qp_ipm_ws_memsize"):
            getattr(lib, name).restype = ctypes.c_size_t
        for name in ("d_ocp_qp_memsize", "d_ocp_qp_sol_memsize", "d_ocp_qp_ipm_arg_memsize"):
            getattr(lib, name).argtypes = [ctypes.c_void_p]
        lib.d_ocp_qp_ipm_ws_memsize.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.d_ocp_qp_dim_memsize.argtypes = [ctypes.c_int]
        lib.d_ocp_qp_set_all.argtypes = [ctypes.c_void_p] * 27
        lib.d_ocp_qp_sol_get_all.argtypes = [ctypes.c_void_p] * 12
        lib.d_ocp_qp_ipm_solve.argtypes = [ctypes.c_void_p] * 4
        lib.d_ocp_qp_ipm_get_status.argtypes = [ctypes.c_void_p] * 2
        lib.d_ocp_qp_ipm_get_iter.argtypes = [ctypes.c_void_p] * 2
        _LIB = lib
    return _LIB


class _Mem:
    """Owns the raw memory blocks handed to hpipm (64-byte aligned, as blasfeo wants)."""

    def __init__(self):
        self._blocks = []

    def block(self, size: int) -> int:
        buf = np.zeros(int(size) + 128, dtype=np.uint8)
        self._blocks.append(buf)
        addr = buf.ctypes.data
        return addr + (-addr) % 64


def _ptrs(rows, n: int, dummy: int):
    """A C array of ``n`` pointers to the rows of a C-contiguous 2-D buffer (``dummy`` beyond)."""
    arr = (ctypes.c_void_p * n)()
    for k in range(n):
        arr[k] = rows[k].ctypes.data if k < len(rows) and rows[k].size else dummy
    return arr


class HpipmQP(StageQP):
    """:class:`StageQP` solved by hpipm's OCP QP interior-point method.

    Parameters
    ----------
    tol : tolerance on the stationarity, equality, inequality and complementarity residuals
    iter_max : interior-point iterations
    mode : hpipm's preset: "speed_abs" (default), "speed", "balance" or "robust".  On the 80 QPs of
        a rig3 closed loop out of stick-slip (N = 50) "speed_abs" at tol 1e-7 took 4.4 iterations
        and 0.43 ms (median) and its first move was within 2e-4 rad/s and 1e-3 N of an exact
        active-set solution at the 95th percentile; "speed" at 1e-5 (the CasADi-era setting)
        took as many iterations and 0.56 ms with errors 2.6e-4 rad/s and 1.9e-3 N
        (``benchmarks/bench_nmpc.py --qp-study``, benchmarks/results/nmpc.md)
    """

    def __init__(self, N, nx, nu, idxbx, idxbu, C, D, *, tol: float = 1e-7, iter_max: int = 100,
                 mode: str = "speed_abs", mu0: float | None = None):
        super().__init__(N, nx, nu, idxbx, idxbu, C, D)
        lib = _hpipm()
        self._lib = lib
        self._mem = mem = _Mem()
        N1 = N + 1
        ci = ctypes.c_int * N1
        nbx = [nx] + [self.idxbx.size] * N
        nbu = [self.idxbu.size] * N + [0]
        ng = [self.ng] * N + [0]
        self._dims = (ci(*([nx] * N1)), ci(*([nu] * N + [0])), ci(*nbx), ci(*nbu), ci(*ng), ci(*([0] * N1)))
        dim = mem.block(lib.d_ocp_qp_dim_strsize())
        lib.d_ocp_qp_dim_create(ctypes.c_int(N), ctypes.c_void_p(dim),
                                ctypes.c_void_p(mem.block(lib.d_ocp_qp_dim_memsize(N))))
        lib.d_ocp_qp_dim_set_all(*self._dims, ctypes.c_void_p(dim))
        qp = mem.block(lib.d_ocp_qp_strsize())
        lib.d_ocp_qp_create(ctypes.c_void_p(dim), ctypes.c_void_p(qp), ctypes.c_void_p(mem.block(lib.d_ocp_qp_memsize(dim))))
        sol = mem.block(lib.d_ocp_qp_sol_strsize())
        lib.d_ocp_qp_sol_create(ctypes.c_void_p(dim), ctypes.c_void_p(sol),
                                ctypes.c_void_p(mem.block(lib.d_ocp_qp_sol_memsize(dim))))
        arg = mem.block(lib.d_ocp_qp_ipm_arg_strsize())
        lib.d_ocp_qp_ipm_arg_create(ctypes.c_void_p(dim), ctypes.c_void_p(arg),
                                    ctypes.c_void_p(mem.block(lib.d_ocp_qp_ipm_arg_memsize(dim))))
        if mode not in HPIPM_MODES:
            raise ConfigError(f"hpipm mode must be one of {', '.join(HPIPM_MODES)}, got {mode!r}")
        lib.d_ocp_qp_ipm_arg_set_default(ctypes.c_int(HPIPM_MODES[mode]), ctypes.c_void_p(arg))
        it = ctypes.c_int(int(iter_max))
        lib.d_ocp_qp_ipm_arg_set_iter_max(ctypes.byref(it), ctypes.c_void_p(arg))
        t = ctypes.c_double(float(tol))
        for name in ("stat", "eq", "ineq", "comp"):
            getattr(lib, f"d_ocp_qp_ipm_arg_set_tol_{name}")(ctypes.byref(t), ctypes.c_void_p(arg))
        if mu0 is not None:
            lib.d_ocp_qp_ipm_arg_set_mu0(ctypes.byref(ctypes.c_double(float(mu0))), ctypes.c_void_p(arg))
        ws = mem.block(lib.d_ocp_qp_ipm_ws_strsize())
        lib.d_ocp_qp_ipm_ws_create(ctypes.c_void_p(dim), ctypes.c_void_p(arg), ctypes.c_void_p(ws),
                                   ctypes.c_void_p(mem.block(lib.d_ocp_qp_ipm_ws_memsize(dim, arg))))
        self._qp, self._sol, self._arg, self._ws = qp, sol, arg, ws
        # the pointer arrays are built once; the buffers never move
        dummy = mem.block(8 * (nx + nu + 1) ** 2 + 64)   # zeros, for the arrays hpipm reads 0 entries of
        null = (ctypes.c_void_p * N1)()
        # stage 0 bounds every state (x0 = lbx0 = ubx0), stages 1..N the states in idxbx
        self._idx0 = np.arange(nx, dtype=np.int32)
        idxbx_rows = [self._idx0] + [self.idxbx] * N
        idxbu_rows = [self.idxbu] * N
        self._lbx_all = np.zeros((N1, max(nx, 1)))
        self._ubx_all = np.zeros((N1, max(nx, 1)))
        lbx_rows = [self._lbx_all[k, :nbx[k]] for k in range(N1)]
        ubx_rows = [self._ubx_all[k, :nbx[k]] for k in range(N1)]
        Cr = [self.C.ravel(order="F")] * N
        Dr = [self.D.ravel(order="F")] * N
        # hpipm reads the multipliers of every constraint back: buffers for them
        self._pi = np.zeros((N, nx))
        nb = nx + self.idxbx.size + self.idxbu.size
        self._lam = [np.zeros((N1, max(nb, 1))) for _ in range(2)] + [np.zeros((N1, max(self.ng, 1))) for _ in range(2)]
        P = lambda rows: _ptrs(rows, N1, dummy)  # noqa: E731
        # no soft constraints, but hpipm reads the slack index of every constraint (-1: none)
        nbg = nx + self.idxbx.size + self.idxbu.size + self.ng
        self._no_slack = np.full((N1, nbg), -1, dtype=np.int32)
        zeros = P([np.zeros(1)] * 0)
        self._set_args = [P(self.A), P(self.B), P(self.b), P(self.Q), P(self.S), P(self.R), P(self.q), P(self.r),
                          P(idxbx_rows), P(lbx_rows), P(ubx_rows), P(idxbu_rows), P(self.lbu), P(self.ubu),
                          P(Cr), P(Dr), P(self.lg), P(self.ug), zeros, zeros, zeros, zeros,
                          P(self._no_slack), P(self._no_slack), zeros, zeros, ctypes.c_void_p(qp)]
        self._keep = (idxbx_rows, lbx_rows, ubx_rows, idxbu_rows, Cr, Dr)
        self._get_args = [ctypes.c_void_p(sol), P(self.u), P(self.x), null, null, P(self._pi),
                          P(self._lam[0]), P(self._lam[1]), P(self._lam[2]), P(self._lam[3]), null, null]
        self._status = ctypes.c_int(0)
        self._iter = ctypes.c_int(0)
        self._solve_args = (ctypes.c_void_p(qp), ctypes.c_void_p(sol), ctypes.c_void_p(arg), ctypes.c_void_p(ws))
        self._ws_p = ctypes.c_void_p(ws)
        self._status_p, self._iter_p = ctypes.byref(self._status), ctypes.byref(self._iter)

    def solve(self) -> None:
        nbx = self.idxbx.size
        self._lbx_all[0, :self.nx] = self.lbx0
        self._ubx_all[0, :self.nx] = self.ubx0
        if nbx:
            self._lbx_all[1:, :nbx] = self.lbx
            self._ubx_all[1:, :nbx] = self.ubx
        lib = self._lib
        lib.d_ocp_qp_set_all(*self._set_args)
        lib.d_ocp_qp_ipm_solve(*self._solve_args)
        lib.d_ocp_qp_ipm_get_status(self._ws_p, self._status_p)
        lib.d_ocp_qp_ipm_get_iter(self._ws_p, self._iter_p)
        self.iterations = self._iter.value
        st = self._status.value
        if st != 0:
            what = HPIPM_STATUS[st] if 0 <= st < len(HPIPM_STATUS) else f"status {st}"
            raise SolverFailure(f"QP (hpipm) failed: {what} after {self.iterations} iterations")
        lib.d_ocp_qp_sol_get_all(*self._get_args)


# ----------------------------------------------------------------------------- CasADi conic
class ConicQP(StageQP):
    """:class:`StageQP` assembled as one sparse QP over ``z = [x0 u0 x1 u1 ... xN]`` and solved
    by CasADi's ``conic`` ("qrqp": active set, exact; "osqp")."""

    def __init__(self, N, nx, nu, idxbx, idxbu, C, D, *, solver: str = "qrqp", tol: float = 1e-8):
        super().__init__(N, nx, nu, idxbx, idxbu, C, D)
        nz = nx + nu
        self.nw = N * nz + nx
        self._ox = np.array([k * nz for k in range(N + 1)])
        # Hessian: dense [[Q S'], [S R]] blocks on (x_k, u_k), Q_N on x_N
        rows, cols = [], []
        for k in range(N + 1):
            m = nz if k < N else nx
            r, c = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
            rows.append(self._ox[k] + r.ravel(order="F"))
            cols.append(self._ox[k] + c.ravel(order="F"))
        self._H = self._pattern(np.concatenate(rows), np.concatenate(cols), self.nw, self.nw)
        # constraints per stage: nx gap rows [A B -I] then ng rows [C D]
        ng, nr = self.ng, nx + self.ng
        rows, cols = [], []
        for k in range(N):
            r, c = np.meshgrid(np.arange(nx), np.arange(nz), indexing="ij")
            rows += [k * nr + r.ravel(order="F"), k * nr + np.arange(nx)]
            cols += [self._ox[k] + c.ravel(order="F"), self._ox[k + 1] + np.arange(nx)]
            if ng:
                r, c = np.meshgrid(np.arange(ng), np.arange(nz), indexing="ij")
                rows.append(k * nr + nx + r.ravel(order="F"))
                cols.append(self._ox[k] + c.ravel(order="F"))
        self._A = self._pattern(np.concatenate(rows), np.concatenate(cols), N * nr, self.nw)
        opts: dict = {"error_on_fail": False}
        if solver == "qrqp":
            opts.update(print_iter=False, print_header=False, print_info=False)
        elif solver == "osqp":
            opts.update(osqp={"verbose": False, "eps_abs": tol, "eps_rel": tol, "polish": True})
        else:
            raise ConfigError(f"qp_solver must be one of {', '.join(QP_SOLVERS)}, got {solver!r}")
        self.solver = solver
        self._conic = ca.conic("nmpc_qp", solver, {"h": self._H[0], "a": self._A[0]}, opts)

    @staticmethod
    def _pattern(rows, cols, nr, nc):
        """CasADi sparsity of the triplets and the permutation from triplet order to its nonzeros."""
        m = sp.coo_matrix((np.arange(1, rows.size + 1, dtype=float), (rows, cols)), shape=(nr, nc)).tocsc()
        m.sort_indices()
        spty = ca.Sparsity(nr, nc, m.indptr.astype(np.int64).tolist(), m.indices.astype(np.int64).tolist())
        return spty, m.data.astype(np.int64) - 1

    def solve(self) -> None:
        N, nx, nu = self.N, self.nx, self.nu
        nz = nx + nu
        Qs = self.Q.reshape(N + 1, nx, nx, order="C").transpose(0, 2, 1)
        Ss = self.S.reshape(N, nx, nu).transpose(0, 2, 1)        # (nu, nx) per stage
        Rs = self.R.reshape(N, nu, nu).transpose(0, 2, 1)
        Hb = np.zeros((N, nz, nz))
        Hb[:, :nx, :nx], Hb[:, nx:, :nx], Hb[:, :nx, nx:], Hb[:, nx:, nx:] = Qs[:N], Ss, Ss.transpose(0, 2, 1), Rs
        hv = np.concatenate([Hb.transpose(0, 2, 1).ravel(), self.Q[N]])
        As = self.A.reshape(N, nx, nx).transpose(0, 2, 1)
        Bs = self.B.reshape(N, nu, nx).transpose(0, 2, 1)
        av = []
        for k in range(N):
            av += [np.hstack([As[k], Bs[k]]).ravel(order="F"), -np.ones(nx)]
            if self.ng:
                av.append(np.hstack([self.C, self.D]).ravel(order="F"))
        av = np.concatenate(av)
        g = np.concatenate([np.concatenate([self.q[:N], self.r], axis=1).ravel(), self.q[N]])
        lbz, ubz = np.full(self.nw, -np.inf), np.full(self.nw, np.inf)
        lbz[:nx], ubz[:nx] = self.lbx0, self.ubx0
        for k in range(N):
            lbz[self._ox[k] + nx + self.idxbu] = self.lbu[k]
            ubz[self._ox[k] + nx + self.idxbu] = self.ubu[k]
            lbz[self._ox[k + 1] + self.idxbx] = self.lbx[k]
            ubz[self._ox[k + 1] + self.idxbx] = self.ubx[k]
        lba = np.concatenate([-self.b, self.lg], axis=1).ravel()
        uba = np.concatenate([-self.b, self.ug], axis=1).ravel()
        H = ca.DM(self._H[0], hv[self._H[1]])
        A = ca.DM(self._A[0], av[self._A[1]])
        sol = self._conic(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbz, ubx=ubz)
        st = self._conic.stats()
        self.iterations = int(st.get("iter_count", 0) or 0)
        if not st["success"]:
            raise SolverFailure(f"QP ({self.solver}) failed: {st.get('return_status', '?')}")
        z = np.array(sol["x"]).ravel()
        Zs = z[:N * nz].reshape(N, nz)
        self.x[:N], self.u[:] = Zs[:, :nx], Zs[:, nx:]
        self.x[N] = z[N * nz:]


def make_qp(solver: str, N, nx, nu, idxbx, idxbu, C, D, *, tol: float, mode: str = "speed_abs",
            mu0: float | None = None) -> StageQP:
    """The QP backend ``solver`` ("hpipm", "qrqp" or "osqp") for these dimensions (``mode``, ``mu0``:
    hpipm's, :class:`HpipmQP`)."""
    if solver == "hpipm":
        return HpipmQP(N, nx, nu, idxbx, idxbu, C, D, tol=tol, mode=mode, mu0=mu0)
    return ConicQP(N, nx, nu, idxbx, idxbu, C, D, solver=solver, tol=tol)
