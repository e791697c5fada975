"""What the EKF's corrected mean may be: the states a rig can reach (:class:`EstimationModel`'s
``project``).

A DC motor's PI integral stays within what its anti-windup lets it reach
(:func:`pi_integral_projection`); the load factors stay within the MHE's bounds (a negative friction
factor, with a twist of the wrong sign along the unobservable twist/zero/load direction, made the
NMPC run ``mismatch_p40`` 42 % fast).  The covariance is left alone.
"""

from __future__ import annotations

import casadi as ca

from models.rig import RigModel

__all__ = ["pi_integral_projection", "projection"]


def pi_integral_projection(model: RigModel, x, u, P):
    """``x`` with a DC motor's PI integral ``z`` clipped to ``sat(G ki z) / (G ki)``: the voltage
    limits (``v_max``, ``i_max``; :meth:`models.rig.RigModel.motor_voltage`) at the state's motor
    speed, evaluated with zero speed error so that the voltage is the integral term alone.

    The rig's anti-windup stops the integral while the limit holds the voltage against the error,
    so a drive that starts unsaturated never has ``G ki z`` beyond the limits (``z`` rises only
    while ``G (kp e + ki z) < hi`` with ``e > 0``, i.e. ``G ki z < hi``).  Beyond them the current
    no longer depends on ``z``: an EKF correction that pushes ``z`` there leaves it unobservable
    for good (realistic rig3, one noise seed in three: ``z`` 0.06 rad in the plant, 255 rad in the
    filter, which then explained the torque by a 30-fold friction and -26 rad of twist).
    """
    d = model.spec.drive
    if model.drive_kind != "dc_motor" or (d.param("v_max") is None and d.param("i_max") is None):
        return x
    nxr = model.nx
    xr = x[:nxr]
    un = {n: u[j] for j, n in enumerate(model.inputs)}
    un[d.input] = xr[model.speed_index(d.body)]     # zero error: V = G ki z
    V, Vs = model.motor_voltage(xr, un, P)
    z = xr[nxr - 1]
    zp = ca.if_else(ca.fabs(V) > 0, z * Vs / V, z)
    return ca.vertcat(x[:nxr - 1], zp, x[nxr:])


def projection(model: RigModel, names, lb, ub, x, uh, p, u, P) -> ca.Function:
    """The named Function ``<rig>_est_project: (x, uh, p) -> x_projected``.

    Parameters
    ----------
    model : the rig; names : the estimator's state names (``load:<contact>`` are clipped)
    lb, ub : the states' bounds (the MHE's); x, uh, p : the Function's symbols
    u : the inputs (symbolic, from ``uh``); P : the parameters by name (symbolic, from ``p``)
    """
    xp = pi_integral_projection(model, x, u, P)
    xp = ca.vertcat(*[ca.fmin(ca.fmax(xp[j], lb[j]), ub[j]) if n.startswith("load:") else xp[j]
                      for j, n in enumerate(names)])
    return ca.Function(f"{model.cname}_est_project", [x, uh, p], [xp], ["x", "uh", "p"], ["x_projected"])
