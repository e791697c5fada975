"""``mitigate estimate``: run an online state estimator over a recorded log of any rig.

Reads a CSV log (:func:`models.logs.read_csv`) of the rig given by ``--model`` (a shipped
rig's name or a rig file's path), runs the EKF, the MHE or the finite-difference baseline
sample by sample exactly as in a closed loop (``update(t, measurement, u)``; the inputs of
row ``k - 1`` are taken as held over the sample that ends at row ``k``, as a DAQ logs
commands), and writes the estimates as CSV: ``t [s]``, then every estimator state and its
standard deviation (``<state> [unit]``, ``<state>_std [unit]``; an augmented state's ``:``
becomes ``_``, e.g. ``load_pin1 [-]``), then ``corrected``, ``warning`` and ``success`` flags
[-].  Row 0 is the prior.

Prints the observability verdict of the configuration (one line: along a start-up at the
rig's operating point and at steady sliding, :mod:`estimators.online.observability`), the
per-step time (median, p95, first step excluded), the dropout/failure/fallback counts,
whether the twist was observable along windows of the log itself, and, if the log holds
true twists (our simulator's ``twist_<spring>`` columns, or ``twist<a><b>`` = ``theta<a> -
theta<b>`` as the independent simulator writes them), the twist RMSE over all rows and after
the first second.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from estimators.base import EstimatorContext
from estimators.online.factory import ESTIMATOR_KINDS, make_estimator
from estimators.online.model import angle_combination, default_channels
from mitigate.cliutil import check_outputs, emit_json, format_table
from models.errors import ConfigError, DataError
from models.files import atomic_write_text
from models.logs import read_csv
from models.rig import load_params
from models.rig import get_model
from models.sensors import SensorOptions

EPILOG = """examples:
  mitigate estimate out/open_stick_slip.csv --model rig3 --out out/est_ekf.csv
  mitigate estimate out/open_stick_slip.csv --estimator mhe --window 20 --json
  mitigate estimate run.csv --model my_rigs/four_disc.toml --channels theta1,theta4,omega1,omega4 --augment none
  mitigate estimate run.csv --augment load:pin1,offset:motor_torque --angles zeroed --params fitted.toml

The twist at power-on (encoders zeroed), the friction load factor and a torque-sensor
offset are estimated by default; the verdict line says whether the twist can be told from
them (at stick-slip they separate, at steady sliding they do not).
"""

#: windows of the log checked for observability: length [s] and at most how many
OBS_WINDOW_S = 4.0
OBS_WINDOWS_MAX = 12


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "estimate", help="estimate the twists (and speeds, drive states, friction load) from a log",
        description="Run an online estimator (EKF, MHE or finite differences) over a CSV log of a rig; write the "
                    "estimated states with standard deviations as CSV and print the observability verdict, timing "
                    "and failure counts.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
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
        chans = [c for c in known if c in log and c not in log.derived]
        angles = [c for c in chans if model.sensor_of(c).kind == "encoder" and model.sensor_of(c).channels[0] == c]
        if len(angles) == 1:      # one angle alone carries no twist
            chans.remove(angles[0])
        if not chans:
            raise DataError(f"{log.source}: no measurement column of rig {model.name!r}; expected some of "
                            f"{', '.join(known)}")
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


def _true_twists(log, model) -> dict[str, np.ndarray]:
    """True twists in the log, by estimator state name: ``twist_<spring>`` columns, or
    ``twist<a><b>`` meaning ``theta<a> - theta<b>`` when that difference is one spring's twist."""
    out = {}
    twists = [s for s in model.states if s.startswith("twist_")]
    for name in twists:
        if name in log:
            out[name] = log[name]

    def comb(ch):
        s = model.sensor_of(ch)
        if s is None or s.kind != "encoder" or s.channels[0] != ch:
            return None
        return angle_combination(model, s.target)

    for col in log.channels:
        if not col.startswith("twist") or col in out or col.startswith("twist_"):
            continue
        digits = col[len("twist"):]
        if len(digits) != 2 or not digits.isdigit():
            continue
        ca_, cb = comb(f"theta{digits[0]}"), comb(f"theta{digits[1]}")
        if ca_ is None or cb is None:
            continue
        d = ca_ - cb
        nz = np.flatnonzero(np.abs(d) > 1e-12)
        if nz.size == 1 and model.states[nz[0]] in twists and model.states[nz[0]] not in out:
            out[model.states[nz[0]]] = d[nz[0]] * log[col]
    return out


