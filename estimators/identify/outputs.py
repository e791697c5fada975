"""Which log channels a fit compares, and how the rig model predicts each of them.

A rig's sensors (:attr:`models.rig.RigModel.sensors`) write the log channels.  The fit compares

- **encoder speeds** as the mean speed over the preceding sample (the DAQ's backward difference
  of counted angles), ``kind = "speed"``;
- **speed, torque and load-cell channels** as the sensor reads them at the sample instant,
  gain and offset applied (:meth:`models.rig.RigModel.outputs`): rig3's ``motor_torque`` is the
  reaction torque of the free-mounted motor, which depends on the acceleration; ``kind = "value"``;
- **encoder angle differences** ``"thetaA-thetaB"`` as the twist they measure (the reference
  angle cancels); ``kind = "twist"``.  Incremental encoders read 0 at power-on, so such a
  difference is the twist minus its value at power-on: with ``encoder_zero = "free"`` each
  log gets one unknown constant per difference (:class:`Channel.zero`).

Channels that are model inputs (a load cell on a normal force, a speed drive's encoder) are
inputs, not outputs.  Every channel may arrive ``delay`` samples late (the rig file's sensor
``delay`` plus ``options.extra_delay``): the problem shifts it back.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from models.errors import ConfigError, DataError
from models.logs import Log

__all__ = ["Channel", "plan_channels", "output_function", "angle_coefficients", "input_delays"]


@dataclass(frozen=True)
class Channel:
    """One compared output.

    Attributes
    ----------
    name : the log channel, or ``"thetaA-thetaB"`` for an angle difference
    kind : "speed" (sample mean of a speed), "value" (reading at the sample instant) or "twist"
    parts : the log columns it is built from (a twist: its two angle channels)
    delays : whole samples each part arrives late
    unit : SI unit
    zero : a twist whose encoder zero is a per-log unknown (``encoder_zero = "free"``)
    coefficients : twist: the state combination it measures (nx,), else None
    """

    name: str
    kind: str
    parts: tuple[str, ...]
    delays: tuple[int, ...]
    unit: str
    zero: bool = False
    coefficients: tuple[float, ...] | None = None

    @property
    def max_delay(self) -> int:
        return max(self.delays)

    def measured(self, log: Log, start: int, n: int) -> np.ndarray:
        """The channel's ``n`` samples from ``start``, each part shifted back by its delay."""
        vals = [np.asarray(log[p], float)[start + d:start + d + n] for p, d in zip(self.parts, self.delays)]
        return vals[0] - vals[1] if self.kind == "twist" else vals[0]


def angle_coefficients(model) -> dict[str, np.ndarray]:
    """``{angle channel: c}`` with ``angle = theta_ref + c . x`` for every encoder of the rig."""
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_p)
    th = ca.SX.sym("th")
    out = model.outputs(x, u, model.unpack(p), th)
    res = {}
    for s in model.sensors:
        if s.kind != "encoder":
            continue
        ang = s.channels[0]
        J = ca.Function("ja", [x, u, p, th], [ca.jacobian(out[ang], x)])
        res[ang] = np.array(J(0, 0, 0, 0), dtype=float).ravel()
    return res


def _sensor_delay(model, channel: str) -> int:
    s = model.sensor_of(channel)
    return int(s.delay) if s is not None else 0


def input_delays(model, extra: int) -> tuple[int, ...]:
    """Delay of every model input's log column: a sensor's (load cell, speed-drive encoder, torque
    sensor of a torque drive) plus ``extra``; commands (set-points) are logged as issued."""
    return tuple(_sensor_delay(model, n) + extra if model.sensor_of(n) is not None else 0 for n in model.inputs)


def _twist_pairs(model, angles: list[str]) -> list[tuple[str, str, np.ndarray]]:
    """An independent set of angle differences, preferring those that equal one twist."""
    coef = angle_coefficients(model)
    cands = []
    for i, a in enumerate(angles):
        for j, b in enumerate(angles):
            if j <= i:
                continue
            v = coef[a] - coef[b]
            nz = np.flatnonzero(np.abs(v) > 1e-12)
            if nz.size == 0:
                continue
            if v[nz[0]] < 0:
                a2, b2, v2 = b, a, -v
            else:
                a2, b2, v2 = a, b, v
            cands.append((nz.size, i, j, a2, b2, v2))
    cands.sort(key=lambda c: (c[0], c[1], c[2]))
    chosen, rows = [], np.zeros((0, model.nx))
    for _, _, _, a, b, v in cands:
        trial = np.vstack([rows, v])
        if np.linalg.matrix_rank(trial, tol=1e-9) > rows.shape[0]:
            rows = trial
            chosen.append((a, b, v))
    return chosen


