"""Rig description files: the TOML schema, and its validation into a :class:`RigSpec`.

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

    [drive]                            # one of: dc_motor, speed, torque
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

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from models.errors import ConfigError
from models.units import DIMENSIONS, factor, parse_quantity

__all__ = ["Ref", "ParamDecl", "BodySpec", "ConnectionSpec", "ContactSpec", "DriveSpec", "ActuatorSpec",
           "SensorSpec", "RigSpec", "parse_rig", "SI_UNITS", "DRIVE_KINDS", "SENSOR_KINDS"]

#: the SI unit shown for each quantity kind
SI_UNITS: dict[str, str] = {
    "inertia": "kg m^2", "stiffness": "N m/rad", "damping": "N m s/rad", "torque": "N m", "force": "N",
    "length": "m", "mass": "kg", "angle": "rad", "speed": "rad/s", "acceleration": "rad/s^2", "time": "s",
    "rate": "1/s", "slowness": "s/rad", "current": "A", "voltage": "V", "resistance": "ohm", "inductance": "H",
    "torque_constant": "N m/A", "voltage_constant": "V s/rad", "pi_kp": "V s/rad", "pi_ki": "V/rad",
    "force_rate": "N/s", "torque_rate": "N m/s", "viscous_torque": "N m s/rad", "dimensionless": "-",
}

DRIVE_KINDS = ("dc_motor", "speed", "torque")
SENSOR_KINDS = ("encoder", "speed", "torque", "load_cell")
NODE_DRIVE, NODE_GROUND = "drive", "ground"

#: drive parameter -> (quantity kind, required, physical lower bound)
DC_MOTOR_FIELDS: dict[str, tuple[str, bool, float]] = {
    "L": ("inductance", True, 0.0), "R": ("resistance", True, 0.0), "KT": ("torque_constant", True, 0.0),
    "KE": ("voltage_constant", True, 0.0), "Tf": ("torque", True, 0.0), "Cm": ("damping", True, 0.0),
    "Jm": ("inertia", True, 0.0), "ratio": ("dimensionless", True, 0.0), "kp": ("pi_kp", True, 0.0),
    "ki": ("pi_ki", True, 0.0), "v_max": ("voltage", False, 0.0), "i_max": ("current", False, 0.0),
}

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


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
    kind: str
    input: str
    body: str = ""
    params: tuple[tuple[str, Ref], ...] = ()
    pi_error: str = "disc"
    eps_motor: float = 0.05

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
        if name == self.drive.input:
            return "torque" if self.drive.kind == "torque" else "speed"
        return "force"

    def with_changes(self, **changes) -> "RigSpec":
        import dataclasses
        return dataclasses.replace(self, **changes)


# ----------------------------------------------------------------------------- parsing helpers
class _Ctx:
    """Collects parameter declarations and the kinds their uses require."""

    def __init__(self, where: str, params: Mapping[str, Any]):
        self.where = where
        self.raw = params
        self.kinds: dict[str, tuple[str, str]] = {}   # param -> (kind, first use)
        self.inputs: dict[str, str] = {}             # input -> kind

    def err(self, field_: str, msg: str) -> ConfigError:
        sep = " " if msg.startswith(("must", "is ", "has ")) else ": "
        return ConfigError(f"{self.where}: {field_}{sep}{msg}")


def _table(data: Mapping, key: str, ctx: _Ctx, required: bool = False) -> Mapping:
    v = data.get(key)
    if v is None:
        if required:
            raise ctx.err(key, "missing section")
        return {}
    if not isinstance(v, Mapping):
        raise ctx.err(key, f"must be a table, got {type(v).__name__}")
    return v


def _check_keys(tab: Mapping, allowed, field_: str, ctx: _Ctx) -> None:
    for k in tab:
        if k not in allowed:
            raise ctx.err(f"{field_}.{k}", f"unknown key; expected one of {', '.join(sorted(allowed))}")


def _check_name(name: str, field_: str, ctx: _Ctx) -> None:
    if not isinstance(name, str) or not _NAME.match(name):
        raise ctx.err(field_, f"must be a name (letters, digits, _; not starting with a digit), got {name!r}")


def _number(v: Any, field_: str, ctx: _Ctx) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ctx.err(field_, f"must be a finite number, got {v!r}")
    return float(v)


def _value(v: Any, kind: str, field_: str, ctx: _Ctx, *, allow_input: bool = False) -> Ref:
    """Resolve a field value to a parameter, a constant (SI) or (if allowed) an input channel."""
    if isinstance(v, bool):
        raise ctx.err(field_, f"must be a number, a parameter name or a quantity, got {v!r}")
    if isinstance(v, (int, float)):
        if not math.isfinite(v):
            raise ctx.err(field_, f"must be finite, got {v!r}")
        return Ref("const", constant=float(v))
    if isinstance(v, str):
        q = parse_quantity(v)
        if q is not None:
            return Ref("const", constant=q[0] * factor(q[1] or "-", kind, f"{ctx.where}: {field_}"))
        if v in ctx.raw:
            prev = ctx.kinds.get(v)
            if prev is not None and prev[0] != kind and not {prev[0], kind} <= {"damping", "viscous_torque"}:
                raise ctx.err(field_, f"parameter {v!r} is a {prev[0].replace('_', ' ')} (used by {prev[1]}), "
                                      f"but here a {kind.replace('_', ' ')} is expected")
            ctx.kinds.setdefault(v, (kind, field_))
            return Ref("param", name=v)
        if allow_input:
            _check_name(v, field_, ctx)
            prev = ctx.inputs.get(v)
            if prev is not None and prev != kind:
                raise ctx.err(field_, f"input {v!r} is a {prev}, but here a {kind} is expected")
            ctx.inputs[v] = kind
            return Ref("input", name=v)
        raise ctx.err(field_, f"{v!r} is neither a [parameters] entry nor a quantity such as \"1.5 N m\"")
    raise ctx.err(field_, f"must be a number, a parameter name or a quantity string, got {type(v).__name__}")


def _const(ref: Ref | None, ctx: _Ctx, decl: Mapping[str, ParamDecl] | None = None) -> float | None:
    if ref is None:
        return None
    if ref.kind == "const":
        return ref.constant
    if ref.kind == "param" and decl is not None and ref.name in decl:
        return decl[ref.name].value
    return None


# ----------------------------------------------------------------------------- sections
def _parse_parameters(raw: Mapping, ctx: _Ctx) -> dict[str, ParamDecl]:
    out = {}
    for name, spec in raw.items():
        f = f"parameters.{name}"
        _check_name(name, f, ctx)
        if not isinstance(spec, Mapping):
            raise ctx.err(f, "must be a table { value = ..., unit = \"...\" }")
        _check_keys(spec, {"value", "unit", "min", "max", "positive", "source", "doc"}, f, ctx)
        if "value" not in spec:
            raise ctx.err(f"{f}.value", "missing field")
        if name not in ctx.kinds:
            raise ctx.err(f, "declared but not used by any body, connection, contact, drive or sensor")
        kind = ctx.kinds[name][0]
        unit = spec.get("unit")
        if unit is None:
            if kind != "dimensionless":
                raise ctx.err(f"{f}.unit", f"missing field (expected a unit of {kind.replace('_', ' ')}, "
                                           f"e.g. {SI_UNITS[kind]!r})")
            unit = "-"
        if not isinstance(unit, str):
            raise ctx.err(f"{f}.unit", f"must be a string, got {unit!r}")
        fac = factor(unit, kind, f"{ctx.where}: {f}.unit")
        val = _number(spec["value"], f"{f}.value", ctx) * fac
        lo = _number(spec["min"], f"{f}.min", ctx) * fac if "min" in spec else -math.inf
        hi = _number(spec["max"], f"{f}.max", ctx) * fac if "max" in spec else math.inf
        pos = spec.get("positive", False)
        if not isinstance(pos, bool):
            raise ctx.err(f"{f}.positive", f"must be true or false, got {pos!r}")
        if lo > hi:
            raise ctx.err(f, f"min must be <= max, got min = {lo:g}, max = {hi:g} {SI_UNITS[kind]}")
        for key in ("source", "doc"):
            if key in spec and not isinstance(spec[key], str):
                raise ctx.err(f"{f}.{key}", f"must be a string, got {spec[key]!r}")
        out[name] = ParamDecl(name, val, kind, SI_UNITS[kind], lo, hi, pos, spec.get("source", ""), spec.get("doc", ""))
    return out


def _positive_check(ref: Ref | None, field_: str, unit: str, ctx: _Ctx, decl, *, strict: bool = False) -> None:
    v = _const(ref, ctx, decl)
    if v is None:
        return
    if strict and not v > 0:
        raise ctx.err(field_, f"must be > 0 {unit}, got {v:g}")
    if v < 0:
        raise ctx.err(field_, f"must be >= 0 {unit}, got {v:g}")


def parse_rig(data: Mapping[str, Any], path: str = "<rig>") -> RigSpec:
    """Validate a rig description (as read from TOML) into a :class:`RigSpec`.

    Raises
    ------
    ConfigError : one line naming the file and the field.
    """
    from models.friction import get_law

    where = Path(path).name if path and not path.startswith("<") else (path or "rig")
    allowed = {"rig", "parameters", "bodies", "connections", "contacts", "drive", "actuators", "sensors"}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: a rig file must be a TOML table")
    raw_params = data.get("parameters", {})
    if not isinstance(raw_params, Mapping):
        raise ConfigError(f"{where}: parameters must be a table, got {type(raw_params).__name__}")
    ctx = _Ctx(where, raw_params)
    for k in data:
        if k not in allowed:
            raise ConfigError(f"{where}: {k}: unknown section; expected one of {', '.join(sorted(allowed))}")
    rig = _table(data, "rig", ctx, required=True)
    _check_keys(rig, {"name", "description", "reference", "objective_body", "operating_point",
                      "measured_modes_hz"}, "rig", ctx)
    name = rig.get("name")
    if not isinstance(name, str) or not name.strip():
        raise ctx.err("rig.name", f"missing field or not a non-empty string (got {name!r})")
    desc = rig.get("description", "")
    if not isinstance(desc, str):
        raise ctx.err("rig.description", f"must be a string, got {desc!r}")

    # ---- bodies
    bodies_raw = _table(data, "bodies", ctx, required=True)
    if not bodies_raw:
        raise ctx.err("bodies", "at least one body is needed")
    bodies = []
    for bname, b in bodies_raw.items():
        f = f"bodies.{bname}"
        _check_name(bname, f, ctx)
        if bname in (NODE_DRIVE, NODE_GROUND):
            raise ctx.err(f, f"{bname!r} is reserved for the drive and the frame")
        if not isinstance(b, Mapping):
            raise ctx.err(f, "must be a table")
        _check_keys(b, {"inertia", "doc"}, f, ctx)
        if "inertia" not in b:
            raise ctx.err(f"{f}.inertia", "missing field")
        bodies.append(BodySpec(bname, _value(b["inertia"], "inertia", f"{f}.inertia", ctx)))
    body_names = [b.name for b in bodies]

    # ---- drive
    drv = _table(data, "drive", ctx, required=True)
    kind = drv.get("kind")
    if kind not in DRIVE_KINDS:
        raise ctx.err("drive.kind", f"must be one of {', '.join(DRIVE_KINDS)}, got {kind!r}")
    if kind == "dc_motor":
        allowed_d = {"kind", "body", "input", "pi_error", "friction_smoothing", "doc"} | set(DC_MOTOR_FIELDS)
    elif kind == "speed":
        allowed_d = {"kind", "input", "doc"}
    else:
        allowed_d = {"kind", "body", "input", "doc"}
    _check_keys(drv, allowed_d, "drive", ctx)
    d_input = drv.get("input")
    _check_name(d_input, "drive.input", ctx)
    d_body = drv.get("body", "")
    if kind in ("dc_motor", "torque"):
        if d_body not in body_names:
            raise ctx.err("drive.body", f"no body {d_body!r} (bodies: {', '.join(body_names)})")
    d_params = []
    pi_error, eps_m = "disc", 0.05
    if kind == "dc_motor":
        for pname, (pkind, req, _lo) in DC_MOTOR_FIELDS.items():
            if pname in drv:
                d_params.append((pname, _value(drv[pname], pkind, f"drive.{pname}", ctx)))
            elif req:
                raise ctx.err(f"drive.{pname}", f"missing field (a dc_motor needs {', '.join(k for k, v in DC_MOTOR_FIELDS.items() if v[1])})")
        pi_error = drv.get("pi_error", "disc")
        if pi_error not in ("disc", "motor"):
            raise ctx.err("drive.pi_error", f"must be 'disc' or 'motor', got {pi_error!r}")
        eps_m = drv.get("friction_smoothing", 0.05)
        eps_m = _number(eps_m, "drive.friction_smoothing", ctx)
        if not eps_m > 0:
            raise ctx.err("drive.friction_smoothing", f"must be > 0 rad/s (motor side), got {eps_m:g}")
    ctx.inputs[d_input] = "torque" if kind == "torque" else "speed"
    drive = DriveSpec(kind, d_input, d_body, tuple(d_params), pi_error, eps_m)

    # ---- connections
    nodes = set(body_names) | {NODE_GROUND} | ({NODE_DRIVE} if kind == "speed" else set())
    conns = []
    for cname, c in _table(data, "connections", ctx).items():
        f = f"connections.{cname}"
        _check_name(cname, f, ctx)
        if not isinstance(c, Mapping):
            raise ctx.err(f, "must be a table")
        _check_keys(c, {"between", "stiffness", "damping", "backlash", "doc"}, f, ctx)
        btw = c.get("between")
        if not (isinstance(btw, list) and len(btw) == 2 and all(isinstance(x, str) for x in btw)):
            raise ctx.err(f"{f}.between", f"must be two node names [a, b], got {btw!r}")
        for x in btw:
            if x not in nodes:
                hint = " ('drive' needs a drive of kind 'speed')" if x == NODE_DRIVE else ""
                raise ctx.err(f"{f}.between", f"no body {x!r}{hint} (bodies: {', '.join(body_names)}; "
                                              f"also 'ground'{', drive' if kind == 'speed' else ''})")
        if btw[0] == btw[1]:
            raise ctx.err(f"{f}.between", f"must join two different nodes, got {btw!r}")
        if NODE_GROUND in btw and NODE_DRIVE in btw:
            raise ctx.err(f"{f}.between", "joins the drive to the frame: that does nothing")
        if "stiffness" not in c and "damping" not in c:
            raise ctx.err(f, "needs a stiffness, a damping or both")
        k = _value(c["stiffness"], "stiffness", f"{f}.stiffness", ctx) if "stiffness" in c else None
        d = _value(c["damping"], "damping", f"{f}.damping", ctx) if "damping" in c else None
        bl = _value(c["backlash"], "angle", f"{f}.backlash", ctx) if "backlash" in c else None
        if bl is not None and k is None:
            raise ctx.err(f"{f}.backlash", "needs a stiffness (backlash is a dead zone of the spring)")
        conns.append(ConnectionSpec(cname, btw[0], btw[1], k, d, bl))

    # ---- contacts
    contacts = []
    for cname, c in _table(data, "contacts", ctx).items():
        f = f"contacts.{cname}"
        _check_name(cname, f, ctx)
        if not isinstance(c, Mapping):
            raise ctx.err(f, "must be a table")
        law = get_law(c.get("law"), f"{where}: {f}.law")
        _check_keys(c, {"body", "law", "normal", "radius", "doc"} | set(law.param_names), f, ctx)
        if c.get("body") not in body_names:
            raise ctx.err(f"{f}.body", f"no body {c.get('body')!r} (bodies: {', '.join(body_names)})")
        has_n, has_r = "normal" in c, "radius" in c
        if has_n != has_r:
            raise ctx.err(f, "give both a normal force and a radius (friction torque = N r mu), or neither "
                             "(the law's levels are then torques in N m)")
        normal = _value(c["normal"], "force", f"{f}.normal", ctx, allow_input=True) if has_n else None
        radius = _value(c["radius"], "length", f"{f}.radius", ctx) if has_r else None
        lp = []
        for p in law.params:
            if p.name not in c:
                raise ctx.err(f"{f}.{p.name}", f"missing field (law {law.name!r} needs {', '.join(law.param_names)})")
            pk = p.kind
            if pk == "level":
                pk = "dimensionless" if has_n else "torque"
            elif pk == "level_slowness":
                pk = "slowness" if has_n else "damping"
            lp.append((p.name, _value(c[p.name], pk, f"{f}.{p.name}", ctx)))
        contacts.append(ContactSpec(cname, c["body"], law.name, normal, radius, tuple(lp)))

    # ---- actuators
    inputs_now = [drive.input] + [c.normal.name for c in contacts if c.normal is not None and c.normal.kind == "input"]
    acts = []
    for aname, a in _table(data, "actuators", ctx).items():
        f = f"actuators.{aname}"
        _check_name(aname, f, ctx)
        if not isinstance(a, Mapping):
            raise ctx.err(f, "must be a table")
        _check_keys(a, {"kind", "input", "n_min", "n_max", "rate_max", "tau", "doc"}, f, ctx)
        if a.get("kind") != "servo":
            raise ctx.err(f"{f}.kind", f"must be 'servo', got {a.get('kind')!r}")
        inp = a.get("input")
        normals = [c.normal.name for c in contacts if c.normal is not None and c.normal.kind == "input"]
        if inp not in normals:
            raise ctx.err(f"{f}.input", f"must be a contact's normal-force input ({', '.join(normals) or 'none'}), got {inp!r}")
        if any(x.input == inp for x in acts):
            raise ctx.err(f"{f}.input", f"input {inp!r} already has an actuator")
        vals = {}
        for key, kk, default in (("n_min", "force", 0.0), ("n_max", "force", None), ("rate_max", "force_rate", None),
                                 ("tau", "time", 0.0)):
            if key not in a:
                if default is None:
                    raise ctx.err(f"{f}.{key}", "missing field")
                vals[key] = default
                continue
            r = _value(a[key], kk, f"{f}.{key}", ctx)
            if r.kind != "const":
                raise ctx.err(f"{f}.{key}", "must be a value (a number in SI units or a quantity string), not a parameter")
            vals[key] = r.constant
        if vals["n_min"] < 0:
            raise ctx.err(f"{f}.n_min", f"must be >= 0 N, got {vals['n_min']:g}")
        if not vals["n_max"] > vals["n_min"]:
            raise ctx.err(f"{f}.n_max", f"must be > n_min = {vals['n_min']:g} N, got {vals['n_max']:g}")
        if not vals["rate_max"] > 0:
            raise ctx.err(f"{f}.rate_max", f"must be > 0 N/s, got {vals['rate_max']:g}")
        if vals["tau"] < 0:
            raise ctx.err(f"{f}.tau", f"must be >= 0 s, got {vals['tau']:g}")
        acts.append(ActuatorSpec(aname, "servo", inp, vals["n_min"], vals["n_max"], vals["rate_max"], vals["tau"]))

    # ---- sensors
    sensors = []
    auto_params: dict[str, ParamDecl] = {}
    channels_seen: dict[str, str] = {}
    conn_names = [c.name for c in conns]
    contact_by_name = {c.name: c for c in contacts}
    for sname, s in _table(data, "sensors", ctx).items():
        f = f"sensors.{sname}"
        _check_name(sname, f, ctx)
        if not isinstance(s, Mapping):
            raise ctx.err(f, "must be a table")
        sk = s.get("kind")
        if sk not in SENSOR_KINDS:
            raise ctx.err(f"{f}.kind", f"must be one of {', '.join(SENSOR_KINDS)}, got {sk!r}")
        common = {"kind", "noise", "delay", "doc"}
        noise_kind = {"encoder": "angle", "speed": "speed", "torque": "torque", "load_cell": "force"}[sk]
        if sk == "encoder":
            _check_keys(s, common | {"body", "ticks", "ratio", "angle", "speed", "zero"}, f, ctx)
        elif sk == "speed":
            _check_keys(s, common | {"body", "channel", "offset", "gain"}, f, ctx)
        elif sk == "torque":
            _check_keys(s, common | {"at", "definition", "channel", "offset", "gain"}, f, ctx)
        else:
            _check_keys(s, common | {"contact", "channel", "offset", "gain"}, f, ctx)
        delay = s.get("delay", 0)
        if isinstance(delay, bool) or not isinstance(delay, int) or not 0 <= delay <= 100:
            raise ctx.err(f"{f}.delay", f"must be an integer number of DAQ samples in [0, 100], got {delay!r}")
        noise = 0.0
        if "noise" in s:
            r = _value(s["noise"], noise_kind, f"{f}.noise", ctx)
            if r.kind != "const" or r.constant < 0:
                raise ctx.err(f"{f}.noise", f"must be a standard deviation >= 0 (a value), got {s['noise']!r}")
            noise = r.constant
        kw: dict[str, Any] = dict(delay=delay, noise=noise)
        if sk in ("encoder", "speed"):
            target = s.get("body")
            if target not in body_names and not (target == NODE_DRIVE and kind == "speed"):
                raise ctx.err(f"{f}.body", f"no body {target!r} (bodies: {', '.join(body_names)})")
            if sk == "encoder":
                ticks = s.get("ticks")
                if isinstance(ticks, bool) or not isinstance(ticks, int) or ticks < 1:
                    raise ctx.err(f"{f}.ticks", f"must be an integer >= 1 per revolution, got {ticks!r}")
                ratio = _number(s.get("ratio", 1.0), f"{f}.ratio", ctx)
                if not ratio > 0:
                    raise ctx.err(f"{f}.ratio", f"must be > 0 (encoder turns per body turn), got {ratio:g}")
                zero = s.get("zero", "power_on")
                if zero not in ("power_on", "absolute"):
                    raise ctx.err(f"{f}.zero", f"must be 'power_on' or 'absolute', got {zero!r}")
                chans = (s.get("angle", f"theta_{target}"), s.get("speed", f"omega_{target}"))
                kw.update(ticks=ticks, ratio=ratio, zero=zero)
            else:
                chans = (s.get("channel", f"omega_{target}"),)
        elif sk == "torque":
            target = s.get("at")
            if target == NODE_DRIVE:
                if kind == "speed":
                    raise ctx.err(f"{f}.at", "a speed drive has no torque to measure; put the sensor on a connection")
                if kind == "dc_motor":
                    definition = s.get("definition", "reaction")
                    if definition not in ("reaction", "electromagnetic"):
                        raise ctx.err(f"{f}.definition", f"must be 'reaction' or 'electromagnetic', got {definition!r}")
                    kw["definition"] = definition
                elif "definition" in s:
                    raise ctx.err(f"{f}.definition", "applies only to a DC motor's torque (a torque drive's sensor "
                                                     "reads the applied torque)")
            elif target in conn_names:
                if "definition" in s:
                    raise ctx.err(f"{f}.definition", "applies only to a torque sensor at the drive")
                cs = next(c for c in conns if c.name == target)
                if cs.stiffness is None and cs.damping is None:
                    raise ctx.err(f"{f}.at", f"connection {target!r} carries no torque")
            else:
                raise ctx.err(f"{f}.at", f"must be 'drive' or a connection ({', '.join(conn_names) or 'none'}), got {target!r}")
            default = d_input if (target == NODE_DRIVE and kind == "torque") else f"torque_{target}"
            chans = (s.get("channel", default),)
        else:
            target = s.get("contact")
            if target not in contact_by_name:
                raise ctx.err(f"{f}.contact", f"no contact {target!r} (contacts: {', '.join(contact_by_name) or 'none'})")
            cn = contact_by_name[target].normal
            if cn is None:
                raise ctx.err(f"{f}.contact", f"contact {target!r} has no normal force to measure")
            default = cn.name if cn.kind == "input" else f"normal_{target}"
            chans = (s.get("channel", default),)
        for ch in chans:
            _check_name(ch, f"{f} channel", ctx)
            if ch in channels_seen:
                raise ctx.err(f, f"channel {ch!r} is already written by sensor {channels_seen[ch]!r}")
            # a sensor may write an input's channel only when it measures that input: a load cell its
            # normal force, a torque drive's torque sensor its torque, a speed drive's encoder its speed
            measures_input = ((sk == "load_cell" and ch == chans[0])
                              or (sk == "torque" and target == NODE_DRIVE and kind == "torque" and ch == d_input)
                              or (sk in ("encoder", "speed") and target == NODE_DRIVE and ch == chans[-1]
                                  and ch == d_input))
            if ch in inputs_now and not measures_input:
                raise ctx.err(f, f"channel {ch!r} is a model input that this sensor does not measure; "
                                 "give the sensor another channel name")
            channels_seen[ch] = sname
        if sk in ("torque", "load_cell", "speed"):
            # offset and gain are parameters (so that identification can free them): a value given
            # here becomes the parameter "<channel>_offset" / "<channel>_gain"
            qkind = {"torque": "torque", "load_cell": "force", "speed": "speed"}[sk]
            for key, kk, default in (("offset", qkind, 0.0), ("gain", "dimensionless", 1.0)):
                r = _value(s.get(key, default), kk, f"{f}.{key}", ctx)
                if r.kind == "const":
                    auto = f"{chans[0]}_{key}"
                    if auto in raw_params or auto in auto_params:
                        raise ctx.err(f"{f}.{key}", f"parameter {auto!r} already exists; refer to it by name")
                    lo = 0.0 if key == "gain" else -math.inf
                    auto_params[auto] = ParamDecl(auto, r.constant, kk, SI_UNITS[kk], lo, math.inf, key == "gain",
                                                  f"sensor {sname} ({'nominal' if r.constant == default else 'rig file'})",
                                                  f"{key} of channel {chans[0]}")
                    r = Ref("param", name=auto)
                kw[key] = r
        sensors.append(SensorSpec(sname, sk, target, tuple(chans), **kw))

    # ---- parameters, now that their kinds are known
    decl = _parse_parameters(raw_params, ctx)
    for n, pd in auto_params.items():
        if pd.kind == "dimensionless" and not pd.value > 0:
            raise ctx.err(f"sensors: {pd.doc}", f"gain must be > 0, got {pd.value:g}")
        decl[n] = pd

    # ---- physical checks on values
    for b in bodies:
        _positive_check(b.inertia, f"bodies.{b.name}.inertia", "kg m^2", ctx, decl)
    for c in conns:
        _positive_check(c.stiffness, f"connections.{c.name}.stiffness", "N m/rad", ctx, decl)
        _positive_check(c.damping, f"connections.{c.name}.damping", "N m s/rad", ctx, decl)
        _positive_check(c.backlash, f"connections.{c.name}.backlash", "rad", ctx, decl)
    for c in contacts:
        _positive_check(c.radius, f"contacts.{c.name}.radius", "m", ctx, decl, strict=True)
        if c.normal is not None and c.normal.kind != "input":
            _positive_check(c.normal, f"contacts.{c.name}.normal", "N", ctx, decl)
    if kind == "dc_motor":
        for pname in ("L", "R", "Jm", "ratio", "KT"):
            _positive_check(drive.param(pname), f"drive.{pname}", SI_UNITS[DC_MOTOR_FIELDS[pname][0]], ctx, decl,
                            strict=True)
        for pname in ("Tf", "Cm", "KE", "kp", "ki", "v_max", "i_max"):
            _positive_check(drive.param(pname), f"drive.{pname}", SI_UNITS[DC_MOTOR_FIELDS[pname][0]], ctx, decl)
    # physical lower bounds for parameters used as inertias, stiffnesses, ...: default [0, inf)
    nonneg = {"inertia", "stiffness", "damping", "length", "mass", "inductance", "resistance", "time", "force_rate",
              "current", "voltage"}
    for n, pd in list(decl.items()):
        if pd.kind in nonneg and pd.lower < 0:
            if pd.value < 0:
                raise ctx.err(f"parameters.{n}.value", f"must be >= 0 {pd.unit} (a {pd.kind.replace('_', ' ')}), got {pd.value:g}")
            decl[n] = ParamDecl(n, pd.value, pd.kind, pd.unit, 0.0, pd.upper, pd.positive, pd.source, pd.doc)
    for pd in decl.values():
        if not pd.lower <= pd.value <= pd.upper or (pd.positive and not pd.value > pd.lower):
            rel = ">" if pd.positive else ">="
            raise ctx.err(f"parameters.{pd.name}.value",
                          f"must be {rel} {pd.lower:g} and <= {pd.upper:g} {pd.unit}, got {pd.value:g}")
    for b in bodies:
        ref = b.inertia
        if ref.kind == "param" and decl[ref.name].value < 0:
            raise ctx.err(f"bodies.{b.name}.inertia", f"must be >= 0 kg m^2, got {decl[ref.name].value:g}")

    # ---- topology: springs form a forest; every body is connected; a reference node
    parent: dict[str, str] = {}

    def find(x):
        while parent.get(x, x) != x:
            x = parent.get(x, x)
        return x

    for c in conns:
        if c.stiffness is None:
            continue
        ra, rb = find(c.a), find(c.b)
        if ra == rb:
            raise ctx.err(f"connections.{c.name}", f"closes a loop of springs between {c.a!r} and {c.b!r}: "
                                                  "twist coordinates need the springs to form a tree")
        parent[ra] = rb
    touched = {x for c in conns for x in (c.a, c.b)}
    if kind in ("dc_motor", "torque"):
        touched.add(drive.body)
    for c in contacts:
        touched.add(c.body)
    alone = [b for b in body_names if b not in {x for c in conns for x in (c.a, c.b)}]
    if len(body_names) + (1 if kind == "speed" else 0) > 1:
        for b in alone:
            raise ctx.err(f"bodies.{b}", "nothing connects this body (give it a connection to another body, "
                                         "the drive or the ground)")
    ref_node = drive.body if kind in ("dc_motor", "torque") else NODE_DRIVE
    if kind == "speed" and NODE_DRIVE not in touched:
        raise ctx.err("drive", "a speed drive must be joined to a body by a connection (between = [\"<body>\", \"drive\"])")
    for s in sensors:
        if s.kind == "encoder" and find(s.target) != find(ref_node) and s.target != ref_node:
            raise ctx.err(f"sensors.{s.name}.body", f"body {s.target!r} has no spring path to {ref_node!r}: "
                                                    "its angle is not defined in twist coordinates")
    for c in contacts:
        if c.normal is not None and c.normal.kind == "input" and c.normal.name == drive.input:
            raise ctx.err(f"contacts.{c.name}.normal", f"{c.normal.name!r} is the drive's input")
    extra: dict[str, Any] = {}
    if "objective_body" in rig:
        extra["objective_body"] = rig["objective_body"]
        if extra["objective_body"] not in body_names:
            raise ctx.err("rig.objective_body", f"no body {extra['objective_body']!r} (bodies: {', '.join(body_names)})")
    op = rig.get("operating_point", {})
    if not isinstance(op, Mapping):
        raise ctx.err("rig.operating_point", "must be a table of input values (and 'speed' for a torque drive)")
    spec_inputs = [drive.input] + [c.normal.name for c in contacts if c.normal is not None and c.normal.kind == "input"]
    opv = {}
    for key, v in op.items():
        if key == "speed" and kind == "torque":
            k2 = "speed"
        elif key in spec_inputs:
            k2 = "force" if key != drive.input else ("torque" if kind == "torque" else "speed")
        else:
            raise ctx.err(f"rig.operating_point.{key}", f"not an input ({', '.join(spec_inputs)})"
                                                        f"{' or speed' if kind == 'torque' else ''}")
        r = _value(v, k2, f"rig.operating_point.{key}", ctx)
        if r.kind != "const":
            raise ctx.err(f"rig.operating_point.{key}", "must be a value, not a parameter")
        opv[key] = r.constant
    extra["operating_point"] = opv
    if "measured_modes_hz" in rig:
        mm = rig["measured_modes_hz"]
        if not (isinstance(mm, list) and mm and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                   and math.isfinite(v) and v >= 0 for v in mm)):
            raise ctx.err("rig.measured_modes_hz", f"must be a list of frequencies >= 0 Hz, got {mm!r}")
        extra["measured_modes_hz"] = tuple(float(v) for v in mm)
    return RigSpec(name.strip(), desc, tuple(decl.values()), tuple(bodies), tuple(conns), tuple(contacts), drive,
                   tuple(acts), tuple(sensors), str(path), ref_node, extra)
