"""``mitigate estimate``: run an online state estimator over a recorded log of any rig.

Argument parsing and writing around :func:`estimators.online.replay.estimate_log`.

Reads a CSV log (:func:`models.logs.read_csv`) of the rig given by ``--model`` (a shipped
rig's name or a rig file's path), runs the EKF, the MHE or the finite-difference baseline
sample by sample exactly as in a closed loop (``update(t, measurement, u)``; the inputs of
row ``k - 1`` are taken as held over the sample that ends at row ``k``, as a DAQ logs
commands), and writes the estimates as CSV: ``t [s]``, then every estimator state and its
standard deviation (``<state> [unit]``, ``<state>_std [unit]``; an augmented state's ``:``
becomes ``_``, e.g. ``load_pin1 [-]``), then ``corrected``, ``warning`` and ``success`` flags
[-].  Row 0 is the prior (NaN for ``fd``, which has none).

Prints the observability verdict of the configuration (one line: along a start-up at the
rig's operating point and at steady sliding, :mod:`estimators.online.observability`), the
per-step time (median, p95, first step excluded), the dropout/failure/fallback counts,
whether the twist was observable along windows of the log itself, and, if the log holds
true twists (our simulator's ``twist_<spring>`` columns, or ``twist<a><b>`` = ``theta<a> -
theta<b>`` as the independent simulator writes them), the twist RMSE over all rows and after
the first second.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimators.online.factory import ESTIMATOR_KINDS
from estimators.online.channels import default_channels
from estimators.online.replay import EstimationResult, estimate_log, log_channels, true_twists
from mitigate.cliutil import add_command, check_outputs, emit_json, format_table
from models.errors import ConfigError, DataError
from models.files import atomic_write_text
from models.logs import read_csv
from models.rig import load_params
from models.rig import get_model

EPILOG = """examples:
  mitigate estimate out/open_stick_slip.csv --model rig3 --out out/est_ekf.csv
  mitigate estimate out/open_stick_slip.csv --estimator mhe --window 20 --json
  mitigate estimate run.csv --model my_rigs/four_disc.toml --channels theta1,theta4,omega1,omega4 --augment none
  mitigate estimate run.csv --augment load:pin1,offset:motor_torque --angles zeroed --params fitted.toml

