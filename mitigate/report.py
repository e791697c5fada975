"""``report.md`` of a scenario run: the table, the plots, and what the numbers say.

The text is generated from the measured metrics only.  For each model-based controller (the
NMPC) it lists, metric by metric, every controller that did better, and the facts that bear on
why (solve time against the control period, fallbacks, the estimator and its observability,
the plant's mismatch and structure).
"""

from __future__ import annotations

import math
from pathlib import Path

from models.files import atomic_write_text
from mitigate.metrics import METRIC_UNITS

__all__ = ["write_report", "render_report", "LOWER_IS_BETTER"]

#: metrics where lower is better, compared in the NMPC section
LOWER_IS_BETTER = ("residual_severity", "time_to_suppress", "peak_overshoot", "stuck_fraction", "speed_error_rms",
                   "setpoint_variation", "pin_work")

_TABLE = ("residual_severity", "time_to_suppress", "peak_overshoot", "speed_ratio", "stuck_fraction",
          "setpoint_variation", "pin_work", "normal_force_ratio", "drive_energy", "sss", "sss_final",
          "stuck_fraction_measured", "rms_twist", "plan_median_ms", "plan_p95_ms", "solve_max_ms",
          "controller_fallbacks", "controller_failures", "estimator_fallbacks", "estimator_dropouts")


def _fmt(v) -> str:
    if isinstance(v, (int,)) and not isinstance(v, bool):
        return str(v)
    v = float(v)
    return "-" if math.isnan(v) else ("inf" if math.isinf(v) else f"{v:.4g}")


def _model_section(sc, runs) -> list[str]:
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
                    if m["plan_p95_ms"] > 1e3 * sc.dt else " (it keeps up)")]
        if m["controller_fallbacks"]:
            facts.append(f"it fell back {m['controller_fallbacks']} times out of {m['controller_steps']} steps "
                         f"({m['controller_failures']} outright failures)")
        if m["estimator_fallbacks"]:
            facts.append(f"its estimator fell back {m['estimator_fallbacks']} times")
        lines.append("Facts that bear on it: " + "; ".join(facts) + ".")
    est = sc.estimator.get("kind", "ekf")
    diff = []
    if sc.mismatch:
        diff.append("parameters " + ", ".join(f"{k} x{v:g}" for k, v in sc.mismatch.items()))
    if sc.structure:
        diff.append("structure " + ", ".join(sorted(sc.structure)))
    why = ["it predicts with the regularised (tanh) friction model, while the plant has exact stick, so its "
           "prediction is poorest exactly around stick",
           f"it sees the `{est}` estimate built from the rig's sensors, never the true state"]
    if diff:
        why.append(f"the plant differs from its model ({'; '.join(diff)})")
    if sc.model.servo_inputs:
        why.append("a servo's force passes through a lagged, rate-limited actuator")
    why.append("where stick-slip is a limit cycle beside a stable sliding state, a cheap law only has to push the "
               "rig once onto the sliding branch")
    lines += ["", "Why a model-based controller can lose here: "
              + "; ".join(f"({i}) {w}" for i, w in enumerate(why, start=1))
              + ". Which of these matters in this run is not separated by this report; the metrics above are "
              "what was measured.", ""]
    return lines


def _verdicts(sc, runs) -> list[str]:
    """One sentence per controller (:func:`mitigate.benchmark.render.verdict` on a single run)."""
    from mitigate.benchmark.stats import summarise
    from mitigate.benchmark.render import verdict
    recs = [{"scenario": sc.name, "controller": r.name, "applicable": True, "failed": int(not r.success),
             "class": "", "message": r.message, "metrics": r.metrics} for r in runs]
    entries = summarise(recs, {r.name: r.kind for r in runs})
    prog_force = any(sc.inputs[n](sc.control_start) > 0 for n in sc.model.servo_inputs)
    return ["## Verdicts", ""] + [f"- {verdict(entries[(sc.name, r.name)], None, prog_force)}" for r in runs] + [""]


