"""Stick-slip metrics of a speed record.

- severity SSS = (max - min) / (2 mean) of the R1 speed (overall and over sliding windows);
- fraction of time stuck (|omega| below a threshold);
- stick-slip amplitude (half peak-to-peak of the speed) and dominant frequency.

All functions take numpy arrays sampled at a constant period ``dt`` [s].
"""

from __future__ import annotations

import numpy as np

__all__ = ["severity", "windowed_severity", "stuck_fraction", "amplitude", "dominant_frequency",
           "rms", "friction_work", "solve_time_stats", "closed_loop_metrics", "METRIC_UNITS"]


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


def rms(x: np.ndarray) -> float:
    """Root mean square ``sqrt(mean(x^2))`` (same unit as ``x``)."""
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def friction_work(omega: np.ndarray, normal_force: np.ndarray, radius: float, mu_s: float, mu_k: float,
                  v_s: float, dt: float) -> float:
    """Energy dissipated by a Stribeck pin contact, ``sum mu(|w|) N r |w| dt`` [J].

    Parameters
    ----------
    omega : (n,) sliding speed of the disc [rad/s] (true, not measured)
    normal_force : (n,) pin normal force held over each sample [N]
    radius : pin radius [m]; mu_s, mu_k, v_s : Stribeck law (thesis eq. 3-13)
    dt : sample period [s] (rectangle rule: sample k holds over [t_k, t_k + dt))
    """
    w = np.abs(np.asarray(omega, dtype=float))
    nf = np.asarray(normal_force, dtype=float)
    mu = mu_k + (mu_s - mu_k) * np.exp(-w / v_s)
    return float(np.sum(mu * nf * radius * w) * dt)


def solve_time_stats(times: np.ndarray) -> dict[str, float]:
    """Median, 95th percentile and maximum of solve times [s] (NaN if there are none)."""
    t = np.asarray(times, dtype=float)
    t = t[np.isfinite(t)]
    if t.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"median": float(np.median(t)), "p95": float(np.percentile(t, 95)), "max": float(np.max(t))}


#: unit of each entry of :func:`closed_loop_metrics`
METRIC_UNITS = {
    "sss": "-", "sss_window_mean": "-", "sss_window_max": "-", "sss_final": "-",
    "stuck_fraction": "-", "stuck_fraction_measured": "-", "mean_omega1": "rad/s", "rms_twist12": "rad",
    "std_twist12": "rad", "motor_torque_std": "N m", "friction_work_pin2": "J", "mean_n2": "N",
    "mean_omega_ref": "rad/s", "solve_median_ms": "ms", "solve_p95_ms": "ms", "solve_max_ms": "ms",
    "plan_median_ms": "ms", "plan_p95_ms": "ms", "plan_max_ms": "ms", "plan_calls": "-",
    "controller_steps": "-", "controller_failures": "-", "controller_fallbacks": "-",
    "estimator_failures": "-", "estimator_fallbacks": "-", "estimator_dropouts": "-",
}


def closed_loop_metrics(result, params, *, window: float = 5.0, stuck_speed: float = 1e-3,
                        stuck_speed_measured: float = 0.31) -> dict[str, float]:
    """Metrics of a closed-loop run after the control start.

    Everything physical is computed from the TRUE plant trajectory (states, applied
    inputs, true motor torque ``eta KT i``); only ``stuck_fraction_measured`` uses the
    measured R1 speed, with a threshold of half an encoder tick per DAQ period.

    Parameters
    ----------
    result : mitigate.closedloop.ClosedLoopResult
    params : the TRUE plant parameters (``scenario.plant_params``)
    window : length of the severity windows [s]
    stuck_speed : |omega1| [rad/s] at or below which the true R1 counts as stuck (it is
        exactly 0 in stick in the hybrid plant)
    stuck_speed_measured : same for the measured (quantised) speed [rad/s]

    Returns
    -------
    dict : see :data:`METRIC_UNITS` (``sss`` is the overall severity; ``sss_final`` the
        severity over the last window, i.e. what is left once transients have died out)
    """
    t = result.t
    dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
    m = t >= result.control_start - 1e-12
    if m.sum() < 2:
        m = np.ones_like(t, dtype=bool)
    w1 = result.state("omega1")[m]
    ws = windowed_severity(w1, dt, window)
    n_win = max(1, int(round(window / dt)))
    w2 = result.state("omega2")[m]
    n2 = result.input("n2")[m]
    torque = params.eta * params.KT * result.state("i")[m]
    st = solve_time_stats(result.solve_times)
    plans = result.plan_calls if result.plan_calls is not None else np.ones(len(result.solve_times), bool)
    sp = solve_time_stats(np.asarray(result.solve_times)[plans] if len(result.solve_times) else result.solve_times)
    cc, ec = result.controller_counts, result.estimator_counts
    return {
        "sss": severity(w1),
        "sss_window_mean": float(np.mean(ws)),
        "sss_window_max": float(np.max(ws)),
        "sss_final": severity(w1[-n_win:]),
        "stuck_fraction": stuck_fraction(w1, stuck_speed),
        "stuck_fraction_measured": stuck_fraction(result.y["omega1"][m], stuck_speed_measured),
        "mean_omega1": float(np.mean(w1)),
        "rms_twist12": rms(result.state("phi12")[m]),
        "std_twist12": float(np.std(result.state("phi12")[m])),
        "motor_torque_std": float(np.std(torque)),
        "friction_work_pin2": friction_work(w2, n2, params.r2, params.mu_s, params.mu_k, params.v_s, dt),
        "mean_n2": float(np.mean(n2)),
        "mean_omega_ref": float(np.mean(result.action_omega_ref[m])),
        "solve_median_ms": 1e3 * st["median"],
        "solve_p95_ms": 1e3 * st["p95"],
        "solve_max_ms": 1e3 * st["max"],
        "plan_median_ms": 1e3 * sp["median"],
        "plan_p95_ms": 1e3 * sp["p95"],
        "plan_max_ms": 1e3 * sp["max"],
        "plan_calls": int(np.sum(plans)),
        "controller_steps": int(cc.get("steps", 0)),
        "controller_failures": int(cc.get("failures", 0)),
        "controller_fallbacks": int(cc.get("fallbacks_shift", 0) + cc.get("fallbacks_baseline", 0)),
        "estimator_failures": int(ec.get("failures", 0)),
        "estimator_fallbacks": int(ec.get("fallbacks", 0)),
        "estimator_dropouts": int(ec.get("dropouts", 0)),
    }
