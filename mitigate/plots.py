"""Comparison plots of a scenario run: overlaid time histories, phase portraits, metric bars.

All plots use the TRUE plant trajectories (what the rig did), not the measurements: the speed
of the body whose stick-slip is suppressed (rig3: R1), the twist of the spring next to it,
the inputs the controllers set (servo forces as applied, the drive's set-point as sent).
"""

from __future__ import annotations

import os
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mitigate.cliutil import finish_figure  # noqa: E402

__all__ = ["plot_comparison", "plot_phase_portraits", "plot_metric_bars", "objective_twist"]

def objective_twist(model) -> str | None:
    """Name of the twist of the first spring that touches the objective body (None if none)."""
    for c in model.spec.connections:
        if c.stiffness is not None and model.objective_body in (c.a, c.b):
            return f"twist_{c.name}"
    return None


def plot_comparison(sc, results: Mapping[str, object], title: str, path: str | os.PathLike, dpi: int = 110):
    """The objective body's speed, its twist and every commanded input of every controller over time."""
    m = sc.model
    tw = objective_twist(m)
    cmds = list(m.commands)
    rows = 1 + (tw is not None) + len(cmds)
    fig, axes = plt.subplots(rows, 1, sharex=True, figsize=(12.5, 2.4 * rows + 0.8), squeeze=False)
    axes = axes[:, 0]
    for name, r in results.items():
        k = 0
        axes[k].plot(r.t, r.objective_speed, lw=0.8, label=name)
        if tw is not None:
            k += 1
            axes[k].plot(r.t, r.twists[tw], lw=0.8, label=name)
        for c in cmds:
            k += 1
            v = r.input(c) if c in m.servo_inputs else r.commands[c]
            axes[k].plot(r.t, v, lw=0.9, label=name)
    labels = [f"speed of {m.objective_body} [rad/s]"] + ([f"{tw} [rad]"] if tw else []) + \
        [f"{c} [{m.input_units[m.inputs.index(c)]}]" + (" (applied)" if c in m.servo_inputs else " (sent)")
         for c in cmds]
    starts = {float(r.control_start) for r in results.values()}
    for ax, lab in zip(axes, labels):
        ax.set_ylabel(lab, fontsize=9)
        ax.grid(True, alpha=0.3)
        for s in starts:
            ax.axvline(s, color="k", ls=":", lw=1.0)
    if results:                  # (every run may have failed before its first sample)
        # outside the axes, right of the top panel: over the data it hid the peaks (issue 18 item 7)
        axes[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    axes[0].set_title("true plant states; dotted line: control switched on")
    axes[-1].set_xlabel("time [s]")
    return finish_figure(fig, path, title, dpi=dpi)


def plot_phase_portraits(sc, results: Mapping[str, object], title: str, path: str | os.PathLike, dpi: int = 110):
    """Objective body speed against its twist (true), before (grey) and after (colour) the control start."""
    tw = objective_twist(sc.model)
    n = max(1, len(results))
    cols = min(n, 3)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.0 * rows), squeeze=False)
    for ax, (name, r) in zip(axes.ravel(), results.items()):
        on = r.t >= r.control_start
        x = r.twists[tw] if tw else r.t
        w = r.objective_speed
        ax.plot(x[~on], w[~on], color="0.7", lw=0.6, label="before control")
        ax.plot(x[on], w[on], color="tab:blue", lw=0.8, label="after control start")
        ax.set_title(name)
        ax.set_xlabel(f"{tw} [rad]" if tw else "time [s]")
        ax.set_ylabel(f"speed of {sc.model.objective_body} [rad/s]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=7)
    for ax in axes.ravel()[len(results):]:
        ax.set_visible(False)
    return finish_figure(fig, path, title, dpi=dpi)


def plot_metric_bars(metrics: Mapping[str, Mapping[str, float]], title: str, path: str | os.PathLike,
                     keys: Sequence[tuple[str, str]] | None = None, dpi: int = 110):
    """One bar panel per metric, one bar per controller; ``keys``: ``(metric, label)`` pairs (None: the
    registry's ``"bars"``, :func:`mitigate.metrics.shown`).  An infinite value (``time_to_suppress``:
    never suppressed) is a hatched bar to the top of the panel labelled as its metric reads it
    ("never") -- the worst, not an empty slot that would read as 0; a missing value (NaN) is "n/a"."""
    from mitigate.metrics import get, shown
    from models.errors import ConfigError
    if keys is None:
        keys = [(m.name, m.label) for m in shown("bars")]
    names = list(metrics)
    cols = 4
    rows = int(np.ceil(len(keys) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.2 * rows), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (key, label) in zip(axes.ravel(), keys):
        vals = np.array([float(metrics[n].get(key, np.nan)) for n in names])
        fin = vals[np.isfinite(vals)]
        top = 1.15 * float(np.max(fin)) if fin.size and np.max(fin) > 0 else 1.0
        try:
            inf_text = get(key).inf
        except ConfigError:
            inf_text = "inf"
        for j, v in enumerate(vals):
            c = colors[j % len(colors)]
            if np.isinf(v):
                ax.bar(j, top, color="white", edgecolor=c, hatch="//", lw=1.2)
                ax.text(j, 0.5 * top, inf_text, ha="center", va="center", rotation=90, fontsize=8)
            elif np.isnan(v):
                ax.text(j, 0.02 * top, "n/a", ha="center", va="bottom", fontsize=8)
            else:
                ax.bar(j, v, color=c)
        ax.set_ylim(0, top * 1.02 if np.isinf(vals).any() else None)
        ax.set_xlim(-0.6, len(names) - 0.4)
        ax.set_xticks(range(len(names)))
        ax.set_xticklabels(names, rotation=30, ha="right", fontsize=8)
        ax.set_title(label, fontsize=9)
        ax.grid(True, axis="y", alpha=0.3)
    for ax in axes.ravel()[len(keys):]:
        ax.set_visible(False)
    return finish_figure(fig, path, title, dpi=dpi)
