"""Stick-slip metrics of a speed record and of a closed-loop run, each measuring one thing.

Of the objective body's TRUE speed (rig3: R1, "the bit") after the control start:

- ``residual_severity``: the oscillation that stays, ``(max - min) / (2 w_prog)`` over the last part
  of the run (a few stick-slip periods, and never more than the second half of the controlled part,
  so the switch-on transient is left out), normalised by the PROGRAMMED speed (a run's own mean would
  reward a controller that runs the bit fast and is 0/0 for a stuck bit);
- ``time_to_suppress``: seconds from the switch-on to the start of the first moving window from which
  the moving severity stays below a threshold (0: never above; inf: still above at the end);
- ``peak_overshoot``: the largest excursion of the speed above its programme, relative to it;
- ``speed_ratio``, ``speed_error_rms``: mean speed / programmed speed, RMS of speed - programme;
  ``residual_speed_ratio`` over the residual window (the bit turning at the programmed speed once the
  transient is over; ``speed_violation`` outside ``MetricOptions.speed_band``);
- ``stuck_fraction`` (all of the controlled part) and ``residual_stuck_fraction`` (residual window);
- the severity of the literature ``sss = (max - min) / (2 mean)`` over everything after the switch-on,
  over windows and over a moving window (:func:`moving_severity`), kept for continuity.

Effort, separately: ``setpoint_variation`` (total variation of every commanded input per second,
each scaled by its programme), ``drive_energy``, and per actuated normal force its mean and ratio to
the programme (``normal_force_mean_<input>``, ``normal_force_ratio_<input>``, ``force_violation``);
``band_violation`` is either violation: the run did not drill as programmed.
Friction work at the contacts whose normal force is an input is split by what the contact is for
(:func:`force_roles`): the process load (the weight on bit: a positive programme) gives
``cutting_work`` (the friction work done at the applied force) and ``cutting_work_ratio`` (against the
work the same speeds would do at the programmed force); a brake (a zero programme) gives ``pin_work``,
its wear, counting only the part of the friction that the normal force causes (a law's viscous term
acts without it).

Every default that carries a unit comes from the scenario (:class:`MetricOptions`): windows from the
rig's stick-slip period, stuck thresholds from the programmed speed and the encoder's resolution.
All functions take numpy arrays sampled at a constant period ``dt`` [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mitigate.severity import (amplitude, moving_severity, rms, severity, stuck_fraction, time_to_suppress,
                               total_variation, windowed_severity)
from models.checks import check_options, option, where_field
from models.errors import ConfigError
from models.signals import dominant_frequency
from models.status import Status

__all__ = ["severity", "windowed_severity", "moving_severity", "time_to_suppress", "stuck_fraction", "amplitude",
           "dominant_frequency", "rms", "contact_work", "solve_time_stats", "closed_loop_metrics", "METRIC_UNITS",
           "MetricOptions", "metric_unit", "programmed_speed", "measured_stuck_speed", "rig_period", "force_roles",
           "total_variation", "windows"]


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


#: unit of each fixed entry of :func:`closed_loop_metrics` (per-input entries: :func:`metric_unit`)
METRIC_UNITS = {
    "sss": "-", "sss_window_mean": "-", "sss_window_max": "-", "sss_final": "-", "sss_moving_mean": "-",
    "sss_moving_final": "-", "time_to_suppress": "s", "stuck_fraction": "-", "stuck_fraction_measured": "-",
    "mean_speed": "rad/s", "speed_error_rms": "rad/s", "rms_twist": "rad", "torque_std": "N m",
    "pin_work": "J", "drive_energy": "J", "mean_pin_force": "N",
    "solve_median_ms": "ms", "solve_p95_ms": "ms", "solve_max_ms": "ms",
    "plan_median_ms": "ms", "plan_p95_ms": "ms", "plan_max_ms": "ms", "plan_calls": "-",
    "controller_steps": "-", "controller_failures": "-", "controller_fallbacks": "-",
    "controller_deadline_misses": "-",
    "estimator_failures": "-", "estimator_fallbacks": "-", "estimator_dropouts": "-", "diverged": "-",
    # what stays, how fast, how far above the programme; effort and the programme's band (issue 17)
    "residual_severity": "-", "residual_stuck_fraction": "-", "peak_overshoot": "-", "speed_ratio": "-",
    "setpoint_variation": "1/s", "normal_force_ratio": "-", "band_violation": "-", "force_violation": "-",
    "residual_speed_ratio": "-", "speed_violation": "-", "cutting_work": "J",
    "cutting_work_ratio": "-", "period": "s", "residual_window": "s",
}


def metric_unit(key: str) -> str:
    """The unit of a metric key, the per-input ones (``normal_force_mean_<input>`` [N],
    ``normal_force_ratio_<input>`` [-]) included; "" if unknown."""
    if key in METRIC_UNITS:
        return METRIC_UNITS[key]
    if key.startswith("normal_force_mean_"):
        return "N"
    if key.startswith("normal_force_ratio_"):
        return "-"
    return ""


def _straddles_one(band: tuple[float, float], where: str) -> None:
    """A band of ratios to the programme holds the programme: ``low < 1 <= high``."""
    if not band[0] < 1 <= band[1]:
        raise ConfigError(f"{where} must have low < 1 <= high, got [{band[0]:g}, {band[1]:g}]")


@dataclass(frozen=True, kw_only=True)
class MetricOptions:
    """Settings of :func:`closed_loop_metrics`; None means "from the scenario" (every default with a
    unit comes from it: windows from the rig's stick-slip period, thresholds from the programmed speed).

    Parameters
    ----------
    period : the stick-slip period [s] that sets the windows (None: the rig's lowest torsional mode
        with the drive held, :func:`rig_period`; the benchmark passes the period it measured on the
        uncontrolled run)
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
    """

    period: float | None = option(None, lo=0.0, lo_open=True, unit="s", none=True)
    residual_periods: float = option(3.0, lo=0.0, lo_open=True)
    residual_fraction: float = option(0.5, lo=0.0, lo_open=True, hi=1.0)
    window_periods: float = option(2.0, lo=0.0, lo_open=True)
    moving_periods: float = option(1.5, lo=0.0, lo_open=True)
    suppress_threshold: float = option(0.1, lo=0.0, lo_open=True)
    stuck_speed: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s", none=True)
    stuck_speed_measured: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s", none=True)
    force_band: tuple = option((0.8, 1.25), items=2, lo=0.0, what="[low, high] (ratios to the programme)",
                               check=_straddles_one)
    speed_band: tuple = option((0.95, 1.05), items=2, lo=0.0, what="[low, high] (ratios to the programme)",
                               check=_straddles_one)
    where: str = where_field("metrics")

    def __post_init__(self):
        check_options(self)


def rig_period(model, params) -> float:
    """The rig's stick-slip period estimate [s]: its lowest torsional mode with the drive held
    (:func:`mitigate.controllers.tuning.stick_slip_frequency`)."""
    from mitigate.controllers.tuning import stick_slip_frequency
    return 1.0 / stick_slip_frequency(model, params)


def programmed_speed(scenario, t: np.ndarray) -> np.ndarray:
    """The objective body's programmed speed at the times ``t`` [rad/s]: the drive's set-point (or
    prescribed speed), or for a torque drive the scenario's ``[control] speed`` (the target its laws aim
    at), else the rig file's ``operating_point.speed`` (NaN if it has none)."""
    m = scenario.model
    t = np.asarray(t, float)
    if m.drive_kind == "torque":
        if getattr(scenario, "control_speed", None) is not None:
            return np.array([scenario.control_speed(tk) for tk in t], float)
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


