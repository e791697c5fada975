"""The programme's band of a commanded servo force, kept on its moving mean.

A servo force with a positive programme is a job (a weight on bit): the metrics judge the mean
applied force over every moving window of one stick-slip period against ``force_band`` times the
programme's mean there (:mod:`mitigate.metrics.closed_loop`, ``force_violation``).  Bounding every
command to the band is stricter than that (the controller could never lower the force for a moment
and make up for it later, as D-OSKIL does), so the NMPC keeps the mean itself:

* :class:`ForceHistory` holds, per commanded servo, the force the servo applied (the NMPC's replica
  of it, :class:`models.actuators.Servo`) and the programme over the last ``W`` DAQ samples;
* :func:`window_bounds` gives the range of the command ``c`` that, held, keeps the mean of every
  window ending in the next ``n_look`` samples within the band: the samples until the next plan
  and the time the servo needs to cross its range (its force cannot jump back when the mean nears
  an edge).  The applied forces come from the servo's own model (lag and rate limit, as the
  replica), so each window's force is a nondecreasing function of ``c``, and each end of the range
  is a bisection.  Where no held command keeps every window in the band (the band outside the
  servo's range, or a past that leaves no room) the command is the middle of the two ends.

The OCP takes the range as the command's box at every stage: the first move is exact; later
stages are re-planned with their own range.  The same arithmetic, in the same order, is the
compiled step's (``csrc/ss_nmpc.c``, ``window_bounds``): the two are bit-identical.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ForceHistory", "window_bounds"]


class ForceHistory:
    """Ring buffers of the applied force and the programme of ``ns`` servos over ``n`` DAQ samples."""

    def __init__(self, ns: int, n: int):
        self.ns, self.n = int(ns), int(n)
        self.force = np.zeros((self.ns, max(self.n, 1)))
        self.programme = np.zeros((self.ns, max(self.n, 1)))
        self.head = 0            # index of the newest sample
        self.filled = False

    def fill(self, forces, programmes) -> None:
        """Every past sample at these forces and programmes [N] (the programme held before the NMPC)."""
        self.force[:] = np.asarray(forces, float)[:, None]
        self.programme[:] = np.asarray(programmes, float)[:, None]
        self.head, self.filled = 0, True

    def push(self, forces, programmes) -> None:
        """One DAQ sample's applied forces and programmes [N]."""
        self.head = (self.head + 1) % self.n
        self.force[:, self.head] = forces
        self.programme[:, self.head] = programmes

    def newest_first(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(forces, programmes) of servo ``k``, the newest sample first."""
        idx = (self.head - np.arange(self.n)) % self.n
        return self.force[k, idx], self.programme[k, idx]


def _sums_ok(c, old_f, old_p, s0, p, servo, n_look, ratio, upper):
    """True if every window ending in the next ``n_look`` samples keeps its force's sum at least
    (``upper``: at most) ``ratio`` x its programme's sum, the command ``c`` held."""
    n_min, n_max, alpha, step = servo
    w = len(old_f)
    target = min(max(c, n_min), n_max)
    s, new = s0, [0.0]
    for j in range(1, n_look + 1):
        delta = alpha * (target - s)
        s += min(max(delta, -step), step)
        new.append(new[-1] + s)
        n_new = j if j < w else w
        n_old = w - n_new
        f = (old_f[n_old - 1] if n_old > 0 else 0.0) + (new[j] - new[j - n_new])
        tot = (old_p[n_old - 1] if n_old > 0 else 0.0) + n_new * p
        if (f > ratio * tot) if upper else (f < ratio * tot):
            return False
    return True


def _end(ok, lo: float, hi: float, smallest: bool) -> float:
    """The smallest (``smallest``) or the largest command in ``[lo, hi]`` for which the monotone test
    ``ok`` holds, by bisection (the nearer end of the range when it holds nowhere)."""
    near, far = (lo, hi) if smallest else (hi, lo)
    if ok(near):
        return near
    if not ok(far):
        return far
    a, b = near, far            # ok(a) false, ok(b) true
    for _ in range(BISECTIONS):
        mid = 0.5 * (a + b)
        if ok(mid):
            b = mid
        else:
            a = mid
    return b


#: bisection steps of :func:`window_bounds` (a servo range over 2^52: at the doubles' resolution)
BISECTIONS = 52


def window_bounds(forces, programmes, s0: float, p: float, servo, n_look: int, band, lo: float,
                  hi: float) -> tuple[float, float]:
    """The range of a servo command [N] that keeps every window's mean force within the band.

    Parameters
    ----------
    forces, programmes : (W,) the applied force and the programme [N] of the last ``W`` samples, the
        newest first
    s0 : the servo's force now [N]; p : the programme over the coming samples [N] (> 0)
    servo : ``(n_min, n_max, alpha, step)``: the servo's range [N], its lag's factor per DAQ sample
        ``1 - exp(-dt_daq / tau)`` (1: no lag) and its rate limit per sample [N]
        (:class:`models.actuators.Servo`'s arithmetic)
    n_look : the windows ending in the next ``n_look`` samples are checked, the command held
        over them (at least the samples until the next plan, and the time the servo needs to
        cross its range: the force cannot jump back)
    band : ``(low, high)`` ratios of a window's mean force to its programme's mean
    lo, hi : the command's range [N]

    Returns
    -------
    (low, high) : the command's range [N], inside ``[lo, hi]``; ``low == high`` when no held command
    keeps every window in the band (the middle of the nearest ends).

    Every window's force is a nondecreasing function of the held command (the servo's step is), so
    each end is a bisection over ``[lo, hi]`` (:data:`BISECTIONS` steps, the feasible end kept).
    """
    old_f = np.cumsum(forces).tolist()      # sequential sums, newest first (the compiled step adds in this order)
    old_p = np.cumsum(programmes).tolist()
    b_lo, b_hi = float(band[0]), float(band[1])
    args = (old_f, old_p, float(s0), float(p), servo, int(n_look))
    c_lo = _end(lambda c: _sums_ok(c, *args, b_lo, False), lo, hi, smallest=True)
    c_hi = _end(lambda c: _sums_ok(c, *args, b_hi, True), lo, hi, smallest=False) if math.isfinite(b_hi) else hi
    if c_lo > c_hi:
        c_lo = c_hi = 0.5 * (c_lo + c_hi)
    return c_lo, c_hi