def render_report(sc, result, files, slug_names) -> str:
    """The markdown text (relative links to the files in the same folder)."""
    runs = result.runs
    rel = {k: Path(v).name for k, v in files.items()}
    period = sc.dt * sc.control_every
    body = sc.model.objective_body
    L = [f"# Scenario `{sc.name}`", "", sc.description or "", "",
         f"- rig: `{sc.model.name}` ({sc.model.description}); scenario file: `{sc.path or '(built in Python)'}`",
         f"- duration {sc.duration:g} s, DAQ period {1e3 * sc.dt:g} ms, controllers run every "
         f"{sc.control_every} sample(s) ({1e3 * period:g} ms), switched on at t = {sc.control_start:g} s "
         "(the programme alone before)",
         f"- plant: `{sc.sim.method}` stepping ({sc.sim.nsub} substeps), start from {sc.sim.start}; "
         f"parameter mismatch {dict(sc.mismatch) if sc.mismatch else 'none'}; structure "
         f"{dict(sc.structure) if sc.structure else 'as the model'}; sensor noise x{sc.sensors.noise_scale:g}",
         f"- estimator: `{sc.estimator.get('kind', 'ekf')}` (controllers see only measurements and estimates)"]
    obs = next((r.result.observability for r in runs if getattr(r.result, "observability", None) is not None), None)
    if obs is not None:
        L.append(f"- observability of the estimator's model: {getattr(obs, 'message', obs)}")
    for note in sc.messages:
        L.append(f"- note: {note}")
    L += [f"- status: {result.status.value}" + (f" ({result.message})" if result.message != "ok" else "")
          + f"; wall time {result.elapsed:.1f} s", "",
          "## Metrics (after the control start)", "",
          f"All physical metrics come from the TRUE plant states and applied inputs (what the rig did), for "
          f"`{body}`, the body whose stick-slip is suppressed (`mitigate/metrics.py`): `residual_severity`, what "
          "stays, (max - min) / (2 x programmed speed) over the last few stick-slip periods; `time_to_suppress` "
          "from the switch-on until the moving severity stays below 0.1 (inf: never); `peak_overshoot` above "
          "the programmed speed; `speed_ratio`, the mean speed over the programmed one; the fraction of time "
          "stuck; `setpoint_variation`, the total variation of the commanded inputs per second, each scaled by "
          "its programme; `pin_work`, the wear a brake's normal force causes at its pin; `normal_force_ratio`, "
          "the mean applied normal force over its programme; the drive's electrical energy; and the "
          "literature's SSS = (max - min)/(2 mean) after the switch-on (`sss`, `sss_final` over the last "
          "window). Solve times are wall times of the controller calls.", ""]
    hdr = ["controller", "kind", "status"] + [f"{k} [{METRIC_UNITS[k]}]" for k in _TABLE]
    L.append("| " + " | ".join(hdr) + " |")
    L.append("|" + "---|" * len(hdr))
    for r in runs:
        L.append("| " + " | ".join([r.name, r.kind, r.status.value] + [_fmt(r.metrics[k]) for k in _TABLE]) + " |")
    L += ["", f"Raw numbers: [metrics.csv]({rel['metrics_csv']}), [metrics.json]({rel['metrics_json']}).", "",
          "## Plots", "",
          f"![controllers compared]({rel['comparison_png']})", "",
          f"![phase portraits]({rel['phase_png']})", "",
          f"![metrics]({rel['metrics_png']})", ""]
    for s, r in zip(slug_names, runs):
        if r.result is None:       # failed before its first sample: nothing to plot or log
            L.append(f"- {r.name}: **{r.status.value}**: {r.message}")
            continue
        L.append(f"- {r.name}: [time histories]({rel['timeseries_' + s]}), [CSV log]({rel['log_' + s]}) "
                 f"({r.status.value}{': ' + r.message if r.message != 'ok' else ''})")
    L.append("")
    if any(r.kind == "brake" for r in runs):
        L += ["## Tuning of the brake", "",
              "The brake gains of the scenario suite come from a grid search on `scenarios/stick_slip_30rpm.toml` "
              "(`python benchmarks/brake_tuning.py`, results in `benchmarks/results/brake_tuning.md`).", ""]
    L += _verdicts(sc, runs)
    L += _model_section(sc, runs)
    return "\n".join(L) + "\n"


def write_report(sc, result, files, slug_names, path) -> Path:
    """Write ``report.md`` atomically (the caller has checked for existing outputs)."""
    return atomic_write_text(path, render_report(sc, result, files, slug_names), overwrite=True)
