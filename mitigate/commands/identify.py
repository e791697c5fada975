"""``mitigate identify``: fit model parameters to one or several logs (multiple shooting, Gauss-Newton).

Reads CSV logs (:mod:`models.logs`) or LabView TDMS files (``--tdms-map MAP.toml``, see
:mod:`models.tdms`), fits the ``--free`` parameters of ``--model`` with
:func:`estimators.identify.identify`, prints estimate +- standard error next to the
published value, and writes the fitted set as a parameter TOML (with ``[stderr]``) that
every other command accepts, plus optionally a PNG of measured vs. fitted outputs.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

from mitigate.cliutil import check_outputs, emit_json, format_table, savefig_atomic
from models.errors import ConfigError
from models.logs import read_csv
from models.params import load_params, published
from models.rigs import MODEL_NAMES, get_model

EPILOG = """examples:
  mitigate identify out/open_stick_slip.csv --model rig3 --free k1,k2,d1,mu_k,mu_s --out fitted.toml   # + fitted.png
  mitigate identify run1.csv run2.csv --model disc --free k,d,mu_k,mu_s --holdout 0.2 --plot fit.png --json
  mitigate identify rig.tdms --tdms-map channels.toml --model rig2 --free k,c,Tc --out fitted.toml --force
  mitigate identify run1.csv --model disc --free k,mu_k --systematic --out fitted.toml   # + regularisation error
  mitigate identify run1.csv --model disc --free k,d,mu_k,mu_s --bootstrap 8 --workers 2   # bootstrap error bars
