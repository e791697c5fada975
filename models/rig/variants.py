"""Structural variants of a rig: a plant that differs from the model in structure.

A real rig differs from its model in ways no parameter factor captures.  Each function here
takes a :class:`RigSpec` and returns the spec of a rig that differs in one structural way,
which the scenario's ``[structure]`` section applies to the *plant* while the controllers and
estimators keep the nominal model:

- :func:`with_torque_definition`: the drive's torque sensor reads the other definition
  (``reaction``: the free-mounted motor's load cell; ``electromagnetic``: ``ratio KT i``);
- :func:`with_pi_error`: the drive's PI loop acts on the motor-side speed error (the thesis
  prints kp and ki without units: on the motor side the loop is ``ratio`` times stiffer);
- :func:`with_delay`: every channel (or some) arrives whole DAQ samples late;
- :func:`with_backlash`: the gearbox has backlash: the rotor and the gearbox output become
  two bodies joined by a stiff mesh with a dead zone;
- :func:`with_shaft_elements`: every shaft section between two bodies is split into elements
  joined by stiffer springs, which adds higher torsional modes (the shaft's own inertia,
  couplings and bearing races lumped at the element nodes);
- :func:`with_friction_law`: the contacts follow another friction law (for example Coulomb
  plus viscous, or a law whose friction strengthens at higher speed).

Sensor offsets and gains are parameters of the rig (``<channel>_offset``, ``<channel>_gain``): a
plant whose load cell reads off is a plant parameter set with other values.  Slow friction drift
(wear) is a plant option (:class:`models.plant.Plant`'s ``drift``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Mapping

from models.errors import ConfigError
from models.friction import get_law, level_kind
from models.rig.drives import get_drive
from models.rig.spec import (ActuatorSpec, BodySpec, ConnectionSpec, ContactSpec, ParamDecl, Ref, RigSpec,
                             SensorSpec, SI_UNITS, NODE_DRIVE)

__all__ = ["with_torque_definition", "with_pi_error", "with_delay", "with_backlash",
           "with_shaft_elements", "with_friction_law"]


def _replace_sensor(spec: RigSpec, name: str, **changes) -> RigSpec:
    sens = tuple(dataclasses.replace(s, **changes) if s.name == name else s for s in spec.sensors)
    return spec.with_changes(sensors=sens)


def _add_params(spec: RigSpec, decls) -> RigSpec:
    names = set(spec.param_names)
    new = [d for d in decls if d.name not in names]
    return spec.with_changes(parameters=spec.parameters + tuple(new))


def with_torque_definition(spec: RigSpec, definition: str) -> RigSpec:
    """Every torque sensor at the DC motor reads ``definition`` ("reaction" or "electromagnetic")."""
    if definition not in ("reaction", "electromagnetic"):
        raise ConfigError(f"structure.torque_definition must be 'reaction' or 'electromagnetic', got {definition!r}")
    readable = definition in get_drive(spec.drive.kind).definitions
    hits = [s for s in spec.sensors if s.kind == "torque" and s.target == NODE_DRIVE and readable]
    if not hits:
        raise ConfigError(f"structure.torque_definition: rig {spec.name!r} has no torque sensor at a DC motor")
    for s in hits:
        spec = _replace_sensor(spec, s.name, definition=definition)
    return spec


def with_pi_error(spec: RigSpec, side: str) -> RigSpec:
    """The DC motor's PI loop acts on the ``"disc"`` (output-side) or ``"motor"``-side speed error."""
    if "pi_error" not in get_drive(spec.drive.kind).keys:
        raise ConfigError(f"structure.pi_error: rig {spec.name!r} has a {spec.drive.kind} drive, not a dc_motor")
    if side not in ("disc", "motor"):
        raise ConfigError(f"structure.pi_error must be 'disc' or 'motor', got {side!r}")
    return spec.with_changes(drive=dataclasses.replace(spec.drive, pi_error=side))


def with_delay(spec: RigSpec, delay: int | Mapping[str, int]) -> RigSpec:
    """Channels arrive whole DAQ samples late: one integer for every sensor, or ``{channel: k}``."""
    if isinstance(delay, Mapping):
        for ch, k in delay.items():
            s = next((s for s in spec.sensors if ch in s.channels), None)
            if s is None:
                raise ConfigError(f"structure.delay.{ch}: no sensor writes channel {ch!r} on rig {spec.name!r}")
            if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k <= 100:
                raise ConfigError(f"structure.delay.{ch} must be an integer in [0, 100] samples, got {k!r}")
            spec = _replace_sensor(spec, s.name, delay=k)
        return spec
    if isinstance(delay, bool) or not isinstance(delay, int) or not 0 <= delay <= 100:
        raise ConfigError(f"structure.delay must be an integer in [0, 100] samples (or a table per channel), got {delay!r}")
    return spec.with_changes(sensors=tuple(dataclasses.replace(s, delay=delay) for s in spec.sensors))


