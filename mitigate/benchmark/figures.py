"""The benchmark's figures: the median true residual severity (reported, not ranked: below what the
rig's sensors resolve) and the rank of every (scenario, controller) (``benchmark.png``), and its
distribution over the switch-on phases and noise seeds (``distribution.png``: one panel per scenario,
a box and the individual runs per controller)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["plot_heatmap", "plot_distribution"]


def _wrap(title: str, fig) -> str:
    """The title wrapped to the figure's width (about 9 characters per inch at the title's size)."""
    import textwrap
    return textwrap.fill(title, max(30, int(fig.get_figwidth() * 9)))


def plot_heatmap(res, path) -> None:
    """Median residual severity [% of the programmed speed] and rank per scenario and controller."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from mitigate.cliutil import finish_figure

    su = res.suite
    names = [c.name for c in su.controllers]
    scen = [sc.name for sc in su.scenarios]
    S = np.full((len(scen), len(names)), np.nan)
    for i, s in enumerate(scen):
        for j, n in enumerate(names):
            e = res.entries[(s, n)]
            if e.applicable and e.n_bad < e.n_runs:
                S[i, j] = 100 * e.value("residual_severity")
    fin = S[np.isfinite(S) & (S > 0)]
    lo, hi = (max(float(fin.min()), 1e-2), max(float(fin.max()), 1.0)) if fin.size else (0.1, 100.0)
    fig, ax = plt.subplots(figsize=(1.25 * len(names) + 3.5, 0.5 * len(scen) + 2.6))
    im = ax.imshow(np.clip(S, lo, hi), cmap="viridis_r", aspect="auto", norm=LogNorm(vmin=lo, vmax=max(hi, lo * 10)))
    for i, s in enumerate(scen):
        for j, n in enumerate(names):
            e = res.entries[(s, n)]
            if not e.applicable:
                txt = "n/a"
            elif e.n_failed == e.n_runs:
                txt = "failed"
            elif e.n_bad == e.n_runs:
                txt = f"not done\n#{e.rank}"
            else:
                txt = f"{S[i, j]:.3g} %\n#{e.rank}" + ("" if e.job_done else "\n(not done)")
            dark = np.isfinite(S[i, j]) and S[i, j] > math.sqrt(lo * hi)
            ax.text(j, i, txt, ha="center", va="center", fontsize=7, color="w" if dark else "k")
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(scen)), scen, fontsize=8)
    fig.colorbar(im, ax=ax, label="true what stays [% of programmed speed]")
    finish_figure(fig, path, _wrap(f"{su.name} ({res.mode}): true what stays (median over the runs that did the job, "
                                   f"{res.phases} phase(s) x {res.seeds} seed(s); reported, not ranked) and rank "
                                   f"(the ranking's order: ranking.md)", fig))


def plot_distribution(res, path) -> None:
    """Per scenario, the residual severity of every run per controller: a box (quartiles) and the runs
    as points (log scale; failed runs are not drawn, a stuck run is 100 %)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mitigate.cliutil import finish_figure

    su = res.suite
    names = [c.name for c in su.controllers]
    scen = [sc.name for sc in su.scenarios]
    cols = min(3, len(scen))
    rows = int(math.ceil(len(scen) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.6 * rows), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    rng = np.random.default_rng(0)                 # the points' horizontal jitter only
    for ax, s in zip(axes.ravel(), scen):
        data = []
        for n in names:
            v = [100 * r.value("residual_severity") for r in res.records
                 if r.run.scenario == s and r.run.controller == n and r.applicable and not r.failed
                 and "residual_severity" in r.metrics]
            data.append(np.maximum(np.array(v, float), 1e-3))
        pos = [j for j, d in enumerate(data) if d.size]
        if pos:
            ax.boxplot([data[j] for j in pos], positions=pos, widths=0.6, showfliers=False,
                       medianprops={"color": "k"})
        for j, d in enumerate(data):
            ax.plot(j + rng.uniform(-0.18, 0.18, d.size), d, "o", ms=3, alpha=0.7, color=colors[j % len(colors)])
            if not d.size:
                ax.text(j, 0.03, "n/a", ha="center", fontsize=7, transform=ax.get_xaxis_transform())
        ax.set_yscale("log")
        ax.set_xticks(range(len(names)), names, rotation=35, ha="right", fontsize=7)
        ax.set_title(s, fontsize=9)
        ax.set_ylabel("what stays [% of programme]", fontsize=8)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    for ax in axes.ravel()[len(scen):]:
        ax.set_visible(False)
    finish_figure(fig, path, _wrap(f"{su.name} ({res.mode}): what stays in every run ({res.phases} phase(s) x "
                                   f"{res.seeds} seed(s)); box: quartiles", fig))
