"""What a closed-loop run window (:mod:`mitigate.metrics.window`) is made of: the metrics' settings
(:class:`MetricOptions`), the stick-slip period and the windows it sets, the programmed speed, the
stuck thresholds, the friction work at a contact, the DC motor's voltage, call-time statistics.

Every default that carries a unit comes from the scenario (:class:`MetricOptions`): windows from the
rig's stick-slip period, stuck thresholds from the programmed speed and the encoder's resolution.
All functions take numpy arrays sampled at a constant period ``dt`` [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.checks import check_options, option, where_field
from models.errors import ConfigError

__all__ = ["FORCE_BAND", "MetricOptions", "contact_work", "solve_time_stats", "programmed_speed", "measured_stuck_speed", "rig_period",
           "force_roles", "straddles_one", "windows"]


def contact_work(model, params, x: np.ndarray, u: np.ndarray, contact: str, dt: float, *,
                 caused_by_normal: bool = False) -> float:
    """Energy dissipated at a friction contact, ``sum |T(|w|)| |w| dt`` [J], from the true states
    ``x`` (n, nx) and applied inputs ``u`` (n, nu) of ``model`` (rectangle rule).

    ``caused_by_normal``: count only the part of the torque that the contact's normal force causes,
    ``|T(|w|, N) - T(|w|, 0)|`` (a law's viscous term, such as the bit-rock law's ``c_b |w|``, acts
    at zero normal force: it is not wear caused by pressing); only for a contact whose normal force
    is an input.
    """
    import casadi as ca
    from models.friction import get_law
    c = next((c for c in model.spec.contacts if c.name == contact), None)
    if c is None:
        raise ConfigError(f"rig {model.name!r} has no contact {contact!r}")
    idx = model.speed_index(c.body)
    xs, us, v = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("v")
    P = model.unpack(ca.DM(params.vector()))
    law = get_law(c.law)

    def torque(u_sym):
        un = {n: u_sym[k] for k, n in enumerate(model.inputs)}
        N, r, LP = model.contact_args(c, P, un)
        return law.torque(v, 1.0, N, r, LP)

    T = torque(us)
    if caused_by_normal:
        if c.normal is None or c.normal.kind != "input":
            raise ConfigError(f"contact {contact!r}: caused_by_normal needs a normal force that is an input")
        j = model.inputs.index(c.normal.name)
        u0 = ca.vertcat(*[0.0 if k == j else us[k] for k in range(model.nu)])
        T = T - torque(u0)
    f = ca.Function("work", [v, xs, us], [ca.fabs(T) * v])
    w = np.abs(np.asarray(x[:, idx], float))
    vals = np.array(f.map(len(w))(w[None, :], np.asarray(x, float).T, np.asarray(u, float).T)).ravel()
    return float(np.sum(vals) * dt)


def solve_time_stats(times: np.ndarray) -> dict[str, float]:
    """Median, 95th percentile and maximum of solve times [s] (NaN if there are none)."""
    t = np.asarray(times, dtype=float)
    t = t[np.isfinite(t)]
    if t.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"median": float(np.median(t)), "p95": float(np.percentile(t, 95)), "max": float(np.max(t))}


#: the driller's band of a programmed normal force (the weight on bit), ratios to the programme: the
#: default of :attr:`MetricOptions.force_band` and of the NMPC's ``force_band``
FORCE_BAND = (0.8, 1.25)


def straddles_one(band: tuple[float, float], where: str) -> None:
    """A band of ratios to the programme holds the programme: ``low < 1 <= high``."""
    if not band[0] < 1 <= band[1]:
        raise ConfigError(f"{where} must have low < 1 <= high, got [{band[0]:g}, {band[1]:g}]")


@dataclass(frozen=True, kw_only=True)
class MetricOptions:
    """Settings of :func:`closed_loop_metrics`; None means "from the scenario" (every default with a
    unit comes from it: windows from the rig's stick-slip period, thresholds from the programmed speed).

    Parameters
    ----------
    period : the stick-slip period [s] that sets the windows (None: the rig's estimate,
        :func:`rig_period`; the benchmark passes the period it measured on the uncontrolled run)
    residual_periods : length of the residual window in periods [-] (3; whole periods, see below)
    residual_fraction : the residual window is at most this fraction of the controlled part [-]
        (0.5: the first half holds the switch-on transient); it is a whole number of periods (at
        least one) that fits in both limits
    window_periods : non-overlapping severity windows (``sss_window_*``, ``sss_final``) in periods (2)
    moving_periods : the drilling convention's moving window in periods (1.5)
    suppress_threshold : moving severity below which stick-slip counts as suppressed [-] (0.1)
    stuck_speed : |speed| at or below which the TRUE body is stuck [rad/s] (None: 1e-3 of the
        programmed speed, :func:`programmed_speed`; with none -- a torque drive without a target --
        1e-3 of the run's mean |speed|; it is exactly 0 in stick in the hybrid plant)
    stuck_speed_measured : the same for the measured speed [rad/s] (None: half an encoder tick per
        DAQ period on an encoder channel, else 5 % of that speed scale: :func:`measured_stuck_speed`)
    force_band : ``(low, high)`` band of the mean applied normal force over its programme [-] outside
        which a run violates the programme (the driller's weight on bit; (0.8, 1.25))
    speed_band : ``(low, high)`` band of the objective body's mean speed over the residual window over
        its programme [-] outside which a run violates the programme (the bit's speed; (0.95, 1.05))
    band_periods : the moving window of the band checks in periods [-] (1): the mean applied normal force
        over EVERY such window must stay in ``force_band``, the mean speed in ``moving_speed_band``
    moving_speed_band : ``(low, high)`` band of the objective body's mean speed over every moving band
        window over its programme [-] ((0.85, 1.15)).  Wider than ``speed_band``: while the stick-slip
        dies the string unwinds or winds up its twist, which moves a period's mean speed by the twist's
        change over ``w_prog T`` whatever the controller does (rig3 at 30 rpm: 0.37 rad, about the swing
        of its stick-slip twist, is 5 % of a period's turn); it catches a set-point left high (a
        driller's bit 17.6 % fast for 25 s) or a bit held back
    band_after : the moving band checks start this many periods after the switch-on [-] (1: the slip
        under way at the switch-on, or the spin-up from rest, is the rig's, not the controller's)
    stuck_limit : a run whose objective body is stuck (TRUE speed at or below ``stuck_speed``) for more
        than this fraction of the residual window has stalled [-] (0.5: the bit does not drill; the
        suite's uncontrolled stick-slip is stuck for 16-38 % of it)
    """

    period: float | None = option(None, lo=0.0, lo_open=True, unit="s", none=True)
    residual_periods: float = option(3.0, lo=0.0, lo_open=True)
    residual_fraction: float = option(0.5, lo=0.0, lo_open=True, hi=1.0)
    window_periods: float = option(2.0, lo=0.0, lo_open=True)
    moving_periods: float = option(1.5, lo=0.0, lo_open=True)
    suppress_threshold: float = option(0.1, lo=0.0, lo_open=True)
    stuck_speed: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s", none=True)
    stuck_speed_measured: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s", none=True)
    force_band: tuple = option(FORCE_BAND, items=2, lo=0.0, what="[low, high] (ratios to the programme)",
                               check=straddles_one)
    speed_band: tuple = option((0.95, 1.05), items=2, lo=0.0, what="[low, high] (ratios to the programme)",
                               check=straddles_one)
    band_periods: float = option(1.0, lo=0.0, lo_open=True)
    moving_speed_band: tuple = option((0.85, 1.15), items=2, lo=0.0, what="[low, high] (ratios to the programme)",
                                      check=straddles_one)
    band_after: float = option(1.0, lo=0.0)
    stuck_limit: float = option(0.5, lo=0.0, hi=1.0, hi_open=True, why="a fraction of the residual window")
    where: str = where_field("metrics")

    def __post_init__(self):
        check_options(self)


def rig_period(model, params) -> float:
    """The rig's stick-slip period estimate [s] (:func:`models.modal.stick_slip_period`: its lowest
    torsional mode with its drive's boundary condition)."""
    from models.modal import stick_slip_period
    return stick_slip_period(model, params)


def programmed_speed(scenario, t: np.ndarray) -> np.ndarray:
    """The objective body's programmed speed at the times ``t`` [rad/s]: the drive's set-point (or
    prescribed speed), or for a torque drive the scenario's ``[control] speed`` (the target its laws aim
    at), else the rig file's ``operating_point.speed`` (NaN if it has none)."""
    m = scenario.model
    t = np.asarray(t, float)
    if not m.drive.sets_speed:
        if scenario.control.speed is not None:
            return np.array([scenario.control.speed(tk) for tk in t], float)
        v = m.spec.extra.get("operating_point", {}).get("speed")      # SI, resolved by the rig parser
        return np.full(t.shape, float(v) if v is not None else np.nan)
    prof = scenario.inputs[m.drive_input]
    return np.array([prof(tk) for tk in t], float)


def force_roles(model, programme: np.ndarray) -> dict[str, str]:
    """``{input: "process" | "brake"}`` for every input that sets a contact's normal force: the
    process load (a positive programme: the weight on bit, the rock the bit cuts) or a brake (a zero
    programme: a pin that only ever brakes).  ``programme`` is (n, nu) in ``model.inputs`` order."""
    out = {}
    for j, name in enumerate(model.inputs):
        if model.contact_of_input(name) is None:
            continue
        out[name] = "process" if float(np.mean(programme[:, j])) > 0 else "brake"
    return out


def windows(o: MetricOptions, period: float, span: float, dt: float) -> tuple[float, float, float]:
    """(residual, non-overlapping, moving) window lengths [s] for ``span`` seconds after the start.
    The residual window is a whole number of periods (a cycle that stays is averaged over whole
    cycles: its mean speed is the programme's), at least one, at most ``residual_periods`` and
    ``residual_fraction`` of the span (a span shorter than one period: that fraction of it)."""
    room = min(o.residual_periods * period, o.residual_fraction * span)
    whole = math.floor(room / period + 1e-9)
    res = max(dt, whole * period if whole >= 1 else min(period, o.residual_fraction * span))
    return res, max(dt, o.window_periods * period), max(dt, min(o.moving_periods * period, span))


def measured_stuck_speed(scenario, w_scale: float, given: float | None = None) -> tuple[str | None, float]:
    """(the objective body's speed channel, the |measured speed| at or below which it counts as stuck
    [rad/s]): ``given``, else half an encoder tick per DAQ period on an encoder channel, else 5 % of
    ``w_scale`` (the programmed speed) [rad/s]."""
    from models.sensors import stuck_speed
    m = scenario.model
    ch = m.speed_channel(m.objective_body)
    return ch, (given if given is not None else stuck_speed(m, ch, scenario.dt, w_scale))
