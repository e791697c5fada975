"""PNG maps of a sweep in the manner of seed 002 Figs. 9.31-9.33.

- 2 axes: filled contours of each metric the registry shows on a map (:func:`mitigate.metrics.shown`
  ``("map")``; first axis horizontal), one figure per start
  mode, with the linear stability boundary of steady sliding (max real part = 0) as a
  thick black line and the limit-cycle threshold as a dashed white line;
- 2 axes and both start modes: a bistability map (where the run from rest and the run
  from steady sliding disagree);
- 3 axes: the threshold contour of the amplitude in the plane of the first two axes,
  one line per value of the third axis (seed 002 Fig. 9.32), plus one amplitude map per value;
- 1 axis: line plots.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mitigate.cliutil import savefig_atomic

__all__ = ["plot_maps", "metric_label"]


def metric_label(name: str, amp_unit: str) -> str:
    """A metric's axis label: ``header [unit]``, the amplitude in the unit of its state ``amp_unit``."""
    from mitigate.metrics import get
    from mitigate.metrics.sweep import AMPLITUDE_UNIT
    m = get(name)
    return f"{m.header or m.name} [{amp_unit if m.unit == AMPLITUDE_UNIT else m.unit}]"


def _mapped() -> tuple[str, ...]:
    from mitigate.metrics import shown
    return tuple(m.name for m in shown("map"))

_UNITS: dict = {}   # name -> SI unit, set by plot_maps from the scenario


def _label(name: str) -> str:
    if name.endswith("_scale") or name.startswith("mismatch."):
        return f"{name} [-]"
    return f"{name} [{_UNITS.get(name, 'SI')}]"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_maps(result, out_dir, *, title: str, amp_unit: str, threshold: float, prefix: str = "map",
              units: dict | None = None) -> list[Path]:
    """Write the PNG maps of a :class:`mitigate.sweep.SweepResult`; returns the paths."""
    _UNITS.clear()
    _UNITS.update(units or {})
    out_dir = Path(out_dir)
    axes = result.axes
    files = []
    if len(axes) == 1:
        files += _lines(result, out_dir, title, amp_unit, prefix)
    elif len(axes) == 2:
        for start, maps in result.maps.items():
            for metric in _mapped():
                files.append(_contour(result, maps[metric], out_dir / f"{prefix}_{metric}_{start}.png",
                                      f"{title}: {metric_label(metric, amp_unit)}\nstarted from {start}", metric,
                                      maps["amplitude"], threshold, amp_unit))
        if len(result.maps) == 2:
            files.append(_bistability(result, out_dir / f"{prefix}_bistability.png", title))
    elif len(axes) == 3:
        files += _threshold_family(result, out_dir, title, amp_unit, threshold, prefix)
    return files


def _stab(result, shape):
    """(X, Y, S) of the sliding-stability sub-grid of a 2-axis sweep, or None."""
    if result.stability is None or not np.any(np.isfinite(result.stability)) or len(result.axes) != 2:
        return None
    i0, i1 = result.stability_subgrid
    S = result.stability.reshape(shape)[np.ix_(i0, i1)]
    if S.shape[0] < 2 or S.shape[1] < 2 or not (np.nanmax(S) > 0 > np.nanmin(S)):
        return None
    X, Y = np.meshgrid(result.axes[0].values[i0], result.axes[1].values[i1], indexing="ij")
    return X, Y, S


def _contour(result, Z, path, title, metric, amp, threshold, amp_unit=""):
    plt = _plt()
    ax0, ax1 = result.axes[:2]
    X, Y = np.meshgrid(ax0.values, ax1.values, indexing="ij")
    fig, ax = plt.subplots(figsize=(6.4, 5.8))
    Zp = np.ma.masked_invalid(Z)
    if Zp.count() and np.ptp(Zp.compressed()) > 0:
        cs = ax.contourf(X, Y, Zp, levels=14, cmap="viridis")
        fig.colorbar(cs, ax=ax, label=metric_label(metric, amp_unit))
    else:
        ax.pcolormesh(X, Y, Zp, shading="nearest", cmap="viridis")
        ax.text(0.5, 0.5, f"{metric_label(metric, amp_unit)} constant ({float(Zp.mean()) if Zp.count() else float('nan'):.3g})",
                transform=ax.transAxes, ha="center", color="w")
    handles = []
    if np.nanmax(amp) > threshold > np.nanmin(amp):
        ax.contour(X, Y, amp, levels=[threshold], colors="w", linestyles="--", linewidths=1.5)
        handles.append(plt.Line2D([], [], color="0.45", ls="--", label=f"white dashed: amplitude = {threshold:g} (limit-cycle threshold)"))
    st = _stab(result, Z.shape)
    if st is not None:
        ax.contour(*st, levels=[0.0], colors="k", linewidths=2.5)
        handles.append(plt.Line2D([], [], color="k", lw=2.5, label="linear stability boundary of steady sliding"))
    if handles:
        ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.13), fontsize=8, ncol=1)
    ax.set_xlabel(_label(ax0.name))
    ax.set_ylabel(_label(ax1.name))
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    p = savefig_atomic(fig, path)
    plt.close(fig)
    return p


