"""Comparison plots of a scenario run: overlaid time histories, phase portraits, metric bars.

Per-controller time histories use :func:`mitigate.timeplots.plot_time_histories`; this
module draws the plots that put the controllers side by side.  All plots use the TRUE
plant trajectories (what the rig did), not the measurements.
"""

from __future__ import annotations

import os
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mitigate.cliutil import finish_figure  # noqa: E402

__all__ = ["plot_comparison", "plot_phase_portraits", "plot_metric_bars", "BAR_METRICS"]

#: (metric key, axis label) of the bar chart
BAR_METRICS = (
    ("sss", "severity SSS [-]"),
    ("sss_final", "SSS, last window [-]"),
    ("stuck_fraction", "fraction of time stuck [-]"),
    ("rms_twist12", "RMS twist R1-R2 [rad]"),
    ("motor_torque_std", "motor torque std [N m]"),
    ("friction_work_pin2", "friction work at pin 2 [J]"),
    ("mean_omega1", "mean R1 speed [rad/s]"),
    ("plan_median_ms", "median planning-call time [ms]"),
)


def plot_comparison(results: Mapping[str, object], title: str, path: str | os.PathLike, dpi: int = 110):
    """R1 speed, twist R1-R2, applied N2 and set-point of every controller over time (true states)."""
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(11, 10))
    for name, r in results.items():
        axes[0].plot(r.t, r.state("omega1"), lw=0.8, label=name)
        axes[1].plot(r.t, r.state("phi12"), lw=0.8, label=name)
        axes[2].plot(r.t, r.input("n2"), lw=0.8, label=name)
        axes[3].plot(r.t, r.action_omega_ref, lw=1.0, label=name)
    labels = ("R1 speed omega1 [rad/s]", "twist theta1-theta2 [rad]", "applied pin force N2 [N]",
              "set-point omega_ref [rad/s]")
    starts = {float(r.control_start) for r in results.values()}
    for ax, lab in zip(axes, labels):
        ax.set_ylabel(lab)
        ax.grid(True, alpha=0.3)
        for s in starts:
            ax.axvline(s, color="k", ls=":", lw=1.0)
    axes[0].legend(loc="upper right", fontsize=8, ncol=min(4, len(results)))
    axes[0].set_title("true plant states; dotted line: control switched on")
    axes[-1].set_xlabel("time [s]")
    return finish_figure(fig, path, title, dpi=dpi)


def plot_phase_portraits(results: Mapping[str, object], title: str, path: str | os.PathLike, dpi: int = 110):
    """omega1 against twist12 (true), before (grey) and after (colour) the control start, one panel each."""
    n = max(1, len(results))
    cols = min(n, 3)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.0 * rows), squeeze=False)
    for ax, (name, r) in zip(axes.ravel(), results.items()):
        on = r.t >= r.control_start
        ax.plot(r.state("phi12")[~on], r.state("omega1")[~on], color="0.7", lw=0.6, label="before control")
        ax.plot(r.state("phi12")[on], r.state("omega1")[on], color="tab:blue", lw=0.8, label="after control start")
        ax.set_title(name)
        ax.set_xlabel("twist theta1-theta2 [rad]")
        ax.set_ylabel("R1 speed omega1 [rad/s]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=7)
    for ax in axes.ravel()[len(results):]:
        ax.set_visible(False)
    return finish_figure(fig, path, title, dpi=dpi)


def plot_metric_bars(metrics: Mapping[str, Mapping[str, float]], title: str, path: str | os.PathLike,
                     keys: Sequence[tuple[str, str]] = BAR_METRICS, dpi: int = 110):
    """One bar panel per metric, one bar per controller (NaN metrics are left empty)."""
    names = list(metrics)
    cols = 4
    rows = int(np.ceil(len(keys) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.2 * rows), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (key, label) in zip(axes.ravel(), keys):
        vals = [float(metrics[n].get(key, np.nan)) for n in names]
        vals = [v if np.isfinite(v) else 0.0 for v in vals]
        ax.bar(range(len(names)), vals, color=[colors[i % len(colors)] for i in range(len(names))])
        ax.set_xticks(range(len(names)))
        ax.set_xticklabels(names, rotation=30, ha="right", fontsize=8)
        ax.set_title(label, fontsize=9)
        ax.set_ylabel(label.split("[")[-1].rstrip("]") if "[" in label else "")
        ax.grid(True, axis="y", alpha=0.3)
    for ax in axes.ravel()[len(keys):]:
        ax.set_visible(False)
    return finish_figure(fig, path, title, dpi=dpi)