def closed_loop_metrics(result, scenario, options: MetricOptions | None = None) -> dict[str, float]:
    """Metrics of a closed-loop run after the control start, from the TRUE plant trajectory
    (only ``stuck_fraction_measured`` uses the measured speed).

    Parameters
    ----------
    result : mitigate.closedloop.ClosedLoopResult
    scenario : its scenario (the plant's model and true parameters, the programme)
    options : :class:`MetricOptions` (default: every window and threshold from the scenario)

    Returns
    -------
    dict : see the module docstring and :data:`METRIC_UNITS`; the per-input entries
    ``normal_force_mean_<input>`` [N] and ``normal_force_ratio_<input>`` [-] for every servo input.
    ``period`` and ``residual_window`` [s] say which windows were used.
    """
    o = options or MetricOptions()
    t = result.t
    dt = scenario.dt
    m = t >= result.control_start - 1e-12
    if m.sum() < 2:
        m = np.ones_like(t, dtype=bool)
    body = result.objective_body
    w = result.state(f"omega_{body}")[m]
    tm = t[m]
    span = float(tm[-1] - tm[0]) + dt
    pm, pp = scenario.plant_model, scenario.plant_params
    period = o.period
    if period is None:
        try:
            period = rig_period(scenario.model, scenario.model_params)
        except ConfigError:          # no torsional mode with the drive held: a quarter of the controlled part
            period = span / 4
    res_win, win, mov_win = windows(o, period, span, dt)
    n_res = max(2, min(len(w), int(round(res_win / dt))))
    n_win = max(1, int(round(win / dt)))
    wp = programmed_speed(scenario, tm)
    w_ref = float(np.mean(wp))
    ref = w_ref if math.isfinite(w_ref) and w_ref != 0 else None
    # the speed scale of a run without a programmed speed (a torque drive, no target): its own mean |speed|
    w_scale = abs(w_ref) if ref else float(np.mean(np.abs(w))) if len(w) else 0.0
    stuck_thr = o.stuck_speed if o.stuck_speed is not None else 1e-3 * w_scale
    ws = windowed_severity(w, dt, win, stuck_thr)
    mov = moving_severity(w, dt, mov_win, stuck=stuck_thr)
    prog = np.array([scenario.programme(tk) for tk in tm]).reshape(len(tm), -1)
    twists = np.column_stack(list(result.twists.values()))[m] if result.twists else np.zeros((m.sum(), 0))
    torque_ch = next((s.channels[0] for s in scenario.model.sensors if s.kind == "torque"), None)
    torque = result.y[torque_ch][m] if torque_ch and torque_ch in result.y else np.full(m.sum(), np.nan)
    X, U = result.x[m], result.u[m]
    out: dict[str, float] = {}

    # --- actuated normal forces, the programme's band, the friction work split by role
    roles = force_roles(pm, prog)
    lo, hi = o.force_band
    ratios, pin_force = [], []
    pin_work = cutting = cutting_prog = 0.0
    has_process = False
    for name in pm.servo_inputs:
        j = pm.inputs.index(name)
        mean_n, mean_p = float(np.mean(U[:, j])), float(np.mean(prog[:, j]))
        r = mean_n / mean_p if mean_p > 0 else float("nan")
        out[f"normal_force_mean_{name}"] = mean_n
        out[f"normal_force_ratio_{name}"] = r
        if math.isfinite(r):
            ratios.append(r)
        pin_force.append(U[:, j])
    for name, role in roles.items():
        c = pm.contact_of_input(name)
        if role == "brake":
            pin_work += contact_work(pm, pp, X, U, c.name, dt, caused_by_normal=True)
        else:
            has_process = True
            Up = U.copy()
            Up[:, pm.inputs.index(name)] = prog[:, pm.inputs.index(name)]
            cutting += contact_work(pm, pp, X, U, c.name, dt)
            cutting_prog += contact_work(pm, pp, X, Up, c.name, dt)
    # the ratio farthest from the programme (on a log scale: half and double are as far)
    out["normal_force_ratio"] = max(ratios, key=lambda r: abs(math.log(r)) if r > 0 else math.inf) if ratios \
        else float("nan")
    out["force_violation"] = int(any(not (lo <= r <= hi) for r in ratios))

    # --- effort on the set-points: total variation per second, each scaled by its programme
    tv = 0.0
    for name, cmd in result.commands.items():
        j = scenario.model.inputs.index(name)
        c = np.asarray(cmd, float)[m]
        own = float(np.max(np.abs(c))) if c.size else 0.0       # last resort: the command's own range
        if name in scenario.model.servo_inputs:
            a = scenario.model.actuator(name)
            scale = float(a.n_max) if a is not None and a.n_max > 0 else max(float(np.max(np.abs(prog[:, j]))), own)
        else:
            scale = max(float(np.mean(np.abs(prog[:, j]))), abs(w_ref) if ref else 0.0) or own
        tv += total_variation(c) / scale if scale > 0 else 0.0
    if pm.drive_kind == "dc_motor":
        drive_energy = float(np.sum(np.abs(result_voltage(pm, pp, X, U) * X[:, pm.nx - 2])) * dt)
    elif pm.drive_kind == "torque":
        drive_energy = float(np.sum(np.abs(U[:, pm.inputs.index(pm.drive_input)]
                                           * X[:, pm.speed_index(pm.drive_body)])) * dt)
    else:
        drive_energy = float("nan")
    st = solve_time_stats(result.solve_times)
    plans = result.plan_calls if result.plan_calls is not None else np.ones(len(result.solve_times), bool)
    sp = solve_time_stats(np.asarray(result.solve_times)[plans] if len(result.solve_times) else result.solve_times)
    cc, ec = result.controller_counts, result.estimator_counts
    meas_ch, stuck_meas = measured_stuck_speed(scenario, w_scale, o.stuck_speed_measured)
    tail = w[-n_res:]
    res_speed = float(np.mean(tail)) / w_ref if ref else float("nan")
    out["residual_speed_ratio"] = res_speed
    out["speed_violation"] = int(math.isfinite(res_speed) and not (o.speed_band[0] <= res_speed <= o.speed_band[1]))
    out["band_violation"] = int(out["force_violation"] or out["speed_violation"])
    out.update({
        "residual_severity": severity(tail, ref, stuck_thr),
        "residual_stuck_fraction": stuck_fraction(tail, stuck_thr),
        "time_to_suppress": time_to_suppress(w, dt, mov_win, o.suppress_threshold, ref, stuck_thr),
        "peak_overshoot": max(0.0, float(np.max((w - wp) / np.abs(wp)))) if ref else float("nan"),
        "speed_ratio": float(np.mean(w)) / w_ref if ref else float("nan"),
        "speed_error_rms": rms(w - wp),
        "setpoint_variation": tv / span,
        "cutting_work": cutting if has_process else float("nan"),
        "cutting_work_ratio": cutting / cutting_prog if has_process and cutting_prog > 0 else float("nan"),
        "pin_work": pin_work,
        "drive_energy": drive_energy,
        "sss": severity(w, stuck=stuck_thr),
        "sss_window_mean": float(np.mean(ws)),
        "sss_window_max": float(np.max(ws)),
        "sss_final": severity(w[-n_win:], stuck=stuck_thr),
        "sss_moving_mean": float(np.mean(mov)),
        "sss_moving_final": float(mov[-1]),
        "stuck_fraction": stuck_fraction(w, stuck_thr),
        "stuck_fraction_measured": stuck_fraction(result.y[meas_ch][m], stuck_meas)
        if meas_ch in result.y else float("nan"),
        "mean_speed": float(np.mean(w)),
        "rms_twist": rms(twists[:, 0]) if twists.shape[1] else float("nan"),
        "torque_std": float(np.std(torque)),
        "mean_pin_force": float(np.mean(np.concatenate(pin_force))) if pin_force else 0.0,
        "period": float(period),
        "residual_window": n_res * dt,
        "solve_median_ms": 1e3 * st["median"],
        "solve_p95_ms": 1e3 * st["p95"],
        "solve_max_ms": 1e3 * st["max"],
        "plan_median_ms": 1e3 * sp["median"],
        "plan_p95_ms": 1e3 * sp["p95"],
        "plan_max_ms": 1e3 * sp["max"],
        "plan_calls": int(np.sum(plans)),
        "controller_steps": int(cc.get("steps", 0)),
        "controller_failures": int(cc.get("failures", 0)),
        "controller_fallbacks": int(cc.get("fallbacks", 0)),
        "controller_deadline_misses": int(cc.get("deadline_misses", 0)),
        "estimator_failures": int(ec.get("failures", 0)),
        "estimator_fallbacks": int(ec.get("fallbacks", 0)),
        "estimator_dropouts": int(ec.get("dropouts", 0)),
        "diverged": int(result.status is Status.DIVERGED),
    })
    return out


def result_voltage(model, params, X: np.ndarray, U: np.ndarray) -> np.ndarray:
    """The DC motor's armature voltage along a trajectory (its drive's limits applied) [V]."""
    f = model.meas_vector(["voltage"])
    return np.array(f.map(X.shape[0])(X.T, U.T, np.asarray(params.vector(), float))).ravel()
