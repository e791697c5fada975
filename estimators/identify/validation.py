"""Hold-out validation: free-run the EXACT stick/slip plant on a held-back segment and compare.

The last ``holdout`` fraction of the first log is kept out of the fit.  From the fitted state at
the end of the training segment, the exact plant (:func:`models.plant.step_function`,
``method = "hybrid"``) is driven by the logged inputs (corrected through the fitted load-cell
offsets and gains) with the fitted parameters.  Encoder speeds are compared as sample means
(differences of the plant's angles, like the DAQ's), angle differences with the fitted encoder
zero subtracted, other channels as read.  The stick-slip period and amplitude of the first compared
speed are compared too: the period from the signal's autocorrelation (:func:`cycle_period`; a
hold-out of a few cycles resolves it to a few per cent, where the spectrum's resolution, one over
the segment's length, would not), else its dominant frequency (:func:`models.signals.period`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from models.errors import DataError
from models.plant import SimOptions, step_function
from models.signals import moving_average, period

__all__ = ["Validation", "validate", "cycle_period"]


def cycle_period(x, dt: float) -> float:
    """Period [s] of the dominant oscillation of ``x``: the first strong maximum of its
    autocorrelation after the first zero crossing, refined by a parabola through the three lags
    around it; NaN when ``x`` does not oscillate within 80 % of its length.

    Parameters
    ----------
    x : (n,) samples; dt : sample period [s]
    """
    x = np.asarray(x, float)
    n = x.size
    if n < 8:
        return float("nan")
    x = moving_average(x - x.mean(), 3)
    if not np.any(x):
        return float("nan")
    f = np.fft.rfft(x, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac = ac / ac[0]
    neg = np.flatnonzero(ac < 0)
    if neg.size == 0:
        return float("nan")
    lo, hi = int(neg[0]), int(0.8 * n)
    if hi <= lo + 2:
        return float("nan")
    seg = ac[lo:hi]
    top = float(np.max(seg))
    if top <= 0:
        return float("nan")
    k = None
    for i in range(1, seg.size - 1):
        if seg[i] >= seg[i - 1] and seg[i] >= seg[i + 1] and seg[i] >= 0.5 * top:
            k = lo + i
            break
    if k is None:
        return float("nan")
    a, b, c = ac[k - 1], ac[k], ac[k + 1]
    den = a - 2 * b + c
    shift = 0.5 * (a - c) / den if den < 0 else 0.0
    return float((k + shift) * dt)


@dataclass(frozen=True)
class Validation:
    """Free-run prediction of a held-back log segment with the fitted parameters.

    Attributes
    ----------
    t : (n,) times [s]; measured, simulated : ``{channel: (n,)}``
    nrmse : per channel RMS error / range of the measured signal
    period_measured, period_simulated [s], period_error (relative)
    amplitude_measured, amplitude_simulated [rad/s], amplitude_error (relative)
    channel : the speed channel the period and amplitude refer to
    method : "hybrid" (the exact stick/slip plant)
    """

    t: np.ndarray
    measured: dict = field(repr=False)
    simulated: dict = field(repr=False)
    nrmse: dict = field(default_factory=dict)
    period_measured: float = float("nan")
    period_simulated: float = float("nan")
    period_error: float = float("nan")
    amplitude_measured: float = float("nan")
    amplitude_simulated: float = float("nan")
    amplitude_error: float = float("nan")
    channel: str = ""
    method: str = "hybrid"


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
    nrmse = {}
    for k in meas:
        span = float(np.ptp(meas[k]))
        nrmse[k] = float(np.sqrt(np.mean((meas[k] - sims[k]) ** 2)) / span) if span > 0 else float("nan")
    speeds = [c.name for c in chans if c.kind in ("speed", "value") and c.unit == "rad/s"]
    key = speeds[0] if speeds else chans[0].name
    Pm, Ps = cycle_period(meas[key], dt), cycle_period(sims[key], dt)
    if not (np.isfinite(Pm) and np.isfinite(Ps)):
        Pm, Ps = period(meas[key], dt), period(sims[key], dt)
    Am, As = 0.5 * float(np.ptp(moving_average(meas[key], 3))), 0.5 * float(np.ptp(sims[key]))
    return Validation(t=t, measured=meas, simulated=sims, nrmse=nrmse, period_measured=Pm, period_simulated=Ps,
                      period_error=(Ps - Pm) / Pm if Pm > 0 else float("nan"), amplitude_measured=Am,
                      amplitude_simulated=As, amplitude_error=(As - Am) / Am if Am > 0 else float("nan"),
                      channel=key)
