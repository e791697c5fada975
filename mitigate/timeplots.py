"""Legible PNG time histories of one run: speeds with the stuck intervals shaded, twists, the
drive's torque channel, the normal forces and the drive's set-point.

:func:`plot_run` draws a closed-loop run of any rig; :func:`plot_log` draws a log or an
open-loop simulation from its channels.
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

__all__ = ["plot_panels", "plot_run", "plot_log", "stick_intervals"]


def stick_intervals(t: np.ndarray, stuck: np.ndarray) -> list[tuple[float, float]]:
    """``[(t_start, t_end)]`` of the runs where ``stuck`` is True [s]."""
    stuck = np.asarray(stuck, dtype=bool)
    if stuck.size == 0:
        return []
    d = np.diff(np.concatenate([[0], stuck.astype(int), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends)]


def plot_panels(t, panels: Mapping[str, Mapping[str, np.ndarray]], title: str, path: str | os.PathLike, *,
                stuck=None, stuck_label: str = "stuck", dpi: int = 110):
    """One panel per ``{y label: {curve label: (n,) array}}``; ``stuck`` (n,) bool shades the first panel."""
    t = np.asarray(t, dtype=float)
    panels = {k: v for k, v in panels.items() if v}
    if not panels:
        raise DataError("nothing to plot")
    for lab, curves in panels.items():
        for name, v in curves.items():
            if np.shape(v) != t.shape:
                raise DataError(f"plot curve {name!r} has shape {np.shape(v)}, expected {t.shape}")
    fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(10, 2.2 + 2.0 * len(panels)), squeeze=False)
    axes = axes[:, 0]
    for k, (ax, (ylabel, curves)) in enumerate(zip(axes, panels.items())):
        for name, v in curves.items():
            style = dict(lw=1.0, ls="--", color="k") if "set-point" in name or "programme" in name else dict(lw=1.0)
            ax.plot(t, np.asarray(v), label=name, **style)
        if k == 0 and stuck is not None:
            for j, (a, b) in enumerate(stick_intervals(t, stuck)):
                ax.axvspan(a, b + (t[1] - t[0] if t.size > 1 else 0), color="tab:red", alpha=0.15, lw=0,
                           label=stuck_label if j == 0 else None)
        ax.legend(loc="upper right", fontsize=8, ncol=min(5, len(curves) + 1))
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    return finish_figure(fig, path, title, dpi=dpi)


def plot_run(sc, r, title: str, path: str | os.PathLike, dpi: int = 110):
    """A closed-loop run: true body speeds (objective body's stuck intervals shaded), true twists,
    the measured torque channel(s), the applied normal forces, the drive's set-point."""
    m = sc.model
    speeds = {f"{b} (true)": r.state(f"omega_{b}") for b in m.bodies if f"omega_{b}" in r.states}
    if m.drive_input in r.commands and m.drive.sets_speed:
        speeds[f"{m.drive_input} (set-point sent)"] = r.commands[m.drive_input]
    twists = {k: v for k, v in r.twists.items()}
    torques = {ch: r.y[s.channels[0]] for s in m.sensors if s.kind == "torque" for ch in s.channels if ch in r.y}
    forces = {n: r.input(n) for n, k in zip(m.inputs, m.input_kinds) if k == "force"}
    panels = {"speed [rad/s]": speeds, "twist [rad]": twists, "torque, measured [N m]": torques,
              "normal force, applied [N]": forces}
    return plot_panels(r.t, panels, title, path, stuck=r.objective_speed == 0.0,
                       stuck_label=f"{m.objective_body} stuck", dpi=dpi)


def plot_log(model, t, channels: Mapping[str, np.ndarray], title: str, path: str | os.PathLike, *,
             truth: Mapping[str, np.ndarray] | None = None, dpi: int = 110):
    """A log or an open-loop simulation of ``model``: its speed, torque and force channels, plus
    true twists and speeds from ``truth`` (the objective body's stuck intervals shaded from its
    true speed when given)."""
    kinds = {}
    for s in model.sensors:
        for ch in s.channels:
            kinds[ch] = {"encoder": "angle" if ch == s.channels[0] else "speed", "speed": "speed",
                         "torque": "torque", "load_cell": "force"}[s.kind]
    for n, k in zip(model.inputs, model.input_kinds):
        kinds.setdefault(n, k)
    pick = lambda kind: {n: v for n, v in channels.items() if kinds.get(n) == kind}  # noqa: E731
    panels = {"speed [rad/s]": pick("speed"), "torque [N m]": pick("torque"), "force [N]": pick("force")}
    stuck = None
    if truth:
        panels["twist, true [rad]"] = {k: v for k, v in truth.items() if k.startswith("twist_")}
        w = truth.get(f"omega_{model.objective_body}")
        if w is not None:
            stuck = np.asarray(w) == 0.0
    return plot_panels(t, panels, title, path, stuck=stuck, stuck_label=f"{model.objective_body} stuck", dpi=dpi)
