"""``mitigate estimate``: run an online state estimator over a recorded rig3 log.

Reads a rig3 CSV log (:func:`models.logs.read_csv`; the inputs ``omega_ref``, ``n1``,
``n2`` come from the log), runs the EKF, the MHE or the finite-difference baseline
sample by sample exactly as in a closed loop (``update(measurement, u_previous, t)``),
and writes the estimates as CSV.  Output columns (units in the header)::

    t [s], twist12 [rad], twist23 [rad], twist12_std [rad], twist23_std [rad],
    omega1 [rad/s], omega2 [rad/s], omega3 [rad/s], omega1_std [rad/s],
    current [A], z [rad], <augmented states, e.g. load1 [-]>, corrected [-], success [-]

(``*_std`` is the square root of the estimator's covariance diagonal; row 0 is the
prior.)  The summary gives the per-step time (median, p95, first step excluded), the
dropout/failure/fallback counts and, if the log holds true twists (``simulate
--truth-twist``), the twist RMSE over all rows and after the first second (the
initial convergence from the prior is not hidden, but reported separately).  Noise covariances use the default sensor
specification (``models.sensors.SensorOptions``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from estimators.factory import ESTIMATOR_KINDS, make_estimator
from mitigate.cliutil import check_outputs, emit_json, format_table
from models.errors import ConfigError, DataError
from models.logs import atomic_write_text, read_csv
from models.params import load_params, published
from models.sensors import SensorOptions

EPILOG = """examples:
  mitigate simulate scenarios/open_stick_slip.toml --out out/ --truth-twist
  mitigate estimate out/open_stick_slip.csv --estimator ekf --out out/est_ekf.csv
  mitigate estimate out/open_stick_slip.csv --estimator mhe --channels omega1,omega2,omega3,motor_torque --json
