"""Steady sliding of a rig, and its nominal operating point.

- :func:`nominal_operating_point`: THE operating point of a rig (the rig file's
  ``[rig] operating_point``; a torque drive's nominal speed, :func:`nominal_speed`); modal
  analysis, the estimators' checks and the controllers' defaults all start from it.
- :func:`sliding_guess`, :func:`operating_point`, :func:`steady_sliding`: the state of steady
  sliding (every body at one speed) from a Gauss-Newton solve of the force balance, polished by
  Newton on the regularised model.  :class:`models.rig.RigModel` offers them as methods.
- :func:`speed_scale`, :func:`by_speed`: a speed-like default measured on rig3 (its 30 rpm) carried
  to another rig by the ratio of the nominal speeds -- the friction regularisation of the model
  (:attr:`models.rig.RigModel.eps_default`), of the estimators and of the identification.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from models.errors import ConfigError, SolverFailure

__all__ = ["nominal_operating_point", "nominal_speed", "speed_scale", "by_speed", "RIG3_SPEED", "drive_speed_index", "sliding_guess", "operating_point",
           "steady_sliding"]

#: a torque drive's steady-sliding solve has converged when its largest acceleration residual fell
#: below this fraction of the one it started from (the solve ends at round-off, ~1e-12 of it)
_STEADY_TOL = 1e-6


def nominal_speed(model) -> float:
    """The rig's nominal sliding speed [rad/s]: the drive's input in the rig file's operating point
    (a drive whose input is not a speed: its ``speed``), 1 rad/s when the file gives none."""
    op = model.spec.extra.get("operating_point", {})
    key = model.drive_input if model.drive.sets_speed else "speed"
    return float(op.get(key, 1.0))


#: rig3's nominal speed [rad/s] (30 rpm): the speed the speed-like defaults were measured at
RIG3_SPEED = math.pi


def speed_scale(model) -> float:
    """The rig's speed scale [rad/s]: its nominal speed (:meth:`models.rig.RigModel.nominal_speed`),
    rig3's when that is 0."""
    return abs(float(model.nominal_speed())) or RIG3_SPEED


def by_speed(value_at_rig3: float, model) -> float:
    """A speed-like default measured on rig3 (``value_at_rig3``, at its 30 rpm) carried to ``model``
    by the ratio of the speed scales (the model's, the estimators' and the identification's ``eps``).
    rig3 gets ``value_at_rig3`` to the bit."""
    return float(value_at_rig3) * speed_scale(model) / RIG3_SPEED


