"""``report.md`` of a scenario run: the table, the plots, and what the numbers say.

The text is generated from the measured metrics only: one verdict per controller (what stays,
how fast, at what effort, whether the job was done, failures and fallbacks:
:func:`mitigate.benchmark.render.verdict` on the single run; the drive's peak against the rig's
limit, and whether the run exceeded it: :func:`drive_limit_note`), the tuning values each controller
runs with (:attr:`mitigate.runner.ControllerRun.tuning`: SoftSpeed's Z, J_v, Kp, Ki, f_t, ...),
and the wall time of its calls against the DAQ period.  The summary table (:func:`summary_rows`,
also the terminal table of ``mitigate run``) keeps what a reader ranks by; every other metric is
in ``metrics.csv`` and ``metrics.json``.
"""

from __future__ import annotations

import math
from pathlib import Path

from models.files import atomic_write_text

__all__ = ["write_report", "render_report", "summary_rows", "verdict_entries", "drive_limit_note"]


def _fmt(v, metric=None) -> str:
    """A number for the report: 4 significant digits, ``-`` for NaN, an infinite value as its metric
    reads it (``never`` for the time to suppress)."""
    if isinstance(v, (int,)) and not isinstance(v, bool):
        return str(v)
    v = float(v)
    if math.isnan(v):
        return "-"
    if math.isinf(v):
        return metric.inf if metric is not None and v > 0 else ("inf" if v > 0 else "-inf")
    return f"{v:.4g}"


def verdict_entries(sc, runs) -> dict:
    """``{controller name: Entry}`` (:func:`mitigate.benchmark.stats.summarise` of each single run)."""
    from mitigate.benchmark.stats import summarise
    from mitigate.record import BenchmarkRun, RunRecord
    recs = [RunRecord.measured(BenchmarkRun(r.name, sc.name, r.name, 0, 0, sc.control.start, sc.seed), r.status,
                               r.message, r.metrics, elapsed=r.elapsed) for r in runs]
    return {c: e for (_s, c), e in summarise(recs, {r.name: r.kind for r in runs}).items()}


def job_done(entry) -> bool:
    """The verdict's "job done", as the benchmark's (:func:`mitigate.benchmark.render.job_words`): the run
    finished and kept the programme (its speed and normal-force bands, not stalled); whether the
    stick-slip was suppressed is the verdict's next statement."""
    return bool(entry.job_done)


def summary_rows(sc, runs) -> tuple[list[str], list[list[str]]]:
    """The summary table (header, rows of strings): controller, kind, status, the metrics the registry
    shows in the ``"report"`` (:func:`mitigate.metrics.shown`), fallbacks (controller / estimator) and
    job done."""
    from mitigate.metrics import shown
    entries = verdict_entries(sc, runs)
    cols = shown("report")
    hdr = ["controller", "kind", "status"] + [m.label for m in cols] + ["fallbacks (ctrl/est)", "job done"]
    rows = []
    for r in runs:
        fb = "/".join(_fmt(r.metrics.get(k, math.nan)) for k in ("controller_fallbacks", "estimator_fallbacks"))
        rows.append([r.name, r.kind, r.status.value]
                    + [_fmt(r.metrics.get(m.name, math.nan), m) for m in cols]
                    + [fb, "yes" if r.success and job_done(entries[r.name]) else "no"])
    return hdr, rows


def _tuning_line(r) -> str:
    if not r.tuning:
        return ""
    return "; ".join(f"{k} = {_fmt(v)}" + (f" {r.tuning_units[k]}" if r.tuning_units.get(k) else "")
                     for k, v in r.tuning.items())


def drive_limit_note(sc, metrics) -> str:
    """The verdict's line on the drive's limit (``drive_load_peak``): the peak of what the rig limits
    against that limit, and whether the run EXCEEDED it or ran at it; "" when the rig declares none."""
    drive = sc.plant_model.drive
    lim = drive.limit(sc.plant_params.as_dict())
    ratio = float(metrics.get("drive_load_peak", math.nan))
    if lim is None or not math.isfinite(ratio):
        return ""
    name, value = lim
    unit = drive.signal_units().get(name, "")
    peak = f"peak |{name}| {_fmt(ratio * value)} {unit}"
    if ratio > 1 + 1e-9:
        return f"Drive: the run EXCEEDED its drive's limit: {peak}, {ratio:.3g} x the rig's limit of {_fmt(value)} {unit}."
    if ratio >= 1 - 1e-3:
        return f"Drive: at its limit: {peak} (the rig's limit {_fmt(value)} {unit})."
    return f"Drive: {peak}, {100 * ratio:.3g} % of the rig's limit of {_fmt(value)} {unit}."


