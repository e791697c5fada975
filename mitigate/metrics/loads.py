"""The loads that damage a rig's hardware, from the TRUE plant trajectory: the torque its springs
(the string) carry, the drive's current or torque against its limit.

All functions take the PLANT's model and true parameters (the string a controller twists is the
real one), states ``x`` (n, nx) and applied inputs ``u`` (n, nu) sampled along a run.
"""

from __future__ import annotations


import casadi as ca
import numpy as np

from models.errors import ConfigError

__all__ = ["string_torques", "steady_string_torque"]


def _torque_function(model) -> ca.Function:
    """``(x, u, p) -> (n_springs,)`` the torque each spring connection carries [N m] (its elastic
    and damping parts, :meth:`models.rig.RigModel.connection_torque`)."""
    x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
    P = model.unpack(p)
    un = {n: u[k] for k, n in enumerate(model.inputs)}
    springs = [c for c in model.spec.connections if c.stiffness is not None]
    out = ca.vertcat(*[model.connection_torque(c, x, un, P) for c in springs]) if springs else ca.DM.zeros(0)
    return ca.Function("string_torque", [x, u, p], [out])


def string_torques(model, params, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(n, n_springs) the torque every spring of the string carries along a trajectory [N m]."""
    f = _torque_function(model)
    if f.size1_out(0) == 0 or len(x) == 0:
        return np.zeros((len(x), 0))
    p = np.asarray(params.vector(), float)
    return np.array(f.map(len(x))(np.asarray(x, float).T, np.asarray(u, float).T, p)).T.reshape(len(x), -1)


def steady_string_torque(model, params, u: np.ndarray) -> float:
    """The largest |torque| a spring carries in steady sliding at the constant inputs ``u`` [N m]
    (the string's load when the rig turns smoothly at its programme); NaN when the steady state
    cannot be found (a torque drive whose programme does not slide)."""
    try:
        xs = model.steady_sliding(np.asarray(u, float), params)
    except (RuntimeError, ConfigError):
        return float("nan")
    if not np.all(np.isfinite(xs)):
        return float("nan")
    T = string_torques(model, params, xs[None, :], np.asarray(u, float)[None, :])
    return float(np.max(np.abs(T))) if T.size else float("nan")

