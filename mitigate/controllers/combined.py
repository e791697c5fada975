"""Z-Torque + D-OSKIL: the industry's two-actuator baseline (the drive's set-point AND the normal force).

No public industry law sets both inputs at once; the combination a driller would field is the two
published single-actuator laws side by side, each on its own input, each tuned as shipped:

- Z-Torque on the drive's set-point (Dwars, SPE/IADC-173037-MS 2015; :mod:`mitigate.controllers.ztorque`);
- D-OSKIL on the normal force (Canudas de Wit, Rubio and Corchero, IEEE TCST 16(6) 2008;
  :mod:`mitigate.controllers.doskil`).

Both read the same DAQ sample and act in the same call; neither knows of the other (the string is
their only coupling).  It is the benchmark's reference for the "both" class, beside the NMPC that
plans both inputs together.  Options are the two laws' tables::

    [[controllers]]
    name = "Z-Torque + D-OSKIL"
    kind = "ztorque_doskil"
    ztorque = { z = 0.35 }           # ZTorqueOptions (every key optional)
    doskil = { gain_factor = 2.0 }   # DOSKILOptions
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from mitigate.controllers.base import Action, Controller, ControlContext
from mitigate.controllers.doskil import DOSKIL, DOSKILOptions
from mitigate.controllers.ztorque import ZTorque, ZTorqueOptions
from models.checks import options_from_mapping
from models.errors import ConfigError

__all__ = ["ZTorqueDOSKILOptions", "ZTorqueDOSKIL"]


@dataclass(frozen=True, kw_only=True)
class ZTorqueDOSKILOptions:
    """Options of ``kind = "ztorque_doskil"``: the two laws' own options.

    Parameters
    ----------
    ztorque : :class:`mitigate.controllers.ztorque.ZTorqueOptions` (the drive's set-point)
    doskil : :class:`mitigate.controllers.doskil.DOSKILOptions` (the normal force)
    """

    ztorque: ZTorqueOptions = field(default_factory=ZTorqueOptions)
    doskil: DOSKILOptions = field(default_factory=DOSKILOptions)

    def __post_init__(self):
        if not isinstance(self.ztorque, ZTorqueOptions) or not isinstance(self.doskil, DOSKILOptions):
            raise ConfigError("ztorque and doskil must be ZTorqueOptions and DOSKILOptions (tables in a scenario)")

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], where: str = "controller") -> "ZTorqueDOSKILOptions":
        """From a scenario's table: ``ztorque`` and ``doskil`` sub-tables (each optional)."""
        bad = sorted(set(table) - {"ztorque", "doskil"})
        if bad:
            raise ConfigError(f"{where}.{bad[0]}: unknown key; expected ztorque and doskil (tables of those laws' "
                              f"options)")
        parts = {}
        for key, oc in (("ztorque", ZTorqueOptions), ("doskil", DOSKILOptions)):
            sub = table.get(key, {})
            if isinstance(sub, oc):
                parts[key] = sub
                continue
            if not isinstance(sub, Mapping):
                raise ConfigError(f"{where}.{key} must be a table of {oc.__name__}, got {sub!r}")
            parts[key] = options_from_mapping(oc, dict(sub), f"{where}.{key}")
        return cls(**parts)


class ZTorqueDOSKIL(Controller):
    """Z-Torque on the drive and D-OSKIL on the normal force (module docstring)."""

    kind = "ztorque_doskil"
    options_class = ZTorqueDOSKILOptions
    needs = tuple(dict.fromkeys(ZTorque.needs + DOSKIL.needs))
    tunables = {**{f"ztorque.{k}": v for k, v in ZTorque.tunables.items()},
                **{f"doskil.{k}": v for k, v in DOSKIL.tunables.items()}}

    def __init__(self, options: ZTorqueDOSKILOptions, context: ControlContext):
        super().__init__(options, context)
        self.drive = ZTorque(options.ztorque, context)
        self.force = DOSKIL(options.doskil, context)
        self.derived_units = {**{f"ztorque.{k}": u for k, u in ZTorque.derived_units.items()},
                              **{f"doskil.{k}": u for k, u in DOSKIL.derived_units.items()}}

    def actuated_inputs(self) -> tuple[str, ...]:
        return self.drive.actuated_inputs() + self.force.actuated_inputs()

    def reset(self) -> None:
        self.drive.reset()
        self.force.reset()

    def _step_impl(self, t: float, measurement: Mapping[str, float], estimate) -> Action:
        # each law's own step, unguarded: the outer step guards, times and counts the call once, and a
        # SolverFailure of either (a dropout) is answered by the fallback (the programme on both inputs)
        a = self.drive._step_impl(t, measurement, estimate)      # noqa: SLF001 - the two laws, composed
        b = self.force._step_impl(t, measurement, estimate)      # noqa: SLF001
        return Action({**a.u, **b.u})

    def tuning_values(self) -> dict[str, float]:
        """Both laws' derived values (``ztorque.<name>``, ``doskil.<name>``)."""
        out = {f"ztorque.{k}": v for k, v in self.drive.tuning_values().items()}
        out.update({f"doskil.{k}": v for k, v in self.force.tuning_values().items()})
        return out
