"""What an online estimator reads and what it adds to the rig's states.

- :func:`default_channels`: every encoder angle and speed, speed sensor and torque sensor
  channel of the rig that is not an input; :func:`resolve_channels` checks a given list (and
  leaves out a lone encoder angle by default: the estimator measures angle differences);
- :func:`default_augment`: ``load:`` on the objective body's contact and ``offset:`` on every
  torque channel used when an angle pair measures the twists (why: :mod:`estimators.online.model`); :func:`resolve_augment` checks a
  given list;
- :func:`angle_combination` / :func:`angle_node`: an encoder angle as a combination of the
  twists; :func:`state_units`: the SI unit of every estimator state.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from models.errors import ConfigError
from models.rig import RigModel
from models.rig.spec import NODE_DRIVE

__all__ = ["default_channels", "default_augment", "resolve_channels", "resolve_augment", "angle_combination",
           "angle_node", "state_units"]

_MEAS_KINDS = ("encoder", "speed", "torque")


def _is_input(model: RigModel, channel: str) -> bool:
    return channel in model.inputs


def default_channels(model: RigModel) -> tuple[str, ...]:
    """Every encoder angle and speed, speed-sensor and torque-sensor channel of the rig that
    is not a model input (a speed drive's speed, a torque drive's torque, a load cell's force
    are inputs)."""
    out = []
    for s in model.sensors:
        if s.kind in _MEAS_KINDS:
            out.extend(c for c in s.channels if not _is_input(model, c))
    return tuple(out)


def default_augment(model: RigModel, channels) -> tuple[str, ...]:
    """``load:`` on the objective body's contact; ``offset:`` on every torque channel used when
    two or more encoder angles measure the twists.

    Without an angle pair the torque channels are the only handle on the twists' level: an offset
    state would trade off exactly against the load factor at steady sliding, and the filter
    drifts along that direction to a bound (measured: a motor encoder and a torque sensor, load
    factor at its bound of 5, twists 5x the truth).  There the channel is taken as tared (its
    rig parameter ``<channel>_offset``); give ``augment`` to estimate it anyway."""
    out = []
    body = model.objective_body
    if body in model.contact_bodies:
        out.append(f"load:{model.contact_names[model.contact_bodies.index(body)][0]}")
    if sum(angle_node(model, c) is not None for c in channels) >= 2:
        for c in channels:
            s = model.sensor_of(c)
            if s is not None and s.kind == "torque":
                out.append(f"offset:{c}")
    return tuple(out)


def angle_combination(model: RigModel, node: str):
    """``c`` with ``angle(node) = theta_ref + c . x`` (coefficients of the twists on the node's
    path through the spring tree), or None if no spring joins the node to the reference."""
    if node == NODE_DRIVE:
        return np.zeros(model.nx)
    xs = ca.SX.sym("x", model.nx)
    try:
        e = model.angle(node, xs, 0)
    except KeyError:
        return None
    return np.array(ca.evalf(ca.jacobian(e, xs))).ravel() if isinstance(e, ca.SX) else np.zeros(model.nx)


def state_units(model: RigModel, names) -> tuple[str, ...]:
    """SI unit of every estimator state."""
    units = dict(zip(model.states, model.state_units))
    out = []
    for n in names:
        kind, _, target = n.partition(":")
        if not target:
            out.append(units[n])
        elif kind == "zero" or kind.startswith("lag"):
            out.append(units[target])
        elif kind in ("load", "gain"):
            out.append("-")
        else:   # offset: the channel's unit
            s = model.sensor_of(target)
            out.append({"torque": "N m", "load_cell": "N", "speed": "rad/s"}.get(s.kind if s else "", "-"))
    return tuple(out)


def resolve_channels(model: RigModel, o, where: str) -> tuple[str, ...]:
    if o.channels is None:
        chans = default_channels(model)
        if not chans:
            raise ConfigError(f"{where}: rig {model.name!r} has no measurement channel (encoder, speed or torque "
                              f"sensor); the estimator has nothing to correct with")
    else:
        ok = default_channels(model)
        for c in o.channels:
            if c in ok:
                continue
            s = model.sensor_of(c)
            if s is None:
                raise ConfigError(f"{where}.channels: unknown channel {c!r} of rig {model.name!r}; expected some of "
                                  f"{', '.join(ok)}")
            raise ConfigError(f"{where}.channels: {c!r} is an input of rig {model.name!r} (a {s.kind.replace('_', ' ')} "
                              f"reading); inputs go in u, the measurements are some of {', '.join(ok)}")
        chans = tuple(c for c in ok if c in o.channels)      # the rig's sensor order
    angles = [c for c in chans if angle_node(model, c) is not None]
    if len(angles) == 1 and o.channels is None:
        # the estimator measures angle differences (twists); a lone encoder's angle carries none, so
        # by default it reads that encoder's speed (and the other sensors) and the observability
        # check decides whether the twists are seen through the dynamics
        chans = tuple(c for c in chans if c != angles[0])
        angles = []
        if not chans:
            raise ConfigError(f"{where}: rig {model.name!r} has one encoder angle and no speed or torque channel; "
                              f"the estimator measures angle differences (twists), and one angle carries none")
    if len(angles) == 1:
        raise ConfigError(f"{where}.channels: one encoder angle ({angles[0]}) alone carries no twist (the estimator "
                          f"measures angle differences); give at least two encoder angles or none")
    for c in angles:
        node = angle_node(model, c)
        if angle_combination(model, node) is None:
            raise ConfigError(f"{where}.channels: encoder angle {c!r} is on {node!r}, which no spring joins to the "
                              f"drive; its angle is not a function of the twists")
    return chans


def angle_node(model: RigModel, channel: str):
    s = model.sensor_of(channel)
    if s is not None and s.kind == "encoder" and s.channels[0] == channel:
        return s.target
    return None


def resolve_augment(model: RigModel, o, chans, where: str) -> tuple[str, ...]:
    aug = default_augment(model, chans) if o.augment is None else tuple(o.augment)
    contacts = [c.name for c in model.spec.contacts]
    for a in aug:
        kind, _, target = a.partition(":")
        if kind == "load":
            if target not in contacts:
                raise ConfigError(f"{where}.augment: {a!r}: rig {model.name!r} has no contact {target!r} "
                                  f"(contacts: {', '.join(contacts) or 'none'})")
            continue
        s = model.sensor_of(target)
        ref = getattr(s, kind, None) if s is not None else None
        if s is None or ref is None or s.kind == "encoder":
            cands = [c for sn in model.sensors if sn.kind in ("torque", "load_cell", "speed") for c in sn.channels]
            raise ConfigError(f"{where}.augment: {a!r}: {target!r} is not a channel with an {kind} (torque, speed "
                              f"sensor or load cell) of rig {model.name!r}; candidates: {', '.join(cands) or 'none'}")
        if s.kind != "load_cell" and target not in chans:
            raise ConfigError(f"{where}.augment: {a!r}: channel {target!r} is not among the measured channels "
                              f"({', '.join(chans)})")
        if s.kind == "load_cell" and target not in model.inputs:
            raise ConfigError(f"{where}.augment: {a!r}: load cell {target!r} does not log an input of rig "
                              f"{model.name!r}")
    return aug
