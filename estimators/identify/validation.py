"""Hold-out validation: free-run the EXACT stick/slip plant on a held-back segment and compare.

The last ``holdout`` fraction of the first log is kept out of the fit.  From the fitted state at
the end of the training segment, the exact plant (:func:`models.plant.step_function`,
``method = "hybrid"``) is driven by the logged inputs (corrected through the fitted load-cell
offsets and gains) with the fitted parameters.  Encoder speeds are compared as sample means
(differences of the plant's angles, like the DAQ's), angle differences with the fitted encoder
zero subtracted, other channels as read.

Per channel: the RMS error in the sensor's noise levels (meaningful on any segment) and, where the
measured signal moves well beyond its noise,
the NRMSE (RMS error over that span; on a steady-sliding segment the span is the noise itself and
an NRMSE of 46.6 % meant nothing).  Moving well beyond its noise: a standard deviation of at least
:data:`RESOLVED_STD` noise levels.  The stick-slip period and amplitude of one channel are compared
too: the sliding body's speed (slips are bursts from rest), else a twist or torque (slips are sharp
drops), else the first speed, each found as slip events (:func:`models.signals.slip_events`; a
spectrum's peak misreads an irregular sawtooth).  A segment without slips (steady sliding) states
no period: ``period_measured`` is NaN and ``period_note`` says why.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from models.errors import DataError
from models.plant import SimOptions, step_function
from models.signals import moving_average, slip_events

__all__ = ["Validation", "validate", "period_channel", "RESOLVED_STD"]

#: a measured channel whose standard deviation is below this many noise levels gets no NRMSE (its
#: variation is then mostly the sensor's noise, which an NRMSE would measure instead of the model)
RESOLVED_STD = 3.0


@dataclass(frozen=True)
class Validation:
    """Free-run prediction of a held-back log segment with the fitted parameters.

    Attributes
    ----------
    t : (n,) times [s]; measured, simulated : ``{channel: (n,)}``
    nrmse : per channel RMS error / span of the measured signal; NaN where its standard deviation is
        within :data:`RESOLVED_STD` noise levels (a steady segment: the NRMSE would measure the noise)
    rms : per channel RMS error in the channel's noise levels
    period_measured, period_simulated [s], period_error (relative): median time between slips
        (:func:`models.signals.slip_events`); NaN where there are fewer than two slips
    amplitude_measured, amplitude_simulated [channel unit], amplitude_error (relative): half the
        peak-to-peak of ``channel`` (NaN without stick-slip in the measured segment)
    channel : the channel the period and amplitude refer to; kind : "speed" or "force"
    slips_measured, slips_simulated : slips found in the segment
    period_note : why there is no measured period ("" when there is one), e.g. steady sliding
    method : "hybrid" (the exact stick/slip plant)
    """

    t: np.ndarray
    measured: dict = field(repr=False)
    simulated: dict = field(repr=False)
    nrmse: dict = field(default_factory=dict)
    rms: dict = field(default_factory=dict)
    period_measured: float = float("nan")
    period_simulated: float = float("nan")
    period_error: float = float("nan")
    amplitude_measured: float = float("nan")
    amplitude_simulated: float = float("nan")
    amplitude_error: float = float("nan")
    channel: str = ""
    kind: str = "speed"
    slips_measured: int = 0
    slips_simulated: int = 0
    period_note: str = ""
    method: str = "hybrid"

    @property
    def stick_slip(self) -> bool:
        """The measured segment sticks and slips (has a period)."""
        return bool(np.isfinite(self.period_measured))

    def as_dict(self) -> dict:
        return {"nrmse": dict(self.nrmse), "rms": dict(self.rms), "period_measured": self.period_measured,
                "period_simulated": self.period_simulated, "period_error": self.period_error,
                "amplitude_measured": self.amplitude_measured, "amplitude_simulated": self.amplitude_simulated,
                "amplitude_error": self.amplitude_error, "channel": self.channel, "kind": self.kind,
                "slips_measured": self.slips_measured, "slips_simulated": self.slips_simulated,
                "period_note": self.period_note, "method": self.method}


def period_channel(model, channels) -> tuple[str, str]:
    """``(channel, kind)`` whose slips give the stick-slip period: the sliding (objective) body's speed,
    else another contact body's, else a twist or torque channel, else the first speed channel."""
    speeds = {c.name for c in channels if c.kind == "speed" or (c.kind == "value" and c.unit == "rad/s")}
    for body in (model.objective_body,) + tuple(model.contact_bodies):
        ch = model.speed_channel(body) if body else None
        if ch in speeds:
            return ch, "speed"
    for c in channels:
        if c.kind == "twist" or getattr(model.sensor_of(c.name), "kind", None) == "torque":
            return c.name, "force"
    first = [c.name for c in channels if c.name in speeds]
    return (first[0], "speed") if first else (channels[0].name, "force")