def nominal_operating_point(model, params=None, *, omega: float | None = None,
                            load: float | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The rig's sliding operating point ``(u, x_op or None)``.

    The rig file's ``[rig] operating_point`` gives the inputs (rig3: 30 rpm, N1 = 20 N);
    ``omega`` [rad/s] replaces the drive's speed and ``load`` [N] the first contact's
    normal-force input.  A torque drive's operating point is a sliding speed
    (:func:`nominal_speed` unless ``omega``): its input torque and state are solved for and
    returned (``x_op``), since pure Coulomb friction has a continuum of equilibria.
    """
    params = model.published() if params is None else model.check_params(params)
    op = dict(model.spec.extra.get("operating_point", {}))
    u = np.array([op.get(n, 0.0) for n in model.inputs], float)
    normals = [j for j, k in enumerate(model.input_kinds) if k == "force"]
    if load is not None:
        if not normals:
            raise ConfigError(f"rig {model.name!r} has no normal-force input for a load")
        u[normals[0]] = float(load)
    if not model.drive.sets_speed:
        return operating_point(model, float(omega) if omega is not None else nominal_speed(model), u, params)
    u[model.inputs.index(model.drive_input)] = float(omega) if omega is not None else nominal_speed(model)
    return u, None


def drive_speed_index(model) -> int | None:
    """Index of the input that sets the sliding speed (a speed set-point or a prescribed
    speed), or None for a torque drive."""
    return model.inputs.index(model.spec.drive.input) if model.drive.sets_speed else None


def _steady_function(model, eps, mode: str, other: tuple, spd_idx: tuple, ju: int) -> ca.Function:
    """``ss(z, p, u, w) -> (residual, d residual / dz)`` of steady sliding (cached on the model).

    ``z`` holds the non-speed states and one extra unknown: the drive's input torque
    (``mode = "torque"``), the common speed (``"speed"``) or nothing (``"fixed"``); every body
    turns at ``w`` unless the speed is the unknown."""
    key = ("steady", eps, mode)
    if key not in model._fcache:
        f = model.ode(eps)
        z = ca.SX.sym("z", len(other) + 1)
        p_s, u_s, w_s = ca.SX.sym("p", model.n_p), ca.SX.sym("u", model.nu), ca.SX.sym("w")
        x = [None] * model.nx
        for k, j in enumerate(other):
            x[j] = z[k]
        extra = z[len(other)]
        uu = [u_s[j] for j in range(model.nu)]
        if mode == "torque":
            uu[ju] = extra
        w = extra if mode == "speed" else w_s
        for j in spd_idx:
            x[j] = w
        keep = [j for j in range(model.nx) if j >= len(model.springs)]          # accelerations and drive rows
        r = f(ca.vertcat(*x), ca.vertcat(*uu), p_s)[keep]
        model._fcache[key] = ca.Function(f"{model.cname}_steady", [z, p_s, u_s, w_s], [r, ca.jacobian(r, z)])
    return model._fcache[key]


def _steady_solve(model, u, params, speed: float | None, eps: float | None = None, iters: int = 30):
    """Gauss-Newton on the accelerations and drive rows with every body at one speed.

    Unknowns: the twists, the drive states and, for a torque drive, either the input torque
    (``speed`` given) or the common speed (``speed`` None).
    """
    pv = np.asarray(params.vector(), float)
    u = np.asarray(u, float).copy()
    n_tw, nb = len(model.springs), len(model.bodies)
    spd_idx = list(range(n_tw, n_tw + nb))
    other = [j for j in range(model.nx) if j not in spd_idx]
    torque_drive = not model.drive.sets_speed
    ju = model.inputs.index(model.spec.drive.input)
    solve_speed = torque_drive and speed is None
    if speed is None:
        speed = float(u[ju]) if not torque_drive else 1.0
    mode = "torque" if torque_drive and not solve_speed else ("speed" if solve_speed else "fixed")
    F = _steady_function(model, eps, mode, tuple(other), tuple(spd_idx), ju)
    zv = np.zeros(len(other) + 1)
    if solve_speed:
        zv[-1] = speed
    # a friction law's own states start at their steady values (rate-and-state's log age is ln(v0/|w|):
    # from 0, Gauss-Newton's first step on its exponential overflows)
    for j, val in model.friction_state_guess(speed, u, dict(zip(model.param_names, pv))).items():
        zv[other.index(j)] = val
    free = np.ones(zv.size, bool)
    if not torque_drive:
        free[-1] = False
    # a spring with backlash carries torque only outside its dead zone: start there, on the side
    # that drives the load forward
    Pn = dict(zip(model.param_names, pv))
    for j, c in enumerate(cc for cc in model.spec.connections if cc.stiffness is not None):
        if c.backlash is not None:
            zv[other.index(j)] = np.sign(speed or 1.0) * float(c.backlash.value(Pn))
    # a drive's voltage and current limits are flat outside their range: solve without them
    # first (they bind only in transients), then polish with them
    limits = [model.param_names.index(r.name) for r in model.drive.limit_refs() if r.kind == "param"]
    pvs = [pv]
    if limits:
        loose = pv.copy()
        loose[limits] = 1e9
        pvs = [loose, pv]
    r_start = None
    for pcur in pvs:
        for _ in range(iters):
            rv, Jv = (np.array(a, float) for a in F(zv, pcur, u, speed))
            rv = rv.ravel()
            if r_start is None:
                r_start = float(np.max(np.abs(rv), initial=0.0))
            step = np.linalg.lstsq(Jv[:, free], -rv, rcond=None)[0]
            zv[free] += step
            if np.max(np.abs(step)) < 1e-12:
                break
    if solve_speed:
        # the common speed is the one unknown that can run off: where no speed balances the
        # drive's torque (a friction level above it at every speed, or below it with nothing
        # to stop the acceleration) Gauss-Newton walks to ever larger speeds (3.4e5 rad/s on a
        # field string whose torque was 15 % below its kinetic friction) -- say so, never return that
        rv = np.array(F(zv, pvs[-1], u, speed)[0], float).ravel()
        r_end = float(np.max(np.abs(rv), initial=0.0))
        if not (np.all(np.isfinite(zv)) and r_end <= _STEADY_TOL * max(r_start or 0.0, 1e-300)):
            raise SolverFailure(f"rig {model.name!r}: no steady sliding under the drive torque "
                                f"{float(u[ju]):.4g} N m (the force balance left {r_end:.3g} rad/s^2 at "
                                f"{float(zv[-1]):.3g} rad/s)")
    xs = np.empty(model.nx)
    for k, j in enumerate(other):
        xs[j] = zv[k]
    xs[spd_idx] = zv[-1] if solve_speed else speed
    if torque_drive and not solve_speed:
        u[ju] = zv[-1]
    return xs, u


def sliding_guess(model, u, params) -> np.ndarray:
    """A state of steady sliding at the drive's speed (every body at that speed), from a
    Gauss-Newton solve of the force balance; a torque drive slides at the speed its
    torque sustains."""
    u = np.asarray(u, float)
    if not model.drive.sets_speed:
        return _steady_solve(model, u, params, None)[0]
    return _steady_solve(model, u, params, float(u[model.inputs.index(model.spec.drive.input)]))[0]


def operating_point(model, speed: float, u, params) -> tuple[np.ndarray, np.ndarray]:
    """``(u, x)`` of steady sliding at ``speed`` [rad/s]: the drive input is set to it
    (a torque drive's input torque is solved for) and the state solved as in
    :meth:`sliding_guess`, then polished by Newton on the regularised model."""
    u = np.asarray(u, float).copy()
    if model.drive.sets_speed:
        u[model.inputs.index(model.spec.drive.input)] = speed
        return u, steady_sliding(model, u, params)
    x, u = _steady_solve(model, u, params, float(speed))
    return u, x


def steady_sliding(model, u, params, x0=None) -> np.ndarray:
    """Equilibrium of the regularised model for a constant input (steady sliding)."""
    f = model.ode()
    x = ca.SX.sym("x", model.nx)
    g = f(x, ca.DM(np.asarray(u, float)), ca.DM(params.vector()))
    solver = ca.rootfinder("ss", "newton", ca.Function("g", [x], [g]), {"abstol": 1e-12})
    guess = sliding_guess(model, u, params) if x0 is None else x0
    return np.array(solver(ca.DM(guess))).ravel()
