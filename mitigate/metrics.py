"""Stick-slip metrics of a speed record.

- severity SSS = (max - min) / (2 mean) of the R1 speed (overall and over sliding windows);
- fraction of time stuck (|omega| below a threshold);
- stick-slip amplitude (half peak-to-peak of the speed) and dominant frequency.

All functions take numpy arrays sampled at a constant period ``dt`` [s].
"""

from __future__ import annotations

import numpy as np

__all__ = ["severity", "windowed_severity", "stuck_fraction", "amplitude", "dominant_frequency"]


def severity(omega: np.ndarray) -> float:
    """Stick-slip severity ``(max - min) / (2 |mean|)`` [-]; ``inf`` if the mean speed is 0."""
    w = np.asarray(omega, dtype=float)
    m = abs(float(np.mean(w)))
    span = float(np.max(w) - np.min(w))
    return span / (2 * m) if m > 0 else float("inf")


def windowed_severity(omega: np.ndarray, dt: float, window: float) -> np.ndarray:
    """Severity over consecutive non-overlapping windows of ``window`` seconds."""
    n = max(1, int(round(window / dt)))
    w = np.asarray(omega, dtype=float)
    k = len(w) // n
    if k == 0:
        return np.array([severity(w)])
    return np.array([severity(w[i * n:(i + 1) * n]) for i in range(k)])


def stuck_fraction(omega: np.ndarray, threshold: float = 0.05) -> float:
    """Fraction of samples with ``|omega| <= threshold`` [rad/s] (measured speeds are noisy, so > 0)."""
    w = np.asarray(omega, dtype=float)
    return float(np.mean(np.abs(w) <= threshold))


def amplitude(omega: np.ndarray) -> float:
    """Half the peak-to-peak speed [rad/s]."""
    w = np.asarray(omega, dtype=float)
    return 0.5 * float(np.max(w) - np.min(w))


def dominant_frequency(signal: np.ndarray, dt: float) -> float:
    """Frequency [Hz] of the largest non-DC peak of the (mean-removed, Hann-windowed) spectrum."""
    x = np.asarray(signal, dtype=float)
    x = x - x.mean()
    if len(x) < 4 or not np.any(x):
        return 0.0
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    freqs = np.fft.rfftfreq(len(x), dt)
    spec[0] = 0.0
    return float(freqs[int(np.argmax(spec))])
