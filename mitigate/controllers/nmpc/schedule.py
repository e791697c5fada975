"""Weights for what stays: the NMPC acts hard while the objective body stick-slips and gently
once it slides calmly.

Why.  At steady sliding nothing is left to suppress but the noise of the state estimate, and a
state feedback passes that noise to the plant with its full gain -- after the estimator's low-
pass, i.e. right in the band of the torsional mode.  With the TRUE state (rig3, 30 rpm, 20 N,
motor only) the NMPC's residual severity is 0.0000; with the EKF's estimate it was 0.0051
against SoftSpeed's 0.0026, whose set-point moves five times less.  Raising the set-point's and
the servo forces' tracking weights (``ref``, ``force``) ten- to fifteen-fold lowers the feedback
gain and the residual three- to fivefold, but such a controller cannot break an established
stick-slip (at 15 rpm it never does).  So the weights are scheduled on what the estimate shows:

    s = sqrt(2) rms((w - w_nom) / w_nom) of the estimated objective speed w over the last
        ``window`` seconds (for an oscillation about the nominal speed, the stick-slip severity
        (max - min) / (2 mean) of a sinusoid, but not set by the estimate's noise peaks; a body
        held off its nominal speed, e.g. by a pin, is not calm either)
    g = clip(log(s / s_lo) / log(s_hi / s_lo), 0, 1)      1: stick-slip, 0: calm sliding
    f = hold_gain ** (1 - g);   ref, d_ref <- x f;   force <- x f^2 (x f without the drive)

with ``window`` one stick-slip period and ``(s_lo, s_hi)`` the options' ``calm_band``.  The servo
forces get the square: calm, the pin or the weight on bit returns to the programme and stays
there (on the lab drill string a weight on bit that dithered by 0.26 N left 2.2 times the
industry's residual, held within 0.002 N 1.4 times).  The weights sit in the OCP's parameter
vector, so nothing is rebuilt.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CalmSchedule"]


class CalmSchedule:
    """The factor on the tracking weights from the recent estimated speed (module docstring).

    Parameters
    ----------
    window : length of the severity window [s] (one stick-slip period)
    dt : period of :meth:`update` calls [s]
    band : ``(s_lo, s_hi)``, severities [-] between which the factor moves from ``hold_gain`` to 1
    hold_gain : factor at calm sliding (1: no scheduling)
    """

    def __init__(self, window: float, dt: float, band: tuple[float, float], hold_gain: float):
        self.n = max(2, int(math.ceil(window / dt)))
        self.lo, self.hi = float(band[0]), float(band[1])
        self.hold_gain = float(hold_gain)
        self.reset()

    def reset(self) -> None:
        self._buf = np.full(self.n, np.nan)
        self._k = 0
        self.severity = math.inf
        self.factor = 1.0

    def update(self, speed: float, nominal: float) -> None:
        """Record the objective body's estimated and nominal speeds [rad/s]."""
        d = (speed - nominal) / abs(nominal) if nominal != 0 else math.inf
        self._buf[self._k % self.n] = d if math.isfinite(d) else 1e6
        self._k += 1

    def current(self) -> float:
        """The factor from the window so far (stick-slip until half a window is recorded)."""
        if self.hold_gain == 1.0 or self._k < self.n // 2:
            self.severity, self.factor = math.inf, 1.0
            return 1.0
        d = self._buf[:min(self._k, self.n)]
        s = math.sqrt(2.0 * float(np.mean(d * d)))
        g = min(max(math.log(max(s, 1e-300) / self.lo) / math.log(self.hi / self.lo), 0.0), 1.0)
        self.severity = s
        self.factor = self.hold_gain ** (1.0 - g)
        return self.factor
