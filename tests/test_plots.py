"""metrics.png (mitigate.plots.plot_metric_bars): a time to suppress of "never" is drawn as the worst
bar, not as an empty slot that reads as 0 s, the best (issue 18 item 7)."""

import math

import mitigate.plots as P


def test_never_is_the_tallest_hatched_bar_and_nan_is_labelled(tmp_path, monkeypatch):
    seen = {}

    def keep(fig, path, title=None, dpi=110):
        seen["fig"] = fig
        fig.savefig(path)

    monkeypatch.setattr(P, "finish_figure", keep)
    m = {"PI": {"time_to_suppress": math.inf, "residual_severity": 1.0},
         "NMPC": {"time_to_suppress": 3.0, "residual_severity": math.nan},
         "SoftSpeed": {"time_to_suppress": 9.0, "residual_severity": 0.02}}
    P.plot_metric_bars(m, "t", tmp_path / "m.png", keys=(("time_to_suppress", "t"), ("residual_severity", "r")))
    ax_t, ax_r = seen["fig"].axes[:2]
    bars = {round(b.get_x() + b.get_width() / 2): b for b in ax_t.patches}
    assert bars[0].get_height() > bars[2].get_height() > bars[1].get_height() > 0     # never > 9 s > 3 s
    assert bars[0].get_hatch() == "//" and bars[1].get_hatch() is None
    assert [t.get_text() for t in ax_t.texts] == ["never"]
    assert [t.get_text() for t in ax_r.texts] == ["n/a"] and len(ax_r.patches) == 2
    assert (tmp_path / "m.png").stat().st_size > 1000
