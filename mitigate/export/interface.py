"""What an exported controller reads and writes: the layout of ``in[]``, ``out[]`` and the runtime
parameters, from the scenario's rig, controller and estimator.

``in[]`` (one DAQ period):

1. every DAQ channel the estimator, the controller or the estimator's input rule reads (the rig's
   channel names and SI units; NaN: missing in this sample);
2. ``programme:<input>`` for every rig input: the operator's programme now (the drive's speed
   set-point or torque, the normal forces);
3. ``target_speed`` [rad/s] on a torque drive: the objective body's target speed (the scenario's
   ``[control] speed``);
4. ``enable``: non-zero hands the commanded inputs to the controller; zero leaves them to the
   programme while the estimator keeps running (switch-on and switch-off without a bump).

``out[]``: the commanded inputs (the drive's set-point first, then the servo commands; the
programme's values when the controller leaves them to it), then the estimate (the estimator's
states, e.g. the unmeasured twists).

Runtime parameters (``create(params)``): the rig's parameters (a refit from ``mitigate identify``
needs no rebuild), then the controller's weights and limits; each with its unit and the exported
default.  What the export derived from the rig at build time (the OCP interval, the substeps, the
stick-slip period, the hold gain, the estimator's noise levels) stays as exported; the library's
README says so.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["Port", "Interface", "c_name", "channel_union"]


@dataclass(frozen=True)
class Port:
    """One entry of ``in[]``, ``out[]`` or the parameters: name, SI unit, and (parameters) default."""

    name: str
    unit: str
    value: float = 0.0
    doc: str = ""


@dataclass(frozen=True)
class Interface:
    """The layout of an exported step (module docstring)."""

    prefix: str
    inputs: tuple[Port, ...]
    outputs: tuple[Port, ...]
    params: tuple[Port, ...]

    def index(self, name: str) -> int:
        return [p.name for p in self.inputs].index(name)


def c_name(text: str) -> str:
    """An identifier for C from a name (``programme:omega_ref`` -> ``PROGRAMME_OMEGA_REF``)."""
    s = re.sub(r"[^0-9A-Za-z]+", "_", text).strip("_").upper()
    return s if s and not s[0].isdigit() else f"X{s}"


def channel_union(*groups) -> tuple[str, ...]:
    """The channels of several readers, each once, in first-seen order."""
    out = []
    for g in groups:
        for c in g:
            if c not in out:
                out.append(c)
    return tuple(out)
