"""The benchmark's report (``ranking.md``): like-for-like tables, per-scenario rankings with
intervals, and one verdict sentence per controller, generated from the measured numbers only."""

from __future__ import annotations

import math

from mitigate.benchmark.stats import Entry
from mitigate.metrics import Metric, ranked, shown

__all__ = ["render_ranking", "verdict", "fmt", "CLASS_TITLES", "table_header", "table_value"]

CLASS_TITLES = {
    "overall": "Overall (every controller, whatever it actuates)",
    "drive": "Drive set-point only (like for like: SoftSpeed, Z-Torque, the motor-only NMPC)",
    "force": "Normal force only (like for like: the brake, D-OSKIL, the pin-only NMPC)",
    "both": "Drive and normal force",
}


def table_header(m: Metric) -> str:
    """A metric's column header in the benchmark's tables: ``header [unit]`` (``[%]`` for a percentage)."""
    return f"{m.header or m.name} [{'%' if m.percent else m.unit}]"


def table_value(m: Metric, v) -> str:
    """A metric's value as the benchmark's tables show it (:func:`fmt`, x 100 for a percentage)."""
    return fmt(v, 100 if m.percent else 1)


def fmt(v, scale: float = 1.0) -> str:
    """A number for a table: 3 significant digits, ``-`` for NaN, ``never`` for inf."""
    if isinstance(v, str):
        return v
    v = float(v)
    if math.isnan(v):
        return "-"
    if math.isinf(v):
        return "never"
    return f"{v * scale:.3g}"


def _ci(e: Entry, metric: Metric) -> str:
    m = e.metrics.get(metric.name)
    if not m or math.isnan(m["median"]):
        return "-"
    if m["ci_low"] == m["ci_high"]:
        return table_value(metric, m["median"])
    return (f"{table_value(metric, m['median'])} [{table_value(metric, m['ci_low'])}, "
            f"{table_value(metric, m['ci_high'])}]")


def verdict(e: Entry, ref=None, programme_force: bool = False) -> str:
    """One sentence: what stays, how fast, at what effort, whether the job was done, where it left
    the programme's band."""
    if not e.applicable:
        return f"**{e.controller}**: not applicable ({e.messages[0] if e.messages else 'the rig lacks what it needs'})."
    if e.n_failed == e.n_runs:
        return f"**{e.controller}**: every run failed ({e.messages[0] if e.messages else 'no reason given'})."
    rs = e.value("residual_severity")
    cls = f" ({e.klass} class)" if e.klass else ""
    parts = [f"**{e.controller}**{cls}: what stays is {fmt(rs, 100)} % of the programmed "
             f"speed" + (f" (uncontrolled {fmt(ref.residual_severity, 100)} %)" if ref is not None else "")]
    n_ok = e.n_runs - e.n_failed
    tts = e.value("time_to_suppress")
    if e.n_suppressed == 0:
        parts.append("never suppressed")
    elif e.n_suppressed < n_ok:
        parts.append(f"suppressed in {e.n_suppressed} of {n_ok} runs (median {fmt(tts)} s after the switch-on)")
    else:
        parts.append(f"suppressed {fmt(tts)} s after the switch-on" + (" (median)" if n_ok > 1 else ""))
    ov = e.value("peak_overshoot")
    if not math.isnan(ov):
        parts.append(f"overshoot {fmt(ov, 100)} %")
    eff = [f"set-point variation {fmt(e.value('setpoint_variation'))} /s"]
    if not math.isnan(e.value("drive_energy")):
        eff.append(f"drive {fmt(e.value('drive_energy'))} J")
    if e.value("pin_work") > 0:
        eff.append(f"brake wear {fmt(e.value('pin_work'))} J")
    parts.append("effort: " + ", ".join(eff))
    fr = e.value("normal_force_ratio")
    if e.n_force_violations:
        parts.append(f"LEFT the programme's normal-force band in {e.n_force_violations} of {n_ok} runs (mean force "
                     f"{fmt(fr, 100)} % of the programme)")
    elif programme_force and not math.isnan(fr):
        parts.append(f"normal force kept ({fmt(fr, 100)} % of the programme)")
    cw = e.value("cutting_work_ratio")
    if programme_force and not math.isnan(cw) and abs(cw - 1) > 0.05:
        parts.append(f"cutting work {fmt(cw, 100)} % of what the programmed force would do")
    rsr = e.value("residual_speed_ratio")
    if e.n_speed_violations:
        parts.append(f"LEFT the programme's speed band in {e.n_speed_violations} of {n_ok} runs (mean speed "
                     f"{fmt(rsr, 100)} % of the programme at the end)")
    if e.n_failed:
        parts.append(f"{e.n_failed} of {e.n_runs} runs FAILED ({e.messages[0] if e.messages else ''})")
    fb = e.counts.get("controller_fallbacks", 0)
    if fb:
        parts.append(f"{fb} fallback(s)")
    if e.job_done and e.n_suppressed == 0:
        parts.append("within the programme's bands, but the stick-slip stays: job NOT done")
    else:
        parts.append("job done" if e.job_done else "job NOT done")
    return "; ".join(parts) + "."