def validate(problem, fit, nsub: int = 10) -> Validation:
    """Predict the held-out end of the problem's first log with the fit (see the module docstring).

    Raises
    ------
    DataError : the held-out segment is shorter than 3 samples.
    """
    model = problem.model
    d = problem.data[0]
    k0 = d.nint * problem.options.shoot_every
    n = d.n
    if n - k0 < 3:
        raise DataError(f"{d.log.source}: hold-out segment too short ({n - k0} samples)")
    dt = problem.dt
    F = step_function(model, SimOptions(dt=dt, nsub=nsub))
    h = model.meas()
    p = fit.params.vector()
    P = model.unpack(p)
    Um = np.array(model.input_from_measured([d.U[:, j] for j in range(model.nu)], P), float).T.reshape(n, model.nu)
    x = np.asarray(fit.states[0][-1], float).copy()
    for idx in model.contacts:        # a numerically tiny speed is stuck for the exact plant
        if abs(x[idx]) < 1e-3:
            x[idx] = 0.0
    th = 0.0
    zeros = dict(fit.encoder_zero[0]) if fit.encoder_zero else {}
    angle_of = {s.channels[1]: s.channels[0] for s in model.sensors if s.kind == "encoder"}
    chans = problem.channels
    sims = {c.name: [] for c in chans}
    row0 = k0 + 1 if problem.options.input_row == "end" else k0
    prev = {k: float(v) for k, v in zip(h.name_out(), h(x, Um[min(row0, n - 1)], p, th))}
    for k in range(k0, n - 1):
        uk = Um[k + 1] if problem.options.input_row == "end" else Um[k]
        xn, thn = F(x, th, uk, p)
        x = np.array(xn).ravel()
        th = float(thn)
        out = {kk: float(v) for kk, v in zip(h.name_out(), h(x, uk, p, th))}
        for c in chans:
            if c.kind == "speed":
                a = angle_of[c.name]
                sims[c.name].append((out[a] - prev[a]) / dt)
            elif c.kind == "twist":
                sims[c.name].append(out[c.parts[0]] - out[c.parts[1]] - zeros.get(c.name, 0.0))
            else:
                sims[c.name].append(out[c.name])
        prev = out
    t = d.t[k0 + 1:n]
    meas = {c.name: d.Y[k0 + 1:n, j] for j, c in enumerate(chans)}
    sims = {k: np.array(v) for k, v in sims.items()}
    nrmse, rms = {}, {}
    for k in meas:
        err = float(np.sqrt(np.mean((meas[k] - sims[k]) ** 2)))
        sig = float(problem.noise.get(k, 0.0))
        span = float(np.ptp(meas[k]))
        rms[k] = err / sig if sig > 0 else float("nan")
        moves = float(np.std(meas[k])) > RESOLVED_STD * sig
        nrmse[k] = err / span if moves and span > 0 else float("nan")
    key, kind = period_channel(model, chans)
    sig = float(problem.noise.get(key, 0.0)) or None
    em = slip_events(meas[key], dt, kind, noise=sig)
    es = slip_events(sims[key], dt, kind)
    Pm, Ps = em.period, es.period
    if em.cycles:
        Am, As = 0.5 * float(np.ptp(moving_average(meas[key], 3))), 0.5 * float(np.ptp(sims[key]))
    else:
        Am = As = float("nan")
    return Validation(t=t, measured=meas, simulated=sims, nrmse=nrmse, rms=rms, period_measured=Pm,
                      period_simulated=Ps, period_error=(Ps - Pm) / Pm if Pm > 0 else float("nan"),
                      amplitude_measured=Am, amplitude_simulated=As,
                      amplitude_error=(As - Am) / Am if Am > 0 else float("nan"), channel=key, kind=kind,
                      slips_measured=int(em.times.size), slips_simulated=int(es.times.size), period_note=em.why)
