"""Logs of the independent rig (``tests/independent_rig3.py``: the physics is specified in that
module's docstring): an open-loop run as a log, the project's CSV format, and the creep of a disc
while it sticks.

numpy and scipy only; nothing from the project's packages.
"""

from __future__ import annotations

import math
from typing import Callable, Optional, Union

import numpy as np

from independent_rig3_options import CHANNELS, LOG_COLUMNS, RigOptions
from independent_rig3_rig import IndependentRig3

Profile = Union[float, Callable[[float], float], np.ndarray]


def _profile(p: Profile, n: int, dt: float) -> np.ndarray:
    if callable(p):
        return np.array([float(p(k * dt)) for k in range(n)])
    arr = np.asarray(p, dtype=float)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if len(arr) < n:
        raise ValueError("profile array shorter than the log (%d < %d)" % (len(arr), n))
    return arr[:n].copy()


def simulate_log(options: RigOptions = RigOptions(), omega_ref_profile: Profile = math.pi,
                 n1_profile: Profile = 20.0, n2_profile: Profile = 0.0,
                 duration: float = 20.0, seed: Optional[int] = 0) -> dict:
    """Open-loop run of the rig, returned as a log (dict of arrays).

    Parameters
    ----------
    options : RigOptions
    omega_ref_profile, n1_profile, n2_profile : float, callable or array
        Commands: a constant, a function of time ``f(t_k)`` or an array with
        one value per sample.  Commands of row k are held over
        ``[t_k, t_{k+1})``.
    duration : float
        Length [s]; the log has ``round(duration/dt) + 1`` rows.
    seed : int or None
        Sensor-noise seed.

    Returns
    -------
    dict of ndarray
        The ``LOG_COLUMNS`` keys (measurements at ``t_k``, command
        ``omega_ref`` issued at ``t_k``, TRUE ``twist12``/``twist23``) plus
        ``n2_cmd``, ``n1_true``, ``n2_true``, ``omega1_true..omega3_true``,
        ``theta1_true..theta3_true``, ``current``, ``voltage``,
        ``torque_reaction_true``, ``torque_em_true``, ``omega_rotor_true``.
    """
    dt = options.dt
    n = int(round(duration / dt)) + 1
    wr = _profile(omega_ref_profile, n, dt)
    u1 = _profile(n1_profile, n, dt)
    u2 = _profile(n2_profile, n, dt)
    rig = IndependentRig3(options, seed)
    keys = [c for c, _ in LOG_COLUMNS]
    extra = ["n2_cmd", "n1_true", "n2_true", "omega1_true", "omega2_true", "omega3_true",
             "theta1_true", "theta2_true", "theta3_true", "current", "voltage",
             "torque_reaction_true", "torque_em_true", "omega_rotor_true"]
    log = {k: np.zeros(n) for k in keys + extra}
    m = rig.reset(wr[0], u1[0], u2[0])
    for k in range(n):
        tr = rig.truth()
        for ch in CHANNELS:
            log[ch][k] = m[ch]
        log["t"][k] = m["t"]
        log["omega_ref"][k] = wr[k]
        log["n2_cmd"][k] = u2[k]
        log["twist12"][k] = tr["twist12"]
        log["twist23"][k] = tr["twist23"]
        log["n1_true"][k] = tr["n1"]
        log["n2_true"][k] = tr["n2"]
        for j in (1, 2, 3):
            log["omega%d_true" % j][k] = tr["omega%d" % j]
            log["theta%d_true" % j][k] = tr["theta%d" % j]
        log["current"][k] = tr["current"]
        log["voltage"][k] = tr["voltage"]
        log["torque_reaction_true"][k] = tr["torque_reaction"]
        log["torque_em_true"][k] = tr["torque_em"]
        log["omega_rotor_true"][k] = tr["omega_rotor"]
        if k < n - 1:
            m = rig.step(wr[k], u1[k], u2[k])
    return log


def write_csv(path, log: dict, extra_columns=()) -> None:
    """Write a log in the project's CSV format.

    Parameters
    ----------
    path : str or path-like
    log : dict
        As returned by ``simulate_log``.
    extra_columns : sequence of (name, unit)
        Further columns to append after the standard ones.
    """
    cols = list(LOG_COLUMNS) + list(extra_columns)
    data = np.column_stack([np.asarray(log[c], dtype=float) for c, _ in cols])
    header = ",".join("%s [%s]" % (c, u) for c, u in cols)
    with open(path, "w", encoding="ascii") as fh:
        fh.write(header + "\n")
        for row in data:
            fh.write(",".join("%.10g" % v for v in row) + "\n")


def measure_creep(log: dict, body: int = 1, stick_speed: float = 0.01,
                  min_samples: int = 5) -> dict:
    """Creep of a disc during its stick phases, from the TRUE speeds of a log.

    Parameters
    ----------
    log : dict
        From ``simulate_log``.
    body : {1, 2}
    stick_speed : float
        A sample belongs to a stick phase when ``|omega_true| < stick_speed``.
    min_samples : int
        Shortest run of samples counted as a stick phase.

    Returns
    -------
    dict
        ``phases`` (number), ``max_speed`` [rad/s] (largest |omega| inside the
        phases, their first and last samples excluded), ``max_drift`` [rad]
        (largest angle change over a phase, same exclusion) and
        ``drift_per_second`` [rad/s] (its rate).
    """
    w = np.asarray(log["omega%d_true" % body])
    th = np.asarray(log["theta%d_true" % body])
    t = np.asarray(log["t"])
    stuck = np.abs(w) < stick_speed
    phases = []
    k = 0
    while k < len(w):
        if stuck[k]:
            j = k
            while j < len(w) and stuck[j]:
                j += 1
            if j - k >= min_samples:
                phases.append((k + 1, j - 1))   # exclude the transition samples
            k = j
        else:
            k += 1
    maxs, drift, rate = 0.0, 0.0, 0.0
    for a, b in phases:
        if b <= a:
            continue
        maxs = max(maxs, float(np.max(np.abs(w[a:b]))))
        d = abs(th[b - 1] - th[a])
        if d > drift:
            drift = d
            rate = d / max(t[b - 1] - t[a], 1e-12)
    return {"phases": len(phases), "max_speed": maxs, "max_drift": drift,
            "drift_per_second": rate}
