"""The data of an identification problem: its logs checked against the rig, and aligned.

:func:`check_logs` refuses what the rig cannot read (another sample period, a missing input);
:func:`check_option_names` refuses options that name what the rig does not have;
:func:`align_logs` shifts every channel back by its delay, low-passes the inputs the options say,
and cuts each log into its training part and shooting intervals (:class:`LogData`);
:func:`split_by_log` cuts a fit's stacked arrays back into one piece per log.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from models.errors import ConfigError, DataError
from models.logs import Log
from models.signals import lowpass

__all__ = ["LogData", "check_logs", "check_option_names", "align_logs", "split_by_log", "nrmse"]

#: the quantity a log column must hold for each kind of rig input
INPUT_QUANTITY = {"speed": "speed", "torque": "torque", "force": "force"}


@dataclass(frozen=True)
class LogData:
    """One log, aligned: row k of ``U`` (logged inputs) and ``Y`` (compared channels) belongs to
    time ``t[k]`` after every channel is shifted back by its delay.  ``nint`` shooting intervals
    of the training part (the first ``ntr`` rows) are fitted."""

    log: Log
    t: np.ndarray
    U: np.ndarray
    Y: np.ndarray
    n: int
    ntr: int
    nint: int


def check_option_names(model, options) -> None:
    """Every parameter and input the options name belongs to the rig.

    Raises
    ------
    ConfigError : "options.<field>: <name> is not ..."
    """
    m, o = model, options
    for n in o.free:
        if n not in m.param_names:
            raise ConfigError(f"options.free: {n!r} is not a parameter of rig {m.name!r}; expected some of "
                              f"{', '.join(m.param_names)}")
    for n in (o.bounds or {}):
        if n not in o.free:
            raise ConfigError(f"options.bounds.{n}: not a free parameter (free: {', '.join(o.free)})")
    for what, table in (("input_cutoff", o.input_cutoff or {}),
                        ("input_noise", o.input_noise if isinstance(o.input_noise, dict) else {})):
        for n in table:
            if n not in m.inputs:
                raise ConfigError(f"options.{what}.{n}: not an input of rig {m.name!r} "
                                  f"(inputs: {', '.join(m.inputs)})")


def check_logs(model, logs, options) -> tuple[tuple[Log, ...], float]:
    """The logs as a tuple (each encoder's missing speed derived from its angle:
    :meth:`models.logs.Log.with_speeds`), and their one sample period [s].

    Raises
    ------
    DataError : no logs, not Log objects, another sample period, a missing or mis-typed input column
    ConfigError : an ``input_cutoff`` at or above the Nyquist frequency
    """
    m = model
    logs = [logs] if isinstance(logs, Log) else list(logs) if isinstance(logs, Sequence) else None
    if not logs:
        raise DataError("logs must be a Log or a non-empty sequence of Logs, got none")
    for lg in logs:
        if not isinstance(lg, Log):
            raise DataError(f"logs must hold models.logs.Log objects, got {type(lg).__name__}")
    # each encoder's speed from its angle, whatever the channels are named (the rig's sensors say which)
    logs = [lg.with_speeds(m) for lg in logs]
    dt = logs[0].dt
    for lg in logs:
        if abs(lg.dt - dt) > 1e-9 * max(1.0, dt):
            raise DataError(f"{lg.source}: sample period {lg.dt:g} s differs from {dt:g} s of "
                            f"{logs[0].source}; resample the logs to one period")
        for name, kind in zip(m.inputs, m.input_kinds):
            if name not in lg.channels:
                raise DataError(f"{lg.source}: missing input column {name!r} needed by rig {m.name!r} "
                                f"(inputs: {', '.join(m.inputs)})")
            lg.require_kind(name, INPUT_QUANTITY[kind])
    for n, fc in (options.input_cutoff or {}).items():
        if not fc < 0.5 / dt:
            raise ConfigError(f"options.input_cutoff.{n} must be below the Nyquist frequency {0.5 / dt:g} Hz, "
                              f"got {fc:g}")
    return tuple(logs), dt


def align_logs(model, logs, channels, input_delays, options, holdout: float) -> tuple[LogData, ...]:
    """Each log shifted back by the largest delay, inputs low-passed where ``input_cutoff`` says,
    cut into ``shoot_every``-sample intervals of its training part (all but the last ``holdout``).

    Raises
    ------
    DataError : a later log lacks an output column of the first, or a log is too short
    """
    m, o = model, options
    for lg in logs[1:]:
        for c in channels:
            for p in c.parts:
                if p not in lg.channels:
                    raise DataError(f"{lg.source}: missing output column {p!r} (present in {logs[0].source})")
    D = max([c.max_delay for c in channels] + list(input_delays))
    M = o.shoot_every
    data = []
    for lg in logs:
        n = len(lg.t) - D
        ntr = n if holdout == 0 else int(round(n * (1 - holdout)))
        nint = (ntr - 1) // M
        if nint < 1:
            raise DataError(f"{lg.source}: needs at least {M + 1 + D} samples for shoot_every = {M}"
                            f"{f' and a delay of {D} samples' if D else ''}, got {len(lg.t)}"
                            f"{' (after the hold-out)' if holdout else ''}")
        cols = []
        for name, d in zip(m.inputs, input_delays):
            x = np.asarray(lg[name], float)
            if name in (o.input_cutoff or {}):
                x = lowpass(x, lg.dt, o.input_cutoff[name])
            cols.append(x[d:d + n])
        U = np.column_stack(cols) if cols else np.zeros((n, 0))
        Y = np.column_stack([c.measured(lg, 0, n) for c in channels])
        data.append(LogData(lg, np.asarray(lg.t[:n], float), U, Y, n, ntr, nint))
    return tuple(data)


def split_by_log(data, zero_index, shoot_every, names, sig, Ym, Yp, nodes, z, deltas):
    """A fit's stacked arrays cut back per log: times, measured, simulated and normalised residual
    channels (dicts by channel name), node states, encoder zeros and input corrections (tuples of
    lists, one item per log)."""
    t_l, meas_l, sim_l, res_l, states, zeros, corr_l = [], [], [], [], [], [], []
    iv = col = node = 0
    for d, zi in zip(data, zero_index):
        ncol = d.nint * shoot_every
        t_l.append(d.t[1:ncol + 1])
        meas_l.append({c: Ym[col:col + ncol, j] for j, c in enumerate(names)})
        sim_l.append({c: Yp[col:col + ncol, j] for j, c in enumerate(names)})
        res_l.append({c: (Ym[col:col + ncol, j] - Yp[col:col + ncol, j]) / sig[j] for j, c in enumerate(names)})
        states.append(nodes[node:node + d.nint + 1].copy())
        zeros.append({c: float(z[j]) for c, j in zi.items()})
        corr_l.append(deltas[iv:iv + d.nint].copy())
        iv += d.nint
        node += d.nint + 1
        col += ncol
    return t_l, meas_l, sim_l, res_l, states, zeros, corr_l


def nrmse(names, Ym, Yp) -> dict[str, float]:
    """RMS of measured minus simulated over the measured range, per channel (NaN for a flat channel)."""
    out = {}
    for j, c in enumerate(names):
        span = float(np.ptp(Ym[:, j]))
        out[c] = float(np.sqrt(np.mean((Ym[:, j] - Yp[:, j]) ** 2)) / span) if span > 0 else float("nan")
    return out
