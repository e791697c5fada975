"""The structure of the NMPC's optimal control problem: what the OCP is built from
(:class:`OCPSpec`) and where everything sits in its vectors (:class:`OCPLayout`).

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

Per-stage parameters ``q`` (:meth:`OCPLayout.q_template`, :meth:`OCPLayout.set_q`) are listed in
:mod:`mitigate.controllers.nmpc.stage`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.errors import ConfigError
from mitigate.controllers.nmpc.options import WEIGHT_NAMES

__all__ = ["OCPSpec", "OCPLayout"]


@dataclass(frozen=True, kw_only=True)
class OCPSpec:
    """Everything that defines the OCP's functions.

    Parameters
    ----------
    horizon : N; dt : interval [s]; nsub : substeps per interval; eps : friction
        regularisation [rad/s]; quasi_static : a DC motor's current at its quasi-static value;
        method : "rk4" or the implicit "sdirk2" (all from :func:`models.discretise.integration`)
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
    method: str = "rk4"

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
        # q = [held inputs (nu), nominal speed, w_s, sp_s, f_1..f_m, linear-cost flags (m), weights,
        #      friction factors, p]
        self.q_hold = 0
        self.q_nom = nu
        self.q_ws, self.q_sps = nu + 1, nu + 2
        self.q_f = nu + 3
        self.q_lin = self.q_f + ns
        self.q_w = self.q_lin + ns
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

    def set_q(self, q: np.ndarray, hold, nominal: float, friction=None, linear=None) -> np.ndarray:
        """Write the held inputs (``model.inputs`` order; the drive's entry is the programme's
        set-point, a commanded servo's its programmed force), the nominal speed [rad/s], the
        friction factors (None: 1) and the servos' linear-cost flags (None: 0; 1 where the
        programme holds that servo at its lower limit) into ``q``."""
        q[:self.model.nu] = hold
        q[self.q_nom] = nominal
        q[self.q_fc:self.q_fc + self.n_fc] = 1.0 if friction is None else friction
        q[self.q_lin:self.q_lin + self.ns] = 0.0 if linear is None else linear
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

