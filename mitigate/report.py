"""``report.md`` of a scenario run: the table, the plots, and what the numbers say.

The text is generated from the measured metrics only.  The section on the NMPC lists,
metric by metric, every controller that did better than it, and the facts that bear on
why (solve time against the control period, fallbacks, estimator and model used).
"""

from __future__ import annotations

import math
from pathlib import Path

from mitigate.metrics import METRIC_UNITS
from models.logs import atomic_write_text

__all__ = ["write_report", "render_report", "LOWER_IS_BETTER"]

#: metrics where lower is better, compared in the NMPC section
LOWER_IS_BETTER = ("sss", "sss_final", "stuck_fraction", "rms_twist12", "std_twist12", "motor_torque_std",
                   "friction_work_pin2")

_TABLE = ("sss", "sss_window_mean", "sss_final", "stuck_fraction", "stuck_fraction_measured", "mean_omega1",
          "rms_twist12", "std_twist12", "motor_torque_std", "friction_work_pin2", "mean_n2", "mean_omega_ref",
          "plan_median_ms", "plan_p95_ms", "plan_max_ms", "solve_median_ms", "solve_p95_ms", "solve_max_ms",
          "controller_fallbacks", "controller_failures",
          "estimator_fallbacks", "estimator_dropouts")


def _fmt(v) -> str:
    if isinstance(v, (int,)) and not isinstance(v, bool):
        return str(v)
    v = float(v)
    return "-" if not math.isfinite(v) else f"{v:.4g}"


def _nmpc_section(sc, runs) -> list[str]:
    nm = [r for r in runs if r.kind == "nmpc"]
    lines = ["## Where the NMPC does not win, and why", ""]
    if not nm:
        return lines + ["This scenario lists no NMPC, so there is nothing to say about it here.", ""]
    period = sc.dt * sc.control_every
    for r in nm:
        beaten = []
        for k in LOWER_IS_BETTER:
            better = [o for o in runs if o is not r and o.success and
                      float(o.metrics[k]) < float(r.metrics[k]) * (1 - 0.05) - 1e-12]
            if better:
                b = min(better, key=lambda o: float(o.metrics[k]))
                beaten.append(f"`{k}` ({_fmt(r.metrics[k])} {METRIC_UNITS[k]} against "
                              f"{_fmt(b.metrics[k])} for {b.name})")
        if beaten:
            lines.append(f"**{r.name}** is beaten by more than 5 % on: " + "; ".join(beaten) + ".")
        else:
            lines.append(f"**{r.name}** is within 5 % of the best controller, or better, on every compared metric "
                         f"({', '.join(LOWER_IS_BETTER)}).")
        m = r.metrics
        facts = [f"its planning calls take {_fmt(m['plan_median_ms'])} ms (median) and {_fmt(m['plan_p95_ms'])} ms "
                 f"(p95), and any call at most {_fmt(m['solve_max_ms'])} ms, against a DAQ period of "
                 f"{1e3 * sc.dt:.3g} ms and a control period of {1e3 * period:.3g} ms"
                 + (" (the p95 EXCEEDS the DAQ period: on the rig it would not keep up)"
                    if m["solve_p95_ms"] > 1e3 * sc.dt else " (it keeps up)")]
        if m["controller_fallbacks"]:
            facts.append(f"it fell back {m['controller_fallbacks']} times out of {m['controller_steps']} steps "
                         f"({m['controller_failures']} outright failures)")
        if m["estimator_fallbacks"]:
            facts.append(f"its estimator fell back {m['estimator_fallbacks']} times")
        lines.append("Facts that bear on it: " + "; ".join(facts) + ".")
    est = sc.estimator.get("kind", "ekf")
    lines += ["",
              "Why a model-based controller can lose here: (1) it predicts with the regularised (tanh) friction "
              "model, while the plant has exact stick, so its prediction is poorest exactly around stick; "
              f"(2) it sees the `{est}` estimate built from quantised encoders (1 tick per 10 ms = 0.63 rad/s "
              "on R1), never the true twist"
              + (f", and the plant differs from its model ({', '.join(f'{k} x{v:g}' for k, v in sc.mismatch.items())})"
                 if sc.mismatch else "")
              + "; (3) N2 passes through a lagged, rate-limited servo; (4) the stick-slip here is a limit cycle "
              "coexisting with a linearly stable sliding state, so the cheap laws only have to push the rig "
              "once onto the sliding branch, which a speed raise or a one-sided brake does without any model. "
              "Which of these matters in this run is not separated by this report; the metrics above are "
              "what was measured.", ""]
    return lines