"""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "identify", help="fit model parameters to logs (multiple shooting, Gauss-Newton)",
        description="Fit the --free parameters of --model to one or several logs (shared parameters, "
                    "separate state nodes); print estimates with standard errors and write a parameter TOML.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logs", nargs="+", metavar="LOG", help="CSV log(s) in the workbench format, or TDMS files")
    p.add_argument("--model", required=True, choices=MODEL_NAMES, help="model to fit")
    p.add_argument("--free", required=True, help="comma-separated parameters to fit, e.g. k1,k2,d1,mu_k,mu_s")
    p.add_argument("--params", metavar="FILE", help="initial/fixed parameter TOML (default: published values; "
                                                     "its [bounds] are the fitting bounds)")
    p.add_argument("--out", default="fitted.toml", metavar="FILE", help="fitted parameter TOML (default: fitted.toml)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--plot", metavar="PNG", help="PNG of measured vs. fitted outputs (default: the --out file "
                                                 "with .png, e.g. fitted.png)")
    p.add_argument("--no-plot", action="store_true", help="do not write the PNG")
    p.add_argument("--holdout", type=float, default=0.0, metavar="FRACTION",
                   help="fraction of the end of the first log kept out of the fit and predicted with the exact "
                        "stick/slip plant (default 0)")
    p.add_argument("--eps", type=float, default=0.005, help="friction regularisation [rad/s] (default 0.005)")
    p.add_argument("--nsub", type=int, default=None, help="RK4 substeps per sample (default: from the stiff rate)")
    p.add_argument("--shoot-every", type=int, default=10, help="samples per shooting interval (default 10)")
    p.add_argument("--max-iter", type=int, default=100, help="solver iteration limit (default 100)")
    p.add_argument("--input-cutoff", action="append", default=[], metavar="CHANNEL=HZ",
                   help="zero-phase low-pass of a noisy, slowly varying input before fitting, e.g. n1=0.5 "
                        "(repeatable; the model takes logged inputs as exact)")
    p.add_argument("--input-noise", action="append", default=[], metavar="CHANNEL=STD|auto|off",
                   help="errors in the variables: treat that logged input as noisy with this std (SI units, "
                        "e.g. n1=0.2): each shooting interval gets a correction with that prior. Default 'auto': "
                        "force/torque inputs whose fast part is white noise, with the estimated std; 'off': none")
    p.add_argument("--systematic", action="store_true",
                   help="also estimate a systematic error: refit with the friction regularisation halved "
                        "(eps/2; lead screw: r1 doubled) and take |theta(eps) - theta(eps/2)|; prints extra columns "
                        "and writes the TOTAL error sqrt(SE^2 + syserr^2) into [stderr] (one more, warm-started fit)")
    p.add_argument("--bootstrap", type=int, default=0, metavar="B",
                   help="parametric bootstrap with B >= 2 replicate logs simulated (exact plant, sensor model) "
                        "from the fit: prints the pipeline's bias and scatter and writes the RMS error "
                        "sqrt(bias^2 + sd^2) into [stderr] (B more fits, each from the same initial guess)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="processes for the bootstrap fits (default 1)")
    p.add_argument("--encoder-ticks", type=int, default=1000, metavar="N",
                   help="bootstrap sensor model: encoder ticks per revolution (default 1000)")
    p.add_argument("--force-noise", type=float, default=0.2, metavar="N",
                   help="bootstrap sensor model: load-cell noise on the pin forces, std [N] (default 0.2)")
    p.add_argument("--torque-noise", type=float, default=0.01, metavar="NM",
                   help="bootstrap sensor model: motor-torque noise, std [N m] (default 0.01)")
    p.add_argument("--tdms-map", metavar="TOML", help="channel mapping for TDMS logs (models.tdms)")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON document on stdout")
    p.set_defaults(func=run)


def _read_log(path: str, tdms_map: str | None):
    if path.lower().endswith(".tdms"):
        if tdms_map is None:
            raise ConfigError(f"{path}: a TDMS log needs --tdms-map MAP.toml (channel names -> vocabulary)")
        from models.tdms import read_tdms
        return read_tdms(path, tdms_map)
    return read_csv(path)


def _plot(fit, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chans = list(fit.measured[0])
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.4 * len(chans) + 0.6), sharex=True, squeeze=False)
    units = {"motor_torque": "N m"}
    for ax, c in zip(axes[:, 0], chans):
        for i, (t, ym, ys) in enumerate(zip(fit.t, fit.measured, fit.simulated)):
            ax.plot(t, ym[c], ".", ms=2, color="0.5", label="measured" if i == 0 else None)
            ax.plot(t, ys[c], "-", lw=1, color="C0", label="fitted model" if i == 0 else None)
        if fit.validation is not None and c in fit.validation.measured:
            v = fit.validation
            ax.plot(v.t, v.measured[c], ".", ms=2, color="0.7", label="held out (measured)")
            ax.plot(v.t, v.simulated[c], "-", lw=1, color="C3", label="held out (exact plant)")
        unit = units.get(c, "rad" if "-" in c else "rad/s")
        ax.set_ylabel(f"{c} [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"identify {fit.model}: measured vs. fitted ({', '.join(fit.names)})")
    fig.tight_layout()
    savefig_atomic(fig, path)
    plt.close(fig)


def _channel_values(items, flag: str, form: str, model) -> dict[str, float]:
    """``CHANNEL=NUMBER`` entries of ``flag`` for inputs of ``model``; one-line ConfigError otherwise."""
    out = {}
    for item in items:
        name, sep, val = item.partition("=")
        name = name.strip()
        try:
            out[name] = float(val)
        except ValueError:
            sep = ""
        if not sep or not name:
            raise ConfigError(f"{flag} must look like {form}, got {item!r}")
        if name not in model.inputs:
            raise ConfigError(f"{flag}: {name} is not an input of {model.name} (inputs: {', '.join(model.inputs)})")
    return out


def _input_noise(items, model, logs, cutoff) -> tuple[dict, set]:
    """``--input-noise`` entries -> ({channel: std}, channels detected automatically)."""
    from estimators.identify import detect_input_noise

    auto = True
    for item in items:
        if item in ("auto", "off"):
            auto = item == "auto"
    explicit = _channel_values([i for i in items if i not in ("auto", "off")], "--input-noise",
                               "CHANNEL=STD, auto or off (e.g. n1=0.2)", model)
    for name, std in explicit.items():
        if not (math.isfinite(std) and std > 0):
            raise ConfigError(f"--input-noise {name}: the std must be a number > 0, got {std!r}")
    detected = set()
    if auto:
        for name, sd in detect_input_noise(logs, model).items():
            if name not in explicit and name not in cutoff:
                explicit[name] = sd
                detected.add(name)
    return explicit, detected


def run(args) -> int:
    from estimators.identify import IdentifyOptions, identify

    model = get_model(args.model)
    free = tuple(s.strip() for s in args.free.split(",") if s.strip())
    initial = load_params(args.params, args.model) if args.params else published(args.model)
    for n in free:
        initial.spec(n)  # ConfigError naming the parameter
    if not (math.isfinite(args.holdout) and 0 <= args.holdout < 0.9):
        raise ConfigError(f"--holdout must be a fraction in [0, 0.9), got {args.holdout}")
    boot = None
    if args.bootstrap:
        from estimators.bootstrap import BootstrapOptions
        from models.sensors import SensorOptions
        if args.bootstrap < 2:
            raise ConfigError(f"--bootstrap must be an integer >= 2 (replicates), got {args.bootstrap}")
        if args.systematic:
            raise ConfigError("--bootstrap and --systematic are alternatives (the bootstrap's exact-plant "
                              "replicates include the regularisation error); got both")
        if args.workers < 1:
            raise ConfigError(f"--workers must be an integer >= 1, got {args.workers}")
        sensors = SensorOptions(ticks_per_rev=args.encoder_ticks, force_noise=args.force_noise,
                                torque_noise=args.torque_noise)
        boot = BootstrapOptions(replicates=args.bootstrap, sensors=sensors, workers=args.workers,
                                progress=(not args.json) and sys.stderr.isatty())
    out = Path(args.out)
    if args.no_plot:
        args.plot = None
    elif not args.plot:
        args.plot = str(out.with_suffix(".png"))
    targets = [out] + ([Path(args.plot)] if args.plot else [])
    check_outputs(targets, args.force)
    logs = [_read_log(p, args.tdms_map) for p in args.logs]
    cutoff = _channel_values(args.input_cutoff, "--input-cutoff", "CHANNEL=HZ (e.g. n1=0.5)", model)
    input_noise, detected = _input_noise(args.input_noise, model, logs, cutoff)
    options = IdentifyOptions(free=free, eps=args.eps, nsub=args.nsub, shoot_every=args.shoot_every,
                              max_iter=args.max_iter, progress=(not args.json) and sys.stderr.isatty(),
                              input_cutoff=cutoff or None, systematic=args.systematic,
                              input_noise=input_noise or None)
    if not args.json:
        sys.stderr.write(f"identify {model.name}: {len(logs)} log(s), {sum(len(lg.t) for lg in logs)} samples, "
                         f"free {', '.join(free)} ...\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # listed in the result and printed below
        fit = identify(logs, model, initial, options, holdout=args.holdout)
    note = (f"fitted by mitigate identify ({fit.status}) from {', '.join(args.logs)}; "
            f"free: {', '.join(free)}; eps = {args.eps} rad/s")
    params = fit.params
    bres = None
    if boot is not None:
        from dataclasses import replace as dc_replace

        from estimators.bootstrap import bootstrap
        if not args.json:
            sys.stderr.write(f"bootstrap: {boot.replicates} replicate logs ...\n")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            bres = bootstrap(fit, logs, options, boot)
        if bres.success:
            params = dc_replace(params, stderr=tuple((n, float(e)) for n, e in zip(fit.names, bres.error)))
            note += (f"; [stderr] is the parametric-bootstrap RMS error sqrt(bias^2 + sd^2) over "
                     f"{bres.replicates.shape[0]} replicates")
    if args.systematic:
        note += ("; [stderr] is the TOTAL error sqrt(SE^2 + syserr^2), syserr = |theta(eps) - theta(eps/2)| "
                 "(regularisation sensitivity), SE statistical")
    out.parent.mkdir(parents=True, exist_ok=True)
    params.save(out, overwrite=args.force, note=note)
    if args.plot:
        _plot(fit, args.plot)
    pub = published(args.model)
    if args.json:
        payload = fit.as_dict()
        payload.update({"out": str(out), "plot": args.plot, "logs": list(args.logs),
                        "input_noise": input_noise, "input_noise_detected": sorted(detected),
                        "published": {n: getattr(pub, n) for n in free},
                        "bootstrap": bres.as_dict() if bres is not None else None})
        emit_json(payload)
    else:
        if bres is not None and bres.success:
            rows = [[n, e, s, b, d, r, getattr(pub, n), fit.params.spec(n).unit]
                    for n, e, s, b, d, r in zip(fit.names, fit.estimate, fit.stderr, bres.bias, bres.sd, bres.error)]
            print(format_table(["parameter", "estimate", "std. error", "boot. bias", "boot. sd", "RMS error",
                                "published", "unit"], rows))
        elif fit.syserr is None:
            rows = [[n, e, s, getattr(pub, n), fit.params.spec(n).unit]
                    for n, e, s in zip(fit.names, fit.estimate, fit.stderr)]
            print(format_table(["parameter", "estimate", "std. error", "published", "unit"], rows))
        else:
            rows = [[n, e, s, y, t, getattr(pub, n), fit.params.spec(n).unit]
                    for n, e, s, y, t in zip(fit.names, fit.estimate, fit.stderr, fit.syserr, fit.error)]
            print(format_table(["parameter", "estimate", "std. error", "syst. error", "total error", "published",
                                "unit"], rows))
        if input_noise:
            units = dict(zip(model.inputs, model.input_units))
            print("errors in the variables: " + ", ".join(
                f"{k} {v:.3g} {units[k]} std" + (" (detected)" if k in detected else "") for k, v in input_noise.items()))
        print(f"status: {fit.status} ({fit.iterations} iterations, {fit.wall_time:.1f} s); NRMSE: "
              + ", ".join(f"{k} {100 * v:.1f} %" for k, v in fit.nrmse.items()))
        if fit.validation is not None:
            v = fit.validation
            print("hold-out (exact plant): NRMSE " + ", ".join(f"{k} {100 * x:.1f} %" for k, x in v.nrmse.items())
                  + f"; stick-slip period {v.period_measured:.3g} s measured vs {v.period_simulated:.3g} s; "
                  f"amplitude {v.amplitude_measured:.3g} vs {v.amplitude_simulated:.3g} rad/s")
        if bres is not None:
            print(f"bootstrap: {bres.status} ({bres.wall_time:.1f} s)"
                  + ("" if bres.success else "; [stderr] keeps the Gauss-Newton standard errors"))
        elif fit.syserr is None:
            print("note: the standard errors are statistical only (quantised encoders, noisy logged inputs and "
                  "the regularised friction bias the estimates by more); --bootstrap 6 gives error bars that "
                  "include that bias")
        for w in fit.warnings:
            print(f"warning: {w}")
        print(f"wrote {out}" + (f" and {args.plot}" if args.plot else ""))
    return 0 if fit.success and (bres is None or bres.success) else 1
