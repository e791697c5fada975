"""The NMPC's optimal control problem on any rig, and its solvers.

The OCP is a multiple-shooting problem over ``N`` intervals of ``dt`` [s], each integrated by
RK4 with ``nsub`` substeps on the rig's regularised model.  The state is augmented so that
every cost term and constraint stays inside one stage (shared/CASADI-FACTS.md)::

    xa = [x,                       the rig's state (model.states)
          s_1 .. s_m,              one servo force per commanded servo input [N] (first-order lag tau)
          w_prev]                  the previous drive set-point, when the drive is commanded
    v  = [d w, c_1 .. c_m]         decision per interval: set-point change, servo commands [N]
    u  = model inputs:             drive = w_prev + d w (commanded) or the programme's value;
                                   servo input j = s_j (its force; s_j' = (c_j - s_j) / tau_j);
                                   every other input held at its measured value

Constraints per stage: ``|d w| <= setpoint_rate dt`` and ``c_j`` within the servo's range
(input boxes); the set-point within the programme's band (a box on ``w_prev`` of the next
stage); the servo's rate, ``|c_j - s_j| <= rate_j tau_j`` (one general row per servo: a
first-order lag commanded that far away moves at its rate limit).  Without a lag model
(``tau = 0``) ``s_j`` is the previous command and the row limits the change per interval.

The cost is a least-squares sum plus a linear servo-force term (friction work at a pin is
linear in its normal force; a linear cost leaves the force at exactly 0 when it does not pay)::

    sum_k 0.5 |r(xa_k, v_k)|^2 + c_f sum_j c_j / f_j   +   0.5 |r_N(xa_N)|^2

    r = [w_speed (w_b - w_nom) / w_s,                     objective body b
         w_rel (w_a - w_a') / w_s  for every spring connection (a, a'),
         w_ref (u_drive - u_drive_programme) / sp_s,      if the drive is commanded
         w_force c_j / f_j,  w_d_ref d w / sp_s,  w_d_force (c_j - s_j) / f_j]
    r_N = w_terminal [speed and spring residuals]

with ``w_s`` = max(|w_nom|, 1 rad/s), ``sp_s`` = ``w_s`` (speed set-point) or the band (torque
drive) and ``f_j`` the servo's ``n_max``, so every weight is dimensionless.  Gauss-Newton gives
a positive semi-definite Hessian at no extra cost.

Per-stage parameters ``q`` (:meth:`OCPLayout.q_template`, :meth:`OCPLayout.set_q`): the held inputs (``model.inputs`` order; the
drive entry is the programme's set-point), the nominal speed, the scales, the weights, one
friction factor per contact body (the disturbance model: 1 = as the rig file says) and the rig's
parameter vector.  Only the structure (N, dt, nsub, eps, inputs, lags, body) enters the
compiled code, so one library serves every tuning.

Solvers (:class:`OCPSolver`):

- ``"rti"``: real-time iteration, one Gauss-Newton QP per call; the stage function and its
  Jacobians for all N stages are one compiled C call, the QP goes to hpipm directly
  (:mod:`mitigate.controllers.nmpc.qp`);
- ``"sqp"``: the same Gauss-Newton SQP iterated to convergence;
- ``"ipopt"``: IPOPT with the exact Hessian on the same NLP, as the reference.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from models import friction as fr
from models.codegen import CtypesFunction, compile_cached
from models.discretise import Integration
from models.errors import ConfigError, SolverFailure
from models.status import Status
from mitigate.controllers.nmpc.options import WEIGHT_NAMES
from mitigate.controllers.nmpc.qp import make_qp

__all__ = ["OCPSpec", "OCPLayout", "OCPSolver", "OCPResult", "stage_functions", "prediction_rhs"]


@dataclass(frozen=True, kw_only=True)
class OCPSpec:
    """Everything that defines the OCP's functions.

    Parameters
    ----------
    horizon : N; dt : interval [s]; nsub : RK4 substeps per interval; eps : friction
        regularisation [rad/s]; quasi_static : a DC motor's current at its quasi-static value
        (both from :func:`models.discretise.integration`)
    body : the objective body
    inputs : the commanded inputs, the drive's first if it is commanded (model input names)
    taus : lag [s] of each commanded servo input, in ``inputs`` order without the drive (0: no
        lag model: the servo force is the previous command)
    speed_scale : w_s [rad/s]; setpoint_scale : sp_s [rad/s or N m]; force_scales : f_j [N]
    weights : the 8 weights in :data:`WEIGHT_NAMES` order
    """

    horizon: int
    dt: float
    nsub: int
    eps: float
    body: str
    inputs: tuple[str, ...]
    taus: tuple[float, ...]
    speed_scale: float
    setpoint_scale: float
    force_scales: tuple[float, ...]
    weights: tuple[float, ...]
    quasi_static: bool = False

    def step_limit(self, j: int, rate: float) -> float:
        """Largest ``|c_j - s_j|`` [N] of commanded servo ``j``: ``rate tau`` (the servo at its rate
        limit), or ``rate dt`` without a lag model."""
        tau = self.taus[j]
        return float(rate) * (tau if tau > 0 else self.dt)


class OCPLayout:
    """Where everything sits in the augmented state ``xa``, the decision ``v`` and ``q``."""

    def __init__(self, model, spec: OCPSpec):
        self.model = model
        nx, nu = model.nx, model.nu
        self.nx = nx
        drive = model.drive_input
        self.drive = drive in spec.inputs
        if self.drive and spec.inputs[0] != drive:
            raise ConfigError(f"OCPSpec.inputs must list the drive {drive!r} first, got {spec.inputs}")
        self.servos = tuple(n for n in spec.inputs if n != drive)
        for n in self.servos:
            if model.actuator(n) is None:
                raise ConfigError(f"OCPSpec.inputs: {n!r} is neither the drive's input nor a servo input of "
                                  f"rig {model.name!r}")
        if len(spec.taus) != len(self.servos) or len(spec.force_scales) != len(self.servos):
            raise ConfigError(f"OCPSpec.taus and force_scales need one entry per servo input {self.servos}")
        ns = len(self.servos)
        self.ns = ns
        self.i_servo = np.arange(nx, nx + ns)
        self.i_wprev = nx + ns if self.drive else None
        self.nxa = nx + ns + (1 if self.drive else 0)
        self.nv = len(spec.inputs)
        self.j_cmd = np.arange(1 if self.drive else 0, self.nv)
        self.u_drive = model.inputs.index(drive)
        self.u_servo = tuple(model.inputs.index(n) for n in self.servos)
        self.states = tuple(model.states) + tuple(f"servo:{n}" for n in self.servos) + \
            ((f"previous:{drive}",) if self.drive else ())
        self.decisions = ((f"change:{drive}",) if self.drive else ()) + tuple(f"command:{n}" for n in self.servos)
        # q = [held inputs (nu), nominal speed, w_s, sp_s, f_1..f_m, weights (8), friction factors, p]
        self.q_hold = 0
        self.q_nom = nu
        self.q_ws, self.q_sps = nu + 1, nu + 2
        self.q_f = nu + 3
        self.q_w = self.q_f + ns
        self.q_fc = self.q_w + len(WEIGHT_NAMES)
        self.n_fc = len(model.contacts)
        self.q_p = self.q_fc + self.n_fc
        self.nq = self.q_p + model.n_p
        # the general rows C xa + D v = c_j - s_j (one per commanded servo)
        self.C = np.zeros((ns, self.nxa))
        self.D = np.zeros((ns, self.nv))
        for k in range(ns):
            self.C[k, self.i_servo[k]] = -1.0
            self.D[k, self.j_cmd[k]] = 1.0

    def q_template(self, spec: OCPSpec, p) -> np.ndarray:
        """``q`` with the structure's constants filled in (scales, weights, parameters ``p``);
        the held inputs, the nominal speed and the friction factors are set per call
        (:meth:`set_q`)."""
        q = np.zeros(self.nq)
        q[self.q_ws], q[self.q_sps] = spec.speed_scale, spec.setpoint_scale
        q[self.q_f:self.q_f + self.ns] = spec.force_scales
        q[self.q_w:self.q_w + len(WEIGHT_NAMES)] = spec.weights
        q[self.q_fc:self.q_fc + self.n_fc] = 1.0
        q[self.q_p:] = np.asarray(p, float)
        return q

    def set_q(self, q: np.ndarray, hold, nominal: float, friction=None) -> np.ndarray:
        """Write the held inputs (``model.inputs`` order; the drive's entry is the programme's
        set-point), the nominal speed [rad/s] and the friction factors (None: 1) into ``q``."""
        q[:self.model.nu] = hold
        q[self.q_nom] = nominal
        q[self.q_fc:self.q_fc + self.n_fc] = 1.0 if friction is None else friction
        return q

    def applied(self, xa, v) -> np.ndarray:
        """The commanded inputs' values ``[set-point, servo commands]`` of decision ``v`` at ``xa``
        (numpy; rows for a plan)."""
        xa, v = np.asarray(xa, float), np.asarray(v, float)
        out = v.copy()
        if self.drive:
            out[..., 0] = xa[..., self.i_wprev] + v[..., 0]
        return out

    def hold(self, xa) -> np.ndarray:
        """The decision that holds the inputs: no set-point change, commands = servo forces."""
        v = np.zeros(self.nv)
        v[self.j_cmd] = np.asarray(xa, float)[self.i_servo]
        return v


def prediction_rhs(model, eps: float) -> ca.Function:
    """``xdot = f(x, u, p, fc)``: the rig's regularised model with the friction torque of contact
    body ``i`` multiplied by ``fc[i]`` (the disturbance model; ``fc = 1`` is ``model.ode(eps)``)."""
    x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
    fc = ca.SX.sym("fc", len(model.contacts))
    P = model.unpack(p)
    Tc = [fc[i] * model.contact_friction(i, x[idx], u, P, eps) for i, idx in enumerate(model.contacts)]
    s = [fr.smooth_sign(x[idx], eps) for idx in model.contacts]
    xdot = ca.vertcat(*model.dynamics(x, u, P, Tc, s))
    return ca.Function(f"{model.cname}_nmpc_rhs", [x, u, p, fc], [xdot], ["x", "u", "p", "fc"], ["xdot"])


def _spring_speeds(model, x, u):
    """Relative speed across every spring connection, ``w(between[0]) - w(between[1])``."""
    drive = model.drive_input

    def node(n):
        if n == "ground":
            return 0
        if n == "drive":
            return u[model.inputs.index(drive)]
        return x[model.speed_index(n)]
    return [node(c.a) - node(c.b) for c in model.spec.connections if c.stiffness is not None]


def stage_functions(model, spec: OCPSpec):
    """Named SX Functions of one stage.

    Returns
    -------
    F : (xa, v, q) -> xa_next, the discrete augmented dynamics
    cost : (xa, v, q) -> (r, l): stage residual and linear cost
    stage : (xa, v, q) -> (xn, A, B, Q, S, R, gx, gv, c): dynamics, Jacobians, the Gauss-Newton
        Hessian blocks (Q = Jx'Jx, S = Jv'Jx, R = Jv'Jv), the gradient and the stage cost
    term : (xa, q) -> (Q, g, c, r): terminal Gauss-Newton Hessian, gradient, cost and residual
    """
    L = OCPLayout(model, spec)
    nx, nu = model.nx, model.nu
    rhs = prediction_rhs(model, spec.eps)
    xa, v, q = ca.SX.sym("xa", L.nxa), ca.SX.sym("v", L.nv), ca.SX.sym("q", L.nq)
    hold = q[L.q_hold:L.q_hold + nu]
    nom, ws, sps = q[L.q_nom], q[L.q_ws], q[L.q_sps]
    fs = q[L.q_f:L.q_f + L.ns]
    w_speed, w_rel, w_ref, w_force, c_force, w_dref, w_dforce, w_term = (q[L.q_w + k] for k in range(len(WEIGHT_NAMES)))
    fc = q[L.q_fc:L.q_fc + L.n_fc]
    p = q[L.q_p:]
    taus = spec.taus

    def inputs(xa_, v_):
        u = [hold[j] for j in range(nu)]
        if L.drive:
            u[L.u_drive] = xa_[L.i_wprev] + v_[0]
        for k, j in enumerate(L.u_servo):
            u[j] = xa_[L.i_servo[k]] if taus[k] > 0 else v_[L.j_cmd[k]]
        return ca.vertcat(*u)

    def faug(xa_, v_, _q):
        xdot = rhs(xa_[:nx], inputs(xa_, v_), p, fc)
        sdot = [(v_[L.j_cmd[k]] - xa_[L.i_servo[k]]) / taus[k] if taus[k] > 0 else 0 for k in range(L.ns)]
        return ca.vertcat(xdot, *sdot, *([0] if L.drive else []))

    xe = Integration(spec.dt, spec.nsub, model.current_index if spec.quasi_static else None).advance(
        faug, xa, v, q, lambda xa_, v_, _q: model.quasi_static_current(xa_[:nx], inputs(xa_, v_), model.unpack(p)))
    xn = [xe[j] for j in range(nx)]
    for k in range(L.ns):
        xn.append(xe[L.i_servo[k]] if taus[k] > 0 else v[L.j_cmd[k]])
    if L.drive:
        xn.append(xa[L.i_wprev] + v[0])
    xn = ca.vertcat(*xn)
    name = f"{model.cname}_nmpc"
    F = ca.Function(f"{name}_F", [xa, v, q], [xn], ["xa", "v", "q"], ["xa_next"])

    u = inputs(xa, v)
    wb = xa[model.speed_index(spec.body)]
    r = [w_speed * (wb - nom) / ws] + [w_rel * dd / ws for dd in _spring_speeds(model, xa, u)]
    if L.drive:
        r += [w_ref * (u[L.u_drive] - hold[L.u_drive]) / sps]
    cmd = [v[L.j_cmd[k]] for k in range(L.ns)]
    r += [w_force * cmd[k] / fs[k] for k in range(L.ns)]
    if L.drive:
        r += [w_dref * v[0] / sps]
    r += [w_dforce * (cmd[k] - xa[L.i_servo[k]]) / fs[k] for k in range(L.ns)]
    r = ca.vertcat(*r)
    lin = c_force * sum((cmd[k] / fs[k] for k in range(L.ns)), ca.SX(0))
    cost = ca.Function(f"{name}_cost", [xa, v, q], [r, lin], ["xa", "v", "q"], ["r", "l"])
    Jx, Jv = ca.jacobian(r, xa), ca.jacobian(r, v)
    d = ca.densify
    stage = ca.Function(f"{name}_stage", [xa, v, q],
                        [xn, d(ca.jacobian(xn, xa)), d(ca.jacobian(xn, v)), d(Jx.T @ Jx), d(Jv.T @ Jx), d(Jv.T @ Jv),
                         d(Jx.T @ r + ca.jacobian(lin, xa).T), d(Jv.T @ r + ca.jacobian(lin, v).T),
                         0.5 * ca.sumsqr(r) + lin],
                        ["xa", "v", "q"], ["xn", "A", "B", "Q", "S", "R", "gx", "gv", "c"])
    # the terminal stage sees the last applied drive input (no decision there)
    uN = [hold[j] for j in range(nu)]
    if L.drive:
        uN[L.u_drive] = xa[L.i_wprev]
    for k, j in enumerate(L.u_servo):
        uN[j] = xa[L.i_servo[k]]
    rN = w_term * ca.vertcat(w_speed * (wb - nom) / ws,
                             *[w_rel * dd / ws for dd in _spring_speeds(model, xa, ca.vertcat(*uN))])
    JN = ca.jacobian(rN, xa)
    term = ca.Function(f"{name}_term", [xa, q], [d(JN.T @ JN), d(JN.T @ rN), 0.5 * ca.sumsqr(rN), rN],
                       ["xa", "q"], ["Q", "g", "c", "r"])
    return F, cost, stage, term


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


class _StageEvaluator:
    """All N stages and the terminal stage as one Function ``(X, V, xN, q) -> blocks``, either
    compiled (gcc, cached on disk; called through preallocated buffers) or as CasADi SX."""

    OUT = ("xn", "A", "B", "Q", "S", "R", "gx", "gv", "c", "QN", "gN", "cN")

    def __init__(self, stage: ca.Function, term: ca.Function, N: int, nxa: int, nv: int, nq: int, compiled: bool,
                 tag: str):
        X, V = ca.MX.sym("X", nxa, N), ca.MX.sym("V", nv, N)
        xN, q = ca.MX.sym("xN", nxa), ca.MX.sym("q", nq)
        xn, A, B, Q, S, R, gx, gv, c = stage.map(N)(X, V, ca.repmat(q, 1, N))
        QN, gN, cN, _ = term(xN, q)
        fn = ca.Function(tag, [X, V, xN, q], [xn, A, B, Q, S, R, gx, gv, ca.sum2(c), QN, gN, cN],
                         ["X", "V", "xN", "q"], list(self.OUT))
        self.fn = fn
        self.compiled = compiled
        if compiled:
            try:
                so = compile_cached([fn], "-O1", tag)
            except RuntimeError as exc:
                raise SolverFailure(f"compiling the NMPC stage failed: {exc}") from None
            self._c = CtypesFunction(so, fn)
            self.inputs = self._c.inputs
            self.outputs = self._c.outputs
        else:
            self.inputs = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
            self.outputs = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]

    def __call__(self) -> None:
        if self.compiled:
            self._c()
            return
        args = [ca.DM(self.fn.sparsity_in(i), b) for i, b in enumerate(self.inputs)]
        for buf, val in zip(self.outputs, self.fn(*args)):
            buf[:] = np.array(val).ravel(order="F")


class OCPSolver:
    """The OCP with a warm-started plan: :meth:`solve` from a state, :meth:`prepare` ahead.

    Parameters
    ----------
    model : the rig (:class:`models.rig.RigModel`)
    spec : OCPSpec
    solver : "rti" | "sqp" | "ipopt"
    compile : compile the stage functions (gcc, cached) for "rti"/"sqp"
    qp_solver : "hpipm" (direct), "qrqp" or "osqp" (CasADi ``conic``)
    qp_tol : QP tolerance; "sqp" uses min(qp_tol, sqp_tol / 10) so that its step test can pass
    sqp_max_iter, sqp_tol : Gauss-Newton iterations and step tolerance of "sqp"

    The plan is ``X`` (N+1, nxa) and ``V`` (N, nv); None until the first solve.
    """

    def __init__(self, model, spec: OCPSpec, *, solver: str = "rti", compile: bool = True,
                 qp_solver: str = "hpipm", qp_tol: float = 1e-7, sqp_max_iter: int = 20, sqp_tol: float = 1e-6):
        if solver not in ("rti", "sqp", "ipopt"):
            raise ConfigError(f"solver must be 'rti', 'sqp' or 'ipopt', got {solver!r}")
        self.model, self.spec, self.solver = model, spec, solver
        self.layout = L = OCPLayout(model, spec)
        self.N = N = spec.horizon
        self.qp_solver = qp_solver
        self.qp_tol = qp_tol if solver != "sqp" else min(qp_tol, 0.1 * sqp_tol)
        self.sqp_max_iter, self.sqp_tol = sqp_max_iter, sqp_tol
        self.F, self.cost_fn, self._stage, self._term = stage_functions(model, spec)
        self.X: np.ndarray | None = None
        self.V: np.ndarray | None = None
        self._lam = None
        self._prepared = False
        self._lim_key, self._lim = None, None
        self.last_bounds = None
        self.compiled = bool(compile and solver != "ipopt")
        if solver == "ipopt":
            self._build_ipopt()
        else:
            idxbx = [L.i_wprev] if L.drive else []
            self.qp = make_qp(qp_solver, N, L.nxa, L.nv, idxbx, np.arange(L.nv), L.C, L.D, tol=self.qp_tol)
            tag = f"{model.cname}_nmpc_N{N}"
            self._ev = _StageEvaluator(self._stage, self._term, N, L.nxa, L.nv, L.nq, self.compiled, tag)
            self._cost = np.nan

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

    # ------------------------------------------------------------------ linearisation
    def _linearise(self, q) -> None:
        """Evaluate all stages at the plan and fill the QP's dynamics and cost blocks."""
        ev, qp, N = self._ev, self.qp, self.N
        ins, out = ev.inputs, ev.outputs
        ins[0][:] = self.X[:N].ravel()
        ins[1][:] = self.V.ravel()
        ins[2][:] = self.X[N]
        ins[3][:] = q
        ev()
        xn = out[0].reshape(N, -1)
        np.subtract(xn, self.X[1:], out=qp.b)
        qp.A[:] = out[1].reshape(N, -1)
        qp.B[:] = out[2].reshape(N, -1)
        qp.Q[:N] = out[3].reshape(N, -1)
        qp.S[:] = out[4].reshape(N, -1)
        qp.R[:] = out[5].reshape(N, -1)
        qp.q[:N] = out[6].reshape(N, -1)
        qp.r[:] = out[7].reshape(N, -1)
        qp.Q[N] = out[9]
        qp.q[N] = out[10]
        self._cost = float(out[8][0] + out[11][0])

    def prepare(self, q) -> None:
        """RTI preparation phase: shift the plan by one interval and linearise there now, so the
        next :meth:`solve` only embeds the new initial state and solves the QP (feedback phase).
        The linearisation uses ``q`` as known now."""
        if self.X is None or self.solver == "ipopt":
            return
        self.shift(1)
        self._linearise(np.asarray(q, float))
        self._prepared = True

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
        if self.X is None:
            self.initialise(xa0, q)
        bnd = self.bounds(xa0, np.asarray(lo, float), np.asarray(hi, float), rate)
        self.last_bounds = bnd
        if self.solver == "ipopt":
            X, V, cost, iters, qp_iters, status, msg = self._solve_ipopt(xa0, q, bnd)
        else:
            X, V, cost, iters, qp_iters, status, msg = self._solve_gn(xa0, q, bnd)
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

    def _qp_step(self, xa0, bnd) -> None:
        """Bounds relative to the linearisation point, then one QP; the step goes to the plan."""
        L, qp, X, V = self.layout, self.qp, self.X, self.V
        lbv, ubv, lbw, ubw, dg = bnd
        np.subtract(xa0, X[0], out=qp.lbx0)
        qp.ubx0[:] = qp.lbx0
        np.subtract(lbv, V, out=qp.lbu)
        np.subtract(ubv, V, out=qp.ubu)
        if L.drive:
            qp.lbx[:, 0] = lbw - X[1:, L.i_wprev]
            qp.ubx[:, 0] = ubw - X[1:, L.i_wprev]
        if L.ns:
            g = V[:, L.j_cmd] - X[:-1, L.i_servo]
            np.subtract(-dg, g, out=qp.lg)
            np.subtract(dg, g, out=qp.ug)
        qp.solve()

    def _solve_gn(self, xa0, q, bnd):
        q = np.asarray(q, float)
        X, V = self.X, self.V
        nmax = 1 if self.solver == "rti" else self.sqp_max_iter
        status, msg = Status.OK, "rti step"
        it = 0
        for it in range(1, nmax + 1):
            if not (it == 1 and self._prepared):
                self._linearise(q)
            self._prepared = False
            self._qp_step(xa0, bnd)
            X += self.qp.x
            V += self.qp.u
            if self.solver == "sqp":
                step = max(np.abs(self.qp.x).max(), np.abs(self.qp.u).max())
                if step < self.sqp_tol:
                    msg = f"converged in {it} Gauss-Newton iterations"
                    break
        else:
            if self.solver == "sqp":
                status, msg = Status.NOT_CONVERGED, f"sqp: {nmax} iterations, last step {step:.2g}"
        return X, V, self._cost, it, self.qp.iterations, status, msg

    # ------------------------------------------------------------------ IPOPT
    def _build_ipopt(self):
        L, N = self.layout, self.N
        nz = L.nxa + L.nv
        w = ca.MX.sym("w", N * nz + L.nxa)
        q = ca.MX.sym("q", L.nq)
        Z = ca.reshape(w[:N * nz], nz, N)
        X, V = Z[:L.nxa, :], Z[L.nxa:, :]
        xN = w[N * nz:]
        xn = self.F.map(N)(X, V, ca.repmat(q, 1, N))
        r, l = self.cost_fn.map(N)(X, V, ca.repmat(q, 1, N))
        _, _, cN, _ = self._term(xN, q)
        obj = 0.5 * ca.sumsqr(r) + ca.sum2(l) + cN
        gaps = xn - ca.horzcat(X[:, 1:], xN)
        rows = ca.DM(L.C) @ X + ca.DM(L.D) @ V
        self._ipopt = ca.nlpsol(f"{self.model.cname}_nmpc_ipopt", "ipopt",
                                {"x": w, "p": q, "f": obj, "g": ca.vec(ca.vertcat(gaps, rows))},
                                {"print_time": False, "error_on_fail": False,
                                 "ipopt": {"print_level": 0, "sb": "yes", "max_iter": 200, "tol": 1e-8,
                                           "warm_start_init_point": "yes"}})

    def _solve_ipopt(self, xa0, q, bnd):
        L, N = self.layout, self.N
        nz = L.nxa + L.nv
        lbv, ubv, lbw, ubw, dg = bnd
        lb = np.full((N + 1, nz), -np.inf)
        ub = np.full((N + 1, nz), np.inf)
        lb[:N, L.nxa:], ub[:N, L.nxa:] = lbv, ubv
        lb[0, :L.nxa] = ub[0, :L.nxa] = xa0
        if L.drive:
            lb[1:, L.i_wprev], ub[1:, L.i_wprev] = lbw, ubw
        lbx, ubx = lb.ravel()[:N * nz + L.nxa], ub.ravel()[:N * nz + L.nxa]
        lbg = np.zeros((N, L.nxa + L.ns))
        ubg = np.zeros((N, L.nxa + L.ns))
        lbg[:, L.nxa:], ubg[:, L.nxa:] = -dg, dg
        w0 = np.concatenate([np.hstack([self.X[:N], self.V]).ravel(), self.X[N]])
        w0[:L.nxa] = xa0
        args = dict(x0=w0, p=q, lbx=lbx, ubx=ubx, lbg=lbg.ravel(), ubg=ubg.ravel())
        if self._lam is not None:
            args["lam_g0"] = self._lam
        sol = self._ipopt(**args)
        st = self._ipopt.stats()
        if not st.get("success", False):
            raise SolverFailure(f"IPOPT failed: {st.get('return_status', '?')}")
        self._lam = np.array(sol["lam_g"]).ravel()
        w = np.array(sol["x"]).ravel()
        Z = w[:N * nz].reshape(N, nz)
        X = np.vstack([Z[:, :L.nxa], w[N * nz:]])
        V = Z[:, L.nxa:].copy()
        it = int(st.get("iter_count", 0))
        return X, V, float(sol["f"]), it, 0, Status.OK, f"ipopt: {st['return_status']} in {it} iterations"
