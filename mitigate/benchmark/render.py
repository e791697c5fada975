"""The benchmark's report (``ranking.md``): like-for-like tables, per-scenario rankings with
intervals, and one verdict sentence per controller, generated from the measured numbers only."""

from __future__ import annotations

import math

from mitigate.benchmark.stats import Entry
from mitigate.metrics import Metric, ranked, shown

__all__ = ["render_ranking", "verdict", "job_words", "fmt", "CLASS_TITLES", "table_header", "table_value"]

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


def job_words(e: Entry) -> str:
    """The verdict on the job, the one wording the tables and the verdict sentences share:
    ``job done`` (every run kept the programme and finished) or ``job NOT done (k of n runs ...)``."""
    if not e.applicable:
        return "not applicable"
    if e.job_done:
        return "job done"
    why = []
    for n, what in ((e.n_failed, "failed"), (e.n_speed_violations, "left the speed band"),
                    (e.n_force_violations, "left the force band"), (e.n_stalled, "stalled")):
        if n:
            why.append(f"{n} {what}")
    return f"job NOT done ({e.n_bad} of {e.n_runs} runs: {', '.join(why) or 'no run'})"


def verdict(e: Entry, ref=None, programme_force: bool = False) -> str:
    """One sentence: whether the job was done (:func:`job_words`, as in the tables), what the rig sees
    and what truly stays, how fast, the hardware loads, the effort, where it left the programme.  The
    medians are over the runs that did the job."""
    if not e.applicable:
        return f"**{e.controller}**: not applicable ({e.messages[0] if e.messages else 'the rig lacks what it needs'})."
    cls = f" ({e.klass} class)" if e.klass else ""
    head = f"**{e.controller}**{cls}: {job_words(e)}"
    if e.n_failed == e.n_runs:
        return f"{head}; every run failed ({e.messages[0] if e.messages else 'no reason given'})."
    n_done = e.n_runs - e.n_bad
    if n_done == 0:
        return f"{head}; no run did the job, so no median."
    parts = [head]
    over = f" over the {n_done} run(s) that did the job" if e.n_bad else ""
    ms, fl = e.value("measured_severity"), e.value("speed_floor")
    rs = e.value("residual_severity")
    parts.append(f"the rig sees {fmt(ms, 100)} % of the programmed speed (floor {fmt(fl, 100)} %), {fmt(rs, 100)} % truly "
                 f"stays" + (f" (uncontrolled {fmt(ref.residual_severity, 100)} %)" if ref is not None else "") + over)
    tts = e.value("measured_time_to_suppress")
    if e.n_suppressed == 0:
        parts.append("but the stick-slip stays: never suppressed as far as the rig can tell")
    elif e.n_suppressed < n_done:
        parts.append(f"suppressed in {e.n_suppressed} of {n_done} runs (median {fmt(tts)} s after the switch-on)")
    else:
        parts.append(f"suppressed {fmt(tts)} s after the switch-on" + (" (median)" if n_done > 1 else ""))
    loads = [f"string torque peak {fmt(e.value('string_torque_peak'))} x steady"]
    if not math.isnan(e.value("drive_load_peak")):
        loads.append(f"drive load peak {fmt(e.value('drive_load_peak'), 100)} % of its limit")
    loads.append(f"set-point excursion {fmt(e.value('setpoint_excursion'), 100)} %")
    ov = e.value("peak_overshoot")
    if not math.isnan(ov):
        loads.append(f"overshoot added {fmt(ov, 100)} %")
    parts.append("hardware: " + ", ".join(loads))
    eff = [f"set-point variation {fmt(e.value('setpoint_variation'))} /s"]
    if not math.isnan(e.value("drive_energy")):
        eff.append(f"drive {fmt(e.value('drive_energy'))} J")
    if e.value("pin_work") > 0:
        eff.append(f"brake wear {fmt(e.value('pin_work'))} J")
    parts.append("effort: " + ", ".join(eff))
    fr = e.value("normal_force_ratio")
    if programme_force and not math.isnan(fr):
        parts.append(f"mean normal force {fmt(fr, 100)} % of the programme")
    cw = e.value("cutting_work_ratio")
    if programme_force and not math.isnan(cw) and abs(cw - 1) > 0.05:
        parts.append(f"cutting work {fmt(cw, 100)} % of what the programmed force would do")
    if e.n_failed:
        parts.append(f"failures: {e.messages[0] if e.messages else 'no reason given'}")
    fb = e.counts.get("controller_fallbacks", 0)
    if fb:
        parts.append(f"{fb} fallback(s)")
    return "; ".join(parts) + "."