def _bistability(result, path, title):
    plt = _plt()
    from matplotlib.colors import ListedColormap
    ax0, ax1 = result.axes[:2]
    X, Y = np.meshgrid(ax0.values, ax1.values, indexing="ij")
    r = result.maps["rest"]["limit_cycle"]
    s = result.maps["sliding"]["limit_cycle"]
    # 0 none, 1 only from rest (triggered: disturbance-induced), 2 only from sliding, 3 both
    code = np.where(np.isfinite(r) & np.isfinite(s), (r > 0.5) * 1 + (s > 0.5) * 2, np.nan)
    fig, ax = plt.subplots(figsize=(7.0, 6.0))
    cmap = ListedColormap(["#d9f0d3", "#fdae61", "#abd9e9", "#d7191c"])
    ax.pcolormesh(X, Y, np.ma.masked_invalid(code), cmap=cmap, vmin=-0.5, vmax=3.5, shading="nearest")
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in cmap.colors]
    labels = ["steady sliding from both starts", "stick-slip from rest only (bistable)",
              "stick-slip from sliding only", "stick-slip from both starts"]
    st = _stab(result, code.shape)
    if st is not None:
        ax.contour(*st, levels=[0.0], colors="k", linewidths=2.5)
        handles.append(plt.Line2D([], [], color="k", lw=2.5))
        labels.append("linear stability boundary of steady sliding")
    ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.13), fontsize=8, ncol=2)
    ax.set_xlabel(_label(ax0.name))
    ax.set_ylabel(_label(ax1.name))
    ax.set_title(f"{title}: bistability (rest vs steady-sliding start)", fontsize=10)
    fig.tight_layout()
    p = savefig_atomic(fig, path)
    plt.close(fig)
    return p


def _threshold_family(result, out_dir, title, amp_unit, threshold, prefix):
    plt = _plt()
    ax0, ax1, ax2 = result.axes
    X, Y = np.meshgrid(ax0.values, ax1.values, indexing="ij")
    files = []
    for start, maps in result.maps.items():
        A = maps["amplitude"]
        fig, ax = plt.subplots(figsize=(6.4, 5.0))
        handles, labels = [], []
        colors = plt.cm.plasma(np.linspace(0.0, 0.85, ax2.count))
        for k, v in enumerate(ax2.values):
            Ak = A[:, :, k]
            if np.nanmax(Ak) > threshold > np.nanmin(Ak):
                ax.contour(X, Y, Ak, levels=[threshold], colors=[colors[k]], linewidths=2.0)
                handles.append(plt.Line2D([], [], color=colors[k], lw=2.0))
                labels.append(f"{ax2.name} = {v:.3g}")
            else:
                handles.append(plt.Line2D([], [], color=colors[k], lw=2.0, ls=":"))
                labels.append(f"{ax2.name} = {v:.3g} ({'all above' if np.nanmin(Ak) >= threshold else 'all below'})")
        ax.legend(handles, labels, loc="best", fontsize=8, title=f"amplitude = {threshold:g} {amp_unit}")
        ax.set_xlabel(_label(ax0.name))
        ax.set_ylabel(_label(ax1.name))
        ax.set_title(f"{title}: instability threshold vs {ax2.name}\nstarted from {start}", fontsize=10)
        fig.tight_layout()
        files.append(savefig_atomic(fig, out_dir / f"{prefix}_threshold_{start}.png"))
        plt.close(fig)
        for k, v in enumerate(ax2.values):
            fig, ax = plt.subplots(figsize=(6.4, 5.0))
            Ak = np.ma.masked_invalid(A[:, :, k])
            if Ak.count() and np.ptp(Ak.compressed()) > 0:
                cs = ax.contourf(X, Y, Ak, levels=14, cmap="viridis")
                fig.colorbar(cs, ax=ax, label=f"amplitude [{amp_unit}]")
                if np.nanmax(Ak) > threshold > np.nanmin(Ak):
                    ax.contour(X, Y, Ak, levels=[threshold], colors="k", linewidths=2.5)
            ax.set_xlabel(_label(ax0.name))
            ax.set_ylabel(_label(ax1.name))
            ax.set_title(f"{title}: amplitude, {ax2.name} = {v:.3g}, from {start}\n"
                         f"(black: amplitude = {threshold:g} {amp_unit})", fontsize=10)
            fig.tight_layout()
            files.append(savefig_atomic(fig, out_dir / f"{prefix}_amplitude_{start}_{ax2.name}{k}.png"))
            plt.close(fig)
    return files


def _lines(result, out_dir, title, amp_unit, prefix):
    plt = _plt()
    ax0 = result.axes[0]
    mapped = _mapped()
    rows = max(1, -(-len(mapped) // 2))
    fig, axs = plt.subplots(rows, 2, figsize=(9, 3.25 * rows), sharex=True, squeeze=False)
    for a, metric in zip(axs.ravel(), mapped):
        for start, maps in result.maps.items():
            a.plot(ax0.values, maps[metric], marker=".", label=f"from {start}")
        a.set_ylabel(metric_label(metric, amp_unit))
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    for a in axs.ravel()[len(mapped):]:
        a.set_visible(False)
    for a in axs[-1]:
        a.set_xlabel(_label(ax0.name))
    fig.suptitle(f"{title}: sweep over {ax0.name}")
    fig.tight_layout()
    p = savefig_atomic(fig, out_dir / f"{prefix}_{ax0.name}.png")
    plt.close(fig)
    return [p]