def plan_channels(model, log: Log, options) -> tuple[Channel, ...]:
    """The compared channels of ``log`` for ``model`` under ``options`` (see the module docstring).

    Raises
    ------
    ConfigError : a requested output that is not a sensor channel of the rig
    DataError : a requested output missing from the log, or no output at all
    """
    extra = options.extra_delay
    inputs = set(model.inputs)
    units = {}
    kinds = {}
    angles_all = []
    for s in model.sensors:
        if s.kind == "encoder":
            angles_all.append(s.channels[0])
            units[s.channels[0]] = "rad"
            units[s.channels[1]] = "rad/s"
            kinds[s.channels[1]] = "speed" if options.speed_average else "value"
        else:
            ch = s.channels[0]
            units[ch] = {"speed": "rad/s", "torque": "N m", "load_cell": "N"}[s.kind]
            kinds[ch] = "value"
    coef = None

    def twist(a: str, b: str, v=None) -> Channel:
        nonlocal coef
        if v is None:
            coef = coef or angle_coefficients(model)
            v = coef[a] - coef[b]
        return Channel(f"{a}-{b}", "twist", (a, b), (_sensor_delay(model, a) + extra, _sensor_delay(model, b) + extra),
                       "rad", options.encoder_zero == "free", tuple(float(c) for c in v))

    chans: list[Channel] = []
    if options.outputs is not None:
        for name in options.outputs:
            if "-" in name:
                a, _, b = name.partition("-")
                if a not in angles_all or b not in angles_all or a == b:
                    raise ConfigError(f"options.outputs: {name!r} must be the difference of two encoder angle channels "
                                      f"of rig {model.name!r} ({', '.join(angles_all) or 'none'})")
                chans.append(twist(a, b))
            elif name in kinds and name not in inputs:
                chans.append(Channel(name, kinds[name], (name,), (_sensor_delay(model, name) + extra,), units[name]))
            else:
                valid = [k for k in kinds if k not in inputs]
                raise ConfigError(f"options.outputs: {name!r} is not an output channel of rig {model.name!r} "
                                  f"(outputs: {', '.join(valid)}; angle differences such as "
                                  f"'{angles_all[0] + '-' + angles_all[1] if len(angles_all) > 1 else 'thetaA-thetaB'}')")
        for c in chans:
            for p in c.parts:
                if p not in log.channels:
                    raise DataError(f"{log.source}: missing output column {p!r} (options.outputs)")
    else:
        for name, kind in kinds.items():
            if name in inputs or name in options.exclude or name not in log.channels:
                continue
            chans.append(Channel(name, kind, (name,), (_sensor_delay(model, name) + extra,), units[name]))
        if options.use_twist:
            present = [a for a in angles_all if a in log.channels]
            for a, b, v in _twist_pairs(model, present):
                if f"{a}-{b}" not in options.exclude:
                    chans.append(twist(a, b, v))
        if not chans:
            valid = [k for k in kinds if k not in inputs]
            raise DataError(f"{log.source}: no output channel of rig {model.name!r} found (expected some of "
                            f"{', '.join(valid)})")
    return tuple(chans)


def output_function(model, channels) -> ca.Function:
    """``y = h(x, u, p)`` stacking the predicted channels (``u``: the model's inputs, corrected)."""
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    p = ca.SX.sym("p", model.n_p)
    out = model.outputs(x, u, model.unpack(p), ca.SX(0))
    ys = []
    for c in channels:
        if c.kind == "twist":
            ys.append(out[c.parts[0]] - out[c.parts[1]])
        else:
            ys.append(out[c.name])
    return ca.Function(f"{model.cname}_id_h", [x, u, p], [ca.vertcat(*ys)], ["x", "u", "p"], ["y"])
