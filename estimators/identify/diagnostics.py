"""What a fitted model's structure misses: the residual's spectrum, its whiteness, the continuity gaps.

A model that can follow the data leaves a residual that looks like the sensors' noise: white,
with no dominant frequency, and its continuity gaps closed.  A model structurally simpler than
the rig (a 1-DOF string fitted to a multi-element one, a friction law of another shape) leaves
what it cannot follow in the residual: a dominant frequency (the stick-slip cycle's harmonics, a
mode the model lacks) holding much of the residual's energy, a residual correlated from sample
to sample, and, where the solver could not close them, gaps at the shooting nodes.  Such a fit
can still be the best the model allows, and useful; :func:`diagnose` says which signs are
present so that the result can say so instead of pretending the model is right.

The tests, on every compared channel (all logs), in units of the channel's noise level:

- **the slow residual**: the residual low-passed at five times the measured signal's dominant
  frequency (the stick-slip cycle and its first harmonics; sensor noise, quantisation and DAQ
  jitter lie mostly above).  A model that follows the data leaves less there than the sensors'
  noise; measured on logs of our own plant (disc, rig3, the drill string) at most 0.42 noise
  levels, on rig3 logs of a plant with a PI loop on another error, a one-sample DAQ delay and a
  torque offset 0.88.  At least :data:`SLOW_ABOVE_NOISE` (1.0) noise levels: the structure
  misses something the sensors resolve.
- **the spectrum**: the largest peak of the residual's Welch spectrum and the share of the
  residual energy within +-5 % of it (at least +-2 bins); a white residual puts 5 bins' worth
  there, or +-5 % of the spectrum's width at high frequencies.  Dominant when the share is at least :data:`SHARE_DOMINANT`.
- **whiteness**: the lag-1 autocorrelation of the residual (white: ``0 +- 2/sqrt(n)``; encoder
  speeds, differences of quantised angles, give negative values), and the Ljung-Box statistic over
  ``min(20, n/5)`` lags with its p-value (reported; with thousands of samples it rejects any
  correlation, and quantisation errors of a slowly turning encoder are themselves correlated, so
  the decision uses the effect sizes).  Correlated: lag-1 autocorrelation at least
  :data:`LAG1_CORRELATED`.
- **gaps**: the largest scaled continuity gap left at a node, where (log, time, state).

A structure "misses" when a channel's slow residual is at least :data:`SLOW_ABOVE_NOISE` noise
levels, or when its residual is correlated with a dominant spectral peak and at least
:data:`RESOLVED` noise levels in RMS (a correlated residual far below the sensors' noise is the
regularised friction's creep, which the sensors do not resolve: 0.057 noise levels on a log of the
student rig's own plant read at the motor only), or when gaps remain above
:data:`~estimators.identify.gauss_newton.GAP_OK`.  The tests are in the noise levels the fit used
(the rig file's sensors or ``options.noise``): a rig file that declares its sensors far coarser
than they are hides a miss, and says so in ``rms`` (far below 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc

from models.signals import dominant_frequency, lowpass
from estimators.identify.gauss_newton import GAP_OK

__all__ = ["StructureDiagnostics", "diagnose", "gap_locator", "residual_peak", "lag1", "ljung_box", "SHARE_DOMINANT",
           "LAG1_CORRELATED", "SLOW_ABOVE_NOISE", "RESOLVED"]

#: share of the residual energy within +-5 % of its spectral peak that makes the peak dominant
SHARE_DOMINANT = 0.25
#: lag-1 autocorrelation of the residual above which it is called correlated (not white)
LAG1_CORRELATED = 0.5
#: RMS of the slow residual (below 5x the signal's dominant frequency), in noise levels, that
#: the sensors resolve: a miss of the structure
SLOW_ABOVE_NOISE = 1.0
#: RMS of a correlated residual with a dominant peak, in noise levels, below which it is not a miss
RESOLVED = 0.5


@dataclass(frozen=True)
class StructureDiagnostics:
    """What the fitted structure leaves in the residual (see the module docstring).

    Attributes
    ----------
    channel : the compared channel whose slow residual is largest (in noise levels)
    rms : ``{channel: RMS of the weighted residual}`` in noise levels (about 1 for a model that
        follows the data to the sensors' noise)
    slow_rms : ``{channel: RMS of the residual below cutoff}`` in noise levels
    cutoff : ``{channel: low-pass frequency [Hz]}`` of the slow residual (5x signal_frequency)
    signal_frequency : ``{channel: dominant frequency [Hz] of the measured signal}``
    peak_frequency : frequency [Hz] of the largest peak of ``channel``'s residual spectrum
    peak_share : share of that residual's energy within +-5 % of ``peak_frequency``
    lag1 : lag-1 autocorrelation of ``channel``'s residual
    ljung_box_p : Ljung-Box p-value of ``channel``'s residual (small: not white)
    sigma2 : residual variance per degree of freedom (noise units)
    max_gap : largest scaled continuity gap at a node (0 without gaps)
    gap_log : 1-based log of that gap; gap_time [s]: the node's time; gap_state: the state
    misses : what the structure misses, in words (empty: nothing found)
    """

    channel: str
    rms: dict
    slow_rms: dict
    cutoff: dict
    signal_frequency: dict
    peak_frequency: float
    peak_share: float
    lag1: float
    ljung_box_p: float
    sigma2: float
    max_gap: float = 0.0
    gap_log: int = 0
    gap_time: float = float("nan")
    gap_state: str = ""
    misses: tuple = ()

    @property
    def dominant(self) -> bool:
        """``channel``'s residual spectrum has a dominant frequency."""
        return bool(self.peak_share >= SHARE_DOMINANT)

    @property
    def white(self) -> bool:
        """``channel``'s residual is (close to) white: neither correlated nor slow above the noise."""
        return bool(self.lag1 < LAG1_CORRELATED and self.slow_rms.get(self.channel, 0.0) < SLOW_ABOVE_NOISE)

    @property
    def structure_ok(self) -> bool:
        return not self.misses

    def as_dict(self) -> dict:
        return {"channel": self.channel, "rms": dict(self.rms), "slow_rms": dict(self.slow_rms),
                "cutoff": dict(self.cutoff), "signal_frequency": dict(self.signal_frequency),
                "peak_frequency": self.peak_frequency, "peak_share": self.peak_share, "lag1": self.lag1,
                "ljung_box_p": self.ljung_box_p, "white": self.white, "dominant": self.dominant,
                "sigma2": self.sigma2, "max_gap": self.max_gap, "gap_log": self.gap_log, "gap_time": self.gap_time,
                "gap_state": self.gap_state, "misses": list(self.misses)}

    def summary(self) -> str:
        """``"structure misses: ..."``, or how close the residual is to noise."""
        if self.misses:
            return "structure misses: " + "; ".join(self.misses)
        c = self.channel
        return (f"the residual looks like the sensors' noise (slowest: {c}, {self.slow_rms.get(c, 0.0):.2g} noise "
                f"levels below {self.cutoff.get(c, float('nan')):.3g} Hz; lag-1 autocorrelation {self.lag1:.2f})")


def lag1(r) -> float:
    """Lag-1 autocorrelation of ``r`` (mean removed); 0 for fewer than 3 samples or a constant."""
    r = np.asarray(r, float)
    if r.size < 3:
        return 0.0
    r = r - r.mean()
    den = float(r @ r)
    return float(r[:-1] @ r[1:] / den) if den > 0 else 0.0


def ljung_box(r, lags: int | None = None) -> tuple[float, float]:
    """Ljung-Box statistic ``Q = n (n+2) sum_k rho_k^2 / (n-k)`` over ``lags`` (default
    ``min(20, n // 5)``) and its chi-square p-value."""
    r = np.asarray(r, float)
    n = r.size
    m = min(20, n // 5) if lags is None else int(lags)
    if n < 10 or m < 1:
        return 0.0, 1.0
    r = r - r.mean()
    den = float(r @ r)
    if den == 0:
        return 0.0, 1.0
    rho = np.array([float(r[:-k] @ r[k:]) / den for k in range(1, m + 1)])
    q = float(n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, m + 1))))
    return q, float(chdtrc(m, q))          # the chi-square survival function


