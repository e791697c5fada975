"""The NMPC's stage functions on any rig: the prediction model, the discrete augmented
dynamics, the least-squares cost and their Gauss-Newton blocks (named CasADi Functions).

The OCP is a multiple-shooting problem over ``N`` intervals of ``dt`` [s], each integrated by
the rig's integration rule (:func:`models.discretise.integration`: RK4 with ``nsub`` substeps,
a fast motor's current quasi-static, or the L-stable implicit step where RK4 would need too many
substeps: a small eps, a friction law with states) on the rig's regularised model (state and decisions:
:mod:`mitigate.controllers.nmpc.layout`).

The cost is a least-squares sum plus a linear servo-force term where the programme holds a
servo at its lower limit (friction work at a pin is linear in its normal force; a linear cost
leaves the force at exactly 0 when it does not pay)::

    sum_k 0.5 |r(xa_k, v_k)|^2 + c_f sum_j l_j c_j / f_j   +   0.5 |r_N(xa_N)|^2

    r = [w_speed (w_b - w_nom) / w_s,                     objective body b
         w_rel (w_a - w_a') / w_s  for every spring connection (a, a'),
         w_ref (u_drive - u_drive_programme) / sp_s,      if the drive is commanded
         w_force (c_j - N_j) / f_j,                       N_j the programme's force (the driller's
                                                          weight on bit: tracked, never pulled to 0)
         w_d_ref d w / sp_s,  w_d_force (c_j - s_j) / f_j]
    r_N = w_terminal [speed and spring residuals]

with ``w_s`` = max(|w_nom|, 1 rad/s), ``sp_s`` = ``w_s`` (speed set-point) or the band (torque
drive), ``f_j`` the servo's ``n_max`` and ``l_j`` = 1 where ``N_j`` is the servo's ``n_min`` (else
0), so every weight is dimensionless.  Gauss-Newton gives a positive semi-definite Hessian at
no extra cost.

Per-stage parameters ``q`` (:meth:`OCPLayout.q_template`, :meth:`OCPLayout.set_q`): the held
inputs (``model.inputs`` order; the drive entry is the programme's set-point, a commanded
servo's its programmed force), the nominal speed, the scales, the linear-cost flags ``l_j``,
the weights, one friction factor per contact body (the disturbance model: 1 = as the rig file
says) and the rig's parameter vector.  Only the structure (N, dt, nsub, eps, inputs, lags,
body) enters the compiled code, so one library serves every tuning.
"""

from __future__ import annotations

import dataclasses

import casadi as ca

from models import friction as fr
from models.discretise import FOLD_ABOVE, Integration
from mitigate.controllers.nmpc.layout import OCPLayout, OCPSpec
from mitigate.controllers.nmpc.options import WEIGHT_NAMES

__all__ = ["stage_functions", "prediction_rhs"]