def _verdicts(sc, runs) -> list[str]:
    """One sentence per controller, and under it the tuning values it ran with and, when the rig limits
    its drive, the peak against that limit (:func:`drive_limit_note`)."""
    from mitigate.benchmark.render import verdict
    entries = verdict_entries(sc, runs)
    prog_force = any(sc.inputs[n](sc.control.start) > 0 for n in sc.model.servo_inputs)
    L = ["## Verdicts", ""]
    for r in runs:
        L.append(f"- {verdict(entries[r.name], None, prog_force)}")
        if r.tuning:
            L.append(f"  Tuning it ran with: {_tuning_line(r)}.")
        note = drive_limit_note(sc, r.metrics) if r.metrics else ""
        if note:
            L.append(f"  {note}")
    return L + [""]


def _timing(sc, runs) -> list[str]:
    """Wall time of each controller's calls against the DAQ period (measured numbers only)."""
    rows = [r for r in runs if math.isfinite(float(r.metrics.get("plan_p95_ms", math.nan)))]
    if not rows:
        return []
    period = 1e3 * sc.dt * sc.control.every
    L = ["## Time per controller call", "",
         f"Wall time of the controller's calls in this run (median / p95 / max), against its control period of "
         f"{period:.3g} ms (a call every {sc.control.every} DAQ sample(s)); a p95 above it would not keep up on "
         "the rig.", ""]
    for r in rows:
        m = r.metrics
        late = float(m["plan_p95_ms"]) > period
        L.append(f"- {r.name}: {_fmt(m['plan_median_ms'])} / {_fmt(m['plan_p95_ms'])} / {_fmt(m['solve_max_ms'])} ms"
                 + (" (the p95 EXCEEDS the control period)" if late else ""))
    return L + [""]


def render_report(sc, result, files, slug_names) -> str:
    """The markdown text (relative links to the files in the same folder)."""
    runs = result.runs
    rel = {k: Path(v).name for k, v in files.items()}
    period = sc.dt * sc.control.every
    body = sc.model.objective_body
    L = [f"# Scenario `{sc.name}`", "", sc.description or "", "",
         f"- rig: `{sc.model.name}`" + (f" ({sc.model.description})" if sc.model.description else "")
         + f"; scenario file: `{sc.path or '(built in Python)'}`",
         f"- duration {sc.duration:g} s, DAQ period {1e3 * sc.dt:g} ms, controllers run every "
         f"{sc.control.every} sample(s) ({1e3 * period:g} ms), switched on at t = {sc.control.start:g} s "
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
          f"*Rig sees*: `measured_severity`, (max - min) / (2 x programmed speed) of `{body}`'s MEASURED speed "
          "(its encoder's counts per DAQ sample) over the last few stick-slip periods, never below the sensor's "
          "resolution floor (at the floor: suppressed as far as the rig can tell); *t suppress*: from the switch-on "
          "until that moving severity stays at or below the threshold or the floor (never: it did not). Every "
          "other physical metric comes from the TRUE plant states and applied inputs (what the rig did, "
          "`mitigate/metrics/`): *true what stays*: `residual_severity`, the same of the true speed; "
          "*set-point var.*: the total variation "
          "of the commanded inputs per second, each scaled by its programme (the effort); *brake wear*: the "
          "friction work a brake's normal force causes at its pin; *fallbacks*: the controller's and the estimator's calls "
          "answered by their fallback; *job done*: the run finished inside the programme's speed and normal-force "
          "bands (over the last periods and every one-period window) and did not stall. The other metrics (SSS, "
          "stuck fraction, the hardware loads, speed error, drive energy, "
          "call times, ...) are in the CSV and JSON files.", ""]
    hdr, rows = summary_rows(sc, runs)
    L.append("| " + " | ".join(hdr) + " |")
    L.append("|" + "---|" * len(hdr))
    for row in rows:
        L.append("| " + " | ".join(row) + " |")
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
    L += _verdicts(sc, runs)
    L += _timing(sc, runs)
    return "\n".join(L) + "\n"


def write_report(sc, result, files, slug_names, path) -> Path:
    """Write ``report.md`` atomically (the caller has checked for existing outputs)."""
    return atomic_write_text(path, render_report(sc, result, files, slug_names), overwrite=True)
