"""The noise and the prior of the estimation model (:mod:`estimators.online.model`).

- :func:`process_variances`: per DAQ sample, an unmodelled torque of standard deviation
  ``q_torque`` on every body (``var(omega_b) = (q_torque dt / J_b)^2``, ``J_b`` the body's total
  inertia), ``q_twist`` on the twists, the drive's states their family's noise (none when a state
  integrates known signals, as a DC motor's PI integral), random walks ``q_load^2 dt``,
  ``q_offset^2 dt``, ``q_gain^2 dt``, and none on the ``zero:`` and ``lag`` states.
- :func:`prior`: load factors at 1, sensor offsets and gains at their parameters, the rest from
  ``x0``; a ``zero:`` or ``lag`` state IS the initial state it follows, so it shares its prior and
  is fully correlated with it.
- :func:`state_bounds`: the MHE's bounds (the EKF projects the load factors into them).

The state-dependent part of the process noise (``q_stick``: bodies at rest) is symbolic and lives
with the model.
"""

from __future__ import annotations

import numpy as np

from models.rig import RigModel
from models.sensors import FLOOR
from models.errors import ConfigError

__all__ = ["process_variances", "prior", "state_bounds"]


def process_variances(model: RigModel, names, P_num: dict, dt: float, o) -> np.ndarray:
    """The constant part of the process-noise variances per DAQ sample (module docstring).

    Parameters
    ----------
    model : the rig; names : the estimator's state names
    P_num : the rig's parameters by name (numbers); dt : DAQ period [s]
    o : :class:`estimators.online.options.EKFOptions` with the rig's defaults filled in

    Returns
    -------
    (nx,) variances, each at least :data:`models.sensors.FLOOR`
    """
    out = []
    drive_states = {s.name: s for s in model.drive.states}
    for n in names:
        kind, _, target = n.partition(":")
        if not target:
            if n.startswith("twist_"):
                v = o.q_twist ** 2
            elif n.startswith("omega_"):
                J = float(model.inertia(n[len("omega_"):], P_num))
                v = (o.q_torque * dt / J) ** 2 if J > 0 else o.q_torque ** 2
            else:           # the drive's: its family's process noise, none when it integrates known signals
                st = drive_states.get(n)
                v = getattr(o, f"q_{st.noise}") ** 2 if st is not None and st.noise else 0.0
        elif kind == "load":
            v = o.q_load ** 2 * dt
        elif kind == "offset":
            v = o.q_offset ** 2 * dt
        elif kind == "gain":
            v = o.q_gain ** 2 * dt
        else:               # zero:, lag: constants and exact copies
            v = 0.0
        out.append(max(v, FLOOR))
    return np.array(out)


def prior(model: RigModel, names, idx, P_num, o, x0, where, friction_std=None):
    """The prior mean and covariance of the estimator's state (module docstring).

    Parameters
    ----------
    model : the rig; names : the estimator's state names; idx : ``{name: index}``
    P_num : the rig's parameters by name (numbers); o : the filled-in options
    x0 : initial guess, ``model.states`` order (nx_rig) or the full state; None: at rest
    where : prefix of error messages
    friction_std : prior standard deviations of the friction laws' states by name
        (:meth:`models.rig.RigModel.friction_state_scale`)

    Returns
    -------
    x0 : (nx,) mean; P0 : (nx, nx) covariance

    Raises
    ------
    ConfigError : ``x0`` of the wrong size or not finite.
    """
    nx, nxr = len(names), model.nx
    x = np.zeros(nx)
    for n in names:
        kind, _, target = n.partition(":")
        if kind == "load":
            x[idx[n]] = 1.0
        elif kind in ("offset", "gain"):
            x[idx[n]] = P_num[getattr(model.sensor_of(target), kind).name]
    full = False
    if x0 is not None:
        x0 = np.asarray(x0, float).ravel()
        if x0.shape not in ((nxr,), (nx,)) or not np.all(np.isfinite(x0)):
            raise ConfigError(f"{where}.x0 must be {nxr} (the rig's states) or {nx} finite numbers, got shape "
                              f"{x0.shape}")
        full = x0.size == nx
        if full:
            x[:] = x0
        else:
            x[:nxr] = x0
    std = []
    drive_prior = {s.name: s.prior for s in model.drive.states}
    for n in names:
        kind, _, target = n.partition(":")
        base = target if (kind == "zero" or kind.startswith("lag")) else n
        if base.startswith("twist_"):
            s = o.p0_twist
        elif base.startswith("omega_"):
            s = o.p0_speed
        elif base in drive_prior:
            s = getattr(o, f"p0_{drive_prior[base]}")
        elif kind == "load":
            s = o.p0_load
        elif kind == "offset":
            s = o.p0_offset
        elif base in (friction_std or {}):
            s = friction_std[base]
        else:
            s = o.p0_gain
        std.append(s)
    P0 = np.diag(np.square(std))
    for n in names:
        kind, _, target = n.partition(":")
        if kind == "zero" or kind.startswith("lag"):
            # the twist at power-on IS the initial twist (a lagged state is the initial state):
            # same prior, fully correlated
            j, t = idx[n], model.states.index(target)
            if not full:
                x[j] = x[t]
            P0[j, t] = P0[t, j] = P0[t, t]
            for m in names:
                km, _, tm = m.partition(":")
                if (km == "zero" or km.startswith("lag")) and tm == target:
                    P0[j, idx[m]] = P0[t, t]
    P0 += 1e-12 * np.eye(nx)
    return x, P0


def state_bounds(names):
    """The states' bounds (the MHE's, and the EKF's projection of the load factors): a load
    factor within ``[0, 5]``, a gain within ``[0.05, 20]``, the rest free (+-1e6).

    Returns
    -------
    lb, ub : (nx,) each
    """
    big = 1e6
    lb, ub = np.full(len(names), -big), np.full(len(names), big)
    for j, n in enumerate(names):
        if n.startswith("load:"):
            lb[j], ub[j] = 0.0, 5.0
        elif n.startswith("gain:"):
            lb[j], ub[j] = 0.05, 20.0
    return lb, ub
