"""Severity and suppression of a speed record: numpy functions of one signal sampled at a constant
period ``dt`` [s] (the metrics of a closed-loop run, :mod:`mitigate.metrics`, are built on them).

``severity`` is ``(max - min) / (2 reference)`` with the record's own mean as the default reference
(the literature's stick-slip severity); ``moving_severity`` and ``windowed_severity`` apply it over
windows; ``time_to_suppress`` is the time until the moving severity stays below a threshold.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["severity", "windowed_severity", "moving_severity", "time_to_suppress", "stuck_fraction", "amplitude",
           "rms", "total_variation"]


def severity(omega: np.ndarray, reference: float | None = None, stuck: float | None = None) -> float:
    """Stick-slip severity ``(max - min) / (2 |reference|)`` [-]; ``reference`` defaults to the mean
    speed (the literature's SSS), and ``inf`` is returned when it is 0.  ``stuck`` [rad/s]: a record
    whose ``|speed|`` stays at or below it throughout (a stopped body, not a quiet one) has severity 1,
    the severity of a full stick-slip cycle (speed between 0 and twice its mean)."""
    w = np.asarray(omega, dtype=float)
    if stuck is not None and float(np.max(np.abs(w))) <= stuck:
        return 1.0
    m = abs(float(np.mean(w))) if reference is None else abs(float(reference))
    span = float(np.max(w) - np.min(w))
    return span / (2 * m) if m > 0 else float("inf")


def windowed_severity(omega: np.ndarray, dt: float, window: float, stuck: float | None = None) -> np.ndarray:
    """Severity over consecutive non-overlapping windows of ``window`` seconds (``stuck``: :func:`severity`)."""
    n = max(1, int(round(window / dt)))
    w = np.asarray(omega, dtype=float)
    k = len(w) // n
    if k == 0:
        return np.array([severity(w, stuck=stuck)])
    return np.array([severity(w[i * n:(i + 1) * n], stuck=stuck) for i in range(k)])


def moving_severity(omega: np.ndarray, dt: float, window: float, reference: float | None = None,
                    stuck: float | None = None) -> np.ndarray:
    """Severity over a window of ``window`` seconds that moves by one sample (the drilling
    convention); element ``j`` covers samples ``j .. j + n - 1``.  ``reference`` and ``stuck`` as in
    :func:`severity` (default: each window's mean; no stuck rule)."""
    w = np.asarray(omega, dtype=float)
    n = max(1, min(len(w), int(round(window / dt))))
    v = sliding_window_view(w, n)
    mean = np.abs(v.mean(axis=1)) if reference is None else np.full(v.shape[0], abs(float(reference)))
    span = v.max(axis=1) - v.min(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(mean > 0, span / (2 * mean), np.inf)
    if stuck is not None:
        s = np.where(np.abs(v).max(axis=1) <= stuck, 1.0, s)
    return s


def time_to_suppress(omega: np.ndarray, dt: float, window: float, threshold: float,
                     reference: float | None = None, stuck: float | None = None) -> float:
    """Seconds from the first sample to the START of the first moving window from which the moving
    severity stays below ``threshold`` to the end of the record: 0 if it never exceeds it, ``inf``
    if the last window is still above it.  No window length is added: a record that is quiet from
    its first sample gives 0.  ``reference``, ``stuck``: as in :func:`severity`."""
    s = moving_severity(omega, dt, window, reference, stuck)
    above = np.flatnonzero(~(s < threshold))
    if above.size == 0:
        return 0.0
    j = int(above[-1]) + 1
    if j >= s.size:
        return float("inf")
    return j * dt


def stuck_fraction(omega: np.ndarray, threshold: float) -> float:
    """Fraction of samples with ``|omega| <= threshold`` [rad/s] (no default: a speed threshold
    comes from the rig and its programme, :func:`measured_stuck_speed`)."""
    w = np.asarray(omega, dtype=float)
    return float(np.mean(np.abs(w) <= threshold))


def amplitude(omega: np.ndarray) -> float:
    """Half the peak-to-peak speed [rad/s]."""
    w = np.asarray(omega, dtype=float)
    return 0.5 * float(np.max(w) - np.min(w))


def rms(x: np.ndarray) -> float:
    """Root mean square ``sqrt(mean(x^2))`` (same unit as ``x``)."""
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def total_variation(x: np.ndarray) -> float:
    """``sum |x[k+1] - x[k]|`` (same unit as ``x``)."""
    x = np.asarray(x, dtype=float)
    return float(np.sum(np.abs(np.diff(x)))) if x.size > 1 else 0.0
