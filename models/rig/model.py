"""The builder: one :class:`RigModel` from any rig description, as named CasADi Functions.

The model is written in *twist coordinates*: a state for the twist of every spring
(``twist_<connection>`` = angle of ``between[0]`` minus angle of ``between[1]`` [rad]), the
speed of every body (``omega_<body>`` [rad/s]) and the drive's states (a DC motor's armature
``current`` [A] and its PI loop's integral ``pi_integral`` [rad]).  No absolute angle is a
state, so nothing drifts; the plant tracks the angle of one reference node (the drive
body, or a speed drive) for the encoders.

Equations, for body ``b`` with inertia ``J_b`` (plus ``ratio^2 Jm`` if the DC motor drives it
and the inertia a contact adds)::

    J_b w_b' = sum over connections c of +-(k_c dz(phi_c) + d_c (w_a - w_b))    (+ on b, - on a)
             + sum of contact friction torques on b
             + T_em  (DC motor:  ratio (KT i - Tf tanh(ratio w_b / eps_m) - Cm ratio w_b))
             + u_drive  (torque drive)
    phi_c'   = w_a - w_b                      (a speed drive's node turns at its input speed)
    L i'     = V - R i - KE ratio w_b,  V = sat(G (kp (w_ref - w_b) + ki z)),  z' = w_ref - w_b

with ``G = ratio`` when the PI acts on the motor-side error (``pi_error = "motor"``), ``dz`` the
backlash dead zone, and ``sat`` the supply-voltage limit and the drive's current limit
(``v_max``, ``i_max``; see :meth:`models.rig.drives.DCMotor.motor_voltage`).  The drive's terms come from
its kind (:mod:`models.rig.drives`).

The rest of the workbench uses the same interface for every rig:

- ``dynamics(x, u, P, Tc, s)``: state derivative for given contact torques ``Tc`` (one per
  contact body) and sliding directions ``s``;
- ``contact_friction(i, v, u, P, eps=None, s=...)``: friction on contact body ``i``, the exact
  law sliding in direction ``s`` at speed ``v >= 0``, or regularised with ``eps`` at signed ``v``;
  ``contact_inertia(i, x, u, P, s)``;
- ``ode(eps)``: the regularised model as a named Function ``xdot = f(x, u, p)``;
- ``outputs(x, u, P, theta_ref)``: what every sensor reads without noise, quantisation or
  delay (its gain and offset applied), plus physical quantities (twists, friction torques).
"""

from __future__ import annotations

import re
from functools import cached_property

import casadi as ca
import numpy as np

from models import friction as fr
from models.errors import ConfigError
from models.params import ParameterSet, Spec
from models.rig import steady
from models.rig.drives import drive_of
from models.rig.friction_states import FrictionStates
from models.rig.outputs import RigOutputs
from models.rig.spec import NODE_DRIVE, NODE_GROUND, RigSpec, SI_UNITS

__all__ = ["RigModel"]


def _sym(x) -> bool:
    return isinstance(x, (ca.SX, ca.MX, ca.DM))


def _dead_zone(phi, half):
    """``phi - clip(phi, -half, half)``: the twist a spring with backlash ``2 half`` actually feels."""
    if _sym(phi) or _sym(half):
        return phi - ca.fmin(ca.fmax(phi, -half), half)
    return phi - min(max(phi, -half), half)


