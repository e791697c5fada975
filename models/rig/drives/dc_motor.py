"""A DC gear motor under its own PI speed loop (thesis Ch. 3: the ENGEL GNM 5480-G6.1 of rig3).

Its input is a speed set-point ``w_ref`` [rad/s] on the output side of the gearbox; it acts on its
body with the torque of its rotor through the gearbox, and adds two states, the armature current
``i`` [A] and the PI loop's integral ``z`` [rad]::

    T_em = ratio (KT i - Tf tanh(ratio w_b / eps_m) - Cm ratio w_b)
    L i' = V - R i - KE ratio w_b,   V = sat(G (kp (w_ref - w_b) + ki z)),   z' = w_ref - w_b

with ``G = ratio`` when the PI acts on the motor-side error (``pi_error = "motor"``, else 1), and
``sat`` the supply voltage ``v_max`` and the current limit ``i_max`` (:meth:`DCMotor.motor_voltage`).
The rotor adds ``ratio^2 Jm`` to the body (thesis eq. 3-3).
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from models.rig.drives.base import Drive, DriveField, DriveState

__all__ = ["DCMotor"]


def _sym(x) -> bool:
    return isinstance(x, (ca.SX, ca.MX, ca.DM))


class DCMotor(Drive):
    """A DC gear motor with its PI speed loop (module docstring)."""

    kind = "dc_motor"
    doc = "DC gear motor under its own PI speed loop (speed set-point, armature current, PI integral)"
    setpoint = "speed"
    on_body = True
    geared = True
    fields = (DriveField("L", "inductance", strict=True), DriveField("R", "resistance", strict=True),
              DriveField("KT", "torque_constant", strict=True), DriveField("KE", "voltage_constant"),
              DriveField("Tf", "torque"), DriveField("Cm", "damping"), DriveField("Jm", "inertia", strict=True),
              DriveField("ratio", "dimensionless", strict=True), DriveField("kp", "pi_kp"), DriveField("ki", "pi_ki"),
              DriveField("v_max", "voltage", required=False), DriveField("i_max", "current", required=False))
    keys = frozenset({"pi_error", "friction_smoothing"})
    states = (DriveState("current", "A", prior="current", noise="current", fast=True, doc="armature current"),
              DriveState("pi_integral", "rad", prior="pi", doc="the PI loop's integral of the speed error"))
    definitions = ("reaction", "electromagnetic")

    @classmethod
    def parse_settings(cls, table, ctx) -> dict:
        from models.rig.fields import number
        pi_error = table.get("pi_error", "disc")
        if pi_error not in ("disc", "motor"):
            raise ctx.err("drive.pi_error", f"must be 'disc' or 'motor', got {pi_error!r}")
        eps_m = number(table.get("friction_smoothing", 0.05), "drive.friction_smoothing", ctx)
        if not eps_m > 0:
            raise ctx.err("drive.friction_smoothing", f"must be > 0 rad/s (motor side), got {eps_m:g}")
        return {"pi_error": pi_error, "eps_motor": eps_m}

    @classmethod
    def reflected_inertia(cls, value, spec):
        eta, jm = value(spec.param("ratio")), value(spec.param("Jm"))
        return None if eta is None or jm is None else eta ** 2 * jm

    # ------------------------------------------------------------------ the motor
    def motor_voltage(self, model, x, u_named, P):
        """``(V, V_limited)``: the armature voltage of the PI loop, and the same limited by the supply
        and the current limit.

        ``V = G (kp e + ki z)`` with ``e = w_ref - w_b`` and ``G`` = 1 (PI on the output-side
        error) or ``ratio`` (on the motor's).  With ``v_max`` it is clipped to the supply; with
        ``i_max`` to ``R i_max + KE w_m`` above and ``-R i_max + KE w_m`` below, the voltage that
        holds the current at its limit in steady state (a current-limited drive).
        """
        d = self.spec
        wb = x[model.speed_index(d.body)]
        eta = d.param("ratio").value(P, u_named)
        G = eta if d.pi_error == "motor" else 1.0
        e = u_named[d.input] - wb
        z = x[model.nx - 1]
        V = G * (d.param("kp").value(P, u_named) * e + d.param("ki").value(P, u_named) * z)
        hi, lo = None, None
        vmax = d.param("v_max")
        if vmax is not None:
            hi, lo = vmax.value(P, u_named), -vmax.value(P, u_named)
        imax = d.param("i_max")
        if imax is not None:
            wm = eta * wb
            Rr, KE, im = d.param("R").value(P, u_named), d.param("KE").value(P, u_named), imax.value(P, u_named)
            ih, il = Rr * im + KE * wm, -Rr * im + KE * wm
            hi = ih if hi is None else ca.fmin(hi, ih)
            lo = il if lo is None else ca.fmax(lo, il)
        Vs = V
        if hi is not None:
            Vs = ca.fmin(ca.fmax(V, lo), hi)
        return V, Vs

    def motor_torque_em(self, model, x, u_named, P, *, friction: bool = True):
        """Torque the rotor delivers through the gearbox, output side [N m]:
        ``ratio (KT i - Tf tanh(w_m/eps_m) - Cm w_m)`` (``friction=False``: ``ratio KT i``)."""
        d = self.spec
        eta = d.param("ratio").value(P, u_named)
        i = x[model.nx - 2]
        T = eta * d.param("KT").value(P, u_named) * i
        if friction:
            wm = eta * x[model.speed_index(d.body)]
            tanh = ca.tanh if _sym(wm) or _sym(T) else np.tanh
            T = T - eta * (d.param("Tf").value(P, u_named) * tanh(wm / d.eps_motor)
                           + d.param("Cm").value(P, u_named) * wm)
        return T

    # ------------------------------------------------------------------ Drive
    def torque(self, model, x, un, P):
        return self.motor_torque_em(model, x, un, P)

    def rates(self, model, x, un, P) -> list:
        d = self.spec
        eta = d.param("ratio").value(P, un)
        wb = x[model.speed_index(d.body)]
        V, Vs = self.motor_voltage(model, x, un, P)
        e = un[d.input] - wb
        di = (Vs - d.param("R").value(P, un) * x[model.nx - 2] - d.param("KE").value(P, un) * eta * wb) \
            / d.param("L").value(P, un)
        if d.param("v_max") is not None or d.param("i_max") is not None:
            # anti-windup: the integral stops while the limit holds the voltage against the error
            sat = ca.logic_and(ca.fabs(V - Vs) > 1e-9, ca.sign(V - Vs) == ca.sign(e))
            e = ca.if_else(sat, 0, e)
        return [di, e]

    def quasi_static(self, model, x, un, P):
        """The armature current with the inductance neglected, ``i = (V - KE ratio w_b) / R`` [A]
        (``V`` the limited PI voltage): what ``L i' = V - R i - KE w_m`` settles to when ``L/R`` is
        far below the time scales of interest (:func:`models.discretise.integration`)."""
        d = self.spec
        _, Vs = self.motor_voltage(model, x, un, P)
        wm = d.param("ratio").value(P) * x[model.speed_index(d.body)]
        return (Vs - d.param("KE").value(P) * wm) / d.param("R").value(P)

    def electrical_time_constant(self, P) -> float:
        """``L/R`` [s]."""
        return float(self.spec.param("L").value(P)) / float(self.spec.param("R").value(P))

    def limit_refs(self):
        return tuple(r for r in (self.spec.param("v_max"), self.spec.param("i_max")) if r is not None)

    def project(self, model, x, u, P):
        """``x`` with the PI integral ``z`` clipped to ``sat(G ki z) / (G ki)``: the voltage limits at
        the state's motor speed, evaluated with zero speed error so that the voltage is the integral
        term alone.

        The anti-windup stops the integral while the limit holds the voltage against the error, so a
        drive that starts unsaturated never has ``G ki z`` beyond the limits (``z`` rises only while
        ``G (kp e + ki z) < hi`` with ``e > 0``, i.e. ``G ki z < hi``).  Beyond them the current no
        longer depends on ``z``: an estimator's correction that pushes ``z`` there leaves it
        unobservable for good (realistic rig3, one noise seed in three: ``z`` 0.06 rad in the plant,
        255 rad in the filter, which then explained the torque by a 30-fold friction and -26 rad of
        twist).
        """
        d = self.spec
        if d.param("v_max") is None and d.param("i_max") is None:
            return x
        nxr = model.nx
        xr = x[:nxr]
        un = {n: u[j] for j, n in enumerate(model.inputs)}
        un[d.input] = xr[model.speed_index(d.body)]     # zero error: V = G ki z
        V, Vs = self.motor_voltage(model, xr, un, P)
        z = xr[nxr - 1]
        zp = ca.if_else(ca.fabs(V) > 0, z * Vs / V, z)
        return ca.vertcat(x[:nxr - 1], zp, x[nxr:])

    # ------------------------------------------------------------------ readings
    def outputs(self, model, x, un, P) -> dict:
        d = self.spec
        eta = d.param("ratio").value(P, un)
        return {"current": x[model.nx - 2], "voltage": self.motor_voltage(model, x, un, P)[1],
                "motor_speed": eta * x[model.speed_index(d.body)],
                "motor_torque_em": self.motor_torque_em(model, x, un, P, friction=False)}

    def output_units(self) -> dict[str, str]:
        return {"current": "A", "voltage": "V", "motor_speed": "rad/s", "motor_torque_em": "N m"}

    def torque_reading(self, model, sensor, x, u, un, P):
        """``"electromagnetic"``: ``ratio KT i``; ``"reaction"`` (a load cell holding the free-mounted
        motor and gearbox): ``T_em - ratio (ratio - 1) Jm w_b'``."""
        if sensor.definition == "electromagnetic":
            return self.motor_torque_em(model, x, un, P, friction=False)
        d = self.spec
        eta, Jm = d.param("ratio").value(P, un), d.param("Jm").value(P, un)
        return self.motor_torque_em(model, x, un, P) - eta * (eta - 1) * Jm * model.acceleration(x, u, P, d.body)

    def pipe_torque_terms(self, model, sensor, P):
        """The electromagnetic torque ``ratio KT i`` reads ``T_pipe + (J_b + ratio^2 Jm) w' + ratio (Tf
        tanh(w_m/eps_m) + Cm w_m)``; the reaction load cell ``T_pipe + ratio Jm w'`` (its body's own
        inertia neglected: 0 on rig3, whose body is the gearbox output)."""
        d = self.spec
        eta, Jm = d.param("ratio").value(P), d.param("Jm").value(P)
        loss = self.pipe_torque_loss(model, sensor, P)
        if loss is not None:
            eta, Tf, Cm, eps = loss
            return model.inertia(d.body, P), lambda w: eta * (Tf * math.tanh(eta * w / eps) + Cm * eta * w)
        return eta * Jm, None

    def pipe_torque_loss(self, model, sensor, P):
        """The electromagnetic torque holds the motor's friction ``ratio (Tf tanh(ratio w / eps) + Cm
        ratio w)``: ``(ratio, Tf, Cm, eps)``; a reaction load cell holds none (None)."""
        if sensor.definition != "electromagnetic":
            return None
        d = self.spec
        return (float(d.param("ratio").value(P)), float(d.param("Tf").value(P)), float(d.param("Cm").value(P)),
                float(d.eps_motor))

    def torque_on_body(self, model, sensor, T, w, acc, P):
        if w is None:
            return None, None
        d = self.spec
        eta, Jm = float(d.param("ratio").value(P)), float(d.param("Jm").value(P))
        if sensor.definition == "electromagnetic":
            return T - eta * (float(d.param("Tf").value(P)) * np.tanh(eta * w / d.eps_motor)
                              + float(d.param("Cm").value(P)) * eta * w), None
        return T + eta * (eta - 1) * Jm * acc, T - eta * Jm * acc

    # ------------------------------------------------------------------ along a run: signals, limits and energy
    def signals(self, model, params, X, U) -> dict[str, np.ndarray]:
        """The armature ``current`` [A] (the state) and ``voltage`` [V] (the PI loop's, limited by the
        supply and the current limit: :meth:`motor_voltage`)."""
        X, U = np.asarray(X, float), np.asarray(U, float)
        i = X[:, self.state_index(model, "current")]
        if not X.shape[0]:
            return {"current": i, "voltage": np.zeros(0)}
        f = model.meas_vector(["voltage"])
        V = np.array(f.map(X.shape[0])(X.T, U.T, np.asarray(params.vector(), float)), float).ravel()
        return {"current": i, "voltage": V}

    def signal_units(self) -> dict[str, str]:
        return {"current": "A", "voltage": "V"}

    def limit(self, P) -> tuple[str, float] | None:
        """The armature current and ``i_max`` (None without one: a supply voltage ``v_max`` alone
        bounds the voltage the loop asks for, never more than the supply gives)."""
        lim = self.current_limit(P)
        return ("current", lim) if math.isfinite(lim) else None

    def current_limit(self, P) -> float:
        cur = self.spec.param("i_max")
        return float(cur.value(P)) if cur is not None else math.nan

    def power(self, model, params, X, U):
        """``V i``: the limited armature voltage times the current."""
        s = self.signals(model, params, X, U)
        return s["voltage"] * s["current"]
