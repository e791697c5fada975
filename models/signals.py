"""Signal helpers on uniformly sampled records: spectra, filters, stick-slip cycles.

These build nothing and solve nothing; they turn a sampled signal (numpy arrays at a constant
period ``dt`` [s]) into a number or a filtered copy.  They live here, on the lowest floor, so
that identification (``estimators``) and the closed-loop metrics (``mitigate``) share them
without one importing the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.errors import ConfigError

__all__ = ["stuck_runs", "dominant_frequency", "period", "moving_average", "lowpass", "autocorrelation_time", "white_part",
           "StickSlipCycles", "stick_slip_cycles"]


def dominant_frequency(signal, dt: float) -> float:
    """Frequency [Hz] of the largest non-DC peak of the (mean-removed, Hann-windowed) spectrum.

    Parameters
    ----------
    signal : (n,) samples
    dt : sample period [s]

    Returns
    -------
    float : the peak frequency [Hz]; 0 for a constant or too short signal.
    """
    x = np.asarray(signal, dtype=float)
    x = x - x.mean() if x.size else x
    if len(x) < 4 or not np.any(x):
        return 0.0
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    freqs = np.fft.rfftfreq(len(x), dt)
    spec[0] = 0.0
    return float(freqs[int(np.argmax(spec))])


def period(signal, dt: float) -> float:
    """``1 / dominant_frequency`` [s]; NaN when there is no dominant frequency."""
    f = dominant_frequency(signal, dt)
    return 1.0 / f if f > 0 else float("nan")


def moving_average(x, n: int) -> np.ndarray:
    """Centred moving average over ``n`` samples (edges padded with the end values)."""
    x = np.asarray(x, dtype=float)
    if n <= 1 or x.size == 0:
        return x.copy()
    k = np.ones(n) / n
    return np.convolve(np.pad(x, (n // 2, n - 1 - n // 2), mode="edge"), k, mode="valid")


def lowpass(x, dt: float, cutoff: float, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass of ``x`` at ``cutoff`` [Hz] (``scipy.signal.filtfilt``).

    Raises
    ------
    ConfigError : ``cutoff`` not in (0, Nyquist).
    """
    from scipy.signal import butter, filtfilt

    nyq = 0.5 / dt
    if not (math.isfinite(cutoff) and 0 < cutoff < nyq):
        raise ConfigError(f"cutoff must be in (0, {nyq:g}) Hz (the Nyquist frequency), got {cutoff!r}")
    x = np.asarray(x, dtype=float)
    b, a = butter(order, cutoff / nyq)
    if x.size <= 3 * (max(len(a), len(b)) + 1):
        return x.copy()
    return filtfilt(b, a, x)


def autocorrelation_time(r) -> float:
    """Integrated autocorrelation time ``1 + 2 sum rho_k`` of a residual sequence (Sokal's
    window: stop at lag ``k >= 5 tau``); at least 1."""
    r = np.asarray(r, dtype=float)
    r = r - np.mean(r) if r.size else r
    n = r.size
    if n < 4 or not np.any(r):
        return 1.0
    f = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac = ac / ac[0]
    tau = 1.0
    for k in range(1, n // 2):
        tau += 2 * ac[k]
        if k >= 5 * tau:
            break
    return max(1.0, float(tau))


def white_part(x, dt: float, corner: float = 0.5) -> tuple[float, float]:
    """``(std, lag-1 autocorrelation)`` of the part of ``x`` above ``corner`` [Hz].

    For white measurement noise on a slowly varying signal the fast part is the noise itself:
    its lag-1 autocorrelation is near 0 and its std is the noise level (at 100 Hz, 99 % of a
    white sequence's variance lies above 0.5 Hz).  A signal that follows a loop (a PI torque)
    has correlated fast content instead.
    """
    x = np.asarray(x, dtype=float)
    if x.size < 8:
        return 0.0, 1.0
    fast = x - lowpass(x, dt, min(corner, 0.45 / dt))
    sd = float(np.std(fast))
    if sd == 0.0:
        return 0.0, 1.0
    return sd, float(np.corrcoef(fast[:-1], fast[1:])[0, 1])


@dataclass(frozen=True)
class StickSlipCycles:
    """Stick-slip cycles found in a speed record (see :func:`stick_slip_cycles`).

    Attributes
    ----------
    cycles : number of complete cycles (stick onset to stick onset)
    period : mean cycle duration [s]
    stick_time : mean stick duration per cycle [s]
    slip_time : ``period - stick_time`` [s]
    peak_speed : mean per-cycle peak of the speed [rad/s]
    mean_speed : mean speed over the complete cycles [rad/s]
    stuck_fraction : fraction of the record's samples below the threshold
    onsets : sample indices of the stick onsets
    """

    cycles: int
    period: float
    stick_time: float
    slip_time: float
    peak_speed: float
    mean_speed: float
    stuck_fraction: float
    onsets: np.ndarray


def stuck_runs(stuck, min_length: int = 1) -> list[tuple[int, int]]:
    """``(onset, release)`` sample indices of the runs of ``stuck`` (a boolean record) that start
    and end within it and last at least ``min_length`` samples (``stuck[onset:release]`` is True)."""
    d = np.diff(np.asarray(stuck).astype(int))
    on = np.flatnonzero(d == 1) + 1
    off = np.flatnonzero(d == -1) + 1
    runs = []
    for a in on:
        b = off[off > a]
        if b.size and b[0] - a >= min_length:
            runs.append((int(a), int(b[0])))
    return runs


def stick_slip_cycles(omega, dt: float, threshold: float, *, skip: float = 0.0) -> StickSlipCycles | None:
    """The stick-slip cycles of a (forward-turning) speed record, or None if it does not stick-slip.

    A sample is stuck when ``|omega| <= threshold`` [rad/s].  A cycle runs from one stick onset
    to the next; its stick time is the length of its stuck run.  Runs shorter than 2 samples
    are merged into the slip.  ``skip`` [s] ignores the start of the record (a start-up transient).
    At least 3 onsets and a stuck fraction in [2 %, 90 %] are required.
    """
    w = np.asarray(omega, dtype=float)
    k0 = int(round(skip / dt))
    w = w[k0:]
    if w.size < 10:
        return None
    stuck = np.abs(w) <= threshold
    frac = float(stuck.mean())
    if not 0.02 <= frac <= 0.9:
        return None
    runs = stuck_runs(stuck, min_length=2)
    if len(runs) < 3:
        return None
    onsets = np.array([a for a, _ in runs])
    periods = np.diff(onsets) * dt
    sticks = np.array([(b - a) * dt for a, b in runs[:-1]])
    peaks = np.array([np.max(w[a:c]) for (a, _), c in zip(runs[:-1], onsets[1:])])
    span = w[onsets[0]:onsets[-1]]
    return StickSlipCycles(len(runs) - 1, float(np.mean(periods)), float(np.mean(sticks)),
                           float(np.mean(periods) - np.mean(sticks)), float(np.mean(peaks)), float(np.mean(span)),
                           frac, onsets + k0)
