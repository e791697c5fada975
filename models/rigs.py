"""Symbolic models of the rigs, as named CasADi Functions.

Every model is written in *twist coordinates*: the states hold angle differences across
springs and absolute speeds, never an absolute angle, so nothing drifts.  Friction acts
at *contacts*: a contact is a body whose speed is a state and on which a dry-friction
torque acts.  The model gives

- ``dynamics(x, u, p, Tc, s)``: the state derivative for given contact torques ``Tc``
  (and sliding directions ``s``, needed where the contact changes the inertia);
- ``contact_torque(i, v_abs, s, x, u, p)``: the friction torque on contact body ``i``
  when it slides in direction ``s`` (+1/-1) at speed ``v_abs >= 0``;
- ``contact_torque_smooth(i, v, x, u, p, eps)``: a regularised, signed version;
- ``contact_inertia(i, x, u, p, s)``: the inertia of body ``i``.

From these, :meth:`RigModel.ode` builds the regularised model for optimisers, and
:mod:`models.hybrid` builds the exact stick/slip plant step.

References
----------
- thesis Ch. 3 (3-disc rig, eqs. 3-3, 3-12, 3-13, Table 3.1)
- seed 001 eq. (1) (2-DOF rig)
- seed 002 eqs. (9.31), (9.33) (1-DOF lead-screw drive)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from models import friction as fr
from models.errors import ConfigError
from models.params import (
    DiscParams,
    LeadScrewParams,
    ParameterSet,
    Rig2Params,
    Rig3Params,
)

__all__ = ["RigModel", "Rig3Model", "Rig2Model", "LeadScrewModel", "DiscModel", "get_model", "MODEL_NAMES"]


class RigModel:
    """Base class of the rig models (see module docstring)."""

    name: str = ""
    param_cls: type[ParameterSet] = ParameterSet
    states: tuple[str, ...] = ()
    state_units: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    input_units: tuple[str, ...] = ()
    #: indices (into ``states``) of the speeds of the contact bodies
    contacts: tuple[int, ...] = ()
    #: index of the speed that drives the reference angle (for absolute encoder angles)
    ref_speed: str = ""
    #: default regularisation of the smooth model (transition speed [rad/s])
    eps_default: float = 0.05
    #: log channels measured on this rig (vocabulary of estimators.logs)
    measured: tuple[str, ...] = ()

    @property
    def nx(self) -> int:
        return len(self.states)

    @property
    def nu(self) -> int:
        return len(self.inputs)

    @property
    def n_p(self) -> int:
        return len(self.param_cls.names())

    def published(self) -> ParameterSet:
        return self.param_cls()

    def unpack(self, p) -> dict:
        """Parameter vector -> dict of named (symbolic or numeric) entries."""
        return {n: p[i] for i, n in enumerate(self.param_cls.names())}

    # --- to implement -------------------------------------------------------
    def dynamics(self, x, u, P, Tc, s):  # pragma: no cover - abstract
        raise NotImplementedError

    def contact_torque(self, i, v_abs, s, x, u, P):  # pragma: no cover - abstract
        raise NotImplementedError

    def contact_torque_smooth(self, i, v, x, u, P, eps):
        """Regularised friction torque on contact ``i`` (default: tanh of a symmetric law)."""
        mag = lambda va: -self.contact_torque(i, va, 1.0, x, u, P)  # noqa: E731
        return -fr.regularised(mag, v, eps, "tanh")

    def contact_inertia(self, i, x, u, P, s):  # pragma: no cover - abstract
        raise NotImplementedError

    def ref_rate(self, x, u, P):
        """Speed of the body whose absolute angle is tracked for encoders [rad/s]."""
        raise NotImplementedError

    def outputs(self, x, u, P, theta_ref) -> dict:
        """Ideal (noise-free) measurable quantities, keyed by the log vocabulary."""
        raise NotImplementedError

    # --- CasADi Functions -------------------------------------------------------
    def _syms(self, kind=ca.SX):
        x = kind.sym("x", self.nx)
        u = kind.sym("u", self.nu)
        p = kind.sym("p", self.n_p)
        return x, u, p

    def smooth_rhs(self, x, u, p, eps):
        P = self.unpack(p)
        Tc, s = [], []
        for i, idx in enumerate(self.contacts):
            v = x[idx]
            Tc.append(self.contact_torque_smooth(i, v, x, u, P, eps))
            s.append(fr.smooth_sign(v, eps))
        return self.dynamics(x, u, P, Tc, s)

    def ode(self, eps: float | None = None) -> ca.Function:
        """Regularised model ``xdot = f(x, u, p)`` with smoothing ``eps``.

        ``eps`` is the transition speed of the tanh regularisation [rad/s]
        (for the lead screw: the rate r1 of eq. 9.33 is a parameter, and ``eps``
        only smooths the sliding direction that enters the inertia).
        """
        eps = self.eps_default if eps is None else float(eps)
        if not eps > 0:
            raise ConfigError(f"eps must be > 0 rad/s, got {eps}")
        x, u, p = self._syms()
        xdot = self.smooth_rhs(x, u, p, eps)
        return ca.Function(f"{self.name}_ode", [x, u, p], [ca.vertcat(*xdot) if isinstance(xdot, list) else xdot],
                           ["x", "u", "p"], ["xdot"])

    def output_names(self) -> tuple[str, ...]:
        x, u, p = self._syms()
        return tuple(self.outputs(x, u, self.unpack(p), ca.SX.sym("th")).keys())

    def meas(self) -> ca.Function:
        """Ideal measurement function ``y = h(x, u, p, theta_ref)``, named outputs."""
        x, u, p = self._syms()
        th = ca.SX.sym("theta_ref")
        out = self.outputs(x, u, self.unpack(p), th)
        return ca.Function(f"{self.name}_meas", [x, u, p, th], list(out.values()),
                           ["x", "u", "p", "theta_ref"], list(out.keys()))

    def meas_vector(self, names) -> ca.Function:
        """``y = h(x, u, p)`` stacking the named outputs that do not need an absolute angle."""
        x, u, p = self._syms()
        out = self.outputs(x, u, self.unpack(p), ca.SX(0))
        missing = [n for n in names if n not in out]
        if missing:
            raise ConfigError(f"{self.name}: unknown output(s) {missing}; expected some of {list(out)}")
        return ca.Function(f"{self.name}_h", [x, u, p], [ca.vertcat(*[out[n] for n in names])],
                           ["x", "u", "p"], ["y"])

    def steady_sliding(self, u, params: ParameterSet, x0=None) -> np.ndarray:
        """Equilibrium of the regularised model for a constant input (steady sliding)."""
        f = self.ode()
        x = ca.SX.sym("x", self.nx)
        g = f(x, ca.DM(u), ca.DM(params.vector()))
        solver = ca.rootfinder("ss", "newton", ca.Function("g", [x], [g]), {"abstol": 1e-12})
        guess = self.sliding_guess(u, params) if x0 is None else x0
        return np.array(solver(ca.DM(guess))).ravel()

    def sliding_guess(self, u, params) -> np.ndarray:  # pragma: no cover - overridden
        return np.zeros(self.nx)


def _sgn_motor(v, eps):
    return ca.tanh(v / eps)


class Rig3Model(RigModel):
    """The 3-disc rig with DC motor, PI speed loop and 8:1 gearbox (thesis Ch. 3).

    States (twist coordinates, disc side of the gearbox)::

        phi12 = theta1 - theta2 [rad], phi23 = theta2 - theta3 [rad],
        omega1, omega2, omega3 [rad/s], i (armature current) [A], z = int(omega_ref - omega3) dt [rad]

    Inputs: ``omega_ref`` [rad/s] (disc side), ``n1`` and ``n2`` [N] (pin normal forces).

    Equations::

        J1 w1' = -k1 phi12 - d1 (w1 - w2) + Tc1
        J2 w2' =  k1 phi12 + d1 (w1 - w2) - k2 phi23 - d2 (w2 - w3) + Tc2
        J3 w3' =  k2 phi23 + d2 (w2 - w3) + eta (KT i - Tf sgn(eta w3) - Cm eta w3),  J3 = eta^2 Jm
        L i'   =  V - R i - KE eta w3,      V = kp (omega_ref - w3) + ki z
        z'     =  omega_ref - w3

    Contact torques ``Tc1``, ``Tc2`` follow the Stribeck law (3-13) with N1 r1 and N2 r2.
    The PI gains are applied to the disc-side speed error in rad/s with the output in V:
    the thesis gives them without units, so this is an assumption (README).
    """

    name = "rig3"
    param_cls = Rig3Params
    states = ("phi12", "phi23", "omega1", "omega2", "omega3", "i", "z")
    state_units = ("rad", "rad", "rad/s", "rad/s", "rad/s", "A", "rad")
    inputs = ("omega_ref", "n1", "n2")
    input_units = ("rad/s", "N", "N")
    contacts = (2, 3)
    eps_default = 0.05
    eps_motor = 0.05  # [rad/s, motor side] smoothing of the motor's own Coulomb friction Tf
    measured = ("theta1", "theta2", "theta3", "omega1", "omega2", "omega3", "motor_torque", "n1", "n2", "omega_ref")

    def dynamics(self, x, u, P, Tc, s):
        phi12, phi23, w1, w2, w3, i, z = (x[j] for j in range(7))
        wref = u[0]
        J3 = P["eta"] ** 2 * P["Jm"]
        T12 = P["k1"] * phi12 + P["d1"] * (w1 - w2)
        T23 = P["k2"] * phi23 + P["d2"] * (w2 - w3)
        wm = P["eta"] * w3
        Tmotor = P["eta"] * (P["KT"] * i - P["Tf"] * _sgn_motor(wm, self.eps_motor) - P["Cm"] * wm)
        V = P["kp"] * (wref - w3) + P["ki"] * z
        return [
            w1 - w2,
            w2 - w3,
            (-T12 + Tc[0]) / P["J1"],
            (T12 - T23 + Tc[1]) / P["J2"],
            (T23 + Tmotor) / J3,
            (V - P["R"] * i - P["KE"] * wm) / P["L"],
            wref - w3,
        ]

    def contact_torque(self, i, v_abs, s, x, u, P):
        N, r = (u[1], P["r1"]) if i == 0 else (u[2], P["r2"])
        return -s * N * r * fr.stribeck_exp(v_abs, P["mu_s"], P["mu_k"], P["v_s"])

    def contact_inertia(self, i, x, u, P, s):
        return P["J1"] if i == 0 else P["J2"]

    def ref_rate(self, x, u, P):
        return x[4]

    def outputs(self, x, u, P, theta_ref):
        wm = P["eta"] * x[4]
        return {
            "theta1": theta_ref + x[1] + x[0],
            "theta2": theta_ref + x[1],
            "theta3": theta_ref,
            "omega1": x[2],
            "omega2": x[3],
            "omega3": x[4],
            "motor_torque": P["eta"] * P["KT"] * x[5],
            "twist12": x[0],
            "twist23": x[1],
            "current": x[5],
            "voltage": P["kp"] * (u[0] - x[4]) + P["ki"] * x[6],
            "motor_speed": wm,
        }

    def sliding_guess(self, u, params):
        p = params
        w = float(u[0])
        T1 = float(u[1]) * p.r1 * (p.mu_k + (p.mu_s - p.mu_k) * np.exp(-abs(w) / p.v_s)) * np.sign(w)
        T2 = float(u[2]) * p.r2 * (p.mu_k + (p.mu_s - p.mu_k) * np.exp(-abs(w) / p.v_s)) * np.sign(w)
        phi12 = -T1 / p.k1
        phi23 = -(T1 + T2) / p.k2
        Tload = T1 + T2
        i = (Tload / p.eta + p.Tf * np.tanh(p.eta * w / self.eps_motor) + p.Cm * p.eta * w) / p.KT
        z = (p.R * i + p.KE * p.eta * w) / p.ki
        return np.array([phi12, phi23, w, w, w, i, z])


class Rig2Model(RigModel):
    """The 2-DOF motor + disc rig of seed 001, eq. (1), with motor torque as input.

    States: ``phi = theta_d - theta_m`` [rad], ``omega_d``, ``omega_m`` [rad/s].
    Input: ``motor_torque`` tau_m [N m].  Friction on the disc: Stribeck/Coulomb with
    ``Ts == Tc`` giving the regularised Coulomb law (4) of the seed.
    """

    name = "rig2"
    param_cls = Rig2Params
    states = ("phi", "omega_d", "omega_m")
    state_units = ("rad", "rad/s", "rad/s")
    inputs = ("motor_torque",)
    input_units = ("N m",)
    contacts = (1,)
    eps_default = 0.05
    measured = ("theta1", "theta3", "omega1", "omega3", "motor_torque")

    def dynamics(self, x, u, P, Tc, s):
        phi, wd, wm = x[0], x[1], x[2]
        Ts_ = P["k"] * phi + P["c"] * (wd - wm)
        return [
            wd - wm,
            (-Ts_ - P["cd"] * wd + Tc[0]) / P["Jd"],
            (Ts_ - P["cm"] * wm + u[0]) / P["Jm"],
        ]

    def contact_torque(self, i, v_abs, s, x, u, P):
        return -s * fr.stribeck_exp(v_abs, P["Ts"], P["Tc"], P["v_s"])

    def contact_inertia(self, i, x, u, P, s):
        return P["Jd"]

    def ref_rate(self, x, u, P):
        return x[2]

    def outputs(self, x, u, P, theta_ref):
        # the disc plays the role of R1 and the motor end the role of R3 in the log vocabulary
        return {
            "theta1": theta_ref + x[0],
            "theta3": theta_ref,
            "omega1": x[1],
            "omega3": x[2],
            "motor_torque": u[0],
            "twist": x[0],
        }

    def sliding_guess(self, u, params):
        p = params
        # steady sliding under constant torque: tau = Tc + (cd + cm) w
        w = max((float(u[0]) - p.Tc) / max(p.cd + p.cm, 1e-9), 0.0)
        return np.array([-(p.Tc + p.cd * w) / p.k, w, w])


class LeadScrewModel(RigModel):
    """The 1-DOF lead-screw drive of seed 002, eq. (9.31) with friction (9.33).

    States: ``phi = theta - theta_G`` [rad] (screw angle minus drive angle), ``omega``
    [rad/s] (screw speed).  Inputs: ``omega_drive`` = omega_G [rad/s] (gearbox output,
    prescribed), ``axial_force`` R [N].

    ``(I - tan(lam) xi m r_m^2) w' + K phi + c w = -r_m xi (R - F0 sgn w) - T0 sgn w``
    with ``xi = (mu s - tan lam) / (1 + mu s tan lam)`` and ``mu`` from (9.8) scaled by
    ``sm`` (9.33).  The zero-speed factor ``(1 - exp(-r1|w|))`` is the regularisation
    used by the smooth model; the exact plant uses the unsmoothed law, whose static
    level is ``sm (mu1 + mu2)``.
    """

    name = "leadscrew"
    param_cls = LeadScrewParams
    states = ("phi", "omega")
    state_units = ("rad", "rad/s")
    inputs = ("omega_drive", "axial_force")
    input_units = ("rad/s", "N")
    contacts = (1,)
    eps_default = 0.05
    measured = ("theta1", "theta_drive", "omega1", "axial_force")

    @staticmethod
    def _xi(mu_signed, P):
        t = ca.tan(P["lam"]) if isinstance(P["lam"], (ca.SX, ca.MX)) else np.tan(P["lam"])
        return (mu_signed - t) / (1 + mu_signed * t), t

    def _torque_from_mu(self, mu_signed, s, u, P):
        xi, _ = self._xi(mu_signed, P)
        return -P["r_m"] * xi * (u[1] - P["F0"] * s) - P["T0"] * s

    def contact_torque(self, i, v_abs, s, x, u, P):
        mu = fr.vahid_araghi(v_abs, P["mu1"], P["mu2"], P["mu3"], P["r0"], P["sm"])
        return self._torque_from_mu(s * mu, s, u, P)

    def contact_torque_smooth(self, i, v, x, u, P, eps):
        mag = lambda va: fr.vahid_araghi(va, P["mu1"], P["mu2"], P["mu3"], P["r0"], P["sm"])  # noqa: E731
        mu_signed = fr.regularised(mag, v, P["r1"], "vahid")
        s_soft = fr.regularised(lambda va: 1.0, v, P["r1"], "vahid")
        return self._torque_from_mu(mu_signed, s_soft, u, P)

    def contact_inertia(self, i, x, u, P, s):
        mu = fr.vahid_araghi(ca.fabs(x[1]) if isinstance(x, (ca.SX, ca.MX)) else abs(x[1]),
                             P["mu1"], P["mu2"], P["mu3"], P["r0"], P["sm"])
        xi, t = self._xi(s * mu, P)
        return P["I"] - t * xi * P["m"] * P["r_m"] ** 2

    def dynamics(self, x, u, P, Tc, s):
        phi, w = x[0], x[1]
        Ieff = self.contact_inertia(0, x, u, P, s[0])
        return [w - u[0], (-P["K"] * phi - P["c"] * w + Tc[0]) / Ieff]

    def ref_rate(self, x, u, P):
        return u[0]

    def outputs(self, x, u, P, theta_ref):
        return {
            "theta1": theta_ref + x[0],
            "theta_drive": theta_ref,
            "omega1": x[1],
            "omega_drive": u[0],
            "axial_force": u[1],
            "twist": x[0],
        }

    def sliding_guess(self, u, params):
        p = params
        w = float(u[0])
        mu = p.sm * (p.mu1 + p.mu2 * np.exp(-p.r0 * abs(w)) + p.mu3 * abs(w))
        t = np.tan(p.lam)
        s = np.sign(w) if w != 0 else 1.0
        xi = (s * mu - t) / (1 + s * mu * t)
        Tc = -p.r_m * xi * (float(u[1]) - p.F0 * s) - p.T0 * s
        return np.array([(Tc - p.c * w) / p.K, w])


class DiscModel(RigModel):
    """One disc on a torsional spring whose drive end turns at a prescribed speed.

    States: ``phi = theta1 - theta3`` [rad], ``omega1`` [rad/s].  Inputs: ``omega3``
    [rad/s] (drive end speed), ``n1`` [N].  ``J w' = -k phi - d (w - omega3) + Tc``,
    Stribeck friction (3-13) with ``n1 r``.  This is the model of the exact Coulomb
    stick-slip check and of logs where only the top and bottom speeds are measured.
    """

    name = "disc"
    param_cls = DiscParams
    states = ("phi", "omega1")
    state_units = ("rad", "rad/s")
    inputs = ("omega3", "n1")
    input_units = ("rad/s", "N")
    contacts = (1,)
    eps_default = 0.05
    measured = ("theta1", "theta3", "omega1", "omega3", "n1")

    def dynamics(self, x, u, P, Tc, s):
        phi, w = x[0], x[1]
        return [w - u[0], (-P["k"] * phi - P["d"] * (w - u[0]) + Tc[0]) / P["J"]]

    def contact_torque(self, i, v_abs, s, x, u, P):
        return -s * u[1] * P["r"] * fr.stribeck_exp(v_abs, P["mu_s"], P["mu_k"], P["v_s"])

    def contact_inertia(self, i, x, u, P, s):
        return P["J"]

    def ref_rate(self, x, u, P):
        return u[0]

    def outputs(self, x, u, P, theta_ref):
        return {
            "theta1": theta_ref + x[0],
            "theta3": theta_ref,
            "omega1": x[1],
            "omega3": u[0],
            "n1": u[1],
            "twist": x[0],
        }

    def sliding_guess(self, u, params):
        p = params
        w = float(u[0])
        T = float(u[1]) * p.r * (p.mu_k + (p.mu_s - p.mu_k) * np.exp(-abs(w) / p.v_s)) * np.sign(w)
        return np.array([-T / p.k, w])


_MODELS = {m.name: m for m in (Rig3Model, Rig2Model, LeadScrewModel, DiscModel)}
MODEL_NAMES = tuple(_MODELS)


def get_model(name: str) -> RigModel:
    """A model by name: "rig3", "rig2", "leadscrew" or "disc"."""
    try:
        return _MODELS[name]()
    except KeyError:
        raise ConfigError(f"model must be one of {', '.join(MODEL_NAMES)}, got {name!r}") from None