def render_report(sc, summary, files) -> str:
    """The markdown text (relative links to the files in the same folder)."""
    runs = summary.runs
    rel = {k: Path(v).name for k, v in files.items()}
    period = sc.dt * sc.control_every
    L = [f"# Scenario `{sc.name}`", "", sc.description or "", "",
         f"- scenario file: `{sc.path}`",
         f"- duration {sc.duration:g} s, DAQ period {1e3 * sc.dt:g} ms, controllers run every "
         f"{sc.control_every} sample(s) ({1e3 * period:g} ms), switched on at t = {sc.control_start:g} s "
         "(baseline PI before)",
         f"- plant: `{sc.sim.method}` stepping, start from {sc.sim.start}, "
         f"mismatch {dict(sc.mismatch) if sc.mismatch else 'none'}; sensors noise scale {sc.sensors.noise_scale:g}",
         f"- estimator: `{sc.estimator.get('kind', 'ekf')}` (controllers see only measurements and estimates)",
         f"- status: {summary.status}; wall time {summary.elapsed:.1f} s", "",
         "## Metrics (after the control start)", "",
         "All physical metrics come from the TRUE plant states and applied inputs (what the rig did): "
         "severity SSS = (max - min)/(2 mean) of the R1 speed, overall and over 5 s windows (`sss_final`: the "
         "last window, i.e. what is left after transients), fraction of time R1 is stuck (true speed, exactly 0 "
         "in stick; `stuck_fraction_measured` uses the quantised measured speed with a half-tick threshold of "
         "0.31 rad/s), RMS and std of the twist R1-R2, std of the motor torque eta KT i, and the friction work "
         "at pin 2 (sum of mu(|w2|) N2 r2 |w2| dt). Solve times are wall times of the controller calls.", ""]
    hdr = ["controller", "kind"] + [f"{k} [{METRIC_UNITS[k]}]" for k in _TABLE]
    L.append("| " + " | ".join(hdr) + " |")
    L.append("|" + "---|" * len(hdr))
    for r in runs:
        L.append("| " + " | ".join([r.name, r.kind] + [_fmt(r.metrics[k]) for k in _TABLE]) + " |")
    L += ["", f"Raw numbers: [metrics.csv]({rel['metrics_csv']}), [metrics.json]({rel['metrics_json']}).", "",
          "## Plots", "",
          f"![controllers compared]({rel['comparison_png']})", "",
          f"![phase portraits]({rel['phase_png']})", "",
          f"![metrics]({rel['metrics_png']})", ""]
    from mitigate.runner import slugs
    for s, r in zip(slugs([r.name for r in runs]), runs):
        L.append(f"- {r.name}: [time histories]({rel['timeseries_' + s]}), [CSV log]({rel['log_' + s]}) "
                 f"({r.status})")
    L.append("")
    if any(r.kind == "brake" for r in runs):
        L += ["## Tuning of the brake", "",
              "The brake gains of the scenario suite come from a grid search over gain_overspeed x gain_relative "
              "x filter_tau on `scenarios/stick_slip_30rpm.toml` (`python benchmarks/brake_tuning.py`, results in "
              "`benchmarks/results/brake_tuning.md`); the criterion is the overall severity after the control "
              "start, with the friction work at pin 2 as tie-breaker.", ""]
    L += _nmpc_section(sc, runs)
    return "\n".join(L) + "\n"


def write_report(sc, summary, files, path) -> Path:
    """Write ``report.md`` atomically (the caller has checked for existing outputs)."""
    return atomic_write_text(path, render_report(sc, summary, files), overwrite=True)
