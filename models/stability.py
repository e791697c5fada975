"""The stability of steady sliding and its maps: is sliding at an input linearly stable, and over
which inputs and speeds (the rig's actuated normal-force input over its rated range).

Built on the linearisation of :mod:`models.modal`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.errors import ConfigError
from models.modal import linearise, operating_point, params_of
from models.params import ParameterSet
from models.rig import get_model

__all__ = ["sliding_stability", "stability_map", "MapAxis", "map_axis", "stribeck_onset"]


# ----------------------------------------------------------------------------- stability of sliding
def sliding_stability(model, params: ParameterSet | None, u, eps: float | None = None,
                      x_op=None) -> tuple[bool, float]:
    """Is steady sliding at input ``u`` linearly stable?

    Returns
    -------
    stable : bool (largest real part < 0, the rigid-body zero of a torque drive excluded)
    max_real : that largest real part [1/s]
    """
    model = get_model(model)
    if x_op is None and not model.drive.sets_speed:
        x_op = model.sliding_guess(u, params_of(model, params))
    lin = linearise(model, params, u, eps=eps, x_op=x_op)
    ev = np.linalg.eigvals(lin.A)
    ev = ev[np.abs(ev) > 1e-9 * max(1.0, float(np.max(np.abs(ev))))]
    mr = float(np.max(ev.real)) if ev.size else 0.0
    return bool(mr < 0.0), mr


@dataclass(frozen=True)
class MapAxis:
    """The normal-force axis of a stability map: ``input`` over ``[lo, hi]`` [N], and ``source``, where
    that input and range come from (said in the output)."""

    input: str
    lo: float
    hi: float
    source: str


def map_axis(model, params: ParameterSet | None = None, input: str | None = None) -> MapAxis:
    """The normal-force axis of a rig's stability map: its actuated input over the actuator's rating.

    ``input`` (default: the first servo's, ``[actuators]``) is a normal-force input of the rig.  A
    servo's input spans the servo's rated range ``[n_min, n_max]``; an input no servo sets (a logged
    force, a rig without actuators) spans 0 to twice its value at the rig's operating point (the
    largest normal force there if its own is 0), as no rating is declared.

    Raises
    ------
    ConfigError : ``input`` is not a normal-force input, or the rig has none, or (without a servo) its
        operating point loads no contact.
    """
    model = get_model(model)
    forces = [n for n, k in zip(model.inputs, model.input_kinds) if k == "force"]
    if input is None:
        input = model.servo_inputs[0] if model.servo_inputs else (forces[0] if forces else None)
    if input not in forces:
        raise ConfigError(f"the stability map's input must be a normal-force input of rig {model.name!r} "
                          f"({', '.join(forces) or 'none'}), got {input!r}")
    a = model.actuator(input)
    if a is not None:
        return MapAxis(input, float(a.n_min), float(a.n_max), f"the rated range of actuator {a.name!r}")
    u_op, _ = operating_point(model, params_of(model, params))
    n_op, whose = float(u_op[model.inputs.index(input)]), "its"
    if not n_op > 0:
        n_op, whose = max(float(u_op[model.inputs.index(n)]) for n in forces), "the largest normal force of"
    if not n_op > 0:
        raise ConfigError(f"rig {model.name!r} declares no actuator for {input!r} and its operating point loads no "
                          f"contact: no range for the stability map's {input!r}")
    return MapAxis(input, 0.0, 2.0 * n_op, f"no actuator sets it: 0 to twice {whose} operating point "
                                           f"({n_op:g} N)")


def stability_map(model, params: ParameterSet | None, load_values, omega_values,
                  eps: float | None = None, *, input: str | None = None) -> np.ndarray:
    """Largest real part [1/s] of the sliding linearisation over (normal force, speed).

    Parameters
    ----------
    model : a rig with a speed-setting drive and a normal-force input
    load_values : (a,) values of the normal-force input ``input`` [N]
    omega_values : (b,) the drive's speed [rad/s]; the other inputs as in the rig's operating point
    input : the normal-force input on the first axis (default: :func:`map_axis`'s, the rig's actuated one)

    Returns
    -------
    (a, b) array; > 0 where steady sliding is unstable (stick-slip onset).
    """
    model = get_model(model)
    params = params_of(model, params)
    if not model.drive.sets_speed or "force" not in model.input_kinds:
        raise ConfigError(f"stability_map needs a rig with a speed-setting drive and a normal-force input, "
                          f"got {model.name!r} ({model.drive_kind} drive, inputs {', '.join(model.inputs)})")
    base, _ = operating_point(model, params)
    if input is None:
        input = map_axis(model, params).input
    elif dict(zip(model.inputs, model.input_kinds)).get(input) != "force":
        raise ConfigError(f"stability_map: input must be a normal-force input of rig {model.name!r}, got {input!r}")
    jl = model.inputs.index(input)
    jw = model.inputs.index(model.drive_input)
    load_values = np.asarray(load_values, dtype=float).ravel()
    omega_values = np.asarray(omega_values, dtype=float).ravel()
    out = np.empty((load_values.size, omega_values.size))
    for a, n1 in enumerate(load_values):
        for b, w in enumerate(omega_values):
            u = base.copy()
            u[jw], u[jl] = w, n1
            out[a, b] = sliding_stability(model, params, u, eps=eps)[1]
    return out


def stribeck_onset(mu_s: float, mu_k: float, v_s: float, radius: float, omega: float, damping: float) -> float:
    """Normal force at which the Stribeck slope cancels a viscous damping (single-DOF estimate).

    The friction torque's slope at sliding speed ``omega`` is ``-N r (mu_s - mu_k)
    exp(-omega/v_s) / v_s``; steady sliding of one disc on a damped spring loses stability when
    this negative damping exceeds ``damping`` [N m s/rad]:
    ``N* = damping v_s exp(omega/v_s) / (r (mu_s - mu_k))`` [N].
    """
    return damping * v_s * math.exp(omega / v_s) / (radius * (mu_s - mu_k))
