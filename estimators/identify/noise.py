"""Noise levels of a fit: of the compared outputs (the weights) and of the logged inputs
(errors in the variables).

Outputs are weighted by ``1 / std``: the rig's sensor model (:func:`models.sensors.channel_std`:
encoder angles ``q^2/12``, encoder speeds ``2 q^2/12/dt^2``, the rig file's ``noise`` of the other
sensors) unless ``options.noise`` gives the level.  Inputs logged through a load cell or a torque
sensor carry noise that a model taking them as exact attributes to the rig (an error in the
variables, which biases damping and friction); :func:`detect_input_noise` finds it.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from models.logs import Log
from models.sensors import channel_std
from models.signals import white_part

__all__ = ["output_noise", "detect_input_noise", "input_noise_hints"]


def output_noise(model, channel, log: Log, options, dt: float) -> tuple[float, str]:
    """Noise std of a compared channel [SI] and where it came from.

    ``options.noise`` if it names the channel; else the rig's sensor model (a twist: both
    encoders' quantisation); a sensor whose rig file states no noise gets the std of the
    channel's white fast part in the log (at least 1e-3 of its range).
    """
    given = (options.noise or {}).get(channel.name)
    if given is not None:
        return float(given), "options.noise"
    if channel.kind == "twist":
        sd = math.sqrt(sum(channel_std(model, p, dt, options.sensors) ** 2 for p in channel.parts))
    else:
        sd = channel_std(model, channel.name, dt, options.sensors)
    x = channel.measured(log, 0, len(log.t) - channel.max_delay)
    span = float(np.ptp(x)) if x.size else 0.0
    if sd <= 1e-5 * max(span, 1e-12):
        est, _ = white_part(x, dt)
        return max(est, 1e-3 * span, 1e-9), "estimated from the log (the rig file gives no noise)"
    return sd, "rig sensors"


def detect_input_noise(logs: Sequence[Log], model) -> dict[str, float]:
    """Force and torque inputs that carry white measurement noise: ``{channel: noise std}``.

    The part of the logged signal above 1 % of the Nyquist frequency (at least 0.5 Hz: 0.5 Hz at
    100 Hz, 5 Hz at 1 kHz, where 99 % of a white sequence's variance lies above) counts as noise
    when it is uncorrelated from sample to sample (|lag-1 autocorrelation| < 0.2) and larger than
    0.1 % of the signal (:func:`models.signals.white_part`).  A torque that follows a speed loop has correlated
    fast content (rig2's PI torque: lag-1 autocorrelation 0.82) and is not flagged: give its
    sensor's noise explicitly.
    """
    found: dict[str, float] = {}
    for name, unit in zip(model.inputs, model.input_units):
        if unit not in ("N", "N m"):
            continue
        sds, rhos, level = [], [], 0.0
        for lg in logs:
            if name not in lg.channels or len(lg.t) < 200:
                continue
            x = np.asarray(lg[name], dtype=float)
            sd, rho = white_part(x, lg.dt, max(0.5, 0.005 / lg.dt))
            sds.append(sd)
            rhos.append(rho)
            level = max(level, float(np.mean(np.abs(x))))
        if not sds:
            continue
        sd = float(np.sqrt(np.mean(np.square(sds))))
        if sd > 1e-3 * max(level, 1e-9) and max(abs(r) for r in rhos) < 0.2:
            found[name] = sd
    return found


def input_noise_hints(logs: Sequence[Log], model, cutoff: Mapping[str, float] | None,
                      input_noise: Mapping[str, float] | None = None) -> list[str]:
    """Hints for inputs with white noise that the fit takes as exact (it biases damping and friction)."""
    hints = []
    units = dict(zip(model.inputs, model.input_units))
    for name, sd in detect_input_noise(logs, model).items():
        if name in (cutoff or {}) or name in (input_noise or {}):
            continue
        hints.append(f"input {name} carries white noise ({sd:.3g} {units[name]} std) that the fit takes "
                     f"as exact: this biases damping and friction; treat it as noisy: input_noise {name}={sd:.2g} "
                     f"(CLI --input-noise {name}={sd:.2g})")
    return hints
