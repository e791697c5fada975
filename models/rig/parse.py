"""Rig files: validation of the TOML schema (:mod:`models.rig.spec`) into a :class:`RigSpec`.

:func:`parse_rig` reads the sections in order (rig, bodies, drive, connections, contacts,
actuators, sensors, parameters), then checks the values physically (signs, a body that cannot
be simulated, rates that overflow) and the topology (springs form a forest, every body is
joined, a reference node).  Every error is one line naming the file and the field.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

from models.errors import ConfigError
from models.friction import get_law, level_kind
from models.rig.checks import check_massless, check_rates, check_values, reference_node
from models.rig.fields import (Context, check_keys, check_name, entries, number, parse_parameters, table,
                               value_ref)
from models.rig.drives import get_drive
from models.rig.spec import (NODE_DRIVE, NODE_GROUND, SENSOR_KINDS, SI_UNITS, TRUTH_PREFIX, ActuatorSpec, BodySpec, ConnectionSpec, ContactSpec, DriveSpec, ParamDecl, Ref,
                             RigSpec, SensorSpec)

__all__ = ["parse_rig"]


def _parse_head(data, path: str):
    """(where, ctx, the [rig] table, name, description)."""
    where = Path(path).name if path and not path.startswith("<") else (path or "rig")
    allowed = {"rig", "parameters", "bodies", "connections", "contacts", "drive", "actuators", "sensors"}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: a rig file must be a TOML table")
    raw_params = data.get("parameters", {})
    if not isinstance(raw_params, Mapping):
        raise ConfigError(f"{where}: parameters must be a table, got {type(raw_params).__name__}")
    ctx = Context(where, raw_params)
    for k in data:
        if k not in allowed:
            raise ConfigError(f"{where}: {k}: unknown section; expected one of {', '.join(sorted(allowed))}")
    rig = table(data, "rig", ctx, required=True)
    check_keys(rig, {"name", "description", "reference", "objective_body", "operating_point",
                      "measured_modes_hz"}, "rig", ctx)
    name = rig.get("name")
    if not isinstance(name, str) or not name.strip():
        raise ctx.err("rig.name", f"missing field or not a non-empty string (got {name!r})")
    desc = rig.get("description", "")
    if not isinstance(desc, str):
        raise ctx.err("rig.description", f"must be a string, got {desc!r}")
    return where, ctx, rig, name, desc


def _parse_bodies(data, ctx: Context) -> list[BodySpec]:
    # ---- bodies
    bodies_raw = table(data, "bodies", ctx, required=True)
    if not bodies_raw:
        raise ctx.err("bodies", "at least one body is needed")
    bodies = []
    for bname, b in bodies_raw.items():
        f = f"bodies.{bname}"
        check_name(bname, f, ctx)
        if bname in (NODE_DRIVE, NODE_GROUND):
            raise ctx.err(f, f"{bname!r} is reserved for the drive and the frame")
        if not isinstance(b, Mapping):
            raise ctx.err(f, "must be a table")
        check_keys(b, {"inertia", "doc"}, f, ctx)
        if "inertia" not in b:
            raise ctx.err(f"{f}.inertia", "missing field")
        bodies.append(BodySpec(bname, value_ref(b["inertia"], "inertia", f"{f}.inertia", ctx)))
    return bodies


def _parse_drive(data, ctx: Context, body_names) -> DriveSpec:
    # ---- drive: its kind (models.rig.drives) says which keys and parameters it reads
    drv = table(data, "drive", ctx, required=True)
    kind = drv.get("kind")
    cls = get_drive(kind, f"{ctx.where}: drive.kind")
    check_keys(drv, cls.allowed_keys(), "drive", ctx)
    d_input = drv.get("input")
    check_name(d_input, "drive.input", ctx)
    d_body = drv.get("body", "")
    if cls.on_body:
        if d_body not in body_names:
            raise ctx.err("drive.body", f"no body {d_body!r} (bodies: {', '.join(body_names)})")
    d_params = []
    for fd in cls.fields:
        if fd.name in drv:
            d_params.append((fd.name, value_ref(drv[fd.name], fd.kind, f"drive.{fd.name}", ctx)))
        elif fd.required:
            raise ctx.err(f"drive.{fd.name}", f"missing field (a {kind} needs {', '.join(f.name for f in cls.fields if f.required)})")
    settings = cls.parse_settings(drv, ctx)
    ctx.inputs[d_input] = cls.setpoint
    return DriveSpec(kind, d_input, d_body, tuple(d_params), setpoint=cls.setpoint, **settings)


def _parse_connections(data, ctx: Context, body_names, drive: DriveSpec) -> list[ConnectionSpec]:
    # ---- connections; a drive that prescribes a speed is the node "drive"
    has_node = not get_drive(drive.kind).on_body
    nodes = set(body_names) | {NODE_GROUND} | ({NODE_DRIVE} if has_node else set())
    conns = []
    for cname, f, c in entries(data, "connections", ctx):
        check_keys(c, {"between", "stiffness", "damping", "backlash", "doc"}, f, ctx)
        btw = c.get("between")
        if not (isinstance(btw, list) and len(btw) == 2 and all(isinstance(x, str) for x in btw)):
            raise ctx.err(f"{f}.between", f"must be two node names [a, b], got {btw!r}")
        for x in btw:
            if x not in nodes:
                hint = " ('drive' needs a drive of kind 'speed')" if x == NODE_DRIVE else ""
                raise ctx.err(f"{f}.between", f"no body {x!r}{hint} (bodies: {', '.join(body_names)}; "
                                              f"also 'ground'{', drive' if has_node else ''})")
        if btw[0] == btw[1]:
            raise ctx.err(f"{f}.between", f"must join two different nodes, got {btw!r}")
        if NODE_GROUND in btw and NODE_DRIVE in btw:
            raise ctx.err(f"{f}.between", "joins the drive to the frame: that does nothing")
        if "stiffness" not in c and "damping" not in c:
            raise ctx.err(f, "needs a stiffness, a damping or both")
        k = value_ref(c["stiffness"], "stiffness", f"{f}.stiffness", ctx) if "stiffness" in c else None
        d = value_ref(c["damping"], "damping", f"{f}.damping", ctx) if "damping" in c else None
        bl = value_ref(c["backlash"], "angle", f"{f}.backlash", ctx) if "backlash" in c else None
        if bl is not None and k is None:
            raise ctx.err(f"{f}.backlash", "needs a stiffness (backlash is a dead zone of the spring)")
        conns.append(ConnectionSpec(cname, btw[0], btw[1], k, d, bl))
    return conns


def _parse_contacts(data, ctx: Context, body_names, where: str) -> list[ContactSpec]:
    # ---- contacts
    contacts = []
    for cname, f, c in entries(data, "contacts", ctx):
        law = get_law(c.get("law"), f"{where}: {f}.law")
        check_keys(c, {"body", "law", "normal", "radius", "doc"} | set(law.param_names), f, ctx)
        if c.get("body") not in body_names:
            raise ctx.err(f"{f}.body", f"no body {c.get('body')!r} (bodies: {', '.join(body_names)})")
        has_n, has_r = "normal" in c, "radius" in c
        if has_n != has_r:
            raise ctx.err(f, "give both a normal force and a radius (friction torque = N r mu), or neither "
                             "(the law's levels are then torques in N m)")
        normal = value_ref(c["normal"], "force", f"{f}.normal", ctx, allow_input=True) if has_n else None
        radius = value_ref(c["radius"], "length", f"{f}.radius", ctx) if has_r else None
        lp = []
        for p in law.params:
            if p.name not in c:
                raise ctx.err(f"{f}.{p.name}", f"missing field (law {law.name!r} needs {', '.join(law.param_names)})")
            pk = level_kind(p.kind, has_n)
            lp.append((p.name, value_ref(c[p.name], pk, f"{f}.{p.name}", ctx)))
        contacts.append(ContactSpec(cname, c["body"], law.name, normal, radius, tuple(lp)))
    return contacts


def _parse_actuators(data, ctx: Context, contacts) -> list[ActuatorSpec]:
    # ---- actuators
    acts = []
    for aname, f, a in entries(data, "actuators", ctx):
        check_keys(a, {"kind", "input", "n_min", "n_max", "rate_max", "tau", "doc"}, f, ctx)
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
            r = value_ref(a[key], kk, f"{f}.{key}", ctx)
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
    return acts


def _parse_sensors(data, ctx: Context, body_names, drive: DriveSpec, conns, contacts, raw_params):
    """(sensors, parameters they create for their offsets and gains)."""
    cls, d_input = get_drive(drive.kind), drive.input
    inputs_now = [drive.input] + [c.normal.name for c in contacts if c.normal is not None and c.normal.kind == "input"]
    # ---- sensors
    sensors = []
    auto_params: dict[str, ParamDecl] = {}
    channels_seen: dict[str, str] = {}
    conn_names = [c.name for c in conns]
    contact_by_name = {c.name: c for c in contacts}
    for sname, f, s in entries(data, "sensors", ctx):
        sk = s.get("kind")
        if sk not in SENSOR_KINDS:
            raise ctx.err(f"{f}.kind", f"must be one of {', '.join(SENSOR_KINDS)}, got {sk!r}")
        common = {"kind", "noise", "delay", "doc"}
        noise_kind = {"encoder": "angle", "speed": "speed", "torque": "torque", "load_cell": "force"}[sk]
        if sk == "encoder":
            check_keys(s, common | {"body", "ticks", "ratio", "angle", "speed", "zero"}, f, ctx)
        elif sk == "speed":
            check_keys(s, common | {"body", "channel", "offset", "gain"}, f, ctx)
        elif sk == "torque":
            check_keys(s, common | {"at", "definition", "channel", "offset", "gain"}, f, ctx)
        else:
            check_keys(s, common | {"contact", "channel", "offset", "gain"}, f, ctx)
        delay = s.get("delay", 0)
        if isinstance(delay, bool) or not isinstance(delay, int) or not 0 <= delay <= 100:
            raise ctx.err(f"{f}.delay", f"must be an integer number of DAQ samples in [0, 100], got {delay!r}")
        noise = 0.0
        if "noise" in s:
            r = value_ref(s["noise"], noise_kind, f"{f}.noise", ctx)
            if r.kind != "const" or r.constant < 0:
                raise ctx.err(f"{f}.noise", f"must be a standard deviation >= 0 (a value), got {s['noise']!r}")
            noise = r.constant
        kw: dict[str, Any] = dict(delay=delay, noise=noise)
        if sk in ("encoder", "speed"):
            target = s.get("body")
            if target not in body_names and not (target == NODE_DRIVE and not cls.on_body):
                raise ctx.err(f"{f}.body", f"no body {target!r} (bodies: {', '.join(body_names)})")
            if sk == "encoder":
                ticks = s.get("ticks")
                if isinstance(ticks, bool) or not isinstance(ticks, int) or ticks < 1:
                    raise ctx.err(f"{f}.ticks", f"must be an integer >= 1 per revolution, got {ticks!r}")
                ratio = number(s.get("ratio", 1.0), f"{f}.ratio", ctx)
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
                kw.update(cls.torque_sensor(s, f, ctx))
            elif target in conn_names:
                if "definition" in s:
                    raise ctx.err(f"{f}.definition", "applies only to a torque sensor at the drive")
                cs = next(c for c in conns if c.name == target)
                if cs.stiffness is None and cs.damping is None:
                    raise ctx.err(f"{f}.at", f"connection {target!r} carries no torque")
            else:
                raise ctx.err(f"{f}.at", f"must be 'drive' or a connection ({', '.join(conn_names) or 'none'}), got {target!r}")
            # a torque sensor at a torque-input drive measures its input (the drive logs its command)
            reads_input = target == NODE_DRIVE and not cls.sets_speed
            default = d_input if reads_input else f"torque_{target}"
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
            check_name(ch, f"{f} channel", ctx)
            if ch.startswith(TRUTH_PREFIX):
                raise ctx.err(f, f"channel {ch!r} starts with {TRUTH_PREFIX!r}, which marks the true-state columns "
                                 "of a simulated log; give the sensor another channel name")
            if ch in channels_seen:
                raise ctx.err(f, f"channel {ch!r} is already written by sensor {channels_seen[ch]!r}")
            # a sensor may write an input's channel only when it measures that input: a load cell its
            # normal force, a torque drive's torque sensor its torque, a speed drive's encoder its speed
            measures_input = ((sk == "load_cell" and ch == chans[0])
                              or (sk == "torque" and target == NODE_DRIVE and not cls.sets_speed and ch == d_input)
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
                r = value_ref(s.get(key, default), kk, f"{f}.{key}", ctx)
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
    return sensors, auto_params


def _parse_declared(ctx: Context, raw_params, auto_params) -> dict[str, ParamDecl]:
    # ---- parameters, now that their kinds are known
    decl = parse_parameters(raw_params, ctx)
    for n, pd in auto_params.items():
        if pd.kind == "dimensionless" and not pd.value > 0:
            raise ctx.err(f"sensors: {pd.doc}", f"gain must be > 0, got {pd.value:g}")
        decl[n] = pd
    return decl


def _rig_extra(ctx: Context, rig, body_names, drive: DriveSpec, contacts) -> dict:
    """``objective_body``, ``operating_point`` and ``measured_modes_hz`` of the [rig] table."""
    cls = get_drive(drive.kind)
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
        if key == "speed" and not cls.sets_speed:
            k2 = "speed"          # the sliding speed of a drive whose input is not a speed
        elif key in spec_inputs:
            k2 = "force" if key != drive.input else cls.setpoint
        else:
            raise ctx.err(f"rig.operating_point.{key}", f"not an input ({', '.join(spec_inputs)})"
                                                        f"{'' if cls.sets_speed else ' or speed'}")
        r = value_ref(v, k2, f"rig.operating_point.{key}", ctx)
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
    return extra


def parse_rig(data: Mapping[str, Any], path: str = "<rig>") -> RigSpec:
    """Validate a rig description (as read from TOML) into a :class:`RigSpec`.

    Raises
    ------
    ConfigError : one line naming the file and the field.
    """
    where, ctx, rig, name, desc = _parse_head(data, path)
    raw_params = ctx.raw
    bodies = _parse_bodies(data, ctx)
    body_names = [b.name for b in bodies]
    drive = _parse_drive(data, ctx, body_names)
    check_massless(ctx, bodies, drive)
    conns = _parse_connections(data, ctx, body_names, drive)
    contacts = _parse_contacts(data, ctx, body_names, where)
    acts = _parse_actuators(data, ctx, contacts)
    sensors, auto_params = _parse_sensors(data, ctx, body_names, drive, conns, contacts, raw_params)
    decl = _parse_declared(ctx, raw_params, auto_params)
    check_values(ctx, decl, bodies, conns, contacts, drive)
    check_massless(ctx, bodies, drive, decl)
    check_rates(ctx, decl, bodies, conns, drive)
    ref_node = reference_node(ctx, conns, contacts, drive, body_names, sensors)
    extra = _rig_extra(ctx, rig, body_names, drive, contacts)
    return RigSpec(name.strip(), desc, tuple(decl.values()), tuple(bodies), tuple(conns), tuple(contacts), drive,
                   tuple(acts), tuple(sensors), str(path), ref_node, extra)
