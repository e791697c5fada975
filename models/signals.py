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
           "StickSlipCycles", "stick_slip_cycles", "SlipEvents", "slip_events", "slip_period", "SLIP_KINDS"]


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


#: what a record of :func:`slip_events` is: "speed" (a sliding body's speed: a slip is a burst from
#: rest) or "force" (a spring's force, twist or torque: a slip is a sharp drop of a slow build-up)
SLIP_KINDS = ("speed", "force")


@dataclass(frozen=True)
class SlipEvents:
    """The slip events of a stick-slip record (see :func:`slip_events`).

    Attributes
    ----------
    times : (n,) onset of each slip [s from the record's first sample]
    period : median time between consecutive slips [s]; NaN with fewer than two slips (steady
        sliding, a stuck record, an oscillation without sticking)
    intervals : (n - 1,) times between consecutive slips [s]
    kind : "speed" or "force" (:data:`SLIP_KINDS`)
    why : why no period was found ("" when there is one)
    """

    times: np.ndarray
    period: float
    intervals: np.ndarray
    kind: str
    why: str = ""

    @property
    def cycles(self) -> int:
        """Number of complete cycles (slip to slip)."""
        return int(self.intervals.size)


#: a force record's running median [samples] before its slips are looked for (removes spikes of up to 4 samples)
DESPIKE = 9
#: a slip's drop is at least this fraction of the force record's span (1st to 99th percentile) ...
SLIP_SPAN = 0.05
#: ... and this many noise levels (the measured slider's noise runs reach 9, its smallest slips 20)
SLIP_NOISE = 15.0


def _noise_level(x) -> float:
    """Robust white-noise level of ``x``: the MAD of its first differences (a slow trend or a
    sawtooth's constant build-up moves the median, not the spread) over sqrt(2)."""
    d = np.diff(x)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2)) if d.size else 0.0


def _resolution(x) -> float:
    """The smallest step of a quantised record (0 for a continuous one)."""
    d = np.abs(np.diff(x))
    d = d[d > 1e-12 * (float(np.max(np.abs(x))) + 1e-300)]
    if d.size < 8:
        return 0.0
    q = float(np.min(d))
    return q if np.mean(np.abs(d / q - np.round(d / q)) < 0.05) > 0.9 else 0.0


def _none(kind: str, why: str) -> SlipEvents:
    return SlipEvents(np.zeros(0), float("nan"), np.zeros(0), kind, why)


def _speed_slips(x, dt: float, floor: float) -> tuple[np.ndarray, str]:
    a = x * (1.0 if np.mean(x) >= 0 else -1.0)
    peak = float(np.percentile(a, 99))
    if peak <= 4 * floor:
        return np.zeros(0), "no speed above the noise"
    lo, hi = min(max(0.1 * peak, 2 * floor), 0.3 * peak), 0.5 * peak
    slips, rest = [], None
    for k in range(a.size):
        if a[k] <= lo:
            rest = k
        elif a[k] >= hi and rest is not None:
            slips.append(rest)          # the last sample at rest before the burst: the slip's onset
            rest = None
    if not slips:
        return np.zeros(0), ("the body never comes to rest (steady sliding)" if np.min(a) > lo
                             else "no slip from rest")
    return np.asarray(slips, float) * dt, ""


def _force_slips(x, dt: float, floor: float) -> tuple[np.ndarray, str]:
    d = np.diff(x)
    if d.size < 4:
        return np.zeros(0), "too short"
    # the slips are the fast edges: drops for a spring loaded forwards, rises for one loaded backwards
    y = x if abs(np.percentile(d, 0.5)) >= abs(np.percentile(d, 99.5)) else -x
    span = float(np.percentile(y, 99) - np.percentile(y, 1))
    if span <= 10 * floor:
        return np.zeros(0), "no variation above the noise (steady sliding)"
    dy = np.diff(y)
    falling = dy < 0
    runs = stuck_runs(np.r_[False, falling, False], 1)           # (first, end) indices into dy, shifted by 1
    # a step or two of plateau inside a slip's edge (a running median's, a quantised record's) does not split it
    joined = []
    for a, b in runs:
        if joined and a - joined[-1][1] <= 2:
            joined[-1] = (joined[-1][0], b)
        else:
            joined.append((a, b))
    runs = joined
    drops = np.array([y[a - 1] - y[b - 1] for a, b in runs]) if runs else np.zeros(0)
    if drops.size == 0:
        return np.zeros(0), "no drop"
    # well above the noise and at least a twentieth of the record's span: a measured slider's slips range
    # over 10x in size (4-45 mN), so no fraction of the largest separates them from the noise's runs
    big = max(SLIP_NOISE * floor, SLIP_SPAN * span)
    keep = [(a - 1, b - 1) for (a, b), dr in zip(runs, drops) if dr >= big]
    if not keep:
        return np.zeros(0), "no drop above the noise (steady sliding)"
    # a slip split by a noise blip is one slip: merge drops closer than their own length
    merged = [list(keep[0])]
    for a, b in keep[1:]:
        if a - merged[-1][1] <= max(2, (merged[-1][1] - merged[-1][0])):
            merged[-1][1] = b
        else:
            merged.append([a, b])
    starts = np.array([a for a, _ in merged], float)
    if starts.size >= 2:
        # a sawtooth: each drop much shorter than the build-up before the next (a smooth
        # oscillation falls for half its period)
        dur = np.median([b - a for a, b in merged])
        if dur > 0.35 * np.median(np.diff(starts)):
            return np.zeros(0), "an oscillation, not a sawtooth (its falls are as slow as its rises)"
    return starts * dt, ""