def _welch(x, dt):
    n = len(x)
    nper = int(min(n, max(64, 2 ** int(np.floor(np.log2(max(n // 2, 64)))))))
    from scipy import signal            # imported here: scipy.signal takes 1-2 s to import

    return signal.welch(x - np.mean(x), fs=1.0 / dt, nperseg=nper, detrend="constant")


def residual_peak(residuals, dt: float) -> tuple[float, float]:
    """``(frequency [Hz], share)``: the largest non-DC peak of the summed Welch spectra of the
    residual segments (one per log) and the share of their energy within +-5 % of it (at least
    +-2 bins)."""
    psd, freqs = None, None
    for r in residuals:
        r = np.asarray(r, float)
        if r.size < 16:
            continue
        f, p = _welch(r, dt)
        if psd is None:
            freqs, psd = f, p.copy()
        elif len(p) == len(psd):
            psd += p
        else:                                   # logs of other lengths: onto the first grid
            psd += np.interp(freqs, f, p)
    if psd is None or not np.any(psd[1:] > 0):
        return float("nan"), 0.0
    psd = psd.copy()
    psd[0] = 0.0
    k = int(np.argmax(psd))
    f0 = float(freqs[k])
    df = float(freqs[1] - freqs[0])
    half = max(0.05 * f0, 2.0 * df)
    band = np.abs(freqs - f0) <= half + 1e-12
    total = float(np.sum(psd))
    return f0, float(np.sum(psd[band]) / total) if total > 0 else 0.0


def _dominant(x, dt) -> float:
    f = dominant_frequency(x, dt)
    return f if f > 0 else float("nan")


def gap_locator(intervals, times, shoot_every: int, states):
    """``index -> (log (1-based), time [s], state)`` for the gap vector of a multiple-shooting fit
    (order: interval, state; intervals of the logs one after another; the gap of an interval sits
    at the node that ends it).

    Parameters
    ----------
    intervals : per log, its number of shooting intervals
    times : per log, (n,) sample times [s]
    shoot_every : samples per interval
    states : the model's state names
    """
    nx = len(states)
    ends = np.cumsum(intervals)

    def where(index: int):
        iv, st = divmod(int(index), nx)
        k = int(np.searchsorted(ends, iv, side="right"))
        first = int(ends[k - 1]) if k else 0
        node = iv - first + 1
        t = np.asarray(times[k], float)
        return k + 1, float(t[min(node * shoot_every, t.size - 1)]), str(states[st])

    return where


def diagnose(residuals, measured, dt: float, *, sigma2: float, gaps=None, gap_locator=None) -> StructureDiagnostics:
    """What the structure misses (see the module docstring).

    Parameters
    ----------
    residuals : per log, ``{channel: (n,) weighted residual}`` (measured - fitted) / noise
    measured : per log, ``{channel: (n,) measured values}`` (the same channels)
    dt : sample period [s]
    sigma2 : residual variance per degree of freedom (noise units)
    gaps : (n_gaps,) scaled continuity gaps or None
    gap_locator : ``callable(index) -> (log (1-based), time [s], state name)`` for a gap index
        (:func:`gap_locator`)

    Returns
    -------
    StructureDiagnostics
    """
    names = list(residuals[0]) if residuals else []
    if not names:
        return StructureDiagnostics("", {}, {}, {}, {}, float("nan"), 0.0, 0.0, 1.0, float(sigma2))
    nyq = 0.5 / dt
    rms, slow, cut, fsig = {}, {}, {}, {}
    for c in names:
        segs = [np.asarray(r[c], float) for r in residuals]
        allr = np.concatenate(segs)
        rms[c] = float(np.sqrt(np.mean(allr ** 2))) if allr.size else 0.0
        longest = int(np.argmax([s.size for s in segs]))
        f = _dominant(measured[longest][c], dt)
        fsig[c] = f
        fc = 5.0 * f if np.isfinite(f) and f > 0 else 0.05 * nyq
        fc = min(fc, 0.4 * nyq)
        cut[c] = fc
        lows = [lowpass(s - s.mean(), dt, fc) if s.size > 12 else np.zeros(s.size) for s in segs]
        slow[c] = float(np.sqrt(np.mean(np.concatenate(lows) ** 2))) if allr.size else 0.0
    ch = max(names, key=lambda c: (slow[c], rms[c]))
    segs = [np.asarray(r[ch], float) for r in residuals]
    f0, share = residual_peak(segs, dt)
    longest = int(np.argmax([s.size for s in segs]))
    l1 = float(np.average([lag1(s) for s in segs], weights=[max(s.size, 1) for s in segs]))
    _, p = ljung_box(segs[longest])
    max_gap, g_log, g_time, g_state = 0.0, 0, float("nan"), ""
    if gaps is not None and np.size(gaps):
        a = np.abs(np.asarray(gaps, float))
        j = int(np.argmax(a))
        max_gap = float(a[j])
        if gap_locator is not None:
            g_log, g_time, g_state = gap_locator(j)
    misses = []
    fs = fsig[ch]
    where = ""
    if np.isfinite(fs) and fs > 0 and np.isfinite(f0) and f0 > 0:
        ratio = f0 / fs
        where = (" (the measured signal's dominant frequency)" if abs(ratio - 1) < 0.1 else
                 f" ({ratio:.2g} x the measured signal's dominant frequency {fs:.3g} Hz)")
    slow_miss = slow[ch] >= SLOW_ABOVE_NOISE
    peak_miss = l1 >= LAG1_CORRELATED and share >= SHARE_DOMINANT and rms[ch] >= RESOLVED
    if slow_miss or peak_miss:
        text = (f"the {ch} residual below {cut[ch]:.3g} Hz is {slow[ch]:.2g} times the sensors' noise" if slow_miss
                else f"the {ch} residual is correlated (lag-1 autocorrelation {l1:.2f})")
        text += f"; its spectrum peaks at {f0:.3g} Hz{where} with {100 * share:.0f} % of its energy"
        misses.append(text)
        misses.append(f"the residual is not white (lag-1 autocorrelation {l1:.2f}, Ljung-Box p = {p:.2g}; "
                      f"RMS {rms[ch]:.2g} noise levels)")
    if max_gap > GAP_OK:
        at = f" at log {g_log}, t = {g_time:.4g} s, state {g_state}" if g_state else ""
        misses.append(f"continuity gaps remain at the shooting nodes (largest {max_gap:.2g}, scaled{at})")
    return StructureDiagnostics(ch, rms, slow, cut, fsig, f0, share, l1, p, float(sigma2), max_gap, g_log, g_time,
                                g_state, tuple(misses))
