"""The leaderboard: every submitted entry of a frozen suite, ranked like for like, as Markdown and HTML.

``mitigate benchmark leaderboard DIR`` reads every entry (``results.json`` or ``results.json.gz``, each
checked against the results' schema) under ``DIR`` and the reference entries
(``benchmarks/results/reference/`` by default), keeps those comparable with each other -- the same
suite name and version, metrics version and compute model -- and ranks every controller of every entry
per actuator class, scenario by scenario, with the benchmark's own order and intervals
(:mod:`mitigate.benchmark.stats`, recomputed from each entry's per-run records).  Every row says where it
comes from (the entry's folder), whether its controller ran with its defaults or tuned (and the tuning
budget), its runs per scenario and the compute model.  :data:`RULES` are written beside the tables.
"""

from __future__ import annotations

import copy
import html
import math
from dataclasses import dataclass, field
from pathlib import Path

from models.errors import ConfigError, DataError

__all__ = ["Submission", "collect", "build", "render_markdown", "render_html", "write_leaderboard", "RULES",
           "LEADERBOARD_FILES"]

LEADERBOARD_FILES = {"markdown": "leaderboard.md", "html": "leaderboard.html"}

#: the rules of a submission (docs/benchmark.md has them too)
RULES = (
    "What a controller may know: the NOMINAL model and its parameters (the rig file's stated values, never "
    "the plant's: mismatch, structure and drift stay in the plant), the scenario's programme, and the DAQ's "
    "channels as the rig file declares its sensors (quantised encoders, noisy load cells, delays), through "
    "the one `Controller.step(t, measurement, estimate)` call; nothing of the simulated truth.",
    "It declares the inputs it sets (`Controller.actuated_inputs()`); its class follows them, and a run that "
    "commands an undeclared input fails.",
    "The compute model is the suite's: every answer is applied one control period after its sample (no "
    "wall-clock deadline), so entries made on different machines compare; the latency scenario (measured "
    "computation time) is reported apart and never ranked.",
    "Tuning: an entry with the shipped options is a *defaults* entry. A *tuned* entry states its budget; the "
    "reference tunes every controller with the same budget of Optuna trials (at least 50) on switch-on phases "
    "and noise seeds the suite never scores (`mitigate benchmark SUITE --tuned --budget N`), scored in the "
    "ranking's order. Tuning on the scored phases or seeds, or on the generated set, is not allowed.",
    "Entries compare only within one suite version, metrics version and compute model, each made from a suite "
    "whose files, rigs and metric code are as its lock says (`suite.lock.json`; an entry from a changed suite is "
    "listed apart, as not frozen).",
    "An entry is the unedited `results.json` of `mitigate benchmark SUITE --controller module:Class --alone`; "
    "it holds every run's record, the commit and the package versions that made it.",
)


@dataclass
class Submission:
    """One controller of one entry: its per-scenario :class:`mitigate.benchmark.stats.Entry` objects."""

    label: str
    controller: str
    source: str
    mode: str
    budget: int | None
    klass: str
    runs_per_scenario: int
    entries: dict = field(default_factory=dict)      # scenario -> Entry


def _entries_from(doc: dict, source: str) -> list[Submission]:
    from mitigate.benchmark.stats import summarise
    from mitigate.record import RunRecord
    timings = doc["timing"].get("timings", {})
    recs = [RunRecord.from_json({**r, "timings": timings.get(r["run"]["key"], {})}, f"{source}: records[{i}]")
            for i, r in enumerate(doc["records"])]
    kinds = {c["name"]: c["kind"] for c in doc["controllers"]}
    per = summarise(recs, kinds)
    budget = (doc.get("tuning") or {}).get("budget")
    out = []
    for c in doc["controllers"]:
        es = {s: e for (s, name), e in per.items() if name == c["name"]}
        if not es:
            continue
        klass = next((e.klass for e in es.values() if e.klass), c.get("class", ""))
        mode = doc["mode"] + (f" ({budget} trials)" if doc["mode"] == "tuned" and budget else "")
        label = f"{c['name']} [{mode}, {source}]"
        out.append(Submission(label, c["name"], source, doc["mode"], budget, klass,
                              doc["suite"]["phases"] * doc["suite"]["seeds"], es))
    return out


def _key(doc: dict) -> tuple:
    """What makes entries comparable: the suite and its version, the metrics version, the compute model,
    and whether the suite was as its lock says (a changed suite is not the version it names)."""
    s = doc["suite"]
    return s["name"], s["version"], doc["metrics_version"], s["compute"], bool(s.get("frozen"))