def slip_events(x, dt: float, kind: str = "speed", *, noise: float | None = None, smooth: int = 3) -> SlipEvents:
    """The slips of a stick-slip record, found as events, not as the spectrum's peak.

    A spectrum's peak misreads an irregular sawtooth (slips every 1.41-1.50 s read as 5.23 s and
    7.41 s on a paper-on-paper slider, issue 28): each slip is found here where it happens.

    - ``kind = "speed"``: a sliding body's speed.  A slip is a burst from rest: the speed rises above
      half its 99th percentile after having been at rest (below 0.1 of it or 2 noise levels, at most
      0.3 of it); its onset is the last sample at rest.  A body that never comes to rest (steady
      sliding, an oscillation about a sliding speed) has none, nor a record whose 99th percentile
      is within 4 noise levels.
    - ``kind = "force"``: a spring's force, twist or a shaft's torque.  A slip is a sharp drop of a
      slow build-up (the fast edges' sign is read from the record: a spring loaded backwards rises):
      a falling run of the record of at least a quarter of the largest drops (the 95th percentile of
      those above 6 noise levels), 6 noise levels and :data:`SLIP_SPAN` of the record's span; runs closer
      than their own length merge.  Spikes go first: a running median over :data:`DESPIKE` samples
      (a measured slider's force holds spikes as large as its slips, which read as 139 slips in 8 s
      where there were 11).  A record whose span (1st to 99th
      percentile) is within 10 noise levels has none.
      The drops must be short against the time between them (at most 0.35 of it): a smooth
      oscillation falls for half its period and is not a stick-slip.

    Parameters
    ----------
    x : (n,) samples
    dt : sample period [s]
    kind : "speed" or "force" (:data:`SLIP_KINDS`)
    noise : the record's noise level (its std, or a quantisation step) in its unit; None: estimated
        from the record (the MAD of its differences; at least its quantisation step)
    smooth : centred moving average over this many samples first (quantised speeds)

    Returns
    -------
    SlipEvents : the onsets, their median interval (the stick-slip period) and, when there is none,
        why (``why``: steady sliding, no sticking, too few slips)

    Raises
    ------
    ConfigError : an unknown ``kind`` or a ``dt`` that is not > 0
    """
    if kind not in SLIP_KINDS:
        raise ConfigError(f"kind must be one of {', '.join(SLIP_KINDS)}, got {kind!r}")
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ConfigError(f"dt must be a number > 0 s, got {dt!r}")
    raw = np.asarray(x, dtype=float)
    if raw.size < 8 or not np.all(np.isfinite(raw)):
        return _none(kind, "too short" if raw.size < 8 else "non-finite samples")
    if kind == "force":
        # a measured force carries impulsive spikes (a paper-on-paper slider's sensor: up to 30 mN, one to a
        # few samples, against slips of 5-35 mN); a running median removes them and keeps a slip's edge
        from scipy.ndimage import median_filter
        xs = moving_average(median_filter(raw, size=DESPIKE, mode="nearest"), smooth)
    else:
        xs = moving_average(raw, smooth)
    # the noise level after the moving average (white noise: / sqrt(smooth)), at least half a quantisation step
    floor = max((noise if noise is not None else _noise_level(raw)) / math.sqrt(max(smooth, 1)), _resolution(raw) / 2)
    times, why = (_speed_slips if kind == "speed" else _force_slips)(xs, float(dt), floor)
    if times.size < 2:
        return SlipEvents(times, float("nan"), np.zeros(0), kind, why or "fewer than two slips")
    iv = np.diff(times)
    return SlipEvents(times, float(np.median(iv)), iv, kind, "")


def slip_period(x, dt: float, kind: str = "speed", *, noise: float | None = None) -> float:
    """The stick-slip period [s] of a record: :func:`slip_events`' median time between slips; NaN
    where it finds fewer than two (steady sliding)."""
    return slip_events(x, dt, kind, noise=noise).period
