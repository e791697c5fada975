"""The NMPC's OCP with a warm-started plan: what every solver of it shares.

:class:`OCPSolver` holds what every solver shares: the plan (shift, warm start), the bounds
from the rate limits and the programme's band, the check of a returned plan, and the
template :meth:`OCPSolver.solve` whose subclasses implement ``_solve_impl``:

- ``"rti"``: real-time iteration, one Gauss-Newton QP per call; the stage function and its
  Jacobians for all N stages are one compiled C call, the QP goes to hpipm directly
  (:class:`mitigate.controllers.nmpc.rti.GaussNewtonSolver`, :mod:`mitigate.controllers.nmpc.qp`);
- ``"sqp"``: the same Gauss-Newton SQP iterated to convergence;
- ``"ipopt"``: IPOPT with the exact Hessian on the same NLP, as the reference
  (:class:`mitigate.controllers.nmpc.ipopt.IpoptSolver`).

:func:`mitigate.controllers.nmpc.solvers.make_ocp_solver` builds the one a name asks for.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from models.errors import SolverFailure
from models.status import Status
from mitigate.controllers.nmpc.layout import OCPLayout, OCPSpec
from mitigate.controllers.nmpc.stage import stage_functions

__all__ = ["OCPSolver", "OCPResult", "solver_failures"]

#: the numerical errors of an OCP solve (CasADi raises RuntimeError; numpy's linear algebra)
NUMERICAL_ERRORS = (RuntimeError, FloatingPointError, ArithmeticError, np.linalg.LinAlgError)


@contextmanager
def solver_failures(what: str):
    """Turn the numerical errors of a solve (:data:`NUMERICAL_ERRORS`) into :class:`SolverFailure`
    naming ``what``; any other exception (a bug) passes unchanged and fails the run."""
    try:
        yield
    except SolverFailure:
        raise
    except NUMERICAL_ERRORS as exc:
        raise SolverFailure(f"{what}: {type(exc).__name__}: {exc}") from exc


@dataclass(frozen=True)
class OCPResult:
    """One OCP solve: the plan (time on axis 0) and its status.

    Attributes
    ----------
    u : (N, m) the commanded inputs' values over the plan (``inputs`` order: set-point, servo commands)
    xa : (N+1, nxa) predicted augmented states (``states`` order)
    inputs, states : names of the columns
    cost : objective at the last linearisation point (rti, sqp: one step before the solution) or at
        the solution (ipopt)
    iterations : Gauss-Newton iterations (rti: 1); qp_iterations : of the last QP
    status : Status.OK, or Status.NOT_CONVERGED ("sqp" hit its iteration limit)
    message : detail; solve_time : wall time [s]
    """

    u: np.ndarray
    xa: np.ndarray
    inputs: tuple[str, ...]
    states: tuple[str, ...]
    cost: float
    iterations: int
    qp_iterations: int
    status: Status
    message: str
    solve_time: float

    @property
    def success(self) -> bool:
        return self.status.success


class OCPSolver:
    """The OCP with a warm-started plan: :meth:`solve` from a state, :meth:`prepare` ahead
    (a template: subclasses implement ``_solve_impl`` and may implement ``prepare``).

    Parameters
    ----------
    model : the rig (:class:`models.rig.RigModel`)
    spec : OCPSpec

    Attributes
    ----------
    solver : the solver's name; layout : the OCPLayout; N : intervals
    F, cost_fn, stage_fn, term_fn : the stage's discrete dynamics, cost, Gauss-Newton blocks and
        terminal blocks (:func:`mitigate.controllers.nmpc.stage.stage_functions`)
    X, V : the plan, (N+1, nxa) states and (N, nv) decisions; None until the first solve
    last_bounds : the bounds of the last solve (:meth:`bounds`)
    """

    solver = "ocp"

    def __init__(self, model, spec: OCPSpec):
        self.model, self.spec = model, spec
        self.layout = OCPLayout(model, spec)
        self.N = spec.horizon
        self.F, self.cost_fn, self.stage_fn, self.term_fn = stage_functions(model, spec)
        self.X: np.ndarray | None = None
        self.V: np.ndarray | None = None
        self._lam = None
        self._prepared = False
        self._lim_key, self._lim = None, None
        self.last_bounds = None

    # ------------------------------------------------------------------ plan handling
    def initialise(self, xa0, q) -> None:
        """Plan = hold the current inputs; states by forward simulation."""
        L, N = self.layout, self.N
        X, V = np.empty((N + 1, L.nxa)), np.empty((N, L.nv))
        x = np.asarray(xa0, float)
        v = L.hold(x)
        for k in range(N):
            X[k], V[k] = x, v
            x = np.array(self.F(x, v, q)).ravel()
        X[N] = x
        self.X, self.V = X, V
        self._lam = None
        self._prepared = False

    def reset(self) -> None:
        """Forget the plan."""
        self.X = self.V = None
        self._lam = None
        self._prepared = False

    @property
    def prepared(self) -> bool:
        """Whether :meth:`prepare` has linearised the current plan."""
        return self._prepared

    def shift(self, steps: int = 1) -> None:
        """Shift the plan by ``steps`` intervals (warm start); the tail holds the last inputs."""
        self._prepared = False
        if self.X is None or steps <= 0:
            return
        s = min(int(steps), self.N)
        L = self.layout
        X, V = self.X, self.V
        X[:-s] = X[s:].copy()
        X[-s:] = X[-s - 1]          # the old last state (s <= N)
        tail = V[-1].copy()
        if L.drive:
            tail[0] = 0.0
        V[:-s] = V[s:].copy()
        V[-s:] = tail
        self._lam = None

    def plan(self) -> tuple[np.ndarray, np.ndarray]:
        """The current plan: commanded inputs (N, m) and augmented states (N+1, nxa)."""
        return self.layout.applied(self.X[:-1], self.V), self.X.copy()

    def prepare(self, q) -> None:
        """Preparation ahead of the next :meth:`solve` (RTI: linearise at the shifted plan);
        nothing for a solver without one."""

    # ------------------------------------------------------------------ bounds
    def _limits(self, rate):
        """Per-stage step limits from the rate limits (cached: they rarely change)."""
        key = rate.tobytes()
        if self._lim_key != key:
            L, sp = self.layout, self.spec
            dw = float(rate[0]) * sp.dt if L.drive else 0.0
            dg = np.array([sp.step_limit(k, rate[L.j_cmd[k]]) for k in range(L.ns)])
            self._lim = (dw, dw * np.arange(1, self.N + 1), dg)
            self._lim_key = key
        return self._lim

    def bounds(self, xa0, lo, hi, rate):
        """Absolute bounds of the plan from ``xa0``.

        ``lo``, ``hi``: bounds of the commanded inputs (``spec.inputs`` order: set-point, then
        servo commands); ``rate``: their rate limits [unit/s].  A bound that a rate-limited move
        cannot reach yet is widened to what it can reach, so the QP is always feasible.

        Returns
        -------
        lbv, ubv : (nv,) decision boxes (the same at every stage)
        lbw, ubw : (N,) box of ``w_prev`` at stages 1..N (None without the drive)
        dg : (ns,) servo rows' half-width ``|c_j - s_j| <= dg_j``
        """
        L = self.layout
        dw, reach, dg = self._limits(np.asarray(rate, float))
        lbv, ubv = np.empty(L.nv), np.empty(L.nv)
        lbw = ubw = None
        if L.drive:
            lbv[0], ubv[0] = -dw, dw
            w0 = xa0[L.i_wprev]
            lbw = np.minimum(lo[0], w0 + reach)
            ubw = np.maximum(hi[0], w0 - reach)
        if L.ns:
            s0 = xa0[L.i_servo]
            jc = L.j_cmd
            lbv[jc] = np.minimum(lo[jc], s0 + dg)
            ubv[jc] = np.maximum(hi[jc], s0 - dg)
        return lbv, ubv, lbw, ubw, dg

    def first_range(self, xa0, lo, hi, rate, bnd=None) -> tuple[np.ndarray, np.ndarray]:
        """Range of the first commanded inputs ``[set-point, servo commands]`` from ``xa0``: the
        bounds, the set-point's rate and the servos' rates, widened where unreachable (``bnd``:
        :meth:`bounds` if already computed)."""
        L = self.layout
        lbv, ubv, lbw, ubw, dg = self.bounds(xa0, lo, hi, rate) if bnd is None else bnd
        lo1, hi1 = lbv.copy(), ubv.copy()
        if L.ns:
            s0 = xa0[L.i_servo]
            lo1[L.j_cmd] = np.maximum(lbv[L.j_cmd], s0 - dg)
            hi1[L.j_cmd] = np.minimum(ubv[L.j_cmd], s0 + dg)
        if L.drive:
            w0 = xa0[L.i_wprev]
            lo1[0] = max(lbw[0], w0 + lbv[0])
            hi1[0] = min(ubw[0], w0 + ubv[0])
        return lo1, hi1

    # ------------------------------------------------------------------ solve
    def solve(self, xa0, q, lo, hi, rate) -> OCPResult:
        """Solve (or take one RTI step of) the OCP from ``xa0`` with parameters ``q``.

        ``lo``, ``hi``, ``rate``: see :meth:`bounds`.  Raises :class:`SolverFailure` if the solver
        fails or returns a plan that violates its bounds.
        """
        t0 = time.perf_counter()
        xa0 = np.asarray(xa0, float)
        with solver_failures(self.solver):
            if self.X is None:
                self.initialise(xa0, q)
            bnd = self.bounds(xa0, np.asarray(lo, float), np.asarray(hi, float), rate)
            self.last_bounds = bnd
            X, V, cost, iters, qp_iters, status, msg = self._solve_impl(xa0, np.asarray(q, float), bnd)
        self._check(X, V, xa0, bnd)
        self.X, self.V = X, V
        self._prepared = False
        L = self.layout
        return OCPResult(L.applied(X[:-1], V), X, self.spec.inputs, L.states, cost, iters, qp_iters, status, msg,
                         time.perf_counter() - t0)

    def _check(self, X, V, xa0, bnd) -> None:
        """Plans with non-finite values or bound violations beyond the QP tolerance are failures
        (an active-set QP solver once reported success on a plan 5 units outside its bounds)."""
        if not (math.isfinite(X.sum()) and math.isfinite(V.sum())):   # finite iff every entry is
            raise SolverFailure(f"{self.solver}: non-finite plan")
        L = self.layout
        lbv, ubv, lbw, ubw, dg = bnd
        viol = max(np.abs(X[0] - xa0).max(), np.maximum(lbv - V, V - ubv).max())
        if L.drive:
            w = X[1:, L.i_wprev]
            viol = max(viol, np.maximum(lbw - w, w - ubw).max())
        if L.ns:
            viol = max(viol, (np.abs(V[:, L.j_cmd] - X[:-1, L.i_servo]) - dg).max())
        scale = max(1.0, np.abs(xa0).max(), np.abs(ubv).max())
        if viol > 1e-4 * scale:
            raise SolverFailure(f"{self.solver}: plan violates its bounds by {viol:.3g}")

    def _solve_impl(self, xa0, q, bnd):
        """Solve from ``xa0`` with parameters ``q`` and bounds ``bnd`` (:meth:`bounds`), starting at
        the plan ``X, V``; return ``(X, V, cost, iterations, qp_iterations, status, message)``."""
        raise NotImplementedError