def collect(*dirs, validate: bool = True) -> tuple[dict, list[str]]:
    """``({comparability key: (documents' suite, [Submission])}, notes)`` of every entry under ``dirs``.

    Raises
    ------
    DataError : an entry that is unreadable or breaks the schema (one line naming it).
    """
    from mitigate.benchmark.entry import read_entry
    from mitigate.benchmark.entry import validate as check
    groups: dict[tuple, tuple[dict, list]] = {}
    notes = []
    found = []
    for d in dirs:
        d = Path(d)
        if d.is_file():
            found.append(d)
            continue
        if not d.is_dir():
            raise ConfigError(f"{d}: not a folder of entries")
        found += sorted(set(d.rglob("results.json")) | set(d.rglob("results.json.gz")))
    for p in found:
        doc = read_entry(p)
        if validate:
            check(doc, str(p))
        base = p.parent
        source = base.name or str(base)
        g = groups.setdefault(_key(doc), (doc["suite"], []))
        g[1].extend(_entries_from(doc, source))
        notes.append(f"{p}: {doc['mode']}, {len(doc['records'])} runs, commit {doc['provenance']['commit'][:12]}")
    if not groups:
        raise DataError(f"no entry (results.json) found under {', '.join(map(str, dirs))}")
    return groups, notes


def build(subs: list[Submission], scenarios: list[str]) -> dict:
    """Per class, the rows (one per submission) and per scenario the ranks, from the benchmark's order."""
    from mitigate.benchmark.stats import rank
    tables = {}
    for klass in ("drive", "force", "both"):
        members = [s for s in subs if s.klass in (klass, "none")]
        if not any(s.klass == klass for s in members):
            continue
        ranks: dict[tuple, int] = {}
        per_scenario = {}
        for sc in scenarios:
            es = {s.label: s.entries[sc] for s in members if sc in s.entries and s.entries[sc].applicable}
            if not es:
                continue
            by_ctrl = {}
            for label, e in es.items():     # rank() keys by controller name: rank copies named by label
                ee = copy.copy(e)
                ee.controller = label
                by_ctrl[label] = ee
            r = rank(list(by_ctrl.values()))
            for label, v in r.items():
                ranks[(label, sc)] = v
            per_scenario[sc] = sorted(((r[label], label, es[label]) for label in es), key=lambda x: (x[0], x[1]))
        rows = []
        for s in members:
            mine = [sc for sc in scenarios if (s.label, sc) in ranks]
            if not mine:
                continue
            es = [s.entries[sc] for sc in mine]
            rows.append({"label": s.label, "controller": s.controller, "source": s.source, "mode": s.mode,
                         "budget": s.budget, "class": s.klass, "scenarios": len(mine), "of": len(scenarios),
                         "runs": s.runs_per_scenario, "job_done": sum(e.job_done for e in es),
                         "first": sum(ranks[(s.label, sc)] == 1 and s.entries[sc].job_done for sc in mine),
                         "mean_rank": sum(ranks[(s.label, sc)] for sc in mine) / len(mine)})
        rows.sort(key=lambda r: (-r["scenarios"], r["mean_rank"], r["label"]))
        tables[klass] = {"rows": rows, "scenarios": per_scenario}
    return tables


def _fmt_ci(e, m) -> str:
    from mitigate.benchmark.render import table_value
    v = e.metrics.get(m.name)
    if not v or math.isnan(v["median"]):
        return "-"
    if v["ci_low"] == v["ci_high"]:
        return table_value(m, v["median"])
    return f"{table_value(m, v['median'])} [{table_value(m, v['ci_low'])}, {table_value(m, v['ci_high'])}]"


