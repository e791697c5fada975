"""Stick-slip metrics of a speed record and of a closed-loop run.

- severity ``SSS = (max - min) / (2 mean)`` of the objective body's speed (rig3: R1, the "bit"):
  over the whole run after the control start, and over a MOVING window, the convention of the
  drilling literature and of NORCE's Simulator4nDOF (:func:`moving_severity`);
- the time to suppress: from the control start until the moving-window severity falls below a
  threshold for good;
- the fraction of time stuck, speed tracking, actuator work (friction work at the servo pins,
  the drive's electrical energy), solve times, failures.

All functions take numpy arrays sampled at a constant period ``dt`` [s].
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from models.signals import dominant_frequency
from models.status import Status

__all__ = ["severity", "windowed_severity", "moving_severity", "time_to_suppress", "stuck_fraction", "amplitude",
           "dominant_frequency", "rms", "contact_work", "solve_time_stats", "closed_loop_metrics", "METRIC_UNITS",
           "MetricOptions"]


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


def moving_severity(omega: np.ndarray, dt: float, window: float) -> np.ndarray:
    """Severity ``(max - min) / (2 mean)`` over a window of ``window`` seconds that moves by one
    sample (the drilling convention); element ``j`` covers samples ``j .. j + n - 1``."""
    w = np.asarray(omega, dtype=float)
    n = max(1, min(len(w), int(round(window / dt))))
    v = sliding_window_view(w, n)
    mean = np.abs(v.mean(axis=1))
    span = v.max(axis=1) - v.min(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(mean > 0, span / (2 * mean), np.inf)


def time_to_suppress(omega: np.ndarray, dt: float, window: float, threshold: float) -> float:
    """Seconds from the first sample to the END of the first moving window from which the
    moving-window severity stays below ``threshold`` to the end of the record; ``inf`` if the
    last window is still above it."""
    w = np.asarray(omega, dtype=float)
    n = max(1, min(len(w), int(round(window / dt))))
    s = moving_severity(w, dt, window)
    above = np.flatnonzero(~(s < threshold))
    if above.size == 0:
        return (n - 1) * dt
    j = int(above[-1]) + 1
    if j >= s.size:
        return float("inf")
    return (j + n - 1) * dt


def stuck_fraction(omega: np.ndarray, threshold: float = 0.05) -> float:
    """Fraction of samples with ``|omega| <= threshold`` [rad/s]."""
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


def contact_work(model, params, x: np.ndarray, u: np.ndarray, contact: str, dt: float) -> float:
    """Energy dissipated at a friction contact, ``sum |T(|w|)| |w| dt`` [J], from the true
    states ``x`` (n, nx) and applied inputs ``u`` (n, nu) of ``model`` (rectangle rule)."""
    import casadi as ca
    i = next(j for j, names in enumerate(model.contact_names) if contact in names)
    idx = model.contacts[i]
    xs, us = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu)
    v = ca.SX.sym("v")
    P = model.unpack(ca.DM(params.vector()))
    c = next(c for c in model.spec.contacts if c.name == contact)
    un = {n: us[k] for k, n in enumerate(model.inputs)}
    N, r, LP = model.contact_args(c, P, un)
    from models.friction import get_law
    T = get_law(c.law).torque(v, 1.0, N, r, LP)
    f = ca.Function("work", [v, xs, us], [ca.fabs(T) * v])
    w = np.abs(np.asarray(x[:, idx], float))
    vals = np.array(f.map(len(w))(w[None, :], x.T, u.T)).ravel()
    return float(np.sum(vals) * dt)


def solve_time_stats(times: np.ndarray) -> dict[str, float]:
    """Median, 95th percentile and maximum of solve times [s] (NaN if there are none)."""
    t = np.asarray(times, dtype=float)
    t = t[np.isfinite(t)]
    if t.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"median": float(np.median(t)), "p95": float(np.percentile(t, 95)), "max": float(np.max(t))}


#: unit of each entry of :func:`closed_loop_metrics`
METRIC_UNITS = {
    "sss": "-", "sss_window_mean": "-", "sss_window_max": "-", "sss_final": "-", "sss_moving_mean": "-",
    "sss_moving_final": "-", "time_to_suppress": "s", "stuck_fraction": "-", "stuck_fraction_measured": "-",
    "mean_speed": "rad/s", "speed_error_rms": "rad/s", "rms_twist": "rad", "torque_std": "N m",
    "pin_work": "J", "drive_energy": "J", "mean_pin_force": "N",
    "solve_median_ms": "ms", "solve_p95_ms": "ms", "solve_max_ms": "ms",
    "plan_median_ms": "ms", "plan_p95_ms": "ms", "plan_max_ms": "ms", "plan_calls": "-",
    "controller_steps": "-", "controller_failures": "-", "controller_fallbacks": "-",
    "estimator_failures": "-", "estimator_fallbacks": "-", "estimator_dropouts": "-", "diverged": "-",
}


class MetricOptions:
    """Settings of :func:`closed_loop_metrics` (defaults shown).

    window : non-overlapping severity windows [s] (5)
    moving_window : the drilling convention's moving window [s] (3: a few stick-slip periods of
        the reference rig, ~2 s, and of a drill string's lower ones)
    suppress_threshold : moving severity below which stick-slip counts as suppressed (0.1)
    stuck_speed : |speed| at or below which the TRUE body counts as stuck [rad/s] (it is exactly 0 in
        stick in the hybrid plant)
    stuck_speed_measured : same for the measured speed [rad/s] (half an encoder tick per DAQ period)
    """

    def __init__(self, *, window: float = 5.0, moving_window: float = 3.0, suppress_threshold: float = 0.1,
                 stuck_speed: float = 1e-3, stuck_speed_measured: float = 0.31):
        self.window, self.moving_window, self.suppress_threshold = window, moving_window, suppress_threshold
        self.stuck_speed, self.stuck_speed_measured = stuck_speed, stuck_speed_measured


def closed_loop_metrics(result, scenario, options: MetricOptions | None = None) -> dict[str, float]:
    """Metrics of a closed-loop run after the control start, from the TRUE plant trajectory
    (only ``stuck_fraction_measured`` uses the measured speed).

    Parameters
    ----------
    result : mitigate.closedloop.ClosedLoopResult
    scenario : its scenario (the plant's model and true parameters, the programme)

    Returns
    -------
    dict : see :data:`METRIC_UNITS`.  ``sss``: the severity over everything after the control
    start; ``sss_final``: over the last window (what is left once transients have died out);
    ``sss_moving_*``: the drilling convention; ``time_to_suppress`` [s] after the control start
    (inf: not suppressed); ``pin_work``: friction work at the servo-set contacts [J];
    ``drive_energy``: the DC motor's electrical energy ``sum |V i| dt`` [J] (torque drives:
    ``sum |tau w| dt``).
    """
    o = options or MetricOptions()
    t = result.t
    dt = scenario.dt
    m = t >= result.control_start - 1e-12
    if m.sum() < 2:
        m = np.ones_like(t, dtype=bool)
    body = result.objective_body
    w = result.state(f"omega_{body}")[m]
    pm, pp = scenario.plant_model, scenario.plant_params
    ws = windowed_severity(w, dt, o.window)
    n_win = max(1, int(round(o.window / dt)))
    mov = moving_severity(w, dt, o.moving_window)
    prog = np.array([scenario.programme(tk)[scenario.model.inputs.index(scenario.model.drive_input)] for tk in t[m]])
    twists = np.column_stack(list(result.twists.values()))[m] if result.twists else np.zeros((m.sum(), 0))
    torque_ch = next((s.channels[0] for s in scenario.model.sensors if s.kind == "torque"), None)
    torque = result.y[torque_ch][m] if torque_ch and torque_ch in result.y else np.full(m.sum(), np.nan)
    X, U = result.x[m], result.u[m]
    pin_work, pin_force = 0.0, []
    for name in pm.servo_inputs:
        c = pm.contact_of_input(name)
        pin_work += contact_work(pm, pp, X, U, c.name, dt)
        pin_force.append(U[:, pm.inputs.index(name)])
    if pm.drive_kind == "dc_motor":
        drive_energy = float(np.sum(np.abs(result_voltage(pm, pp, X, U) * X[:, pm.nx - 2])) * dt)
    elif pm.drive_kind == "torque":
        drive_energy = float(np.sum(np.abs(U[:, pm.inputs.index(pm.drive_input)] * X[:, pm.speed_index(pm.drive_body)]))
                             * dt)
    else:
        drive_energy = float("nan")
    st = solve_time_stats(result.solve_times)
    plans = result.plan_calls if result.plan_calls is not None else np.ones(len(result.solve_times), bool)
    sp = solve_time_stats(np.asarray(result.solve_times)[plans] if len(result.solve_times) else result.solve_times)
    cc, ec = result.controller_counts, result.estimator_counts
    meas_ch = scenario.model.speed_channel(body)
    return {
        "sss": severity(w),
        "sss_window_mean": float(np.mean(ws)),
        "sss_window_max": float(np.max(ws)),
        "sss_final": severity(w[-n_win:]),
        "sss_moving_mean": float(np.mean(mov)),
        "sss_moving_final": float(mov[-1]),
        "time_to_suppress": time_to_suppress(w, dt, o.moving_window, o.suppress_threshold),
        "stuck_fraction": stuck_fraction(w, o.stuck_speed),
        "stuck_fraction_measured": stuck_fraction(result.y[meas_ch][m], o.stuck_speed_measured)
        if meas_ch in result.y else float("nan"),
        "mean_speed": float(np.mean(w)),
        "speed_error_rms": rms(w - prog),
        "rms_twist": rms(twists[:, 0]) if twists.shape[1] else float("nan"),
        "torque_std": float(np.std(torque)),
        "pin_work": pin_work,
        "drive_energy": drive_energy,
        "mean_pin_force": float(np.mean(np.concatenate(pin_force))) if pin_force else 0.0,
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
        "estimator_failures": int(ec.get("failures", 0)),
        "estimator_fallbacks": int(ec.get("fallbacks", 0)),
        "estimator_dropouts": int(ec.get("dropouts", 0)),
        "diverged": int(result.status is Status.DIVERGED),
    }


def result_voltage(model, params, X: np.ndarray, U: np.ndarray) -> np.ndarray:
    """The DC motor's armature voltage along a trajectory (its drive's limits applied) [V]."""
    f = model.meas_vector(["voltage"])
    return np.array(f.map(X.shape[0])(X.T, U.T, np.asarray(params.vector(), float))).ravel()