class RigModel(RigOutputs, FrictionStates):
    """A rig built from a :class:`models.rig.spec.RigSpec` (see module docstring).

    Attributes
    ----------
    name : the rig's name; key : how it was picked (shipped name or resolved file path)
    states, state_units, inputs, input_units : names and SI units
    contacts : indices (into ``states``) of the speeds of the bodies that carry friction
    contact_bodies : those bodies' names; contact_names : the contacts on each of them
    measured : the log channels the rig's sensors write, then its inputs
    param_names : the parameter vector's order
    """

    #: the friction regularisation [rad/s, or m/s on a linear contact] of :meth:`ode` and of the
    #: modal analysis, the regularised simulation and the integration's rates when none is given:
    #: 0.05 rad/s on rig3 (30 rpm), carried to another rig by its nominal speed
    #: (:func:`models.rig.steady.by_speed`): a field string at 0.5 rad/s gets 0.008 rad/s, a friction
    #: bench at 1e-4 m/s 1.6e-6 m/s, not rig3's number, which would smooth their whole stick-slip
    EPS_RIG3 = 0.05

    @property
    def eps_default(self) -> float:
        """The rig's default friction regularisation (:data:`EPS_RIG3` carried by the nominal speed)."""
        return steady.by_speed(self.EPS_RIG3, self)

    def __init__(self, spec: RigSpec, key: str = ""):
        self.spec = spec
        self.name = spec.name
        #: the name as a C identifier (CasADi Function names are compiled)
        self.cname = re.sub(r"\W", "_", spec.name) if re.match(r"^[A-Za-z_]", spec.name) else "rig_" + re.sub(r"\W", "_", spec.name)
        self.key = key or spec.name
        self.description = spec.description
        self._springs = tuple(c for c in spec.connections if c.stiffness is not None)
        self._bodies = spec.body_names
        #: the drive (:mod:`models.rig.drives`): every question about it is asked there
        self.drive = drive_of(spec.drive)
        self.drive_body = spec.drive.body
        twist = tuple(f"twist_{c.name}" for c in self._springs)
        speeds = tuple(f"omega_{b}" for b in self._bodies)
        # a friction law's own states (LuGre's bristles, rate-and-state's contact age), after the speeds
        # and before the drive's states
        laws = {c.name: fr.get_law(c.law) for c in spec.contacts}
        fstates, funits, self._fstate = [], [], {}
        for c in spec.contacts:
            idx = []
            for q in laws[c.name].states:
                idx.append(len(twist) + len(speeds) + len(fstates))
                fstates.append(f"{q.name}_{c.name}")
                funits.append(SI_UNITS[q.kind])
            if idx:
                self._fstate[c.name] = tuple(idx)
        self.states = twist + speeds + tuple(fstates) + tuple(s.name for s in self.drive.states)
        self.state_units = ("rad",) * len(twist) + ("rad/s",) * len(speeds) + tuple(funits) \
            + tuple(s.unit for s in self.drive.states)
        self.inputs = spec.inputs
        self.input_units = tuple(SI_UNITS[spec.input_kind(n)] for n in self.inputs)
        self.input_kinds = tuple(spec.input_kind(n) for n in self.inputs)
        self.param_names = spec.param_names
        self._n_tw = len(twist)
        self._speed_index = {b: self._n_tw + j for j, b in enumerate(self._bodies)}
        # contacts grouped by body (each body with friction is one "contact" of the exact plant)
        groups: dict[str, list] = {}
        for c in spec.contacts:
            groups.setdefault(c.body, []).append(c)
        self.contact_bodies = tuple(groups)
        self._contact_groups = tuple(tuple(groups[b]) for b in self.contact_bodies)
        self.contact_names = tuple(tuple(c.name for c in g) for g in self._contact_groups)
        self.contacts = tuple(self._speed_index[b] for b in self.contact_bodies)
        self._laws = laws
        for b, g in zip(self.contact_bodies, self._contact_groups):
            kinds = {laws[c.name].stateful for c in g}
            if len(kinds) > 1:
                raise ConfigError(f"{spec.name}: body {b!r} has contacts with and without friction states "
                                  f"({', '.join(f'{c.name}: {c.law}' for c in g)}); a body's contacts must all be "
                                  f"laws with state or all memoryless")
        #: contact bodies (indices into ``contacts``) whose laws have states: smooth models of stick
        #: themselves (presliding, creep), never held at rest by the exact plant
        self.stateful_contacts = tuple(i for i, g in enumerate(self._contact_groups)
                                       if any(laws[c.name].stateful for c in g))
        self._ang_path = self._angle_paths()
        self.sensors = spec.sensors
        chans = []
        for s in spec.sensors:
            chans.extend(s.channels)
        self.measured = tuple(dict.fromkeys(tuple(chans) + self.inputs))
        self.actuators = spec.actuators
        self.objective_body = spec.extra.get("objective_body") or (self.contact_bodies[0] if self.contact_bodies
                                                                    else self._bodies[0])

    # ------------------------------------------------------------------ structure
    def __reduce__(self):
        # CasADi Functions are rebuilt on demand: a model pickles as its spec (worker processes)
        return (RigModel, (self.spec, self.key))

    def __repr__(self) -> str:
        return f"RigModel({self.name!r}: {len(self._bodies)} bodies, {len(self.states)} states, inputs {self.inputs})"

    @property
    def nx(self) -> int:
        return len(self.states)

    @property
    def nu(self) -> int:
        return len(self.inputs)

    @property
    def n_p(self) -> int:
        return len(self.param_names)

    @property
    def bodies(self) -> tuple[str, ...]:
        return self._bodies

    @property
    def springs(self) -> tuple[str, ...]:
        return tuple(c.name for c in self._springs)

    def speed_index(self, body: str) -> int:
        """Index of ``omega_<body>`` in the state."""
        try:
            return self._speed_index[body]
        except KeyError:
            raise ConfigError(f"{self.name}: no body {body!r} (bodies: {', '.join(self._bodies)})") from None

    @property
    def drive_kind(self) -> str:
        """The drive's kind, by name (for messages; ask :attr:`drive` what it does)."""
        return self.drive.kind

    @property
    def drive_node(self) -> str:
        """The node whose speed is the drive's: the drive body, or ``"drive"`` for a drive that
        prescribes a speed."""
        return self.drive.node

    @property
    def drive_input(self) -> str:
        """The drive's input: a speed set-point (DC motor), a prescribed speed, or a torque."""
        return self.spec.drive.input

    @cached_property
    def servo_inputs(self) -> tuple[str, ...]:
        """Inputs set through a servo (normal forces a controller can modulate)."""
        return tuple(a.input for a in self.actuators)

    @cached_property
    def commands(self) -> tuple[str, ...]:
        """Inputs a controller may set: the drive's input, then every servo's (asked on every control
        call: computed once, the rig's spec does not change)."""
        return (self.drive_input,) + self.servo_inputs

    def actuator(self, input_name: str):
        """The actuator spec that sets ``input_name``, or None."""
        return next((a for a in self.actuators if a.input == input_name), None)

    def contact_of_input(self, input_name: str):
        """The contact whose normal force is the input ``input_name``, or None."""
        return next((c for c in self.spec.contacts if c.normal is not None and c.normal.kind == "input"
                     and c.normal.name == input_name), None)

    def speed_channel(self, body: str) -> str | None:
        """The log channel that measures ``body``'s speed (an encoder's or a speed sensor's), or None."""
        for s in self.sensors:
            if s.target == body and s.kind in ("encoder", "speed"):
                return s.channels[-1]
        return None

    def angle_channel(self, body: str) -> str | None:
        """The encoder channel of ``body``'s angle, or None."""
        for s in self.sensors:
            if s.target == body and s.kind == "encoder":
                return s.channels[0]
        return None

    def sensor_of(self, channel: str):
        """The sensor spec that writes ``channel``, or None."""
        return next((s for s in self.sensors if channel in s.channels), None)

    def channel_body(self, channel: str) -> str | None:
        """The body (or "drive") an encoder or speed channel belongs to, else None."""
        s = self.sensor_of(channel)
        return s.target if s is not None and s.kind in ("encoder", "speed") else None

    @cached_property
    def _published(self) -> ParameterSet:
        specs = {p.name: Spec(p.unit, p.lower, p.upper, p.source, p.doc, p.positive, p.kind)
                 for p in self.spec.parameters}
        return ParameterSet(self.key, specs, {p.name: p.value for p in self.spec.parameters})

    def published(self) -> ParameterSet:
        """The parameter set as the rig file gives it (each value's provenance in its ``source``)."""
        return self._published

    @property
    def values_label(self) -> str:
        """How outputs name :meth:`published`: ``"the rig file's values (<rig name>)"``.  They are the
        user's own design values unless a parameter's ``source`` cites a publication (rig3's "thesis
        Table 3.1"): outputs that list parameters show that source, never "published" for all."""
        return f"the rig file's values ({self.name})"

    def check_params(self, params: ParameterSet, what: str = "params") -> ParameterSet:
        """``params`` if it belongs to this rig (same names), else a one-line ConfigError."""
        if not isinstance(params, ParameterSet) or params.names() != self.param_names:
            got = params.model if isinstance(params, ParameterSet) else type(params).__name__
            raise ConfigError(f"{what} must be a parameter set of rig {self.name!r}, got {got!r}")
        return params

    def unpack(self, p) -> dict:
        """Parameter vector -> dict of named (symbolic or numeric) entries."""
        return {n: p[i] for i, n in enumerate(self.param_names)}

    # ------------------------------------------------------------------ pieces of the dynamics
    def _u_named(self, u) -> dict:
        return {n: u[i] for i, n in enumerate(self.inputs)}

    def _node_speed(self, node: str, x, u_named):
        if node == NODE_GROUND:
            return 0.0
        if node == NODE_DRIVE:
            return u_named[self.spec.drive.input]
        return x[self._speed_index[node]]

    def connection_torque(self, c, x, u_named, P):
        """Torque connection ``c`` exerts on ``between[1]`` (minus that on ``between[0]``) [N m]."""
        T = 0.0
        wa, wb = self._node_speed(c.a, x, u_named), self._node_speed(c.b, x, u_named)
        if c.stiffness is not None:
            phi = x[self._springs.index(c)]
            if c.backlash is not None:
                phi = _dead_zone(phi, 0.5 * c.backlash.value(P, u_named))
            T = T + c.stiffness.value(P, u_named) * phi
        if c.damping is not None:
            T = T + c.damping.value(P, u_named) * (wa - wb)
        return T

    @property
    def current_index(self) -> int | None:
        """Index of the drive's fast state (a DC motor's armature current) in the state, or None."""
        name = self.drive.fast_state
        return None if name is None else self.drive.state_index(self, name)

    def quasi_static_current(self, x, u, P):
        """The drive's fast state with its own dynamics neglected (a DC motor's armature current with
        the inductance neglected, :meth:`models.rig.drives.DCMotor.quasi_static`): what it settles to
        when its time constant is far below the time scales of interest
        (:func:`models.discretise.integration`).  ``u`` in ``inputs`` order or named."""
        return self.drive.quasi_static(self, x, self._named_inputs(u), P)

    def electrical_time_constant(self, params) -> float:
        """The time constant of the drive's fast state [s] (a DC motor's ``L/R``; 0 for other drives)."""
        if self.drive.fast_state is None:
            return 0.0
        P = params if isinstance(params, dict) else dict(zip(self.param_names, np.asarray(
            params.vector() if hasattr(params, "vector") else params, float)))
        return self.drive.electrical_time_constant(P)

    def inertia(self, body: str, P) -> float:
        """The body's total inertia [kg m^2]: its own, plus what its drive adds (a DC motor's rotor
        reflected through the gearbox, ``ratio^2 Jm``; thesis eq. 3-3), without what a contact adds.

        Parameters
        ----------
        body : a body name
        P : parameter name -> value (symbolic or numeric), e.g. ``rig.unpack(p)`` or a ParameterSet
        """
        self.speed_index(body)
        J = self.spec.body(body).inertia.value(P)
        d = self.drive
        if d.geared and d.body == body:
            J = J + d.reflected_inertia(lambda r: r.value(P), d.spec)
        return J

    def _named_inputs(self, u):
        if u is None or isinstance(u, dict):
            return u
        return self._u_named(u)

    def contact(self, name: str):
        """The contact spec called ``name``."""
        for c in self.spec.contacts:
            if c.name == name:
                return c
        raise ConfigError(f"{self.name}: no contact {name!r} (contacts: "
                          f"{', '.join(c.name for c in self.spec.contacts) or 'none'})")

    def law(self, contact: str):
        """The friction law (:class:`models.friction.FrictionLaw`) of the contact ``contact``."""
        self.contact(contact)
        return self._laws[contact]

    def contact_args(self, contact, P, u=None) -> tuple:
        """``(N, r, law_params)`` of a contact: its normal force [N] (1 if it gives none), radius
        [m] (1 if none) and ``{law parameter: value}``, what :class:`models.friction.FrictionLaw`
        takes.

        Parameters
        ----------
        contact : a contact's name or its spec
        P : parameter name -> value (symbolic or numeric)
        u : the inputs, named (dict) or in ``inputs`` order; needed when the normal force is an input
        """
        c = self.contact(contact) if isinstance(contact, str) else contact
        un = self._named_inputs(u)
        N = c.normal.value(P, un) if c.normal is not None else 1.0
        r = c.radius.value(P, un) if c.radius is not None else 1.0
        LP = {k: ref.value(P, un) for k, ref in c.params}
        return N, r, LP

    def contact_friction(self, i: int, v, u, P, eps: float | None = None, *, s=None, factors=None, x=None):
        """Friction torque on contact body ``i`` [N m], the sum over its contacts.

        With ``eps`` the law's regularised torque at the signed speed ``v``
        (:meth:`models.friction.FrictionLaw.smooth`); without, the exact law sliding in direction
        ``s`` (+1/-1) at the speed ``v >= 0``.  A law with states takes them from the state ``x``
        (required then) and gives its dynamic torque at the signed speed (``v``, or ``s v``
        without ``eps``), whatever ``eps``.  ``factors`` ({contact name: factor}) scale single
        contacts' torques (estimators' friction-level states).
        """
        un = self._named_inputs(u)
        T = 0.0
        for c in self._contact_groups[i]:
            N, r, LP = self.contact_args(c, P, un)
            law = self._laws[c.name]
            if law.stateful:
                if x is None:
                    raise ConfigError(f"{self.name}: contact {c.name!r} (law {law.name!r}) has friction states; "
                                      f"contact_friction needs the state x")
                Tk = law.dynamic_torque(v if eps is not None else s * v, [x[j] for j in self._fstate[c.name]],
                                        N, r, LP)[0]
            else:
                Tk = law.smooth(v, N, r, LP, eps) if eps is not None else law.torque(v, s, N, r, LP)
            T = T + (factors[c.name] * Tk if factors and c.name in factors else Tk)
        return T

    def dynamics(self, x, u, P, Tc, s):
        """State derivative (list) for contact torques ``Tc`` and sliding directions ``s`` per contact body."""
        un = self._u_named(u)
        torque = {b: 0.0 for b in self._bodies}
        for c in self.spec.connections:
            T = self.connection_torque(c, x, un, P)
            if c.b in torque:
                torque[c.b] = torque[c.b] + T
            if c.a in torque:
                torque[c.a] = torque[c.a] - T
        for i, b in enumerate(self.contact_bodies):
            torque[b] = torque[b] + Tc[i]
        d = self.drive
        if d.on_body:
            torque[d.body] = torque[d.body] + d.torque(self, x, un, P)
        out = []
        for c in self._springs:
            out.append(self._node_speed(c.a, x, un) - self._node_speed(c.b, x, un))
        for b in self._bodies:
            J = self.inertia(b, P)
            if b in self.contact_bodies:
                i = self.contact_bodies.index(b)
                J = J + self._added_inertia(i, x, un, P, s[i])
            out.append(torque[b] / J)
        if self._fstate:
            out.extend(self.friction_state_rates(x, un, P))
        out.extend(d.rates(self, x, un, P))
        return out

    def _added_inertia(self, i, x, un, P, s):
        J = 0.0
        v_abs = ca.fabs(x[self.contacts[i]]) if _sym(x) else abs(x[self.contacts[i]])
        for c in self._contact_groups[i]:
            law = self._laws[c.name]
            if law.inertia is not None:
                N, r, LP = self.contact_args(c, P, un)
                J = J + law.added_inertia(v_abs, s, N, r, LP)
        return J

    def contact_inertia(self, i, x, u, P, s):
        b = self.contact_bodies[i]
        un = self._u_named(u)
        return self.inertia(b, P) + self._added_inertia(i, x, un, P, s)

    def ref_rate(self, x, u, P):
        """Speed of the reference node (the drive body, or a speed drive's input) [rad/s]."""
        un = self._u_named(u)
        return self._node_speed(self.spec.reference_node, x, un)

    # ------------------------------------------------------------------ CasADi Functions
    def _syms(self, kind=ca.SX):
        return kind.sym("x", self.nx), kind.sym("u", self.nu), kind.sym("p", self.n_p)

    def smooth_rhs(self, x, u, p, eps):
        P = self.unpack(p)
        Tc = [self.contact_friction(i, x[idx], u, P, eps, x=x) for i, idx in enumerate(self.contacts)]
        s = [fr.smooth_sign(x[idx], eps) for idx in self.contacts]
        return self.dynamics(x, u, P, Tc, s)

    def ode(self, eps: float | None = None) -> ca.Function:
        """Regularised model ``xdot = f(x, u, p)``, friction smoothed with ``eps`` [rad/s]
        (a law with its own regularisation, such as the lead screw's, uses that instead)."""
        eps = self.eps_default if eps is None else float(eps)
        if not eps > 0:
            raise ConfigError(f"eps must be > 0 rad/s, got {eps}")
        key = ("ode", eps)
        if key not in self._fcache:
            x, u, p = self._syms()
            xdot = ca.vertcat(*self.smooth_rhs(x, u, p, eps))
            self._fcache[key] = ca.Function(f"{self.cname}_ode", [x, u, p], [xdot], ["x", "u", "p"], ["xdot"])
        return self._fcache[key]

    @cached_property
    def _fcache(self) -> dict:
        return {}

    # ------------------------------------------------------------------ steady sliding (models.rig.steady)
    def nominal_speed(self) -> float:
        """:func:`models.rig.steady.nominal_speed`."""
        return steady.nominal_speed(self)

    def drive_speed_index(self) -> int | None:
        """:func:`models.rig.steady.drive_speed_index`."""
        return steady.drive_speed_index(self)

    def sliding_guess(self, u, params) -> np.ndarray:
        """:func:`models.rig.steady.sliding_guess`."""
        return steady.sliding_guess(self, u, params)

    def operating_point(self, speed: float, u, params) -> tuple[np.ndarray, np.ndarray]:
        """:func:`models.rig.steady.operating_point`."""
        return steady.operating_point(self, speed, u, params)

    def steady_sliding(self, u, params: ParameterSet, x0=None) -> np.ndarray:
        """:func:`models.rig.steady.steady_sliding`."""
        return steady.steady_sliding(self, u, params, x0)