def _tables(suite: dict, tables: dict) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) of every table of a leaderboard."""
    from mitigate.benchmark.render import CLASS_TITLES, job_words, table_header
    from mitigate.metrics import ranked
    out = []
    cols = ranked()
    for klass, t in tables.items():
        out.append((f"{CLASS_TITLES[klass]}: summary",
                    ["controller", "entry", "mode", "class", "scenarios", "runs per scenario", "job done", "first",
                     "mean rank"],
                    [[r["controller"], r["source"], r["mode"] + (f" ({r['budget']} trials)" if r["budget"] else ""),
                      r["class"], f"{r['scenarios']}/{r['of']}", str(r["runs"]), f"{r['job_done']}/{r['scenarios']}",
                      str(r["first"]), f"{r['mean_rank']:.2f}"] for r in t["rows"]]))
        for sc, ranked_rows in t["scenarios"].items():
            out.append((f"{CLASS_TITLES[klass]}: scenario `{sc}`",
                        ["rank", "controller [mode, entry]", "job"] + [table_header(m) for m in cols],
                        [[str(r), label, job_words(e)] + [_fmt_ci(e, m) for m in cols] for r, label, e in ranked_rows]))
    return out


def _intro(suite: dict, notes: list[str]) -> list[str]:
    from mitigate.benchmark.render import how_to_read
    frozen = "frozen (its files, rigs and metric code as its lock says)" if suite.get("frozen") else \
        "NOT frozen (no lock, or its files differ from the lock)"
    return [f"Suite `{suite['name']}` version {suite['version'] or '-'}, {frozen}; compute model: "
            f"{suite['compute_model']}.", "", how_to_read(), "",
            "Entries read:", ""] + [f"- {n}" for n in notes] + [""]


def render_markdown(groups: dict, notes: list[str]) -> str:
    """The leaderboard as Markdown: the rules, then per comparable group and class the tables."""
    L = ["# Leaderboard", "", "## Rules", ""] + [f"{i}. {r}" for i, r in enumerate(RULES, 1)] + [""]
    for key, (suite, subs) in groups.items():
        L += [f"## {suite['name']} v{suite['version']}, metrics {key[2]}, compute {key[3]}"
              + ("" if key[4] else " (not frozen)"), ""] + _intro(suite, notes)
        for title, hdr, rows in _tables(suite, build(subs, _scenarios(suite, subs))):
            L += [f"### {title}", "", "| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
            L += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows] + [""]
    return "\n".join(L) + "\n"


def _scenarios(suite: dict, subs: list[Submission]) -> list[str]:
    names = list(suite["scenarios"])
    for s in subs:
        names += [n for n in s.entries if n not in names]
    return names


def render_html(groups: dict, notes: list[str]) -> str:
    """The leaderboard as one static HTML page (the same tables as :func:`render_markdown`)."""
    e = html.escape
    css = ("body{font-family:system-ui,sans-serif;max-width:80em;margin:2em auto;padding:0 1em;color:#222}"
           "table{border-collapse:collapse;margin:1em 0;font-size:90%}th,td{border:1px solid #ccc;padding:.25em .5em;"
           "text-align:left}th{background:#f3f3f3}tr:nth-child(even){background:#fafafa}code{background:#f3f3f3}")
    H = ["<!DOCTYPE html>", "<html lang=\"en\"><head><meta charset=\"utf-8\"><title>Stick-slip benchmark leaderboard"
         "</title>", f"<style>{css}</style></head><body>", "<h1>Leaderboard</h1>", "<h2>Rules</h2>", "<ol>"]
    H += [f"<li>{e(r)}</li>" for r in RULES] + ["</ol>"]
    for key, (suite, subs) in groups.items():
        H.append(f"<h2>{e(suite['name'])} v{e(suite['version'])}, metrics {e(key[2])}, compute {e(key[3])}"
                 f"{'' if key[4] else ' (not frozen)'}</h2>")
        H += [f"<p>{e(line)}</p>" for line in _intro(suite, notes) if line and not line.startswith("- ")]
        H += ["<ul>"] + [f"<li>{e(n)}</li>" for n in notes] + ["</ul>"]
        for title, hdr, rows in _tables(suite, build(subs, _scenarios(suite, subs))):
            H += [f"<h3>{e(title)}</h3>", "<table><thead><tr>" + "".join(f"<th>{e(h)}</th>" for h in hdr)
                  + "</tr></thead><tbody>"]
            H += ["<tr>" + "".join(f"<td>{e(c)}</td>" for c in row) + "</tr>" for row in rows]
            H.append("</tbody></table>")
    H.append("</body></html>")
    return "\n".join(H) + "\n"


def write_leaderboard(dirs, out, *, force: bool = False) -> dict[str, Path]:
    """Read the entries under ``dirs`` and write ``leaderboard.md`` and ``leaderboard.html`` to ``out``
    as one output set; ``{key: path}``."""
    from models.files import output_set
    groups, notes = collect(*dirs)
    with output_set(out, LEADERBOARD_FILES.values(), force=force) as w:
        w.write_text(LEADERBOARD_FILES["markdown"], render_markdown(groups, notes))
        w.write_text(LEADERBOARD_FILES["html"], render_html(groups, notes))
        return {k: w.final(v) for k, v in LEADERBOARD_FILES.items()}