The twist at power-on (encoders zeroed), the friction load factor and a torque-sensor
offset are estimated by default; the verdict line says whether the twist can be told from
them (at stick-slip they separate, at steady sliding they do not).
"""

def register(subparsers) -> None:
    p = add_command(
        subparsers, "estimate", help="estimate the twists (and speeds, drive states, friction load) from a log",
        description="Run an online estimator (EKF, MHE or finite differences) over a CSV log of a rig; write the "
                    "estimated states with standard deviations as CSV and print the observability verdict, timing "
                    "and failure counts.",
        epilog=EPILOG)
    p.add_argument("log", help="CSV log with the rig's inputs and some of its sensor channels")
    p.add_argument("--model", default="rig3", metavar="RIG",
                   help="shipped rig name or rig-file path (default: rig3)")
    p.add_argument("--estimator", choices=ESTIMATOR_KINDS, default="ekf", help="estimator kind (default: ekf)")
    p.add_argument("--params", metavar="FILE", help="parameter TOML the estimator believes (default: the rig file's)")
    p.add_argument("--channels", metavar="LIST", help="comma-separated measured channels (default: the rig's "
                                                      "encoder, speed and torque channels present in the log)")
    p.add_argument("--augment", metavar="LIST", help="comma-separated augmented states, e.g. "
                                                     "load:pin1,offset:motor_torque, or 'none' (default: the rig's)")
    p.add_argument("--angles", choices=("zeroed", "absolute"),
                   help="encoders zeroed at power-on (default) or referenced to the untwisted shaft")
    p.add_argument("--window", type=int, metavar="N", help="MHE window [samples] (default: 20)")
    p.add_argument("--no-compile", action="store_true", help="do not build the C step functions (slower)")
    p.add_argument("--out", metavar="FILE", help="output CSV (default: <log stem>_<estimator>.csv next to the log)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON summary on stdout")
    p.set_defaults(func=run)


def _list(text: str, what: str) -> list[str]:
    items = [c.strip() for c in text.split(",") if c.strip()]
    if not items:
        raise ConfigError(f"{what} must be a comma-separated list, got {text!r}")
    return items


def _spec(args, model, log) -> dict:
    spec: dict = {"kind": args.estimator}
    if args.estimator == "fd":
        bad = [f for f, v in (("--channels", args.channels), ("--augment", args.augment), ("--window", args.window))
               if v is not None]
        if bad:
            raise ConfigError(f"{bad[0]} does not apply to --estimator fd")
        if args.angles:
            spec["angles"] = args.angles
        return spec
    known = default_channels(model)
    if args.channels:
        chans = _list(args.channels, "--channels")
        bad = [c for c in chans if c not in known]
        if bad:
            raise ConfigError(f"--channels: unknown channel {bad[0]!r} of rig {model.name!r}; expected some of "
                              f"{', '.join(known)}")
        missing = [c for c in chans if c not in log]
        if missing:
            raise DataError(f"{log.source}: --channels asks for column {missing[0]!r}, not in the log "
                            f"(present: {', '.join(c for c in known if c in log) or 'none'})")
    else:
        chans = log_channels(model, log)
    spec["channels"] = chans
    if args.augment is not None:
        spec["augment"] = [] if args.augment.strip().lower() == "none" else _list(args.augment, "--augment")
    if args.angles:
        spec["angles"] = args.angles
    spec["compile"] = not args.no_compile
    if args.window is not None:
        if args.estimator != "mhe":
            raise ConfigError("--window applies to --estimator mhe only")
        spec["window"] = args.window
    return spec


def _csv(res: EstimationResult) -> str:
    cols = [("t [s]", res.t)]
    cols += [(f"{nm.replace(':', '_')} [{unit}]", res.x[:, j]) for j, (nm, unit) in enumerate(zip(res.names, res.units))]
    cols += [(f"{nm.replace(':', '_')}_std [{unit}]", res.std[:, j])
             for j, (nm, unit) in enumerate(zip(res.names, res.units))]
    cols += [("corrected [-]", res.corrected), ("warning [-]", res.warned), ("success [-]", res.succeeded)]
    lines = [",".join(h for h, _ in cols)]
    for row in zip(*[np.asarray(c, float) for _, c in cols]):
        lines.append(",".join(f"{v:.9g}" for v in row))
    return "\n".join(lines) + "\n"


def _summary(res: EstimationResult, log, log_path, out, model) -> dict:
    tt = res.step_times[1:] if res.step_times.size > 1 else res.step_times
    tt = tt * 1e3
    summary = {
        "log": str(log_path), "out": str(out), "model": model.key, "estimator": res.kind,
        "channels": list(res.channels), "states": list(res.names), "steps": res.counts["steps"], "dt_s": log.dt,
        "observability": res.observability,
        "step_time_median_ms": float(np.median(tt)) if tt.size else float("nan"),
        "step_time_p95_ms": float(np.percentile(tt, 95)) if tt.size else float("nan"),
        **res.counts,
        "warned_fraction": float(np.mean(res.warned[1:])) if res.t.size > 1 else 0.0,
    }
    for name, rep in res.observability_reports.items():
        summary[f"{name}_report"] = rep.as_dict()
    if res.observability_along_log:
        summary["observability_along_log"] = res.observability_along_log
    if res.compile_status is not None:
        summary["compile"] = res.compile_status
    for tw, true in true_twists(log, model).items():
        if tw not in res.names:
            continue
        summary[f"{tw}_final_rad"] = float(res.state(tw)[-1])
        summary[f"{tw}_rmse_rad"] = res.rmse(tw, true)
        if (res.t[1:] >= res.t[0] + 1.0).any():
            summary[f"{tw}_rmse_after_1s_rad"] = res.rmse(tw, true, after=1.0)
    return summary


def run(args) -> int:
    log_path = Path(args.log)
    out = Path(args.out) if args.out else log_path.with_name(f"{log_path.stem}_{args.estimator}.csv")
    check_outputs([out], args.force)
    model = get_model(args.model)
    log = read_csv(log_path)
    for n in model.inputs:
        if n not in log:
            raise DataError(f"{log_path}: missing input column {n!r} of rig {model.name!r} (inputs: "
                            f"{', '.join(model.inputs)})")
    params = load_params(args.params, model) if args.params else model.published()
    res = estimate_log(log, _spec(args, model, log), model, params)
    atomic_write_text(out, _csv(res), overwrite=args.force)
    summary = _summary(res, log, log_path, out, model)
    if args.json:
        emit_json(summary)
    else:
        print(f"observability: {res.observability}")
        skip = ("states", "channels", "observability", "observability_report", "observability_steady_report",
                "observability_along_log")
        rows = [[k, v] for k, v in summary.items() if k not in skip]
        rows.insert(5, ["channels", ",".join(res.channels)])
        along = res.observability_along_log
        if along:
            rows.append(["twist observable along the log", f"{along['twist_observable_windows']}/{along['windows']} "
                                                            f"windows of {along['window_s']:g} s"])
        print(format_table(["quantity", "value"], rows))
    return 0
