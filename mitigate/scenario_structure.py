"""``[structure]`` of a scenario: the plant differs from the model in structure (README).

:func:`apply_structure` builds the plant's rig and true parameters from the model's (torque
definition, PI error, DAQ delay, shaft elements, backlash, another friction law, sensor offsets
and gains) and reads its drift (wear).
"""

from __future__ import annotations

from typing import Mapping

from models.checks import finite_number
from models.errors import ConfigError
from models.params import ParameterSet
from models.rig import RigModel, variants
from mitigate.scenario_fields import check_keys, si_value

__all__ = ["apply_structure"]

def apply_structure(model: RigModel, params: ParameterSet, st: Mapping, where: str
                     ) -> tuple[RigModel, ParameterSet, dict, list[str]]:
    """The plant's rig and parameters under ``[structure]``, its drift, and notes."""
    allowed = {"torque_definition", "sensor_offsets", "sensor_gains", "pi_error", "delay", "backlash",
               "shaft_elements", "friction", "drift"}
    check_keys(st, allowed, f"{where}: structure")
    spec = model.spec
    w = f"{where}: structure"
    try:
        if "torque_definition" in st:
            spec = variants.with_torque_definition(spec, st["torque_definition"])
        if "pi_error" in st:
            spec = variants.with_pi_error(spec, st["pi_error"])
        if "delay" in st:
            spec = variants.with_delay(spec, st["delay"])
        if "shaft_elements" in st:
            s = st["shaft_elements"]
            if not isinstance(s, Mapping) or "count" not in s or "inertia" not in s:
                raise ConfigError(f"{w}.shaft_elements must be a table {{count, inertia}}, got {s!r}")
            check_keys(s, {"count", "inertia"}, f"{w}.shaft_elements")
            spec = variants.with_shaft_elements(spec, s["count"], si_value(s["inertia"], "inertia", f"{w}.shaft_elements.inertia"))
        if "backlash" in st:
            b = st["backlash"]
            if not isinstance(b, Mapping):
                raise ConfigError(f"{w}.backlash must be a table {{gap, stiffness, inertia, damping}}, got {b!r}")
            check_keys(b, {"gap", "stiffness", "inertia", "damping"}, f"{w}.backlash")
            spec = variants.with_backlash(
                spec, si_value(b.get("gap", "0.5 deg"), "angle", f"{w}.backlash.gap"),
                si_value(b.get("stiffness", "200 N m/rad"), "stiffness", f"{w}.backlash.stiffness"),
                si_value(b.get("inertia", "1e-3 kg m^2"), "inertia", f"{w}.backlash.inertia"),
                si_value(b.get("damping", "0.02 N m s/rad"), "damping", f"{w}.backlash.damping"))
        if "friction" in st:
            fr = st["friction"]
            if not isinstance(fr, Mapping) or "law" not in fr:
                raise ConfigError(f"{w}.friction must be a table with a law, got {fr!r}")
            spec = variants.with_friction_law(spec, fr["law"], {k: v for k, v in fr.items() if k != "law"})
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(where) else f"{where}: {msg}") from None
    plant = RigModel(spec, model.key) if spec is not model.spec else model
    base = plant.published()
    vals = {n: (params[n] if n in params else base[n]) for n in plant.param_names}
    for what, kind_of in (("sensor_offsets", "offset"), ("sensor_gains", "gain")):
        tab = st.get(what, {})
        if not isinstance(tab, Mapping):
            raise ConfigError(f"{w}.{what} must be a table {{channel = value}}, got {tab!r}")
        for ch, v in tab.items():
            s = next((s for s in plant.sensors if ch in s.channels and s.kind in ("torque", "load_cell", "speed")), None)
            ref = getattr(s, kind_of, None) if s is not None else None
            if ref is None or ref.kind != "param":
                raise ConfigError(f"{w}.{what}.{ch}: no torque sensor, load cell or speed sensor with a calibration "
                                  f"parameter writes channel {ch!r} on rig {model.name!r}")
            kind = "dimensionless" if kind_of == "gain" else {"torque": "torque", "load_cell": "force",
                                                               "speed": "speed"}[s.kind]
            vals[ref.name] = si_value(v, kind, f"{w}.{what}.{ch}")
    pparams = ParameterSet(base.model, base.specs, vals, where=f"{where}: structure")
    drift = {}
    dr = st.get("drift", {})
    if not isinstance(dr, Mapping):
        raise ConfigError(f"{w}.drift must be a table {{parameter = relative rate per second}}, got {dr!r}")
    for k, v in dr.items():
        if k not in plant.param_names:
            raise ConfigError(f"{w}.drift.{k}: not a parameter of rig {model.name!r}")
        drift[k] = finite_number(v, f"{w}.drift.{k} [1/s]")
    return plant, pparams, drift, []