def _observability_along_log(est, X, U) -> dict:
    """Observability along windows of the estimated trajectory (``U[k]``: the input over the
    sample that ended at row k)."""
    if not hasattr(est, "observability_windows"):
        return {}
    reps = est.observability_windows(X, U, window=OBS_WINDOW_S, max_windows=OBS_WINDOWS_MAX)
    if not reps:
        return {}
    worst = max(reps, key=lambda r: float(np.max(r.twist_std / r.scales[[r.names.index(t) for t in r.twist_names]])))
    return {"windows": len(reps), "window_s": reps[0].samples * est.em.dt,
            "twist_observable_windows": int(sum(r.twist_observable for r in reps)), "worst": worst.message}


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
    spec = _spec(args, model, log)
    dt = log.dt
    est = make_estimator(spec, EstimatorContext(model, params, dt, SensorOptions(), where="estimator"))

    n = len(log.t)
    U = np.column_stack([log[name] for name in model.inputs])
    chan = {c: log[c] for c in est.channels}
    names = est.names
    X = np.zeros((n, len(names)))
    S = np.zeros((n, len(names)))
    flags = np.zeros((n, 3))          # corrected, warning, success
    src = getattr(est, "ekf", est)
    if hasattr(src, "x") and np.shape(src.x) == (len(names),):
        X[0] = src.x
        S[0] = np.sqrt(np.diag(src.P))
    flags[0] = (0.0, 0.0, 1.0)
    times = []
    for k in range(1, n):
        e = est.update(float(log.t[k]), {c: v[k] for c, v in chan.items()}, U[k - 1])
        X[k] = e.x
        S[k] = np.sqrt(np.maximum(np.diag(e.P), 0.0))
        flags[k] = (float(e.corrected), float(e.status.name == "WARNING"), float(e.success))
        times.append(e.solve_time)

    units = getattr(getattr(est, "em", None), "units", None) or model.state_units
    cols = [("t [s]", log.t)]
    for j, (nm, unit) in enumerate(zip(names, units)):
        cols.append((f"{nm.replace(':', '_')} [{unit}]", X[:, j]))
    for j, (nm, unit) in enumerate(zip(names, units)):
        cols.append((f"{nm.replace(':', '_')}_std [{unit}]", S[:, j]))
    cols += [("corrected [-]", flags[:, 0]), ("warning [-]", flags[:, 1]), ("success [-]", flags[:, 2])]
    lines = [",".join(h for h, _ in cols)]
    for row in zip(*[c for _, c in cols]):
        lines.append(",".join(f"{v:.9g}" for v in row))
    atomic_write_text(out, "\n".join(lines) + "\n", overwrite=args.force)

    tt = np.array(times[1:] if len(times) > 1 else times) * 1e3
    verdict = getattr(est, "observability_message", "fd: estimates nothing it does not read")
    summary = {
        "log": str(log_path), "out": str(out), "model": model.key, "estimator": args.estimator,
        "channels": list(est.channels), "states": list(names), "steps": est.counts.steps, "dt_s": dt,
        "observability": verdict,
        "step_time_median_ms": float(np.median(tt)) if tt.size else float("nan"),
        "step_time_p95_ms": float(np.percentile(tt, 95)) if tt.size else float("nan"),
        **est.counts.as_dict(),
        "warned_fraction": float(np.mean(flags[1:, 1])) if n > 1 else 0.0,
    }
    for rep_name in ("observability", "observability_steady"):
        rep = getattr(est, rep_name, None)
        if rep is not None:
            summary[f"{rep_name}_report"] = rep.as_dict()
    U_held = np.vstack([U[:1], U[:-1]])           # row k: the input over the sample ending at k
    along = _observability_along_log(est, X, U_held)
    if along:
        summary["observability_along_log"] = along
    if hasattr(est, "compile_status"):
        summary["compile"] = est.compile_status
    idx = {nm: i for i, nm in enumerate(names)}
    for tw, true in _true_twists(log, model).items():
        if tw not in idx:
            continue
        err = X[1:, idx[tw]] - true[1:]
        summary[f"{tw}_final_rad"] = float(X[-1, idx[tw]])
        summary[f"{tw}_rmse_rad"] = float(np.sqrt(np.mean(err ** 2)))
        late = log.t[1:] >= log.t[0] + 1.0
        if late.any():
            summary[f"{tw}_rmse_after_1s_rad"] = float(np.sqrt(np.mean(err[late] ** 2)))
    if args.json:
        emit_json(summary)
    else:
        print(f"observability: {verdict}")
        skip = ("states", "channels", "observability", "observability_report", "observability_steady_report",
                "observability_along_log")
        rows = [[k, v] for k, v in summary.items() if k not in skip]
        rows.insert(5, ["channels", ",".join(est.channels)])
        if along:
            rows.append(["twist observable along the log", f"{along['twist_observable_windows']}/{along['windows']} "
                                                            f"windows of {along['window_s']:g} s"])
        print(format_table(["quantity", "value"], rows))
    return 0
