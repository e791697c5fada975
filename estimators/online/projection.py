"""What the EKF's corrected mean may be: the states a rig can reach (:class:`EstimationModel`'s
``project``).

The drive's states stay where the drive can take them (:meth:`models.rig.drives.Drive.project`: a
DC motor's PI integral within what its anti-windup lets it reach); the load factors stay within the
MHE's bounds (a negative friction factor, with a twist of the wrong sign along the unobservable
twist/zero/load direction, made the NMPC run ``mismatch_p40`` 42 % fast).  The covariance is left alone.
"""

from __future__ import annotations

import casadi as ca

from models.rig import RigModel

__all__ = ["projection"]


def projection(model: RigModel, names, lb, ub, x, uh, p, u, P) -> ca.Function:
    """The named Function ``<rig>_est_project: (x, uh, p) -> x_projected``.

    Parameters
    ----------
    model : the rig; names : the estimator's state names (``load:<contact>`` are clipped)
    lb, ub : the states' bounds (the MHE's); x, uh, p : the Function's symbols
    u : the inputs (symbolic, from ``uh``); P : the parameters by name (symbolic, from ``p``)
    """
    xp = model.drive.project(model, x, u, P)
    xp = ca.vertcat(*[ca.fmin(ca.fmax(xp[j], lb[j]), ub[j]) if n.startswith("load:") else xp[j]
                      for j, n in enumerate(names)])
    return ca.Function(f"{model.cname}_est_project", [x, uh, p], [xp], ["x", "uh", "p"], ["x_projected"])
