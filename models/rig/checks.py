"""Physical checks of a parsed rig: signs and bounds of values, bodies that cannot be simulated
(no inertia), rates that overflow, and the topology (springs form a forest, every body is joined,
a reference node for the angles)."""

from __future__ import annotations

import math

from models.rig.fields import Context, const_value, positive_check
from models.rig.drives import get_drive
from models.rig.spec import NODE_DRIVE, NODE_GROUND, SI_UNITS, DriveSpec, ParamDecl

__all__ = ["check_values", "check_massless", "check_rates", "reference_node", "MAX_RATE"]


def check_values(ctx: Context, decl, bodies, conns, contacts, drive: DriveSpec) -> None:
    # ---- physical checks on values
    for b in bodies:
        positive_check(b.inertia, f"bodies.{b.name}.inertia", "kg m^2", ctx, decl)
    for c in conns:
        positive_check(c.stiffness, f"connections.{c.name}.stiffness", "N m/rad", ctx, decl)
        positive_check(c.damping, f"connections.{c.name}.damping", "N m s/rad", ctx, decl)
        positive_check(c.backlash, f"connections.{c.name}.backlash", "rad", ctx, decl)
    for c in contacts:
        positive_check(c.radius, f"contacts.{c.name}.radius", "m", ctx, decl, strict=True)
        if c.normal is not None and c.normal.kind != "input":
            positive_check(c.normal, f"contacts.{c.name}.normal", "N", ctx, decl)
    fields = get_drive(drive.kind).fields
    for fd in sorted(fields, key=lambda fd: not fd.strict):        # the strictly positive ones first
        positive_check(drive.param(fd.name), f"drive.{fd.name}", SI_UNITS[fd.kind], ctx, decl, strict=fd.strict)
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


def reference_node(ctx: Context, conns, contacts, drive: DriveSpec, body_names, sensors) -> str:
    """The reference node, after checking that the springs form a forest and every body is joined."""
    on_body = get_drive(drive.kind).on_body
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
    if on_body:
        touched.add(drive.body)
    for c in contacts:
        touched.add(c.body)
    alone = [b for b in body_names if b not in {x for c in conns for x in (c.a, c.b)}]
    if len(body_names) + (0 if on_body else 1) > 1:
        for b in alone:
            raise ctx.err(f"bodies.{b}", "nothing connects this body (give it a connection to another body, "
                                         "the drive or the ground)")
    ref_node = drive.body if on_body else NODE_DRIVE
    if not on_body and NODE_DRIVE not in touched:
        raise ctx.err("drive", "a speed drive must be joined to a body by a connection (between = [\"<body>\", \"drive\"])")
    for s in sensors:
        if s.kind == "encoder" and find(s.target) != find(ref_node) and s.target != ref_node:
            raise ctx.err(f"sensors.{s.name}.body", f"body {s.target!r} has no spring path to {ref_node!r}: "
                                                    "its angle is not defined in twist coordinates")
    for c in contacts:
        if c.normal is not None and c.normal.kind == "input" and c.normal.name == drive.input:
            raise ctx.err(f"contacts.{c.name}.normal", f"{c.normal.name!r} is the drive's input")
    return ref_node


#: the fastest rate [1/s] a rig may have: beyond it no step the workbench takes resolves it, and
#: the numbers overflow (a stiffness of 1e308 N m/rad); 1e8 1/s is a 16 MHz mode
MAX_RATE = 1e8


def _reflected(ctx: Context, drive: DriveSpec, decl) -> tuple[str, float | None]:
    """(body, the inertia its drive adds to it: a geared rotor's ``ratio^2 Jm``); ("", 0) for a drive
    without a rotor; the value None while it is not known."""
    cls = get_drive(drive.kind)
    if not cls.geared:
        return "", 0.0
    return drive.body, cls.reflected_inertia(lambda r: const_value(r, ctx, decl), drive)


def check_massless(ctx: Context, bodies, drive: DriveSpec, decl=None) -> None:
    """A body whose total inertia is 0 (its own, plus a DC motor's reflected rotor) cannot be
    simulated: its acceleration is a torque over 0.  Checked on constants before the parameters
    are read (so that an unused parameter does not hide the cause), then on parameters."""
    motor_body, reflected = _reflected(ctx, drive, decl)
    for b in bodies:
        own = const_value(b.inertia, ctx, decl)
        if own is None or (decl is None and b.inertia.kind != "const") or own != 0:
            continue
        if b.name == motor_body and (reflected is None or reflected > 0):
            continue
        what = f"parameter {b.inertia.name!r} = 0 kg m^2" if b.inertia.kind == "param" else "0 kg m^2"
        raise ctx.err(f"bodies.{b.name}.inertia", f"{what} and no motor drives it: a massless body cannot be "
                                                  "simulated (its acceleration would be a torque over zero inertia); "
                                                  "give its inertia, or merge it with the body it is joined to")


def check_rates(ctx: Context, decl, bodies, conns, drive: DriveSpec) -> None:
    """Every spring's and damper's rate on the bodies it joins, ``k (1/J_a + 1/J_b)`` [1/s^2] and
    ``d (1/J_a + 1/J_b)`` [1/s], finite and at most :data:`MAX_RATE` (squared for a spring)."""
    motor_body, reflected = _reflected(ctx, drive, decl)
    J = {}
    for b in bodies:
        own = const_value(b.inertia, ctx, decl)
        if own is not None:
            J[b.name] = own + ((reflected or 0.0) if b.name == motor_body else 0.0)
    for c in conns:
        if not all(n in J or n in (NODE_DRIVE, NODE_GROUND) for n in (c.a, c.b)):
            continue
        inv = sum(1.0 / J[n] for n in (c.a, c.b) if n in J and J[n] > 0)
        for ref, what, unit, power in ((c.stiffness, "stiffness", "N m/rad", 2), (c.damping, "damping", "N m s/rad", 1)):
            v = const_value(ref, ctx, decl)
            if v is None:
                continue
            rate = (v * inv) ** (1.0 / power)      # python floats overflow to inf, never raise here
            if not (math.isfinite(rate) and rate <= MAX_RATE):
                raise ctx.err(f"connections.{c.name}.{what}",
                              f"{v:g} {unit}{f' (parameter {ref.name!r})' if ref.kind == 'param' else ''} on {', '.join(f'{n} ({J[n]:g} kg m^2)' for n in (c.a, c.b) if n in J)} "
                              f"gives a rate of {rate:.3g} 1/s (at most {MAX_RATE:g}): not a physical rig, and no "
                              f"integrator can step it")