def prediction_rhs(model, eps: float) -> ca.Function:
    """``xdot = f(x, u, p, fc)``: the rig's regularised model with the friction torque of contact
    body ``i`` multiplied by ``fc[i]`` (the disturbance model; ``fc = 1`` is ``model.ode(eps)``)."""
    x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
    fc = ca.SX.sym("fc", len(model.contacts))
    P = model.unpack(p)
    Tc = [fc[i] * model.contact_friction(i, x[idx], u, P, eps, x=x) for i, idx in enumerate(model.contacts)]
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
    flin = q[L.q_lin:L.q_lin + L.ns]
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

    # the implicit step's predictor needs the contact speeds with a memoryless (sign-like) law
    stiff = tuple(idx for i, idx in enumerate(model.contacts) if i not in model.stateful_contacts) \
        if spec.method != "rk4" else ()
    brk = tuple(model.contacts[i] for i in model.stateful_contacts if model.rest_free(i)) \
        if spec.method != "rk4" else ()
    integ = Integration(spec.dt, spec.nsub, model.current_index if spec.quasi_static else None,
                        method=spec.method, stiff=stiff, band=spec.eps, bracket=brk)

    def fast(xa_, v_, _q):
        return model.quasi_static_current(xa_[:nx], inputs(xa_, v_), model.unpack(p))

    def finish(xe_, xa_, v_):
        """The interval's end from the integrated augmented state: a servo without lag takes its
        command, the last drive input its increment."""
        xn_ = [xe_[j] for j in range(nx)]
        for k in range(L.ns):
            xn_.append(xe_[L.i_servo[k]] if taus[k] > 0 else v_[L.j_cmd[k]])
        if L.drive:
            xn_.append(xa_[L.i_wprev] + v_[0])
        return ca.vertcat(*xn_)

    name = f"{model.cname}_nmpc"
    folded = spec.nsub > FOLD_ABOVE
    one = dataclasses.replace(integ, dt=spec.dt / spec.nsub, nsub=1) if folded else None
    # unrolled: the interval's end as one expression (folded: a loop over one substep, below); the
    # implicit step's Jacobians by the implicit function theorem (models.sdirk), from the same Newton
    # iterates as its values, not by differentiating them (8x the instructions, C that does not build)
    xn = Ex = Ev = None
    if not folded:
        if integ.implicit:
            xe, (Ex, Ev) = integ.advance_jacobian(faug, xa, v, q, fast)
        else:
            xe = integ.advance(faug, xa, v, q, fast)
        xn = finish(xe, xa, v)
    if folded:
        step = _folded_dynamics(one, spec.nsub, faug, fast, finish, xa, v, q, name, values_only=True)
        xaM, vM, qM = ca.MX.sym("xa", L.nxa), ca.MX.sym("v", L.nv), ca.MX.sym("q", L.nq)
        F = ca.Function(f"{name}_F", [xaM, vM, qM], [step(xaM, vM, qM)], ["xa", "v", "q"], ["xa_next"])
    else:
        F = ca.Function(f"{name}_F", [xa, v, q], [xn], ["xa", "v", "q"], ["xa_next"])

    u = inputs(xa, v)
    wb = xa[model.speed_index(spec.body)]
    r = [w_speed * (wb - nom) / ws] + [w_rel * dd / ws for dd in _spring_speeds(model, xa, u)]
    if L.drive:
        r += [w_ref * (u[L.u_drive] - hold[L.u_drive]) / sps]
    cmd = [v[L.j_cmd[k]] for k in range(L.ns)]
    r += [w_force * (cmd[k] - hold[L.u_servo[k]]) / fs[k] for k in range(L.ns)]
    if L.drive:
        r += [w_dref * v[0] / sps]
    r += [w_dforce * (cmd[k] - xa[L.i_servo[k]]) / fs[k] for k in range(L.ns)]
    r = ca.vertcat(*r)
    lin = c_force * sum((flin[k] * cmd[k] / fs[k] for k in range(L.ns)), ca.SX(0))
    cost = ca.Function(f"{name}_cost", [xa, v, q], [r, lin], ["xa", "v", "q"], ["r", "l"])
    Jx, Jv = ca.jacobian(r, xa), ca.jacobian(r, v)
    d = ca.densify
    blocks = [d(Jx.T @ Jx), d(Jv.T @ Jx), d(Jv.T @ Jv), d(Jx.T @ r + ca.jacobian(lin, xa).T),
              d(Jv.T @ r + ca.jacobian(lin, v).T), 0.5 * ca.sumsqr(r) + lin]
    outs = ["xn", "A", "B", "Q", "S", "R", "gx", "gv", "c"]
    if not folded and integ.implicit:
        A, B = _finish_jacobians(finish, xe, Ex, Ev, xa, v)
        stage = ca.Function(f"{name}_stage", [xa, v, q], [xn, d(A), d(B), *blocks], ["xa", "v", "q"], outs)
    elif not folded:
        stage = ca.Function(f"{name}_stage", [xa, v, q], [xn, d(ca.jacobian(xn, xa)), d(ca.jacobian(xn, v)), *blocks],
                            ["xa", "v", "q"], outs)
    else:
        dyn = _folded_dynamics(one, spec.nsub, faug, fast, finish, xa, v, q, name)
        gn = ca.Function(f"{name}_gn", [xa, v, q], blocks, ["xa", "v", "q"], outs[3:])
        xaM, vM, qM = ca.MX.sym("xa", L.nxa), ca.MX.sym("v", L.nv), ca.MX.sym("q", L.nq)
        stage = ca.Function(f"{name}_stage", [xaM, vM, qM], [*dyn(xaM, vM, qM), *gn(xaM, vM, qM)],
                            ["xa", "v", "q"], outs)
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