"""

MEAS = ("theta1", "theta2", "theta3", "omega1", "omega2", "omega3", "motor_torque")
UNITS = {"phi12": ("twist12", "rad"), "phi23": ("twist23", "rad"), "omega1": ("omega1", "rad/s"),
         "omega2": ("omega2", "rad/s"), "omega3": ("omega3", "rad/s"), "i": ("current", "A"), "z": ("z", "rad"),
         "o12": ("offset12", "rad"), "o23": ("offset23", "rad"), "load1": ("load1", "-"), "load2": ("load2", "-")}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "estimate", help="estimate the shaft twists (and speeds, current, load) from a rig3 log",
        description="Run an online estimator (EKF, MHE or finite differences) over a rig3 CSV log; write the "
                    "estimated states with standard deviations as CSV and print timing and failure counts.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", help="rig3 CSV log (needs omega_ref, n1, n2 and some of " + ", ".join(MEAS) + ")")
    p.add_argument("--estimator", choices=ESTIMATOR_KINDS, default="ekf", help="estimator kind (default: ekf)")
    p.add_argument("--params", metavar="FILE", help="rig3 parameter TOML the estimator believes (default: published)")
    p.add_argument("--channels", metavar="LIST", help="comma-separated measurement channels to use "
                                                      "(default: all of " + ",".join(MEAS) + " in the log)")
    p.add_argument("--window", type=int, help="MHE window [samples]")
    p.add_argument("--no-compile", action="store_true", help="do not build the C step functions (slower)")
    p.add_argument("--out", metavar="FILE", help="output CSV (default: <log stem>_<estimator>.csv next to the log)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON summary on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    log_path = Path(args.log)
    out = Path(args.out) if args.out else log_path.with_name(f"{log_path.stem}_{args.estimator}.csv")
    check_outputs([out], args.force)
    log = read_csv(log_path, required=("omega_ref", "n1", "n2"))
    params = load_params(args.params, "rig3") if args.params else published("rig3")
    present = [c for c in MEAS if c in log]
    if args.channels:
        chans = [c.strip() for c in args.channels.split(",") if c.strip()]
        bad = [c for c in chans if c not in MEAS]
        if bad:
            raise ConfigError(f"--channels: unknown channel {bad[0]!r}; expected some of {', '.join(MEAS)}")
        missing = [c for c in chans if c not in log]
        if missing:
            raise DataError(f"{log_path}: --channels asks for column {missing[0]!r}, not in the log "
                            f"(present: {', '.join(present) or 'none'})")
    else:
        chans = present
    spec: dict = {"kind": args.estimator}
    if args.estimator == "fd":
        need = ("theta1", "theta2", "theta3", "omega1", "omega2", "omega3")
        miss = [c for c in need if c not in log]
        if miss:
            raise DataError(f"{log_path}: the fd estimator needs column {miss[0]!r}")
        if args.window is not None or args.channels:
            raise ConfigError("--window and --channels do not apply to --estimator fd")
    else:
        if not chans:
            raise DataError(f"{log_path}: no measurement columns; expected some of {', '.join(MEAS)}")
        if len([c for c in chans if c.startswith("theta")]) == 1:
            chans = [c for c in chans if not c.startswith("theta")]   # one angle alone carries no twist
        spec["channels"] = list(chans)
        spec["compile"] = not args.no_compile
        if args.window is not None:
            if args.estimator != "mhe":
                raise ConfigError("--window applies to --estimator mhe only")
            spec["window"] = args.window
    dt = log.dt
    est = make_estimator(spec, params, SensorOptions(), dt)

    n = len(log.t)
    U = np.column_stack([log["omega_ref"], log["n1"], log["n2"]])
    chan_data = {c: log[c] for c in est.channels if c in log}
    names = est.names
    X = np.zeros((n, len(names)))
    S = np.zeros((n, len(names)))
    corrected = np.zeros(n)
    success = np.ones(n)
    src = getattr(est, "ekf", est)    # the MHE's prior is its inner EKF's
    x0 = getattr(src, "x", None)
    P0 = getattr(src, "P", None)
    if x0 is not None and np.shape(x0) == (len(names),):
        X[0] = x0
        S[0] = np.sqrt(np.diag(P0))
    times = []
    for k in range(1, n):
        e = est.update({c: v[k] for c, v in chan_data.items()}, U[k - 1], float(log.t[k]))
        X[k] = e.x
        S[k] = np.sqrt(np.maximum(np.diag(e.P), 0.0))
        corrected[k] = float(e.corrected)
        success[k] = float(e.success)
        times.append(e.solve_time)

    cols = [("t [s]", log.t)]
    idx = {nm: i for i, nm in enumerate(names)}
    for nm in ("phi12", "phi23"):
        cols.append((f"{UNITS[nm][0]} [rad]", X[:, idx[nm]]))
    for nm in ("phi12", "phi23"):
        cols.append((f"{UNITS[nm][0]}_std [rad]", S[:, idx[nm]]))
    for nm in names[2:]:
        lab, unit = UNITS[nm]
        cols.append((f"{lab} [{unit}]", X[:, idx[nm]]))
        if nm == "omega1":
            cols.append(("omega1_std [rad/s]", S[:, idx[nm]]))
    cols += [("corrected [-]", corrected), ("success [-]", success)]
    lines = [",".join(h for h, _ in cols)]
    for row in zip(*[c for _, c in cols]):
        lines.append(",".join(f"{v:.9g}" for v in row))
    atomic_write_text(out, "\n".join(lines) + "\n", overwrite=args.force)

    tt = np.array(times[1:] if len(times) > 1 else times) * 1e3
    summary = {
        "log": str(log_path), "out": str(out), "estimator": args.estimator, "channels": list(est.channels),
        "states": list(names), "steps": est.counts.steps, "dt_s": dt,
        "step_time_median_ms": float(np.median(tt)) if tt.size else float("nan"),
        "step_time_p95_ms": float(np.percentile(tt, 95)) if tt.size else float("nan"),
        **est.counts.as_dict(),
        "twist12_final_rad": float(X[-1, idx["phi12"]]), "twist23_final_rad": float(X[-1, idx["phi23"]]),
    }
    if hasattr(est, "compile_status"):
        summary["compile"] = est.compile_status
    for j, tw in enumerate(("twist12", "twist23")):
        if tw in log:
            err = X[1:, j] - log[tw][1:]
            summary[f"{tw}_rmse_rad"] = float(np.sqrt(np.mean(err ** 2)))
            late = log.t[1:] >= log.t[0] + 1.0     # after the initial convergence
            if late.any():
                summary[f"{tw}_rmse_after_1s_rad"] = float(np.sqrt(np.mean(err[late] ** 2)))
    if args.json:
        emit_json(summary)
    else:
        rows = [[k, v] for k, v in summary.items() if k not in ("states", "channels")]
        rows.insert(4, ["channels", ",".join(est.channels)])
        print(format_table(["quantity", "value"], rows))
    return 0