def _class_table(rows) -> list[str]:
    cols = shown("ranking")
    hdr = ["controller", "class", "mean rank", "first", "job done"] + [table_header(m) for m in cols] + \
        ["runs", "failed", "left force band", "left speed band", "stalled", "fallbacks"]
    L = ["| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
    for r in rows:
        L.append("| " + " | ".join([r["controller"], r["class"] or "-", f"{r['mean_rank']:.2f}",
                                    f"{r['first']}/{r['scenarios']}", f"{r['job_done']}/{r['scenarios']}"]
                                   + [table_value(m, r[m.name]) for m in cols]
                                   + [str(r["n_runs"]), str(r["failed"]), str(r["force_violations"]),
                                      str(r["speed_violations"]), str(r["stalled"]), str(r["fallbacks"])])
                 + " |")
    return L


def how_to_read() -> str:
    """The paragraph that says how the benchmark ranks (the report's and the leaderboard's)."""
    return ("How to read it. Every number is the median over the runs of a controller on a scenario that DID THE JOB "
            "(its switch-on phases spread over one stick-slip period of the uncontrolled run, and its noise seeds), "
            "with a 95 % bootstrap interval in brackets. A run did the job when it finished and kept the programme: "
            "the objective body's mean speed and every programmed normal force inside the suite's bands over the "
            "last stick-slip periods AND over every one-period moving window (from one period after the switch-on), "
            "and the body not stuck for more than the suite's stuck limit of the last periods; any other run is a "
            "failed run, counted and never a median entry. An entry did the job when every run did. The ranked "
            "columns, in order: "
            + " ".join(f"*{m.header or m.name}* ({m.name}, {m.better} is better): {m.description}." for m in ranked())
            + " A rank is one plus the number of controllers clearly better: one that did the job beats one that "
            "did not (two that did not: fewer failed runs); otherwise, in the order above, at the first ranked "
            "column whose intervals do not overlap, the one whose interval lies entirely on the better side. "
            "Overlapping intervals share a rank, and so do entries that beat each other round a cycle (A before B "
            "before C before A, each on another column); an entry with a failed run is never counted first. The true "
            "speed's residual (*true what stays*), the overshoot the controller added, the drive energy and the "
            "brake wear are shown beside the ranks, never folded into them. Wall-clock call times are this "
            "machine's and are reported apart.")


def _timing_table(res) -> list[str]:
    """This machine's call times per controller (medians over scenarios of each entry's median), apart."""
    from mitigate.benchmark.stats import timing_metrics
    keys = [k for k in timing_metrics() if k.startswith("plan_")]
    names = [c.name for c in res.suite.controllers]
    L = ["| controller | " + " | ".join(f"{k} [ms]" for k in keys) + " | deadline misses |",
         "|" + "---|" * (len(keys) + 2)]
    for n in names:
        es = [e for (s, c), e in res.entries.items() if c == n and e.applicable]
        vals = []
        for k in keys:
            v = [e.timings.get(k, math.nan) for e in es]
            v = [x for x in v if not math.isnan(x)]
            vals.append(fmt(sorted(v)[len(v) // 2]) if v else "-")
        misses = sum(int(r.timings.get("controller_deadline_misses", 0) or 0) for r in res.records
                     if r.run.controller == n)
        L.append(f"| {n} | " + " | ".join(vals) + f" | {misses} |")
    return L


def render_ranking(res, command: str = "") -> str:
    """The markdown report of a :class:`mitigate.benchmark.BenchmarkResult`."""
    su = res.suite
    title = f"{su.name} v{su.version}" if su.version else su.name
    L = [f"# Benchmark `{title}` ({res.mode})", "", su.description, ""]
    if command:
        L += ["Made with:", "", "```bash", command, "```", ""]
    L += [f"{len(su.scenarios)} scenarios x {len(su.controllers)} controllers x {res.phases} switch-on phase(s) x "
          f"{res.seeds} noise seed(s) = {len(res.records)} runs ({res.computed} computed now); wall time "
          f"{res.elapsed:.0f} s; status: {res.status.value} ({res.message}).", "",
          f"Compute model: {su.compute_text}. Metrics version {res.metrics_version}."
          + (f" Timing scenarios (each answer applied after its own measured computation time, or a wall-clock "
             f"deadline: their numbers depend on this machine, and they are left out of the class tables): "
             f"{', '.join(su.timing)}." if su.timing else ""), "", how_to_read(), ""]
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
        timing = " (a TIMING scenario: its numbers depend on this machine; not in the class tables)" \
            if sc.name in su.timing else ""
        L += [f"## Scenario `{sc.name}`{timing}", "", sc.description, "",
              "| rank | controller | class | did the job | " + " | ".join(table_header(m) for m in cols)
              + " | left force band | left speed band | stalled |", "|" + "---|" * (len(cols) + 7)]
        for e in es:
            if not e.applicable:
                L.append(f"| - | {e.controller} | - | n/a |" + " |" * (len(cols) + 3))
                continue
            L.append(f"| {e.rank} | {e.controller} | {e.klass} | {e.n_runs - e.n_bad}/{e.n_runs} | "
                     + " | ".join(_ci(e, m) for m in cols)
                     + f" | {e.n_force_violations} | {e.n_speed_violations} | {e.n_stalled} |")
        L.append("")
        L += [f"- {verdict(e, ref, prog_force)}" for e in es]
        L.append("")
    L += ["## Computation time on this machine (not ranked)", "",
          "Median over scenarios of each entry's median call time, and the deadline misses of the timing "
          "scenarios: wall-clock numbers of the machine that ran this, which the compute model keeps out of every "
          "ranked result.", ""] + _timing_table(res) + [""]
    if res.tuned:
        L += ["## Tuned values", "", "Each controller tuned on this scenario with the same budget (`mitigate tune`: "
              f"{res.tuning.get('budget', '?')} trials, {res.tuning.get('sampler', '')}), on switch-on phases and "
              "noise seeds the benchmark does not use, scored in the ranking's order:", "",
              "| scenario | controller | options |", "|---|---|---|"]
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