def _folded_dynamics(one, nsub: int, faug, fast, finish, xa, v, q, name: str, *,
                     values_only: bool = False) -> ca.Function:
    """``(xa, v, q) -> (xn, A, B)`` as ``nsub`` repetitions of the substep ``one`` (an
    :class:`~models.discretise.Integration` of one substep of ``dt / nsub``): a ``fold`` over one
    substep and its Jacobian ``J = d xe' / d(xe, v)``; with ``Z = d xe / d(xa, v)``,
    ``Z' = J_x Z + [0, J_v]`` from ``Z = [I, 0]``; then the interval's end ``finish(xe, xa, v)`` and
    its Jacobians by the chain rule.  The same numbers as the unrolled step up to rounding; C code
    that does not grow with ``nsub``.  ``values_only``: ``(xa, v, q) -> xn`` (the same substeps'
    values, no Jacobians)."""
    nxa, nv = xa.numel(), v.numel()
    if values_only:
        xe1 = one.advance(faug, xa, v, q, fast)
        sub = ca.Function(f"{name}_substep_x", [xa, v, q], [xe1], ["xe", "v", "q"], ["xe_next"])
        xaM, vM, qM = ca.MX.sym("xa", nxa), ca.MX.sym("v", nv), ca.MX.sym("q", q.numel())
        xe = sub.fold(nsub)(xaM, ca.repmat(vM, 1, nsub), ca.repmat(qM, 1, nsub))
        xe_s = ca.SX.sym("xe", nxa)
        end = ca.Function(f"{name}_end_x", [xe_s, xa, v], [finish(xe_s, xa, v)])
        return ca.Function(f"{name}_dyn_x", [xaM, vM, qM], [end(xe, xaM, vM)], ["xa", "v", "q"], ["xn"])
    if one.implicit:
        xe1, (Jx, Jv) = one.advance_jacobian(faug, xa, v, q, fast)
        J = ca.horzcat(Jx, Jv)
    else:
        xe1 = one.advance(faug, xa, v, q, fast)
        J = ca.jacobian(xe1, ca.vertcat(xa, v))
    Z = ca.SX.sym("Z", nxa, nxa + nv)
    Zn = J[:, :nxa] @ Z + ca.horzcat(ca.SX(nxa, nxa), J[:, nxa:])
    sub = ca.Function(f"{name}_substep", [ca.vertcat(xa, ca.vec(Z)), v, q], [ca.vertcat(xe1, ca.vec(Zn))],
                      ["z", "v", "q"], ["z_next"])
    xe, Ze = ca.SX.sym("xe", nxa), ca.SX.sym("Ze", nxa, nxa + nv)
    xn = finish(xe, xa, v)
    Pe, Pa, Pv = ca.jacobian(xn, xe), ca.jacobian(xn, xa), ca.jacobian(xn, v)
    end = ca.Function(f"{name}_end", [xe, Ze, xa, v], [xn, ca.densify(Pe @ Ze[:, :nxa] + Pa),
                                                      ca.densify(Pe @ Ze[:, nxa:] + Pv)])
    xaM, vM, qM = ca.MX.sym("xa", nxa), ca.MX.sym("v", nv), ca.MX.sym("q", q.numel())
    z0 = ca.vertcat(xaM, ca.vec(ca.horzcat(ca.MX.eye(nxa), ca.MX(nxa, nv))))
    zN = sub.fold(nsub)(z0, ca.repmat(vM, 1, nsub), ca.repmat(qM, 1, nsub))
    xn_, A, B = end(zN[:nxa], ca.reshape(zN[nxa:], nxa, nxa + nv), xaM, vM)
    return ca.Function(f"{name}_dyn", [xaM, vM, qM], [xn_, A, B], ["xa", "v", "q"], ["xn", "A", "B"])


def _finish_jacobians(finish, xe, Ex, Ev, xa, v):
    """``d finish(xe, xa, v) / d(xa, v)`` by the chain rule, given ``xe``'s Jacobians ``Ex``, ``Ev``."""
    xe_s = ca.SX.sym("xe", xe.numel())
    xn = finish(xe_s, xa, v)
    Pe, Pa, Pv = (ca.substitute(ca.jacobian(xn, a), xe_s, xe) for a in (xe_s, xa, v))
    return Pe @ Ex + Pa, Pe @ Ev + Pv