def _class_table(rows) -> list[str]:
    cols = shown("ranking")
    hdr = ["controller", "class", "mean rank", "first", "job done"] + [table_header(m) for m in cols] + \
        ["runs", "failed", "left force band", "left speed band", "fallbacks"]
    L = ["| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
    for r in rows:
        L.append("| " + " | ".join([r["controller"], r["class"] or "-", f"{r['mean_rank']:.2f}",
                                    f"{r['first']}/{r['scenarios']}", f"{r['job_done']}/{r['scenarios']}"]
                                   + [table_value(m, r[m.name]) for m in cols]
                                   + [str(r["n_runs"]), str(r["failed"]), str(r["force_violations"]),
                                      str(r["speed_violations"]), str(r["fallbacks"])])
                 + " |")
    return L


def render_ranking(res, command: str = "") -> str:
    """The markdown report of a :class:`mitigate.benchmark.BenchmarkResult`."""
    su = res.suite
    L = [f"# Benchmark `{su.name}` ({res.mode})", "", su.description, ""]
    if command:
        L += ["Made with:", "", "```bash", command, "```", ""]
    L += [f"{len(su.scenarios)} scenarios x {len(su.controllers)} controllers x {res.phases} switch-on phase(s) x "
          f"{res.seeds} noise seed(s) = {len(res.records)} runs ({res.computed} computed now); wall time "
          f"{res.elapsed:.0f} s; status: {res.status.value} ({res.message}).", "",
          "How to read it. Every number is the median over a controller's runs on a scenario (its switch-on "
          "phases spread over one stick-slip period of the uncontrolled run, and its noise seeds), with a 95 % "
          "bootstrap interval in brackets. "
          + " ".join(f"*{m.header or m.name}* ({m.name}): {m.description}." for m in ranked()) +
          " A rank is one plus the number of controllers clearly better: a controller that did the job (kept the "
          "programme, did not fail) beats one that did not; otherwise, in this order, "
          + ", then ".join(f"*{m.header or m.name}* ({m.better} is better)" for m in ranked()) +
          ": at the first whose intervals do not overlap, the one whose interval lies entirely on the better side. "
          "The programme is the speed and the normal forces: a run whose mean speed over the last periods, or "
          "mean applied normal force, leaves the suite's band around it has not drilled as programmed. "
          "Overlapping intervals share a rank. Every other column (effort: set-point variation per second, "
          "drive energy, brake wear) is shown beside the ranks, never folded into them.", ""]
    L += ["## The uncontrolled runs", "",
          "| scenario | kind | stick-slip period [s] | stick-slip at switch-on | severity before [%] | "
          "what stays uncontrolled [%] |", "|---|---|---|---|---|---|"]
    for sc in su.scenarios:
        r = res.references[sc.name]
        L.append(f"| {sc.name} | {'prevention (from t = 0)' if r.prevention else 'suppression'} | "
                 f"{r.period:.3g} ({r.period_source}) | {'-' if r.prevention else ('yes' if r.stick_slip else 'NO')} | "
                 f"{fmt(r.severity_before, 100)} | {fmt(r.residual_severity, 100)} |")
    L.append("")
    for klass in ("drive", "force", "both", "overall"):
        rows = res.tables.get(klass)
        if not rows:
            continue
        L += [f"## {CLASS_TITLES[klass]}", "",
              "Mean rank over the scenarios (ranked among this table's controllers and the programme alone), "
              "scenarios ranked first (ties included), scenarios where the job was done, then the median over "
              "scenarios of each controller's medians.", ""] + _class_table(rows) + [""]
    names = [c.name for c in su.controllers]
    cols = shown("scenario")
    for sc in su.scenarios:
        ref = res.references[sc.name]
        es = sorted((res.entries[(sc.name, n)] for n in names), key=lambda e: (e.rank or 10**6, e.controller))
        prog_force = any(sc.model.contact_of_input(n) is not None and sc.inputs[n](sc.control.start) > 0
                         for n in sc.model.servo_inputs)
        L += [f"## Scenario `{sc.name}`", "", sc.description, "",
              "| rank | controller | class | runs | " + " | ".join(table_header(m) for m in cols)
              + " | left force band | left speed band |", "|" + "---|" * (len(cols) + 6)]
        for e in es:
            if not e.applicable:
                L.append(f"| - | {e.controller} | - | 0 | n/a |" + " |" * (len(cols) + 1))
                continue
            L.append(f"| {e.rank} | {e.controller} | {e.klass} | {e.n_runs - e.n_failed}/{e.n_runs} | "
                     + " | ".join(_ci(e, m) for m in cols)
                     + f" | {e.n_force_violations} | {e.n_speed_violations} |")
        L.append("")
        L += [f"- {verdict(e, ref, prog_force)}" for e in es]
        L.append("")
    if res.tuned:
        L += ["## Tuned values", "", "Each controller tuned on this scenario with the same budget (`mitigate tune`), "
              "on tuning seeds the benchmark does not use:", "", "| scenario | controller | options |", "|---|---|---|"]
        for (s, c), o in res.tuned.items():
            L.append(f"| {s} | {c} | {', '.join(f'{k} = {v}' for k, v in sorted(_flat(o).items()))} |")
        L.append("")
    return "\n".join(L) + "\n"


def _flat(o, prefix: str = "") -> dict:
    out = {}
    for k, v in o.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = f"{v:.4g}" if isinstance(v, float) else v
    return out
