"""Build a controller from a scenario's ``[[controllers]]`` entry.

Kinds: ``pi`` (baseline (a)), ``brake`` (semi-active R2 brake), ``supervisor``
(speed-raise supervisor), ``nmpc`` (:mod:`mitigate.controllers.nmpc`).  Options are the
entry's other keys; they are validated by frozen option dataclasses and a bad one is
reported as one line naming ``controllers[i].<field>``.
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Any, Mapping

from mitigate.controllers.base import Controller
from models.errors import ConfigError

__all__ = ["make_controller", "CONTROLLER_KINDS", "parse_options"]

CONTROLLER_KINDS = ("pi", "brake", "supervisor", "nmpc")


def parse_options(cls, options: Mapping[str, Any], where: str):
    """``cls(**options)`` with one-line errors naming ``where.<field>``."""
    names = [f.name for f in fields(cls)]
    for k in options:
        if k not in names:
            raise ConfigError(f"{where}.{k}: unknown option; expected one of {', '.join(names) or '(none)'}")
    try:
        return cls(**options)
    except ConfigError as exc:
        raise ConfigError(f"{where}.{exc}") from None
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def make_controller(spec, scenario, index: int) -> Controller:
    """The controller of ``scenario.controllers[index]`` (``spec``), ready for :func:`closedloop.run_closed_loop`.

    Parameters
    ----------
    spec : mitigate.scenario.ControllerSpec
    scenario : mitigate.scenario.Scenario (its ``model_params`` are what the controller believes)
    index : position in ``[[controllers]]`` (for error messages)

    Raises
    ------
    ConfigError : unknown kind or bad option (one line naming ``controllers[i].<field>``).
    """
    src = Path(scenario.path).name if scenario.path else "scenario"
    where = f"{src}: controllers[{index}]"
    omega0 = float(scenario.inputs["omega_ref"](0.0)) if "omega_ref" in scenario.inputs else 0.0
    dt_c = scenario.dt * scenario.control_every
    opts = dict(spec.options)
    if spec.kind == "pi":
        from mitigate.controllers.pi import PIOnly, PIOptions
        return PIOnly(parse_options(PIOptions, opts, where), omega0)
    if spec.kind == "brake":
        from mitigate.controllers.brake import BrakeController, BrakeOptions
        return BrakeController(parse_options(BrakeOptions, opts, where), omega0, dt_c)
    if spec.kind == "supervisor":
        from mitigate.controllers.supervisor import SpeedSupervisor, SupervisorOptions
        return SpeedSupervisor(parse_options(SupervisorOptions, opts, where), omega0, dt_c)
    if spec.kind == "nmpc":
        try:
            from mitigate.controllers.nmpc import make_nmpc
        except ModuleNotFoundError as exc:
            if exc.name == "mitigate.controllers.nmpc":
                raise ConfigError(f"{where}.kind: 'nmpc' is not available in this installation") from None
            raise
        # the NMPC re-plans on its own OCP grid (options.dt) and is given the DAQ period
        return make_nmpc(opts, scenario.model_params, scenario.dt, omega0, scenario.servo, where)
    raise ConfigError(f"{where}.kind must be one of {', '.join(CONTROLLER_KINDS)}, got {spec.kind!r}")
