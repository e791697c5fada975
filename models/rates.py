"""The rates of a rig that decide how it is integrated (:mod:`models.discretise`): the largest
eigenvalue of the regularised model's Jacobian over the points of steady sliding and rest that the
integration rule considers, and the oscillation and growth rates an implicit step must resolve."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from models.rig.steady import by_speed

__all__ = ["rate_jacobian", "stiff_rates", "unstable_rate", "sliding_points", "speed_floor"]


def rate_jacobian(model, eps: float, reduced: bool = False) -> ca.Function:
    """``J(x, u, p)`` of the regularised model, or of the model with the current quasi-static
    (cached on the model)."""
    key = ("stiff_jac", eps, reduced)
    cache = model._fcache
    if key not in cache:
        f = model.ode(eps)
        x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
        if reduced:
            j = model.current_index
            xq = ca.vertcat(x[:j], model.quasi_static_current(x, u, model.unpack(p)), x[j + 1:])
            xd = f(xq, u, p)
            xd = ca.vertcat(xd[:j], 0, xd[j + 1:])
        else:
            xd = f(x, u, p)
        cache[key] = ca.Function(f"{model.cname}_stiff_jac", [x, u, p], [ca.jacobian(xd, x)])
    return cache[key]


def stiff_rates(model, params, u, *, eps: float | None = None, speed: float | None = None,
                reduced: bool = False) -> float:
    """The largest eigenvalue magnitude [1/s] of the model's Jacobian over the points of the rule.

    Parameters
    ----------
    model : the rig; params : its ParameterSet (or a parameter vector)
    u : (nu,) inputs (the consumer's largest; forces at their largest)
    eps : friction regularisation [rad/s] of a regularised consumer: every contact body at rest
        or sliding at ``speed`` counts; None (the exact stick/slip plant): only sliding, at the
        model's default regularisation (whose sliding slope is the law's own)
    speed : the sliding speed [rad/s] of every body (default: the drive's, at least :func:`speed_floor`;
        a torque drive's: the speed its torque sustains, or the rig's nominal speed where it sustains
        none)
    reduced : with the DC motor's current quasi-static
    """
    xs, pv, u = sliding_points(model, params, u)
    J = rate_jacobian(model, model.eps_default if eps is None else float(eps), reduced)
    if speed is None:
        speed = lo = speed_floor(model)
        if model.drive.sets_speed:
            speed = max(abs(float(u[model.inputs.index(model.drive_input)])), lo)
        elif model.contacts:
            # the speed the torque sustains; where none does, the guess runs off (100 x the rig's nominal
            # speed and more): the rig's nominal speed then
            w, w_nom = abs(float(xs[model.contacts[0]])), abs(float(model.nominal_speed()))
            speed = max(w if w <= 100 * max(w_nom, lo) else w_nom, lo)
    # every body at the sliding speed (the guess has them at one speed, its own): a torque the friction
    # holds at every speed has no steady sliding and the guess runs off (a lead screw under an axial load
    # its drive torque cannot turn: 6e8 rad/s), and the springs' dampers between a body at that speed and
    # a contact body at ``speed`` then gave the lead screw's speed-dependent inertia a rate of 2e8 1/s
    for b in model.bodies:
        xs[model.speed_index(b)] = speed
    nc = min(len(model.contacts), 4)
    # the exact plant holds a memoryless contact at rest (no rate there); a law with states never is
    held = sum(1 << i for i in range(nc) if i not in model.stateful_contacts)
    combos = [c for c in range(2 ** nc) if c & held == held] if eps is None else range(2 ** nc)
    lam = 0.0
    for combo in combos:
        xx = xs.copy()
        for i in range(nc):
            xx[model.contacts[i]] = speed if combo >> i & 1 else 0.0
        A = np.array(J(xx, u, pv), float)
        if not np.all(np.isfinite(A)):
            return math.inf
        ev = np.linalg.eigvals(A) if A.size else np.zeros(0)
        lam = max(lam, float(np.max(np.abs(ev))) if ev.size else 0.0)
    return lam


def speed_floor(model) -> float:
    """The lowest sliding speed [rad/s, or m/s] the rates are taken at when none is given: 1 rad/s on
    rig3 (30 rpm), carried to the rig by its nominal speed (:func:`models.rig.steady.by_speed`; a
    friction bench at micrometres per second is not rated at 1 m/s)."""
    return by_speed(1.0, model)


def sliding_points(model, params, u):
    """``(xs, pv, u)``: a state of steady sliding to perturb (non-finite entries 0), the parameter
    vector and the inputs as arrays."""
    pv = np.asarray(params.vector() if hasattr(params, "vector") else params, float)
    u = np.asarray(u, float).ravel()
    try:
        with np.errstate(all="ignore"):
            xs = np.asarray(model.sliding_guess(u, params), float)
    except Exception:  # noqa: BLE001 - any finite point will do for a rate estimate
        xs = np.zeros(model.nx)
    return np.where(np.isfinite(xs), xs, 0.0), pv, u


def unstable_rate(model, params, u, *, eps: float | None, speed: float | None = None) -> tuple[float, float]:
    """``(oscillation, growth)`` [1/s]: the largest ``|Im lambda|`` and the largest positive ``Re lambda``
    of the regularised model's Jacobian, every contact body at rest or sliding at speeds from 10 ``eps``
    (just beyond the regularisation band, where a Stribeck fall is steepest) up to ``speed`` (default:
    as :func:`stiff_rates`).  These are the rates an L-stable implicit step must resolve; its large
    negative real rates (the band, a law's relaxing states) it damps in one step whatever the substep.
    """
    xs, pv, u = sliding_points(model, params, u)
    e = model.eps_default if eps is None else float(eps)
    J = rate_jacobian(model, e, False)
    if speed is None:
        lo = speed_floor(model)
        speed = max(abs(float(u[model.inputs.index(model.drive_input)])), lo) if model.drive.sets_speed \
            else max(abs(float(model.nominal_speed())), lo)
    # a regularised consumer: down to just beyond its band; the exact plant (a law with states, whose
    # own speed scale may be anything): eight decades
    floor = 10 * e if eps is not None else speed * 1e-8
    speeds = [speed * 10.0 ** -k for k in range(9) if speed * 10.0 ** -k >= floor] or [speed]
    if eps is not None:
        speeds += [10 * e, 100 * e]
    speeds = sorted(set(speeds))
    osc = grow = 0.0
    nc = min(len(model.contacts), 4)
    for w in speeds:
        for combo in range(2 ** nc):
            xx = xs.copy()
            for b in model.bodies:
                xx[model.speed_index(b)] = w
            for i in range(nc):
                xx[model.contacts[i]] = w if combo >> i & 1 else 0.0
            A = np.array(J(xx, u, pv), float)
            if not np.all(np.isfinite(A)):
                return math.inf, math.inf
            ev = np.linalg.eigvals(A) if A.size else np.zeros(0)
            if ev.size:
                osc = max(osc, float(np.max(np.abs(ev.imag))))
                grow = max(grow, float(np.max(ev.real)))
    return osc, grow
