"""Rig description files: the TOML schema and the validated :class:`RigSpec` (read by
:func:`models.rig.parse.parse_rig`).

A rig file describes a torsional chain completely: its parameters (with units, bounds and
provenance), bodies, connections, friction contacts, drive, actuators and sensors.  The
builder (:mod:`models.rig.model`) turns a :class:`RigSpec` into CasADi Functions.  Every
error is one line naming the file and the field, e.g. ``"four_disc.toml: contacts.pin3.body:
no body 'D5' (bodies: D1, D2, D3, D4)"``.

Schema (see ``models/rigs/*.toml`` for complete examples)::

    [rig]
    name = "rig3"
    description = "..."

    [parameters]                       # named, unit-carrying parameters
    J1 = { value = 0.02888, unit = "kg m^2", source = "thesis Table 3.2", doc = "disc R1" }
    k1 = { value = 1.1175, unit = "N m/rad", min = 0, source = "thesis eq. 3-7" }

    [bodies.R1]
    inertia = "J1"                     # a parameter name, a number (SI) or "0.02888 kg m^2"

    [connections.shaft1]               # spring and/or damper between two nodes
    between = ["R1", "R2"]             # a body, "drive" (a speed drive) or "ground"
    stiffness = "k1"
    damping = "d1"
    backlash = 0.0                     # optional dead zone [rad] of the spring

    [contacts.pin1]                    # dry friction on a body
    body = "R1"
    law = "stribeck"                   # see models.friction.LAWS
    normal = "n1"                      # an input channel [N], or a parameter / value
    radius = "r1"
    mu_s = "mu_s"                      # the law's parameters
    mu_k = "mu_k"
    v_s = "v_s"

    [drive]                            # a kind of models.rig.drives.DRIVES: dc_motor, speed, torque
    kind = "dc_motor"
    body = "R3"
    input = "omega_ref"                # speed set-point [rad/s], output side of the gearbox
    pi_error = "disc"                  # the PI acts on the output-side error ("disc") or the motor's ("motor")
    L = "L"  ...  ratio = "eta"        # L, R, KT, KE, Tf, Cm, Jm, ratio, kp, ki; optional v_max, i_max

    [actuators.servo2]
    kind = "servo"
    input = "n2"                       # a contact's normal-force input
    n_min = "0 N"
    n_max = "40 N"
    rate_max = "200 N/s"
    tau = "50 ms"

    [sensors.enc1]
    kind = "encoder"                   # encoder | speed | torque | load_cell
    body = "R1"
    ticks = 1000
    angle = "theta1"                   # channel names in logs
    speed = "omega1"

A value may be a parameter name, a number (taken in SI units) or a quantity string
``"<number> <unit>"``.  Only named parameters can be freed by identification and varied by
sweeps; anonymous values are constants.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from models.errors import ConfigError

__all__ = ["Ref", "ParamDecl", "BodySpec", "ConnectionSpec", "ContactSpec", "DriveSpec", "ActuatorSpec",
           "SensorSpec", "RigSpec", "SI_UNITS", "SENSOR_KINDS", "NODE_DRIVE", "NODE_GROUND"]

#: prefix of the true-state columns a simulation writes (``true_twist_<connection>``, ``true_omega_<body>``);
#: a rig file may not name a sensor channel with it
TRUTH_PREFIX = "true_"

#: the SI unit shown for each quantity kind
SI_UNITS: dict[str, str] = {
    "inertia": "kg m^2", "stiffness": "N m/rad", "damping": "N m s/rad", "torque": "N m", "force": "N",
    "length": "m", "mass": "kg", "angle": "rad", "speed": "rad/s", "acceleration": "rad/s^2", "time": "s",
    "rate": "1/s", "slowness": "s/rad", "current": "A", "voltage": "V", "resistance": "ohm", "inductance": "H",
    "torque_constant": "N m/A", "voltage_constant": "V s/rad", "pi_kp": "V s/rad", "pi_ki": "V/rad",
    "force_rate": "N/s", "torque_rate": "N m/s", "viscous_torque": "N m s/rad", "dimensionless": "-",
    "per_angle": "1/rad",
}

SENSOR_KINDS = ("encoder", "speed", "torque", "load_cell")
NODE_DRIVE, NODE_GROUND = "drive", "ground"



# ----------------------------------------------------------------------------- data
@dataclass(frozen=True)
class Ref:
    """Where a numeric field of the rig gets its value: a named parameter, a constant (SI) or an input.

    Attributes
    ----------
    kind : "param" | "const" | "input"
    name : the parameter's or input's name
    constant : the value of a "const" reference (SI)
    """

    kind: str
    name: str = ""
    constant: float = 0.0

    @property
    def is_param(self) -> bool:
        return self.kind == "param"

    def value(self, P: Mapping, u: Mapping | None = None):
        """The value: ``P[name]`` for a parameter (symbolic or numeric), ``u[name]`` for an input,
        the constant otherwise.

        Parameters
        ----------
        P : parameter name -> value (e.g. :meth:`models.rig.RigModel.unpack` of a vector)
        u : input name -> value; needed only by input references (a contact's normal force)
        """
        if self.kind == "param":
            return P[self.name]
        if self.kind == "input":
            if u is None:
                raise ConfigError(f"the value of input {self.name!r} is needed here but no inputs were given")
            return u[self.name]
        return self.constant


@dataclass(frozen=True)
class ParamDecl:
    """A named parameter: SI value, quantity kind, bounds (SI), provenance."""

    name: str
    value: float
    kind: str
    unit: str
    lower: float
    upper: float
    positive: bool
    source: str = ""
    doc: str = ""


@dataclass(frozen=True)
class BodySpec:
    name: str
    inertia: Ref


@dataclass(frozen=True)
class ConnectionSpec:
    name: str
    a: str
    b: str
    stiffness: Ref | None
    damping: Ref | None
    backlash: Ref | None = None


@dataclass(frozen=True)
class ContactSpec:
    name: str
    body: str
    law: str
    normal: Ref | None
    radius: Ref | None
    params: tuple[tuple[str, Ref], ...]


@dataclass(frozen=True)
class DriveSpec:
    """The rig file's ``[drive]``: its kind (:data:`models.rig.drives.DRIVES`), input, body, parameters
    and the settings some kinds read (a DC motor's ``pi_error`` and motor-side friction smoothing
    [rad/s], a torque drive's ``torque_max``)."""

    kind: str
    input: str
    body: str = ""
    params: tuple[tuple[str, Ref], ...] = ()
    pi_error: str = "disc"
    eps_motor: float = 0.05
    #: a torque drive's torque limit [N m] (the plant clips its input to +-torque_max; inf: none)
    torque_max: float = float("inf")
    #: what the drive's input sets, "speed" or "torque" (the kind's ``setpoint``, filled by the parser:
    #: the spec itself knows no registry)
    setpoint: str = "speed"

    def param(self, name: str) -> Ref | None:
        return dict(self.params).get(name)


@dataclass(frozen=True)
class ActuatorSpec:
    name: str
    kind: str
    input: str
    n_min: float
    n_max: float
    rate_max: float
    tau: float


@dataclass(frozen=True)
class SensorSpec:
    """One sensor.  ``channels`` lists the log channels it writes (encoder: angle then speed)."""

    name: str
    kind: str
    target: str                 # body (encoder/speed), connection or "drive" (torque), contact (load cell)
    channels: tuple[str, ...]
    ticks: int = 0
    ratio: float = 1.0
    zero: str = "power_on"      # encoders: "power_on" (reads 0 at start) or "absolute"
    definition: str = ""        # torque at the drive: "reaction" | "electromagnetic"
    noise: float = 0.0          # standard deviation, SI
    offset: Ref | None = None
    gain: Ref | None = None
    delay: int = 0              # whole DAQ samples


@dataclass(frozen=True)
class RigSpec:
    """A validated rig description."""

    name: str
    description: str
    parameters: tuple[ParamDecl, ...]
    bodies: tuple[BodySpec, ...]
    connections: tuple[ConnectionSpec, ...]
    contacts: tuple[ContactSpec, ...]
    drive: DriveSpec
    actuators: tuple[ActuatorSpec, ...] = ()
    sensors: tuple[SensorSpec, ...] = ()
    path: str = ""
    reference_node: str = ""
    extra: Mapping[str, Any] = field(default_factory=dict)

    def body(self, name: str) -> BodySpec:
        return next(b for b in self.bodies if b.name == name)

    @property
    def body_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bodies)

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def param(self, name: str) -> ParamDecl:
        return next(p for p in self.parameters if p.name == name)

    @property
    def inputs(self) -> tuple[str, ...]:
        """Model inputs: the drive's, then each contact's normal-force input (file order)."""
        out = [self.drive.input] if self.drive.input else []
        for c in self.contacts:
            if c.normal is not None and c.normal.kind == "input" and c.normal.name not in out:
                out.append(c.normal.name)
        return tuple(out)

    def input_kind(self, name: str) -> str:
        return self.drive.setpoint if name == self.drive.input else "force"

    def with_changes(self, **changes) -> "RigSpec":
        import dataclasses
        return dataclasses.replace(self, **changes)
