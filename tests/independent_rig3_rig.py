"""The steppable independent rig (``tests/independent_rig3.py``: the physics is specified in that
module's docstring): :class:`IndependentRig3`, its initial state, DAQ sampling, integration and
true state.

numpy and scipy only; nothing from the project's packages.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy.integrate import BDF, LSODA, Radau, ode

from independent_rig3_dynamics import ChainStructure, RigDynamics, friction_coefficient
from independent_rig3_options import CHANNELS, RigOptions, daq_delays


class IndependentRig3(RigDynamics):
    """The 3-disc rig with its DAQ, steppable sample by sample.

    Parameters
    ----------
    options : RigOptions, optional
        Parameters (defaults = thesis values).
    seed : int or None
        Seed of the sensor noise.

    Notes
    -----
    State vector ``x = [q (nb), v (nb), i, z, N2]``: body angles and speeds
    (disc side), armature current, PI integrator state and servo force.

    Examples
    --------
    Closed loop with an external controller ``ctrl(meas) -> (w_ref, n2_cmd)``::

        rig = IndependentRig3(RigOptions(), seed=1)
        meas = rig.reset(omega_ref=3.0, n1=20.0, n2_cmd=0.0)   # t = 0
        for k in range(2000):
            w_ref, n2_cmd = ctrl(meas)                      # commands at t_k
            meas = rig.step(w_ref, 20.0, n2_cmd)            # measured at t_{k+1}
            true = rig.truth()                              # for scoring only
    """

    def __init__(self, options: RigOptions = RigOptions(), seed: Optional[int] = 0):
        options.validate()
        self.opt = options
        self.seed = seed
        self.s = ChainStructure(options)
        self._delay = daq_delays(options)
        self._solver_cls = {"Radau": Radau, "BDF": BDF, "LSODA": LSODA,
                            "odepack": None}[options.method]
        self._rtol = (options.rtol if options.rtol is not None else
                      (1e-6 if options.method == "odepack" else 1e-5))
        nb = self.s.nb
        self._n = 2 * nb + 3
        self._atol = np.concatenate([np.full(nb, 1e-9), np.full(nb, 1e-3 * options.v_t),
                                     [1e-4, 1e-6, 1e-6]])
        self._tick = 2 * math.pi / options.ticks_per_rev
        # constant part of the Jacobian
        Jc = np.zeros((self._n, self._n))
        Jc[:nb, nb:2 * nb] = np.eye(nb)
        Jc[nb:2 * nb, :nb] = -self.s.invJ[:, None] * self.s.K
        Jc[nb:2 * nb, nb:2 * nb] = -self.s.invJ[:, None] * self.s.D
        self._Jc = Jc
        self._fast = self._make_fast_rhs()
        self.reset()

    # -------------------------------------------------------------- state I/O
    def _initial_state(self, omega_ref, n1, n2_cmd):
        o = self.opt
        s = self.s
        nb = s.nb
        x = np.zeros(self._n)
        n1_0 = o.initial_n1 if o.initial_n1 is not None else (n1 if n1 is not None else 0.0)
        if o.initial_n2 is not None:
            n2_0 = o.initial_n2
        elif n2_cmd is not None:
            n2_0 = min(max(n2_cmd, o.servo_min), o.servo_max)
        else:
            n2_0 = 0.0
        x[2 * nb + 2] = n2_0
        self._n1_prev = float(n1_0)
        if o.initial_condition == "rest":
            return x
        if o.initial_condition == "twisted":
            # linear interpolation along each section; R3 angle = 0
            q = np.zeros(nb)
            n = int(o.shaft_elements)
            th2 = o.initial_twist23
            th1 = th2 + o.initial_twist12
            for j in range(n + 1):
                q[j] = th1 - o.initial_twist12 * j / n
                q[n + j] = th2 - o.initial_twist23 * j / n
            x[:nb] = q
            return x
        # steady sliding at w0: every body at w0, twists balance the friction
        w0 = o.initial_omega if o.initial_omega is not None else (omega_ref or 0.0)
        T1 = n1_0 * o.r1 * float(friction_coefficient(o, w0)) * math.tanh(w0 / o.v_t)
        T2 = n2_0 * o.r2 * float(friction_coefficient(o, w0)) * math.tanh(w0 / o.v_t)
        n = int(o.shaft_elements)
        # torque carried by section 1 elements: T1; section 2: T1 + T2
        q = np.zeros(nb)
        # build angles backwards from the gearbox output at 0
        tw23 = -(T1 + T2) / o.k2
        tw12 = -T1 / o.k1
        th2 = tw23
        th1 = th2 + tw12
        for j in range(n + 1):
            q[j] = th1 - tw12 * j / n
            q[n + j] = th2 - tw23 * j / n
        Tdel = T1 + T2
        if s.backlash:
            # rotor ahead of output by the gap plus the mesh deflection
            q[s.irot] = s.half_gap + Tdel / s.k_mesh if Tdel >= 0 else -s.half_gap + Tdel / s.k_mesh
            q[s.irot] = q[s.i3] + q[s.irot]
        x[:nb] = q
        x[nb:2 * nb] = w0
        if o.ideal_drive is None:
            wm = o.eta * w0
            i = (Tdel / o.eta + o.Tf * math.tanh(wm / (o.eta * o.v_t)) + o.Cm * wm) / o.KT
            V = o.R * i + o.KE * wm
            x[2 * nb] = i
            x[2 * nb + 1] = V / o.ki
        return x

    def reset(self, omega_ref: Optional[float] = None, n1: Optional[float] = None,
              n2_cmd: Optional[float] = None) -> dict:
        """Power the rig on at t = 0 and return the measurements at t = 0.

        Parameters
        ----------
        omega_ref, n1, n2_cmd : float, optional
            First commands, used as the initial speed/forces when the
            corresponding ``initial_*`` options are None.

        Returns
        -------
        dict
            Measured channels (see ``step``).
        """
        self.rng = np.random.default_rng(self.seed)
        self.t = 0.0
        self.k = 0
        self._h = None
        self._ode = None
        x = self._initial_state(omega_ref, n1, n2_cmd)
        self.x = x
        self._u = (0.0 if omega_ref is None else float(omega_ref), self._n1_prev, 0.0)
        self._q0 = x[:self.s.nb].copy()
        if self.opt.ideal_drive is not None:
            self._u = (self.x[self.s.nb + self.s.drive_body], self._n1_prev, 0.0)
        self._prev_q = None
        self._hist = []
        self.nfev = 0
        return self._sample()

    def _true_torques(self):
        """True reaction and electromagnetic torques at the current state."""
        o = self.opt
        s = self.s
        nb = s.nb
        x = self.x
        dx, _, tau = self._rhs_jac(self.t, x, False)
        a, b, k, d = s.link3 if s.drive_body is None else self._drive_link()
        q = x[:nb]
        v = x[nb:2 * nb]
        if s.drive_body is None:
            # link3 joins the last shaft node (a) to the gearbox output (b).
            # The torque the flange delivers into the shaft also accelerates
            # the shaft inertia lumped on body b (shaft_elements > 1), which is
            # not part of the floating assembly.
            acc = dx[nb:2 * nb]
            own = o.gear_output_inertia if s.backlash else o.eta ** 2 * o.Jm
            t_del = k * (q[b] - q[a]) + d * (v[b] - v[a]) + (s.J[b] - own) * acc[b]
            t_react = t_del + o.Jm * o.eta * acc[s.irot]
            if s.backlash:
                t_react += o.gear_output_inertia * acc[s.i3]
            t_em = o.eta * o.KT * x[2 * nb]
        else:
            t_del = k * (q[b] - q[a]) + d * (v[b] - v[a])
            t_react = t_em = t_del
        return t_del, t_react, t_em

    def _drive_link(self):
        s = self.s
        for (a, b, k, d) in s.links:
            if b == s.drive_body:
                return a, b, k, d
        raise RuntimeError("no link into the drive body")

    def _sample(self) -> dict:
        """Sample the DAQ at the current time; return delayed channels."""
        o = self.opt
        s = self.s
        nb = s.nb
        x = self.x
        rel = x[:nb] - self._q0
        tick = self._tick
        th1 = math.floor(rel[s.i1] / tick) * tick
        th2 = math.floor(rel[s.i2] / tick) * tick
        th3 = math.floor(o.eta * rel[s.irot] / tick) * tick / o.eta
        thq = (th1, th2, th3)
        if self._prev_q is None:
            om = (0.0, 0.0, 0.0)
        else:
            om = tuple((a - b) / o.dt for a, b in zip(thq, self._prev_q))
        self._prev_q = thq
        _, t_react, t_em = self._true_torques()
        t_true = t_react if o.torque_definition == "reaction" else t_em
        noise = self.rng.standard_normal(3)
        meas = {
            "theta1": th1, "theta2": th2, "theta3": th3,
            "omega1": om[0], "omega2": om[1], "omega3": om[2],
            "motor_torque": o.torque_gain * t_true + o.torque_offset + o.torque_noise * noise[0],
            "n1": o.n1_gain * self._u[1] + o.n1_offset + o.n1_noise * noise[1],
            "n2": o.n2_gain * x[2 * nb + 2] + o.n2_offset + o.n2_noise * noise[2],
        }
        self._hist.append(meas)
        out = {"t": self.t}
        k = len(self._hist) - 1
        for ch in CHANNELS:
            out[ch] = self._hist[max(k - self._delay[ch], 0)][ch]
        return out

    # ----------------------------------------------------------------- public
    def _step_odepack(self, x, t0, t1):
        if self._ode is None:
            self._ode = ode(self._fun, self._jac)
            self._ode.set_integrator("lsoda", rtol=self._rtol, atol=self._atol,
                                     nsteps=1000000)
        r = self._ode
        r.set_initial_value(x, t0)
        y = r.integrate(t1)
        if not r.successful():
            raise RuntimeError("integration failed at t=%.4f (LSODA status %s)"
                               % (t0, r.get_return_code()))
        return np.array(y, dtype=float)

    def _step_ivp(self, x, t0, t1):
        kw = dict(rtol=self._rtol, atol=self._atol, jac=self._jac)
        if self._h is not None:
            kw["first_step"] = min(self._h, t1 - t0)
        solver = self._solver_cls(self._fun, t0, x, t1, **kw)
        hmax = 0.0
        while solver.status == "running":
            tb = solver.t
            msg = solver.step()
            if solver.status == "failed":
                raise RuntimeError("integration failed at t=%.4f: %s" % (solver.t, msg))
            h = getattr(solver, "h_abs", None)
            if solver.status == "running" and h is not None:
                hmax = max(hmax, h)      # proposal after an untruncated step
            else:
                hmax = max(hmax, solver.t - tb)
        if hmax > 0:
            # next sample starts with the step size the solver was using
            self._h = max(1.2 * hmax, 1e-7)
        return solver.y.copy()

    def step(self, omega_ref_cmd: float, n1: float, n2_cmd: float) -> dict:
        """Advance one DAQ sample with the commands held.

        Parameters
        ----------
        omega_ref_cmd : float
            Speed reference of the drive [rad/s, disc side].
        n1 : float
            Normal force on the R1 pin [N] over the interval.
        n2_cmd : float
            Servo force command for the R2 pin [N].

        Returns
        -------
        dict
            ``t`` [s] (the new sample time) and the measured channels
            ``theta1, theta2, theta3`` [rad], ``omega1, omega2, omega3``
            [rad/s], ``motor_torque`` [N m], ``n1, n2`` [N].
        """
        o = self.opt
        s = self.s
        nb = s.nb
        self._u = (float(omega_ref_cmd), float(n1), float(n2_cmd))
        x = self.x.copy()
        if o.ideal_drive is not None:
            x[nb:2 * nb][s.kin] = omega_ref_cmd
        t0 = self.t
        t1 = (self.k + 1) * o.dt
        if self._solver_cls is None:
            x1 = self._step_odepack(x, t0, t1)
        else:
            x1 = self._step_ivp(x, t0, t1)
        self.x = x1
        self.k += 1
        self.t = t1
        return self._sample()

    def truth(self) -> dict:
        """True state at the current sample time.

        Returns
        -------
        dict
            ``t``; absolute angles ``theta1, theta2, theta3`` [rad] (zero =
            R3 at t = 0; ``theta3`` is the gearbox output); speeds
            ``omega1..3``; ``twist12 = theta1 - theta2``, ``twist23 = theta2 -
            theta3``; ``theta_rotor, omega_rotor`` (disc side; equal to R3
            without backlash); ``current`` [A], ``voltage`` [V], ``pi_state``;
            ``n1, n2`` (true forces [N]); ``friction1, friction2`` [N m];
            ``torque_delivered, torque_reaction, torque_em`` [N m];
            ``shaft_nodes`` (all body angles).
        """
        o = self.opt
        s = self.s
        nb = s.nb
        x = self.x
        q = x[:nb]
        v = x[nb:2 * nb]
        t_del, t_react, t_em = self._true_torques()
        f1 = self._fric(v[s.i1], self.t)[0]
        f2 = self._fric(v[s.i2], self.t)[0]
        if o.ideal_drive is None:
            volt = self._motor(x, self._u[0])[2]
        else:
            volt = 0.0
        return {
            "t": self.t,
            "theta1": q[s.i1], "theta2": q[s.i2], "theta3": q[s.i3],
            "omega1": v[s.i1], "omega2": v[s.i2], "omega3": v[s.i3],
            "twist12": q[s.i1] - q[s.i2], "twist23": q[s.i2] - q[s.i3],
            "theta_rotor": q[s.irot], "omega_rotor": v[s.irot],
            "current": x[2 * nb], "pi_state": x[2 * nb + 1], "voltage": volt,
            "n1": self._u[1], "n2": x[2 * nb + 2],
            "friction1": self._u[1] * o.r1 * f1, "friction2": x[2 * nb + 2] * o.r2 * f2,
            "torque_delivered": t_del, "torque_reaction": t_react, "torque_em": t_em,
            "shaft_nodes": q.copy(),
        }
