"""What a rig's sensors read: absolute angles from the twists, every channel's noise-free
reading (gain and offset applied), the logged inputs corrected through load cells, and the
measurement Functions.  :class:`RigOutputs` is the measurement side of
:class:`models.rig.RigModel` (a mixin: the model's structure and dynamics are in
:mod:`models.rig.model`)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import casadi as ca

from models import friction as fr
from models.errors import ConfigError
from models.rig.spec import NODE_DRIVE

__all__ = ["RigOutputs", "DriveLoadSensor"]


@dataclass(frozen=True)
class DriveLoadSensor:
    """The torque sensor that tells the torque the string loads the drive with (:meth:`RigOutputs.drive_load_sensor`).

    Attributes
    ----------
    sensor : the sensor's spec (its ``channels[0]`` is the reading)
    sign : +1 or -1: ``T_string = sign * reading`` (a shaft's torque is positive while its first
        node drives its second, ``between = [a, b]``)
    at_drive : True for a sensor at the drive (``at = "drive"``: its reading also holds the drive's
        own inertia and, for a motor's electromagnetic torque, its losses); False for a flange in
        the shaft at the drive, which reads the string's torque itself
    """

    sensor: object
    sign: float
    at_drive: bool

    @property
    def channel(self) -> str:
        return self.sensor.channels[0]


class RigOutputs:
    """Angles, sensor readings and measurement Functions of a rig (see the module docstring)."""

    def _angle_paths(self) -> dict[str, list[tuple[int, float]]]:
        """For every node reachable by springs from the reference node: [(twist index, sign)] so
        that ``theta_node = theta_ref + sum(sign * twist)``."""
        ref = self.spec.reference_node
        adj: dict[str, list] = {}
        for j, c in enumerate(self._springs):
            adj.setdefault(c.a, []).append((c.b, j, -1.0))   # theta_b = theta_a - phi
            adj.setdefault(c.b, []).append((c.a, j, +1.0))   # theta_a = theta_b + phi
        paths = {ref: []}
        q = deque([ref])
        while q:
            n = q.popleft()
            for m, j, sgn in adj.get(n, []):
                if m not in paths:
                    paths[m] = paths[n] + [(j, sgn)]
                    q.append(m)
        return paths

    def angle(self, body: str, x, theta_ref):
        """Absolute angle of ``body`` from the reference angle and the twists [rad]."""
        th = theta_ref
        for j, sgn in self._ang_path[body]:
            th = th + sgn * x[j]
        return th

    def acceleration(self, x, u, P, body: str, eps: float | None = None):
        """``omega_<body>'`` of the regularised model (contact friction smoothed with ``eps``)."""
        eps = self.eps_default if eps is None else eps
        Tc = [self.contact_friction(i, x[idx], u, P, eps, x=x) for i, idx in enumerate(self.contacts)]
        s = [fr.smooth_sign(x[idx], eps) for idx in self.contacts]
        return self.dynamics(x, u, P, Tc, s)[self._speed_index[body]]

    def _ideal(self, s, x, u, P, theta_ref, un):
        """A sensor's ideal reading, before gain and offset."""
        if s.kind == "encoder":
            th = theta_ref if s.target == NODE_DRIVE else self.angle(s.target, x, theta_ref)
            return [th, self._node_speed(s.target, x, un)]
        if s.kind == "speed":
            return [self._node_speed(s.target, x, un)]
        if s.kind == "torque":
            if s.target == NODE_DRIVE:
                return [self.drive.torque_reading(self, s, x, u, un, P)]
            c = next(c for c in self.spec.connections if c.name == s.target)
            return [self.connection_torque(c, x, un, P)]
        c = next(c for c in self.spec.contacts if c.name == s.target)
        return [c.normal.value(P, un)]

    def outputs(self, x, u, P, theta_ref) -> dict:
        """Noise-free readings of every sensor channel (gain and offset applied), the inputs,
        and physical quantities: twists (state names), body speeds, friction torques
        (``friction_<contact>``, regularised), and the drive's own quantities (a DC motor's
        ``current``, ``voltage``, ``motor_speed`` and ``motor_torque_em``)."""
        un = self._u_named(u)
        out: dict = {}
        for s in self.sensors:
            vals = self._ideal(s, x, u, P, theta_ref, un)
            if s.offset is not None:
                vals = [s.gain.value(P, un) * v + s.offset.value(P, un) for v in vals]
            out.update(zip(s.channels, vals))
        for n in self.inputs:
            out.setdefault(n, un[n])
        for j, c in enumerate(self._springs):
            out[f"twist_{c.name}"] = x[j]
        for b in self._bodies:
            out[f"omega_{b}"] = x[self._speed_index[b]]
        for j in self.friction_states:
            out[self.states[j]] = x[j]
        out.update(self.drive.outputs(self, x, un, P))
        return out

    def input_from_measured(self, u_meas, P):
        """Model inputs from logged ones: a normal force logged through a load cell is corrected
        for the cell's gain and offset, ``N = (reading - offset) / gain``."""
        out = [u_meas[i] for i in range(self.nu)]
        for s in self.sensors:
            if s.kind in ("load_cell", "torque") and s.channels[0] in self.inputs:
                j = self.inputs.index(s.channels[0])
                out[j] = (out[j] - s.offset.value(P, {})) / s.gain.value(P, {})
        return out

    def output_units(self) -> dict[str, str]:
        """SI unit of every name :meth:`outputs` gives: a sensor channel takes its sensor's quantity
        (an encoder's angle and speed, a torque sensor's N m, a load cell's N), an input the unit of
        the quantity it drives (a drive's speed or torque, a contact's normal force in N), whatever
        the user named it."""
        units: dict[str, str] = {}
        for s in self.sensors:
            kinds = {"encoder": ("rad", "rad/s"), "speed": ("rad/s",), "torque": ("N m",),
                     "load_cell": ("N",)}[s.kind]
            units.update(zip(s.channels, kinds))
        for n, u in zip(self.inputs, self.input_units):
            units.setdefault(n, u)
        units.update(zip(self.states, self.state_units))
        units.update(self.drive.output_units())
        return units

    def output_names(self) -> tuple[str, ...]:
        """Names of :meth:`outputs` (the measurement Function's outputs)."""
        return tuple(self.meas().name_out())

    def meas(self) -> ca.Function:
        """Noise-free measurement function ``y = h(x, u, p, theta_ref)`` with named outputs.

        The outputs carry the channel names; the inputs are named ``in:x``, ``in:u``, ``in:p``,
        ``in:theta_ref`` so that no channel a user names (``u``, ``x``, ``p``, ``theta_ref`` are
        legal channel and input names) collides with them (CasADi refuses duplicate IO names)."""
        if "meas" not in self._fcache:
            x, u, p = self._syms()
            th = ca.SX.sym("theta_ref")
            out = self.outputs(x, u, self.unpack(p), th)
            self._fcache["meas"] = ca.Function(f"{self.cname}_meas", [x, u, p, th], [ca.SX(v) for v in out.values()],
                                               [f"in:{a}" for a in ("x", "u", "p", "theta_ref")], list(out.keys()))
        return self._fcache["meas"]

    def meas_vector(self, names) -> ca.Function:
        """``y = h(x, u, p)`` stacking the named outputs that need no absolute angle."""
        x, u, p = self._syms()
        out = self.outputs(x, u, self.unpack(p), ca.SX(0))
        missing = [n for n in names if n not in out]
        if missing:
            raise ConfigError(f"{self.name}: unknown output(s) {missing}; expected some of {list(out)}")
        return ca.Function(f"{self.cname}_h", [x, u, p], [ca.vertcat(*[out[n] for n in names])], ["x", "u", "p"], ["y"])

    def drive_load_sensor(self) -> "DriveLoadSensor | None":
        """The sensor of the torque the string loads the drive with, or None.

        A torque sensor at the drive (``at = "drive"``) comes first.  Otherwise an inline torque
        flange on the shaft that joins the drive to the string serves: the connection at the drive's
        node (the drive's body, or ``"drive"`` for a speed drive) when it is the only one there that
        is not to ``"ground"``; its reading is that torque itself, signed by the shaft's direction.
        A flange further down the string reads the torque beyond bodies whose inertia and friction
        the drive also carries: it does not serve (None).
        """
        from models.rig.spec import NODE_GROUND
        model = self
        for s in model.sensors:
            if s.kind == "torque" and s.target == NODE_DRIVE:
                return DriveLoadSensor(s, 1.0, True)
        node = model.drive_node
        at_node = [c for c in model.spec.connections if node in (c.a, c.b) and NODE_GROUND not in (c.a, c.b)]
        if len(at_node) != 1:
            return None
        (c,) = at_node
        for s in model.sensors:
            if s.kind == "torque" and s.target == c.name:
                return DriveLoadSensor(s, 1.0 if c.a == node else -1.0, False)
        return None
