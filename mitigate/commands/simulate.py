"""``mitigate simulate``: one open-loop run of a scenario's input programme.

The scenario's ``[[controllers]]`` and ``[estimator]`` are ignored: the plant is driven by
its ``[inputs]`` profiles only (the rig's own PI speed loop is part of the rig3 model).
Writes ``<name>.csv`` (the log format of :mod:`models.logs`, measured channels; with
``--truth-twist`` also the true twists) and ``<name>.png`` (time histories), and prints a
summary: stuck fraction of R1 from the *true* speed, stick-slip severity, mean speed.
"""

from __future__ import annotations

import sys

import numpy as np

from mitigate import metrics
from mitigate.cliutil import add_command, add_common, emit_json, format_table
from mitigate.scenario import load_scenario
from models.errors import SolverFailure
from models.files import check_output_dir, file_stem, output_set
from models.plant import simulate

EPILOG = """examples:
  mitigate simulate scenarios/open_stick_slip.toml --out out/
  mitigate simulate scenarios/open_steady.toml --out out/ --ideal --truth --json
  mitigate simulate scenarios/four_disc_stick_slip.toml --out out/four
"""


def register(subparsers) -> None:
    p = add_command(
        subparsers, "simulate", help="simulate a scenario's input programme open loop (CSV log + PNG)",
        description="Simulate a scenario open loop (its [[controllers]] are ignored): write <name>.csv in the "
                    "log format and <name>.png, print the stuck fraction, severity and mean speed of the rig's "
                    "objective body (rig3: R1).",
        epilog=EPILOG)
    p.add_argument("scenario", help="scenario TOML file")
    add_common(p)
    p.add_argument("--ideal", action="store_true",
                   help="record ideal measurements (no encoder quantisation, no load-cell noise)")
    p.add_argument("--truth", action="store_true",
                   help="also write the true twists and body speeds as columns true_twist_<connection>, "
                        "true_omega_<body> (apart from a sensor's omega_<body>)")
    p.add_argument("--no-plot", action="store_true", help="do not write the PNG")
    p.set_defaults(func=run)


def summarise(t: np.ndarray, omega_true: np.ndarray, omega_meas: np.ndarray | None = None,
              stuck_measured: float | None = None) -> dict:
    """Run summary from a body's true speed (exact zeros in stick for the hybrid plant); the measured
    speed counts as stuck at or below ``stuck_measured`` [rad/s] (:func:`mitigate.metrics.measured_stuck_speed`)."""
    w = np.asarray(omega_true, dtype=float)
    stuck = np.abs(w) <= 1e-9
    out = {
        "stuck_fraction_true": float(np.mean(stuck)),
        "severity": metrics.severity(w),
        "severity_second_half": metrics.severity(w[len(w) // 2:]),
        "mean_speed": float(np.mean(w)),
        "max_speed": float(np.max(w)),
        "min_speed": float(np.min(w)),
    }
    if omega_meas is not None and stuck_measured is not None:
        out["stuck_fraction_measured"] = metrics.stuck_fraction(omega_meas, stuck_measured)
        out["stuck_speed_measured"] = float(stuck_measured)
    return out


def run(args) -> int:
    out = check_output_dir(args.out)
    sc = load_scenario(args.scenario)
    model = sc.plant_model
    stem = file_stem(sc.name, f"{sc.where}: scenario.name")     # <name>.csv stays inside --out
    csv_path, png_path = out / f"{stem}.csv", out / f"{stem}.png"
    targets = [csv_path] + ([] if args.no_plot else [png_path])
    progress = (not args.json) and sys.stderr.isatty() and sc.samples > 2000
    body = sc.model.objective_body
    with output_set(out, [p.name for p in targets], force=args.force) as w:
        res = simulate(model, sc.plant_params, sc.programme, sc.duration, sc.sim,
                       sensors=None if args.ideal else sc.sensors, drift=sc.drift, progress=progress)
        if not res.success:
            raise SolverFailure(f"simulation of {sc.name!r} failed: {res.message}")
        log = res.to_log(measured=True, include_truth=args.truth)
        log.write_csv(w.path(csv_path.name), overwrite=True)
        if not args.no_plot:
            from mitigate.timeplots import plot_log

            truth = {n: res.x[:, j] for j, n in enumerate(res.states)}
            plot_log(sc.model, res.t, res.y,
                     f"{sc.name}: open loop ({model.name}, {sc.sim.method}; shaded: {body} stuck)",
                     w.path(png_path.name), truth=truth)
    w_prog = float(np.mean(metrics.programmed_speed(sc, res.t)))
    w_true = res.state(f"omega_{body}")
    ch, thr = metrics.measured_stuck_speed(sc, w_prog if np.isfinite(w_prog) and w_prog != 0
                                           else float(np.mean(np.abs(w_true))))
    summary = summarise(res.t, w_true, res.y.get(ch) if ch else None, thr)
    payload = {"scenario": sc.name, "model": model.name, "body": body, "method": sc.sim.method,
               "duration": sc.duration, "dt": sc.dt, "csv": str(csv_path), "png": None if args.no_plot else str(png_path),
               **summary, "status": res.status.value, "message": res.message}
    if args.json:
        emit_json(payload)
    else:
        rows = [[f"stuck fraction of {body} (true speed == 0)", summary["stuck_fraction_true"], "-"],
                [f"stuck fraction of {body} (measured |w| <= {summary.get('stuck_speed_measured', np.nan):.3g} rad/s)",
                 summary.get("stuck_fraction_measured", np.nan),
                 "-"],
                ["severity (max - min)/(2 mean)", summary["severity"], "-"],
                ["severity, second half (after start-up)", summary["severity_second_half"], "-"],
                [f"mean speed of {body}", summary["mean_speed"], "rad/s"],
                [f"max speed of {body}", summary["max_speed"], "rad/s"]]
        print(f"{sc.name}: {model.name}, {sc.duration:g} s at dt = {sc.dt:g} s, method {sc.sim.method}")
        for note in sc.messages:
            print(f"note: {note}")
        print(format_table(["quantity", "value", "unit"], rows))
        print(f"wrote {csv_path}" + ("" if args.no_plot else f" and {png_path}"))
    return 0
