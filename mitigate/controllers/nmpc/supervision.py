"""The NMPC's supervision: what it decides around its OCP from the objective body's recent speed.

The OCP (:mod:`.stage`) minimises, over half a stick-slip period ahead, the objective body's
speed error and the springs' relative speeds, against staying near the programme (``ref``,
``force``) and moving gently (``d_ref``, ``d_force``).  Three decisions around it need a memory
of the last stick-slip period, and they share ONE window of the objective body's estimated
speed (:class:`SpeedWindow`, fed once per controller call, so it spans one period whatever the
call period):

**The calm schedule (weights for what stays).**  At steady sliding nothing is left to suppress
but the noise of the state estimate, and a state feedback passes that noise to the plant with
its full gain -- after the estimator's low-pass, right in the band of the torsional mode.  With
the TRUE state (rig3, 30 rpm, 20 N, motor only) the NMPC's residual severity is 0.0000; with the
EKF's estimate it was 0.0051 against SoftSpeed's 0.0026, whose set-point moves five times less.
Raising the tracking weights ten- to fifteen-fold lowers the residual three- to fivefold, but
such a controller cannot break an established stick-slip.  So the weights follow what the
estimate shows::

    s = sqrt(2) rms((w - w_nom) / w_nom)   over the window (for an oscillation about the nominal
        speed, the stick-slip severity of a sinusoid; a body held off its nominal speed is not calm)
    g = clip(log(s / s_lo) / log(s_hi / s_lo), 0, 1)      1: stick-slip, 0: calm sliding
    f = hold_gain ** (1 - g);   ref, d_ref <- x f;   force <- x f^2 (x f without the drive)

with ``(s_lo, s_hi)`` the options' ``calm_band``; until half a window is recorded, f = 1.  The
servo forces get the square: calm, the pin or the weight on bit returns to the programme and
stays there (on the lab drill string a weight on bit that dithered by 0.26 N left 2.2 times the
industry's residual, held within 0.002 N 1.4 times).

**The offset-free speed trim.**  Where the plant is not the model, the estimator settles on a
state the model can explain, and along the directions unobservable at steady sliding (twist,
encoder zero, friction factor) that state can be far from the truth; the set-point the model
says holds the programme does not hold the plant's (suite ``mismatch_p40``: the motor-only NMPC
ran the disc 4.2 % fast, 6 of 18 runs left the speed band).  The speed itself is measured, so
the target moves by an integral of the mean speed error (offset-free MPC)::

    d(trim)/dt = (w_prog - mean(w)) / tau,   |trim| <= TRIM_LIMIT w_prog,   target = w_prog + trim

integrated once the window is full, only while calm (``sqrt(2) std(w) / w_prog`` below
``calm_band[0]``), only while the body slides (``min |w|`` above :data:`SLIDING_FRACTION` of the
programme: a still body is calm too; from rest the trim once wound up by 11 % in 8 s), and only
beyond :data:`TRIM_DEADBAND` of the programme (on ``established`` the estimate's noise doubled
what stays).  ``tau`` is one stick-slip period by default (the mean's window delays the error by
about T/2: 60 degrees of phase margin).  Only an NMPC that commands the drive trims.

**The stall guard** (:meth:`Supervisor.stalled`).  Within its horizon (half a period) the plan
cannot see the wind-up that breaks a stuck string free, and every term of its cost then favours a
still drive: on ``mismatch_m40`` the NMPC set the drive to 0 and left the disc stuck to the end in
3 of 18 runs.  When the objective body has not slid (above :data:`SLIDING_FRACTION` of its
nominal speed) for a whole stick-slip period and the plan holds the drive below that fraction of
its programme, the programme acts instead (a counted fallback).

The state is explicit and small (:class:`SupervisionState`): the window, the trim and the last
time the body slid -- what the compiled step holds in its own memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SpeedWindow", "Supervisor", "Decision", "SupervisionState", "SLIDING_FRACTION", "TRIM_LIMIT",
           "TRIM_DEADBAND"]

#: a body slides above this fraction of its nominal speed (the trim's sliding test, the stall guard,
#: the load factor taken from the estimate)
SLIDING_FRACTION = 0.5
#: the largest trim, as a fraction of the programmed speed
TRIM_LIMIT = 0.25
#: mean speed errors below this fraction of the programmed speed are left alone (a tenth of the
#: benchmark's speed band)
TRIM_DEADBAND = 0.005


class SpeedWindow:
    """The objective body's estimated speed and its nominal speed over the last ``period`` seconds
    (a ring buffer fed once per controller call).

    Parameters
    ----------
    period : window length [s] (one stick-slip period)
    call_period : time between :meth:`push` calls [s] (the controller's call period)
    """

    def __init__(self, period: float, call_period: float):
        self.n = max(2, int(math.ceil(period / call_period - 1e-9)))
        self.speed = np.full(self.n, np.nan)
        self.nominal = np.full(self.n, np.nan)
        self.count = 0

    def reset(self) -> None:
        self.speed[:] = np.nan
        self.nominal[:] = np.nan
        self.count = 0

    def push(self, speed: float, nominal: float) -> None:
        """Record the estimated [rad/s] and the nominal speed [rad/s] of one call."""
        k = self.count % self.n
        self.speed[k], self.nominal[k] = speed, nominal
        self.count += 1

    @property
    def full(self) -> bool:
        return self.count >= self.n

    def recorded(self) -> tuple[np.ndarray, np.ndarray]:
        """The speeds and nominal speeds recorded (at most ``n``, in buffer order)."""
        m = min(self.count, self.n)
        return self.speed[:m], self.nominal[:m]


@dataclass(frozen=True)
class Decision:
    """What the supervision decided for one plan (the report can show it).

    Attributes
    ----------
    weight_factor : factor f on the ``ref`` and ``d_ref`` weights (f^2 on ``force`` with the drive)
    severity : the window's severity s [-] (inf before half a window)
    nominal : the nominal speed [rad/s]; trim : the speed trim [rad/s]; target : the speed the plan
        aims at [rad/s] (nominal + trim)
    """

    weight_factor: float
    severity: float
    nominal: float
    trim: float
    target: float


@dataclass
class SupervisionState:
    """The supervision's memory: the speed window, the trim [rad/s] and the last time the
    objective body slid [s] (None: not yet called)."""

    window: SpeedWindow
    trim: float = 0.0
    t_moving: float | None = None


class Supervisor:
    """The calm schedule, the speed trim and the stall guard (module docstring).

    Parameters
    ----------
    period : the rig's stick-slip period [s] (the window)
    call_period : the controller's call period [s]
    calm_band : ``(s_lo, s_hi)`` [-]; hold_gain : the calm factor (1: no schedule)
    trim_tau : the trim's time constant [s] (0: no trim; an NMPC without the drive passes 0)
    drives : whether the NMPC commands the drive (the stall guard acts only then)
    """

    def __init__(self, period: float, call_period: float, calm_band: tuple[float, float], hold_gain: float,
                 trim_tau: float, drives: bool):
        self.period, self.call_period = float(period), float(call_period)
        self.lo, self.hi = float(calm_band[0]), float(calm_band[1])
        self.hold_gain = float(hold_gain)
        self.trim_tau = float(trim_tau)
        self.drives = bool(drives)
        self.state = SupervisionState(SpeedWindow(period, call_period))

    def reset(self) -> None:
        self.state.window.reset()
        self.state.trim = 0.0
        self.state.t_moving = None

    def observe(self, t: float, speed: float, nominal: float) -> None:
        """Record one call's estimated objective speed [rad/s] at its nominal speed [rad/s]: the
        window, the trim's integration and the last time the body slid."""
        s, win = self.state, self.state.window
        win.push(speed, nominal)
        if s.t_moving is None or abs(speed) > SLIDING_FRACTION * abs(nominal):
            s.t_moving = t
        if self.trim_tau > 0 and nominal != 0 and win.full:
            w = win.speed
            mean, osc = float(np.mean(w)), math.sqrt(2.0) * float(np.std(w)) / abs(nominal)
            sliding = float(np.min(np.abs(w))) > SLIDING_FRACTION * abs(nominal)
            if sliding and osc < self.lo and abs(nominal - mean) > TRIM_DEADBAND * abs(nominal):
                lim = TRIM_LIMIT * abs(nominal)
                s.trim = min(max(s.trim + self.call_period / self.trim_tau * (nominal - mean), -lim), lim)

    def decide(self, nominal: float) -> Decision:
        """The decision for a plan now, at the nominal speed [rad/s]."""
        win = self.state.window
        f, sev = 1.0, math.inf
        if self.hold_gain != 1.0 and win.count >= win.n // 2:
            w, nom = win.recorded()
            with np.errstate(divide="ignore", invalid="ignore"):
                d = np.where(nom != 0, (w - nom) / np.abs(nom), np.inf)
            d = np.where(np.isfinite(d), d, 1e6)
            sev = math.sqrt(2.0 * float(np.mean(d * d)))
            g = min(max(math.log(max(sev, 1e-300) / self.lo) / math.log(self.hi / self.lo), 0.0), 1.0)
            f = self.hold_gain ** (1.0 - g)
        trim = self.state.trim
        return Decision(f, sev, nominal, trim, nominal + trim)

    def stalled(self, t: float, drive_planned: float, drive_programme: float) -> bool:
        """The stall guard (module docstring): the body has not slid for a stick-slip period and the
        plan holds the drive below :data:`SLIDING_FRACTION` of its programme."""
        s = self.state
        if not self.drives or s.t_moving is None:
            return False
        return t - s.t_moving >= self.period and abs(drive_planned) < SLIDING_FRACTION * abs(drive_programme)
