"""Legible PNG time-history plots of a run (speeds with stick intervals, twists, torque, forces).

:func:`plot_time_histories` takes a dict of named channels in the log vocabulary
(:mod:`models.logs`) and draws one panel per group that is present:

- speeds ``omega1/omega2/omega3`` (and ``omega_ref``) [rad/s], with the intervals where
  R1 is stuck shaded (from ``stuck1``, a boolean channel, if given, else from
  ``omega1 == 0`` exactly, which only the exact hybrid plant's true speed satisfies);
- twists ``twist12/twist23/twist`` [rad];
- ``motor_torque`` [N m];
- pin forces ``n1/n2`` and ``axial_force`` [N].

Extra channels may be passed as ``{"label [unit]": array}`` in ``extra``.
"""

from __future__ import annotations

import os
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mitigate.cliutil import finish_figure  # noqa: E402
from models.errors import DataError  # noqa: E402

__all__ = ["plot_time_histories", "stick_intervals"]

_GROUPS = (
    ("speed [rad/s]", ("omega1", "omega2", "omega3", "omega_ref", "omega_drive")),
    ("twist [rad]", ("twist12", "twist23", "twist")),
    ("motor torque [N m]", ("motor_torque",)),
    ("force [N]", ("n1", "n2", "axial_force")),
)
_LABELS = {
    "omega1": "R1 (bit)", "omega2": "R2", "omega3": "R3 (motor end)", "omega_ref": "reference",
    "omega_drive": "drive", "twist12": "theta1 - theta2", "twist23": "theta2 - theta3", "twist": "twist",
    "motor_torque": "eta KT i (disc side)", "n1": "N1 (R1 pin)", "n2": "N2 (R2 pin)", "axial_force": "axial force R",
}


def stick_intervals(t: np.ndarray, stuck: np.ndarray) -> list[tuple[float, float]]:
    """``[(t_start, t_end)]`` of the runs where ``stuck`` is True [s]."""
    stuck = np.asarray(stuck, dtype=bool)
    if stuck.size == 0:
        return []
    d = np.diff(np.concatenate([[0], stuck.astype(int), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends)]


def plot_time_histories(t, channels: Mapping[str, np.ndarray], title: str, path: str | os.PathLike, *,
                        stuck1=None, extra: Mapping[str, np.ndarray] | None = None, dpi: int = 110):
    """Draw the run and save it as a PNG (atomically).

    Parameters
    ----------
    t : (n,) time [s]
    channels : name -> (n,) array, names from the log vocabulary (unknown names ignored
        unless given through ``extra``)
    title : figure title
    path : PNG path
    stuck1 : (n,) bool, optional: where R1 is stuck (shaded); default ``omega1 == 0``
    extra : label -> (n,) array, drawn in one more panel each

    Returns
    -------
    pathlib.Path of the PNG.
    """
    t = np.asarray(t, dtype=float)
    for name, v in {**channels, **(extra or {})}.items():
        if np.shape(v) != t.shape:
            raise DataError(f"plot channel {name!r} has shape {np.shape(v)}, expected {t.shape}")
    panels = [(ylabel, [n for n in names if n in channels]) for ylabel, names in _GROUPS]
    panels = [(y, ns) for y, ns in panels if ns]
    panels += [(label, None) for label in (extra or {})]
    if not panels:
        raise DataError(f"nothing to plot: no known channel among {sorted(channels)}")
    fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(10, 2.2 + 2.0 * len(panels)), squeeze=False)
    axes = axes[:, 0]
    if stuck1 is None and "omega1" in channels:
        stuck1 = np.asarray(channels["omega1"]) == 0.0
    intervals = stick_intervals(t, stuck1) if stuck1 is not None else []
    for ax, (ylabel, names) in zip(axes, panels):
        if names is None:
            ax.plot(t, np.asarray(extra[ylabel]), lw=1.0)
        else:
            for n in names:
                style = dict(lw=1.0)
                if n in ("omega_ref",):
                    style = dict(lw=1.0, ls="--", color="k")
                ax.plot(t, np.asarray(channels[n]), label=_LABELS.get(n, n), **style)
            ax.legend(loc="upper right", fontsize=8, ncol=min(4, len(names)))
        if ylabel.startswith("speed"):
            for k, (a, b) in enumerate(intervals):
                ax.axvspan(a, b + (t[1] - t[0] if t.size > 1 else 0), color="tab:red", alpha=0.15, lw=0,
                           label="R1 stuck" if k == 0 else None)
            if intervals:
                ax.legend(loc="upper right", fontsize=8, ncol=5)
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    return finish_figure(fig, path, title, dpi=dpi)
