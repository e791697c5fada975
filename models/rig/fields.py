"""Field readers of the rig-file parser: one place that turns a TOML value into a checked number,
name, reference (:class:`models.rig.spec.Ref`) or parameter declaration, with errors that name
the file and the field (``Context.err``)."""

from __future__ import annotations

import math
import re
from typing import Any, Mapping

from models.errors import ConfigError
from models.rig.spec import SI_UNITS, ParamDecl, Ref
from models.units import factor, parse_quantity

__all__ = ["Context", "NAME", "table", "entries", "check_keys", "check_name", "number", "value_ref", "const_value",
           "parse_parameters", "positive_check"]

NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

# ----------------------------------------------------------------------------- parsing helpers
class Context:
    """Collects parameter declarations and the kinds their uses require."""

    def __init__(self, where: str, params: Mapping[str, Any]):
        self.where = where
        self.raw = params
        self.kinds: dict[str, tuple[str, str]] = {}   # param -> (kind, first use)
        self.inputs: dict[str, str] = {}             # input -> kind

    def err(self, field_: str, msg: str) -> ConfigError:
        sep = " " if msg.startswith(("must", "is ", "has ")) else ": "
        return ConfigError(f"{self.where}: {field_}{sep}{msg}")


def table(data: Mapping, key: str, ctx: Context, required: bool = False) -> Mapping:
    v = data.get(key)
    if v is None:
        if required:
            raise ctx.err(key, "missing section")
        return {}
    if not isinstance(v, Mapping):
        raise ctx.err(key, f"must be a table, got {type(v).__name__}")
    return v


def entries(data: Mapping, key: str, ctx: Context):
    """``(name, field, table)`` of every entry of the section ``key`` (``[bodies.X]``, ...), the name
    checked and the entry a table; ``field`` is ``"<key>.<name>"`` for messages."""
    for name, tab in table(data, key, ctx).items():
        f = f"{key}.{name}"
        check_name(name, f, ctx)
        if not isinstance(tab, Mapping):
            raise ctx.err(f, "must be a table")
        yield name, f, tab


def check_keys(tab: Mapping, allowed, field_: str, ctx: Context) -> None:
    for k in tab:
        if k not in allowed:
            raise ctx.err(f"{field_}.{k}", f"unknown key; expected one of {', '.join(sorted(allowed))}")


def check_name(name: str, field_: str, ctx: Context) -> None:
    if not isinstance(name, str) or not NAME.match(name):
        raise ctx.err(field_, f"must be a name (letters, digits, _; not starting with a digit), got {name!r}")


def number(v: Any, field_: str, ctx: Context) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ctx.err(field_, f"must be a finite number, got {v!r}")
    return float(v)


def value_ref(v: Any, kind: str, field_: str, ctx: Context, *, allow_input: bool = False) -> Ref:
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
            check_name(v, field_, ctx)
            prev = ctx.inputs.get(v)
            if prev is not None and prev != kind:
                raise ctx.err(field_, f"input {v!r} is a {prev}, but here a {kind} is expected")
            ctx.inputs[v] = kind
            return Ref("input", name=v)
        raise ctx.err(field_, f"{v!r} is neither a [parameters] entry nor a quantity such as \"1.5 N m\"")
    raise ctx.err(field_, f"must be a number, a parameter name or a quantity string, got {type(v).__name__}")


def const_value(ref: Ref | None, ctx: Context, decl: Mapping[str, ParamDecl] | None = None) -> float | None:
    if ref is None:
        return None
    if ref.kind == "const":
        return ref.constant
    if ref.kind == "param" and decl is not None and ref.name in decl:
        return decl[ref.name].value
    return None


# ----------------------------------------------------------------------------- sections
def parse_parameters(raw: Mapping, ctx: Context) -> dict[str, ParamDecl]:
    out = {}
    for name, spec in raw.items():
        f = f"parameters.{name}"
        check_name(name, f, ctx)
        if not isinstance(spec, Mapping):
            raise ctx.err(f, "must be a table { value = ..., unit = \"...\" }")
        check_keys(spec, {"value", "unit", "min", "max", "positive", "source", "doc"}, f, ctx)
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
        val = number(spec["value"], f"{f}.value", ctx) * fac
        lo = number(spec["min"], f"{f}.min", ctx) * fac if "min" in spec else -math.inf
        hi = number(spec["max"], f"{f}.max", ctx) * fac if "max" in spec else math.inf
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


def positive_check(ref: Ref | None, field_: str, unit: str, ctx: Context, decl, *, strict: bool = False) -> None:
    v = const_value(ref, ctx, decl)
    if v is None:
        return
    if strict and not v > 0:
        raise ctx.err(field_, f"must be > 0 {unit}, got {v:g}")
    if v < 0:
        raise ctx.err(field_, f"must be >= 0 {unit}, got {v:g}")
