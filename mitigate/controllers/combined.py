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

from dataclasses import dataclass
from typing import Mapping

from mitigate.controllers.base import Action, Controller, ControlContext
from mitigate.controllers.doskil import DOSKIL, DOSKILOptions
from mitigate.controllers.ztorque import ZTorque, ZTorqueOptions
from models.checks import check_options, option

__all__ = ["ZTorqueDOSKILOptions", "ZTorqueDOSKIL"]


@dataclass(frozen=True, kw_only=True)
class ZTorqueDOSKILOptions:
    """Options of ``kind = "ztorque_doskil"``: the two laws' own options.

    Parameters
    ----------
    ztorque : :class:`mitigate.controllers.ztorque.ZTorqueOptions` (the drive's set-point)
    doskil : :class:`mitigate.controllers.doskil.DOSKILOptions` (the normal force)
    """

    ztorque: ZTorqueOptions = option(ZTorqueOptions(), table=ZTorqueOptions, what="a table of Z-Torque's options")
    doskil: DOSKILOptions = option(DOSKILOptions(), table=DOSKILOptions, what="a table of D-OSKIL's options")

    def __post_init__(self):
        check_options(self)


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
