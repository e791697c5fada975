"""Scale-free defaults of the NMPC: every option that carries a unit comes from the rig.

A field drill string (10^3 kg m^2, 10 kN m, a stick-slip period of ~10 s) and a lab rig (10^-2
kg m^2, 0.3 N m, ~2 s) need the same controller with different numbers.  Each default is a
dimensionless rule times one of the rig's own scales (its stick-slip period, the programme's
operating point), chosen so that rig3 gets the values it was tuned with:

============== ============================================================= ===================
option         rule                                                          rig3 (30 rpm)
============== ============================================================= ===================
dt             T / 40, floored to a whole number of DAQ periods              0.05 s
eps            1.6 % of the nominal speed of the objective body              0.050 rad/s
setpoint_band  speed drive: the programme's set-point (the set-point stays   3.14 rad/s
               in [0, 2 w_prog]); torque drive: the programme's torque
setpoint_rate  15 x band / T (the set-point may cross its band in 1/15 of   20 rad/s^2
               a period)
force_filter   the horizon, horizon x dt                                     1.0 s
schedule       one period T                                                  2.3 s
speed_trim     one period T (the offset-free trim's time constant, ``trim``) 2.3 s
hold_gain      60 where steady sliding at the programme (at the nominal      60 (30 rpm, 20 N;
               speed) is linearly stable, 15 where it is unstable or cannot  15 at 20 rpm, 15 N
               be decided (dimensionless; the rig decides which)             or 50 N)
============== ============================================================= ===================

Why the hold gain follows the stability of sliding.  Once the stick-slip is gone, a rig whose
sliding equilibrium is stable needs nothing from the controller, and everything the plan does is
the state estimate's noise fed back.  On an unstable equilibrium (negative friction
slope at the programme) the calm plan must keep damping: at 60 the residual on the suite's
unstable-sliding and low-speed scenarios rose from 0.0044 / 0.0058 to 0.0125 / 0.0208
(``benchmarks/results/nmpc.md``).

``T`` is the rig's stick-slip period (:func:`models.modal.stick_slip_period`): the lowest torsional
mode with the drive held (rig3: 2.33 s, its stick-slip cycle at 30 rpm is 2.3 s) -- or, on a torque
drive, whose drive body turns freely, the lowest torsional mode of the free chain (the field drill string: 7.2 s, its stick-slip cycle at 10 kN m 8.3 s;
with its table held it would be 15.7 s, and an NMPC planning at that period's 0.39 s ran the
bit 27 % fast).  With the default horizon of 20 intervals the NMPC looks half a period ahead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from models.errors import ConfigError

__all__ = ["Resolved", "resolve", "sliding_is_stable", "INTERVALS_PER_PERIOD", "EPS_FRACTION", "RATE_PER_PERIOD",
           "HOLD_GAIN_STABLE", "HOLD_GAIN_UNSTABLE"]

#: OCP intervals per stick-slip period (dt = T / 40)
INTERVALS_PER_PERIOD = 40
#: friction regularisation as a fraction of the nominal speed
EPS_FRACTION = 0.016
#: band crossings per period allowed by the set-point's rate limit
RATE_PER_PERIOD = 15.0
#: calm-sliding factor on the tracking weights where sliding at the programme is stable / is not
HOLD_GAIN_STABLE = 60.0
HOLD_GAIN_UNSTABLE = 15.0


@dataclass(frozen=True)
class Resolved:
    """The NMPC's unit-carrying settings on one rig: given options, or the rig's defaults.

    period [s]; dt [s]; eps [rad/s]; setpoint_band, setpoint_rate [rad/s, rad/s^2 or N m, N m/s];
    force_filter [s]; hold_gain [-]; speed_trim [s]; derived: the names of the settings that came from the rig
    """

    period: float
    dt: float
    eps: float
    setpoint_band: float
    setpoint_rate: float
    force_filter: float
    hold_gain: float
    speed_trim: float
    derived: tuple[str, ...]


def resolve(options, model, params, dt_daq: float, nominal_speed: float, setpoint: float, where: str,
            u=None) -> Resolved:
    """The settings of ``options`` (:class:`mitigate.controllers.nmpc.options.NMPCOptions`) with
    every None replaced by the rig's default (module docstring).

    Parameters
    ----------
    model, params : the rig and its nominal parameters
    dt_daq : the DAQ period [s]
    nominal_speed : nominal speed of the objective body [rad/s]
    setpoint : the programme's drive input at the start (a speed [rad/s] or a torque [N m])
    where : prefix of error messages
    u : the programme's inputs at the start (for the hold gain; None: not known, 15)

    Raises
    ------
    ConfigError : a rig without a torsional mode and no ``dt``, or a ``dt`` below the DAQ period.
    """
    o = options
    derived = []
    period = _period(model, params)
    if o.dt is not None:
        dt = float(o.dt)
    else:
        if period is None:
            raise ConfigError(f"{where}.dt: rig {model.name!r} has no torsional mode to derive "
                              f"the OCP interval from; give dt [s]")
        dt = max(1, math.floor(period / INTERVALS_PER_PERIOD / dt_daq + 1e-9)) * dt_daq
        derived.append("dt")
    if dt < dt_daq - 1e-12:
        raise ConfigError(f"{where}.dt must be >= the DAQ period {dt_daq} s, got {dt}")
    if period is None:
        period = o.horizon * dt
    w_s = abs(nominal_speed) if nominal_speed != 0 else 1.0
    if o.eps is not None:
        eps = float(o.eps)
    else:
        eps = EPS_FRACTION * w_s
        derived.append("eps")
    if o.setpoint_band is not None:
        band = float(o.setpoint_band)
    else:
        band = abs(setpoint) if setpoint != 0 else w_s
        derived.append("setpoint_band")
    if o.setpoint_rate is not None:
        rate = float(o.setpoint_rate)
    else:
        rate = RATE_PER_PERIOD * band / period if band > 0 else RATE_PER_PERIOD * w_s / period
        derived.append("setpoint_rate")
    if o.force_filter is not None:
        ff = float(o.force_filter)
    else:
        ff = o.horizon * dt
        derived.append("force_filter")
    if o.hold_gain is not None:
        hold = float(o.hold_gain)
    else:
        stable = u is not None and sliding_is_stable(model, params, u, nominal_speed)
        hold = HOLD_GAIN_STABLE if stable else HOLD_GAIN_UNSTABLE
        derived.append("hold_gain")
    if o.speed_trim is not None:
        trim = float(o.speed_trim)
    else:
        trim = period
        derived.append("speed_trim")
    return Resolved(period, dt, eps, band, rate, ff, hold, trim, tuple(derived))


def sliding_is_stable(model, params, u, nominal_speed: float) -> bool | None:
    """Whether steady sliding of the rig at inputs ``u`` is linearly stable
    (:func:`models.stability.sliding_stability`); on a torque drive at the equilibrium with the
    objective body at ``nominal_speed`` (a torque may sustain several; the programme's is the one
    at the nominal speed).  None when it cannot be decided (no equilibrium found)."""
    import numpy as np

    from models.stability import sliding_stability
    try:
        x_op, u = None, np.asarray(u, float)
        if not model.drive.sets_speed:
            u, x_op = model.operating_point(float(nominal_speed), u, params)
            if not (np.all(np.isfinite(x_op)) and np.all(np.isfinite(u))):
                return None
        return sliding_stability(model, params, u, x_op=x_op)[0]
    except (ConfigError, RuntimeError, ArithmeticError, np.linalg.LinAlgError):
        return None


def _period(model, params) -> float | None:
    """The rig's stick-slip period [s] (:func:`models.modal.stick_slip_period`), or None without a torsional mode."""
    from models.modal import stick_slip_period
    try:
        return stick_slip_period(model, params)
    except ConfigError:
        return None
