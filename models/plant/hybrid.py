"""Exact stick/slip plant stepping ("event-capturing time stepping").

Why this and not a regularised model: a regularised (tanh) friction law lets a stuck
disc creep at a speed set by the smoothing, and the creep distorts exactly what a
stick-slip study measures (stick time, twist build-up).  Here a contact body is either

- *stuck*: its speed is exactly 0 and its acceleration is held at 0, the friction
  torque being whatever keeps it there, as long as that torque lies within the static
  limits; or
- *slipping* in a direction ``s`` (+1/-1): the kinetic law applies with that sign.

The mode is decided at the start of every substep from the state (a body is at rest iff
its speed is *exactly* zero, which this scheme assigns on sticking), frozen over the RK4
substep, and a slipping body whose speed changes sign within a substep is brought to
rest (speed set to exactly 0).  Stick and slip switching times are thus resolved to one
substep; there is no creep at all.  The test against the exact Coulomb cycle (period and
peak speed within 1 %) is in ``tests/test_coulomb_cycle.py``.

A contact body whose friction law has states (LuGre, rate-and-state) has no such modes: the law is
itself a smooth model of stick (LuGre's presliding bristles, rate-and-state's creep at a speed that
falls exponentially with the contact's age), so the body is integrated with its law like any other
state, never held.  A rig whose contacts all have such laws needs no event logic at all, and the
simulator steps it with the integration rule's method (:mod:`models.discretise`: an L-stable
implicit method where the law is stiff) instead of this stepper.

The whole sample (``nsub`` substeps) is one SX ``casadi.Function`` built with
``if_else``, so it can be evaluated per DAQ sample, compiled, or mapped over thousands
of parameter points for sweeps.
"""

from __future__ import annotations

import casadi as ca

from models.errors import ConfigError

__all__ = ["hybrid_step_function"]


def _substep(model, x, th, u, P, h, quasi_static: bool = False):
    nc = len(model.contacts)
    j_i = model.current_index

    def project(xx):
        # the armature current at its quasi-static value (models.discretise)
        if not quasi_static:
            return xx
        return ca.vertcat(xx[:j_i], model.quasi_static_current(xx, u, P), xx[j_i + 1:])

    x = project(x)
    # --- modes, frozen over the substep
    zeros = [ca.SX(0)] * nc
    xd0 = model.dynamics(x, u, P, zeros, [ca.SX(1)] * nc)
    stuck, s = [], []
    for i, idx in enumerate(model.contacts):
        v = x[idx]
        if i in model.stateful_contacts:
            # a law with states is its own smooth model of stick: never held, its direction the speed's
            stuck.append(ca.SX(0))
            s.append(ca.if_else(v >= 0, 1, -1))
            continue
        J = model.contact_inertia(i, x, u, P, 1.0)
        T_ext = J * xd0[idx]
        T_plus = model.contact_friction(i, ca.SX(0), u, P, s=1.0)    # static limit opposing +motion (<= 0)
        T_minus = model.contact_friction(i, ca.SX(0), u, P, s=-1.0)  # static limit opposing -motion (>= 0)
        at_rest = v == 0
        st = ca.logic_and(at_rest, ca.logic_and(T_ext + T_plus <= 0, T_ext + T_minus >= 0))
        s_rest = ca.if_else(T_ext + T_plus > 0, 1, -1)
        stuck.append(st)
        s.append(ca.if_else(at_rest, s_rest, ca.sign(v)))

    def rhs(xx):
        xx = project(xx)
        Tc = [model.contact_friction(i, xx[idx], u, P, s=1.0, x=xx) if i in model.stateful_contacts
              else model.contact_friction(i, ca.fmax(s[i] * xx[idx], 0), u, P, s=s[i])
              for i, idx in enumerate(model.contacts)]
        xd = model.dynamics(xx, u, P, Tc, s)
        xd = [ca.if_else(stuck[model.contacts.index(j)], 0, xd[j]) if j in model.contacts else xd[j]
              for j in range(model.nx)]
        if quasi_static:
            xd[j_i] = 0
        return ca.vertcat(*xd), model.ref_rate(xx, u, P)

    k1, r1 = rhs(x)
    k2, r2 = rhs(x + h / 2 * k1)
    k3, r3 = rhs(x + h / 2 * k2)
    k4, r4 = rhs(x + h * k3)
    xn = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    thn = th + h / 6 * (r1 + 2 * r2 + 2 * r3 + r4)
    # a slipping body whose speed changed sign comes to rest (exactly zero)
    parts = [xn[j] for j in range(model.nx)]
    for i, idx in enumerate(model.contacts):
        if i not in model.stateful_contacts:
            parts[idx] = ca.if_else(ca.logic_or(stuck[i], s[i] * xn[idx] <= 0), 0, xn[idx])
    return project(ca.vertcat(*parts)), thn


def hybrid_step_function(model, dt: float, nsub: int, *, quasi_static: bool = False) -> ca.Function:
    """One DAQ sample of the exact stick/slip plant, zero-order-hold input.

    Returns ``F(x, theta_ref, u, p) -> (x_next, theta_ref_next)`` where ``theta_ref`` is
    the absolute angle of the model's reference body (for encoder angles).

    Parameters
    ----------
    model : models.rig.RigModel
    dt : sample period [s]
    nsub : substeps per sample; switching times are resolved to ``dt/nsub``
    quasi_static : a DC motor's current at its quasi-static value (:func:`models.discretise.integration`
        decides; :attr:`models.discretise.Integration.quasi_static`)
    """
    if not dt > 0:
        raise ConfigError(f"dt must be > 0 s, got {dt}")
    if int(nsub) != nsub or nsub < 1:
        raise ConfigError(f"nsub must be an integer >= 1, got {nsub}")
    x = ca.SX.sym("x", model.nx)
    th = ca.SX.sym("theta_ref")
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_p)
    P = model.unpack(p)
    if quasi_static and model.current_index is None:
        raise ConfigError(f"quasi_static needs a drive with a fast state (a DC motor's current); rig {model.name!r} has a "
                          f"{model.drive_kind} drive")
    # one substep as its own Function keeps the graph small; it is called nsub times
    xs, ths = ca.SX.sym("xs", model.nx), ca.SX.sym("ths")
    sub = ca.Function(f"{model.cname}_hybrid_substep", [xs, ths, u, p], list(_substep(model, xs, ths, u, P, dt / nsub, quasi_static)),
                      ["x", "theta_ref", "u", "p"], ["x_next", "theta_ref_next"])
    xk, thk = x, th
    for _ in range(int(nsub)):
        xk, thk = sub(xk, thk, u, p)
    return ca.Function(f"{model.cname}_plant_step{'_qs' if quasi_static else ''}", [x, th, u, p], [xk, thk],
                       ["x", "theta_ref", "u", "p"], ["x_next", "theta_ref_next"])