def with_backlash(spec: RigSpec, gap: float, stiffness: float, inertia: float, damping: float = 0.0) -> RigSpec:
    """Backlash between the DC motor's rotor and the gearbox output.

    The drive body keeps its connections and becomes the gearbox output, of inertia
    ``inertia`` [kg m^2] plus its own; a new body ``<drive>_rotor`` carries the motor (and
    the encoders and torque sensor on the motor side) and meets the output through a mesh of
    stiffness ``stiffness`` [N m/rad] with a dead zone of ``gap`` [rad] (output side) and
    damping ``damping`` [N m s/rad].
    """
    d = spec.drive
    if not get_drive(d.kind).geared:
        raise ConfigError(f"structure.backlash: rig {spec.name!r} has a {d.kind} drive, not a dc_motor with a gearbox")
    for name, v, strict in (("gap", gap, False), ("stiffness", stiffness, True), ("inertia", inertia, True),
                            ("damping", damping, False)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 or (strict and v == 0):
            raise ConfigError(f"structure.backlash.{name} must be a finite number {'> 0' if strict else '>= 0'}, got {v!r}")
    out = d.body
    rotor = f"{out}_rotor"
    old = spec.body(out)
    own = old.inertia
    bodies = []
    for b in spec.bodies:
        if b.name == out:
            total = Ref("const", constant=inertia + (own.constant if own.kind == "const" else 0.0))
            if own.kind == "param":
                raise ConfigError("structure.backlash: the drive body's inertia is a parameter; give the gearbox "
                                  "output's inertia in the rig file as a value")
            bodies.append(BodySpec(out, total))
        else:
            bodies.append(b)
    bodies.append(BodySpec(rotor, Ref("const", constant=0.0)))
    mesh = ConnectionSpec(f"{out}_mesh", rotor, out, Ref("const", constant=stiffness),
                          Ref("const", constant=damping) if damping > 0 else None, Ref("const", constant=gap))
    sens = []
    for s in spec.sensors:
        if s.target == out and s.kind in ("encoder", "speed") and s.ratio != 1.0:
            s = dataclasses.replace(s, target=rotor)     # an encoder on the motor shaft sits on the rotor
        sens.append(s)
    return spec.with_changes(bodies=tuple(bodies), connections=spec.connections + (mesh,),
                             drive=dataclasses.replace(d, body=rotor), sensors=tuple(sens), reference_node=rotor)


def with_shaft_elements(spec: RigSpec, count: int, inertia: float) -> RigSpec:
    """Split every spring between two bodies into ``count`` elements.

    Each element has ``count`` times the stiffness and damping (same total compliance) and
    the ``count - 1`` new nodes each carry ``inertia`` [kg m^2].  The twist across the
    original section (what the model calls ``twist_<connection>``) is the sum of the element
    twists; the plant reports the first element's twist under the original name only if
    ``count == 1``.
    """
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= 20:
        raise ConfigError(f"structure.shaft_elements.count must be an integer in [1, 20], got {count!r}")
    if isinstance(inertia, bool) or not isinstance(inertia, (int, float)) or not (math.isfinite(inertia) and inertia > 0):
        raise ConfigError(f"structure.shaft_elements.inertia must be a finite number > 0 kg m^2, got {inertia!r}")
    if count == 1:
        return spec
    decl = {p.name: p for p in spec.parameters}
    bodies = list(spec.bodies)
    conns = []
    bnames = set(spec.body_names)

    def scaled(ref):
        if ref is None:
            return None
        if ref.kind == "const":
            return Ref("const", constant=ref.constant * count)
        return Ref("const", constant=decl[ref.name].value * count)

    for c in spec.connections:
        if c.stiffness is None or c.a not in bnames or c.b not in bnames:
            conns.append(c)
            continue
        nodes = [c.a] + [f"{c.name}_e{j}" for j in range(1, count)] + [c.b]
        for j in range(1, count):
            bodies.append(BodySpec(nodes[j], Ref("const", constant=float(inertia))))
        for j in range(count):
            conns.append(ConnectionSpec(c.name if j == 0 else f"{c.name}_{j}", nodes[j], nodes[j + 1],
                                        scaled(c.stiffness), scaled(c.damping), c.backlash))
    return spec.with_changes(bodies=tuple(bodies), connections=tuple(conns))


def with_friction_law(spec: RigSpec, law: str, values: Mapping[str, float], contacts=None) -> RigSpec:
    """The contacts follow ``law``; a law parameter named like one of the contact's current
    parameters keeps it (e.g. ``mu_s``, ``mu_k``), the others take ``values`` (SI)."""
    L = get_law(law, "structure.friction.law")
    names = contacts or [c.name for c in spec.contacts]
    new_params = []
    out = []
    for c in spec.contacts:
        if c.name not in names:
            out.append(c)
            continue
        old = dict(c.params)
        lp = []
        for p in L.params:
            if p.name in values:
                v = values[p.name]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ConfigError(f"structure.friction.{p.name} must be a finite number, got {v!r}")
                pname = f"{c.name}_{p.name}"
                kind = level_kind(p.kind, c.normal is not None)
                new_params.append(ParamDecl(pname, float(v), kind, SI_UNITS[kind], -math.inf, math.inf, False,
                                            "structure.friction (plant only)", p.doc))
                lp.append((p.name, Ref("param", name=pname)))
            elif p.name in old:
                lp.append((p.name, old[p.name]))
            else:
                raise ConfigError(f"structure.friction.{p.name}: missing field (law {law!r} needs "
                                  f"{', '.join(L.param_names)}; contact {c.name!r} has {', '.join(old)})")
        out.append(dataclasses.replace(c, law=law, params=tuple(lp)))
    unknown = [k for k in values if k not in L.param_names and k != "law"]
    if unknown:
        raise ConfigError(f"structure.friction.{unknown[0]}: not a parameter of law {law!r} ({', '.join(L.param_names)})")
    spec = _add_params(spec, new_params)
    return spec.with_changes(contacts=tuple(out))
