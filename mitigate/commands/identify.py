"""``mitigate identify``: fit a rig's parameters to one or several logs.

Reads CSV logs (:mod:`models.logs`) or LabView TDMS files (``--tdms-map``), fits the ``--free``
parameters of the rig ``--model`` (a shipped name or a rig file) with
:func:`estimators.identify.identify`, prints the estimates with their standard errors, the
conditioning and how the fit ended, and writes the fitted set as a parameter TOML (with
``[stderr]``) that every other command accepts, plus a PNG of measured against fitted outputs.

The library names its own arguments in errors ("options.free", "holdout"); this command
translates them to its flags.  Bad input is one line on stderr and exit code 2; an unconverged
fit exits 1 (its message says why and what to try); nothing is overwritten without ``--force``.
A fit that is the best its model allows but whose residual shows that the model's structure misses
something in the log (a slow residual above the sensors' noise, a dominant residual frequency, gaps
left at the shooting nodes) ends with status WARNING, the line ``best fit within the model (...);
structure misses: ...`` and exit 0.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import warnings
from pathlib import Path

from mitigate.cliutil import add_command, check_outputs, emit_json, format_table, quantity
from models.errors import ConfigError, DataError
from models.files import atomic_path
from models.logs import read_csv
from models.rig import load_params
from models.rig import get_model, shipped_rigs

EPILOG = """examples:
  mitigate identify tests/data/drillstring_stickslip.csv --model drillstring --free k,d,mu_sb,mu_cb --out fitted.toml
      (a 3 s, 1 kHz drill-string log: the starting values come from the data, the torque-on-bit pins
       the friction level; --exclude torque_bit shows what the fit does without it)
  mitigate identify out/open_stick_slip.csv --model rig3 --free k1,k2,d1,d2,mu_k,mu_s,motor_torque_offset \\
      --encoder-zero untwisted --holdout 0.2
  mitigate identify run1.csv run2.csv --model disc --free k,d,mu_k,mu_s --constraint "d <= 0.05" --json
  mitigate identify rig.tdms --tdms-map channels.toml --model my_rigs/four_disc.toml --free k1,k2 --detect-delay 2
  mitigate identify run1.csv --model disc --free k,d,mu_k,mu_s --bootstrap 8 --workers 2   # bootstrap error bars

A twist measured by two incremental encoders is the twist minus its value at power-on: by default
every log gets one unknown per angle difference (--encoder-zero free).  Say --encoder-zero untwisted
when the logs started untwisted (at rest, no preload); without a torque sensor or a varying normal
force that is what fixes the friction level.
"""

#: library argument -> command-line flag (for error messages)
_FLAGS = {
    "free": "--free", "eps": "--eps", "nsub": "--nsub", "shoot_every": "--shoot-every", "max_iter": "--max-iter",
    "input_cutoff": "--input-cutoff", "input_noise": "--input-noise", "outputs": "--outputs", "exclude": "--exclude",
    "constraints": "--constraint", "encoder_zero": "--encoder-zero", "input_row": "--input-row",
    "extra_delay": "--delay", "detect_delay": "--detect-delay", "solver": "--solver", "bounds": "--params [bounds]",
    "systematic_iter": "--systematic", "tol": "--tol", "globalise": "--globalise",
}


def _translate(msg: str) -> str:
    """Library argument names -> flags: "options.eps must ..." -> "--eps must ..."."""
    msg = re.sub(r"\boptions\.(\w+)\.(\w+)", lambda m: f"{_FLAGS.get(m.group(1), '--' + m.group(1))} {m.group(2)}", msg)
    msg = re.sub(r"\boptions\.(\w+)", lambda m: _FLAGS.get(m.group(1), "--" + m.group(1).replace("_", "-")), msg)
    msg = re.sub(r"^holdout\b", "--holdout", msg)
    msg = msg.replace("bootstrap.replicates", "--bootstrap").replace("bootstrap.workers", "--workers")
    return msg.replace("sensors.noise_scale", "--noise-scale")


def register(subparsers) -> None:
    p = add_command(
        subparsers, "identify", help="fit a rig's parameters to logs (multiple shooting, constrained Gauss-Newton)",
        description="Fit the --free parameters of the rig --model (a shipped name or a rig file) to one or several "
                    "logs (shared parameters, separate state nodes and encoder zeros); print the estimates with "
                    "standard errors, the conditioning and how the fit ended; write a parameter TOML and a PNG.",
        epilog=EPILOG)
    p.add_argument("logs", nargs="+", metavar="LOG", help="CSV log(s) in the workbench format, or TDMS files")
    p.add_argument("--model", required=True, metavar="RIG",
                   help=f"rig to fit: a shipped rig ({', '.join(shipped_rigs())}) or the path of a rig file")
    p.add_argument("--free", required=True, metavar="NAMES",
                   help="comma-separated parameters to fit, physical ones or sensor offsets/gains, "
                        "e.g. k1,k2,mu_k,mu_s,motor_torque_offset")
    p.add_argument("--params", metavar="FILE", help="initial/fixed parameter TOML (default: the rig file's values; "
                                                     "its [bounds] are the fitting bounds)")
    p.add_argument("--guess", choices=("auto", "off"), default=None,
                   help="derive starting values of the free parameters from the data (stick-slip cycle, torque "
                        "balance, twist regression): default auto without --params, off with it")
    p.add_argument("--out", default="fitted.toml", metavar="FILE", help="fitted parameter TOML (default: fitted.toml)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--plot", metavar="PNG", help="PNG of measured vs. fitted outputs (default: the --out file "
                                                 "with .png)")
    p.add_argument("--no-plot", action="store_true", help="do not write the PNG")
    p.add_argument("--holdout", type=float, default=0.0, metavar="FRACTION",
                   help="fraction of the end of the logs kept out of the fit; the first log's is predicted with the "
                        "exact stick/slip plant (default 0)")
    p.add_argument("--eps", type=quantity("speed"), default=None, metavar="SPEED",
                   help="friction regularisation, in rad/s or with a unit (\"0.05 rpm\"; default: from the rig, "
                        "0.16 %% of its nominal speed: rig3's 0.005 rad/s at 30 rpm)")
    p.add_argument("--nsub", type=int, default=None,
                   help="RK4 substeps per sample (default: the integration rule: RK4 with substeps from the stiff rate, or "
                        "an implicit step where RK4 would need too many)")
    p.add_argument("--shoot-every", type=int, default=10, metavar="M",
                   help="samples per shooting interval (default 10)")
    p.add_argument("--max-iter", type=int, default=100, metavar="N", help="iteration limit (default 100)")
    p.add_argument("--solver", choices=("gn", "ipopt"), default="gn",
                   help="gn: constrained Gauss-Newton, compiled (default); ipopt: cross-check, slower")
    p.add_argument("--globalise", choices=("auto", "always", "off"), default="auto",
                   help="gn: auto (default) repeats a fit that does not converge, or whose residual shows that the "
                        "model's structure misses, along a continuation in --eps from 10x down and keeps the better "
                        "end; always; off (the direct fit only)")
    p.add_argument("--encoder-zero", choices=("free", "untwisted"), default="free",
                   help="free: one unknown twist at power-on per angle difference and log (default); untwisted: "
                        "the logs started untwisted")
    p.add_argument("--input-row", choices=("end", "start"), default="end",
                   help="end: row k+1 holds the input over [t_k, t_k+1) (our plant's logs, default); start: row k")
    p.add_argument("--outputs", metavar="CHANNELS",
                   help="compared channels, e.g. omega1,motor_torque,theta1-theta2 (default: every sensor channel "
                        "of the rig in the log and the encoder twists)")
    p.add_argument("--exclude", metavar="CHANNELS", default="", help="channels left out of the default outputs")
    p.add_argument("--constraint", action="append", default=[], metavar="'EXPR <= NUM'",
                   help="linear inequality on parameters, e.g. 'k1 - 3 k2 <= 0' (repeatable); mu_k <= mu_s is "
                        "added for every Stribeck-type contact whose levels are both free")
    p.add_argument("--no-order-friction", action="store_true", help="do not add mu_k <= mu_s")
    p.add_argument("--delay", type=int, default=0, metavar="N",
                   help="whole samples added to every sensor's delay (the rig file's), commands not delayed")
    p.add_argument("--detect-delay", type=int, default=0, metavar="N",
                   help="also fit with 0..N extra samples of sensor delay and keep the best (reported)")
    p.add_argument("--input-cutoff", action="append", default=[], metavar="CHANNEL=FREQUENCY",
                   help="zero-phase low-pass of a noisy, slowly varying input before fitting, in Hz or with a "
                        "unit, e.g. n1=0.5 or \"n1=0.5 Hz\"")
    p.add_argument("--input-noise", action="append", default=[], metavar="CHANNEL=STD|auto|off",
                   help="errors in the variables: that logged input is noisy with this std, in the input's SI unit "
                        "or with a unit, e.g. n1=0.2 or \"n1=0.2 N\". Default auto: force/torque inputs whose fast "
                        "part is white noise; off: none")
    p.add_argument("--systematic", action="store_true",
                   help="also refit with the regularisation halved and report |theta(eps) - theta(eps/2)|; "
                        "[stderr] then holds the TOTAL error sqrt(SE^2 + syserr^2)")
    p.add_argument("--bootstrap", type=int, default=0, metavar="B",
                   help="parametric bootstrap with B >= 2 replicate logs from the exact plant with the fitted "
                        "parameters; [stderr] then holds its RMS error sqrt(bias^2 + sd^2)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="processes for the bootstrap fits (default 1)")
    p.add_argument("--noise-scale", type=float, default=1.0, metavar="X",
                   help="bootstrap: scale of the rig file's sensor noise in the replicates (default 1)")
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


def _names(text: str | None) -> tuple[str, ...] | None:
    if text is None:
        return None
    return tuple(s.strip() for s in text.split(",") if s.strip())


def _channel_values(items, flag: str, form: str, kind, **bounds) -> dict[str, float]:
    """``CHANNEL=VALUE`` entries of ``flag``, each value a quantity of ``kind(channel)`` (a number in SI
    or with its unit: :func:`mitigate.cliutil.quantity`; None: an SI number); one-line ConfigError
    otherwise."""
    out = {}
    for item in items:
        name, sep, val = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ConfigError(f"{flag} must look like {form}, got {item!r}")
        try:
            out[name] = quantity(kind(name) or "dimensionless", **bounds)(val.strip())
        except argparse.ArgumentTypeError as exc:
            raise ConfigError(f"{flag} {name}: {exc}") from None
    return out


def _input_noise(items, model):
    """``--input-noise`` entries -> the library's ``input_noise`` ("auto", "off" or a table of stds in
    each input's SI unit)."""
    mode = "auto"
    for item in items:
        if item in ("auto", "off"):
            mode = item
    kinds = dict(zip(model.inputs, model.input_kinds))
    explicit = _channel_values([i for i in items if i not in ("auto", "off")], "--input-noise",
                               "CHANNEL=STD, auto or off (e.g. n1=0.2)", kinds.get, lo=0.0, lo_open=True)
    if explicit:
        return explicit
    return mode


def _plot(fit, path, force: bool):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chans = fit.problem.channels
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.4 * len(chans) + 0.6), sharex=True, squeeze=False)
    for ax, c in zip(axes[:, 0], chans):
        for i, (t, ym, ys) in enumerate(zip(fit.t, fit.measured, fit.simulated)):
            ax.plot(t, ym[c.name], ".", ms=2, color="0.5", label="measured" if i == 0 else None)
            ax.plot(t, ys[c.name], "-", lw=1, color="C0", label="fitted model" if i == 0 else None)
        v = fit.validation
        if v is not None and c.name in v.measured:
            ax.plot(v.t, v.measured[c.name], ".", ms=2, color="0.7", label="held out (measured)")
            ax.plot(v.t, v.simulated[c.name], "-", lw=1, color="C3", label="held out (exact plant)")
        ax.set_ylabel(f"{c.name} [{c.unit}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"identify {fit.model}: measured vs. fitted ({', '.join(fit.names)}; {fit.status.value})")
    fig.tight_layout()
    try:
        with atomic_path(path, overwrite=force) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)


def holdout_line(v, units) -> str:
    """The hold-out's line: NRMSE where the measured signal moves beyond its noise (else the RMS error in
    noise levels), and the stick-slip period only where the measured segment sticks and slips."""
    parts = []
    for k, e in v.rms.items():
        nr = v.nrmse.get(k, math.nan)
        parts.append(f"{k} {100 * nr:.1f} %" if math.isfinite(nr) else f"{k} {e:.2g} noise levels RMS (steady)")
    line = "hold-out (exact plant): NRMSE " + ", ".join(parts)
    if v.stick_slip:
        pred = (f"{v.period_simulated:.3g} s predicted ({v.slips_simulated} slips)" if math.isfinite(v.period_simulated)
                else "none predicted (the prediction does not stick-slip)")
        line += (f"; stick-slip period {v.period_measured:.3g} s measured ({v.slips_measured} slips) vs {pred}; "
                 f"amplitude {v.amplitude_measured:.3g} vs {v.amplitude_simulated:.3g} {units.get(v.channel, '')} "
                 f"({v.channel})")
    else:
        line += f"; no stick-slip period: the held-out {v.channel} shows none ({v.period_note})"
        if math.isfinite(v.period_simulated):
            line += f", the prediction sticks and slips every {v.period_simulated:.3g} s"
    return line


def run(args) -> int:
    try:
        return _run(args)
    except (ConfigError, DataError) as exc:
        raise type(exc)(_translate(str(exc))) from None


def _run(args) -> int:
    from estimators.identify import BootstrapOptions, IdentificationProblem, IdentifyOptions, bootstrap, initial_guess
    from models.sensors import SensorOptions

    model = get_model(args.model)
    free = _names(args.free)
    initial = load_params(args.params, model) if args.params else None
    for n in free:
        model.published().spec(n)  # "unknown parameter 'zz'" with the rig's names
    if isinstance(args.holdout, bool) or not (math.isfinite(args.holdout) and 0 <= args.holdout < 0.9):
        raise ConfigError(f"--holdout must be a fraction in [0, 0.9), got {args.holdout}")
    boot = None
    if args.bootstrap:
        if args.bootstrap < 2:
            raise ConfigError(f"--bootstrap must be an integer >= 2 (replicates), got {args.bootstrap}")
        if args.systematic:
            raise ConfigError("--bootstrap and --systematic are alternatives (the bootstrap's exact-plant "
                              "replicates include the regularisation error); got both")
        boot = BootstrapOptions(replicates=args.bootstrap, sensors=SensorOptions(noise_scale=args.noise_scale),
                                workers=args.workers, progress=(not args.json) and sys.stderr.isatty())
    options = IdentifyOptions(
        free=free, eps=args.eps, nsub=args.nsub, shoot_every=args.shoot_every, max_iter=args.max_iter,
        solver=args.solver, globalise=args.globalise, encoder_zero=args.encoder_zero, input_row=args.input_row, outputs=_names(args.outputs),
        exclude=_names(args.exclude) or (), constraints=tuple(args.constraint),
        order_friction=not args.no_order_friction, extra_delay=args.delay, detect_delay=args.detect_delay,
        input_cutoff=_channel_values(args.input_cutoff, "--input-cutoff", "CHANNEL=FREQUENCY (e.g. n1=0.5)",
                                     lambda _n: "rate") or None,
        input_noise=_input_noise(args.input_noise, model), systematic=args.systematic,
        progress=(not args.json) and sys.stderr.isatty())
    out = Path(args.out)
    plot = None if args.no_plot else (args.plot or str(out.with_suffix(".png")))
    check_outputs([out] + ([Path(plot)] if plot else []), args.force)
    logs = [_read_log(p, args.tdms_map).with_speeds(model) for p in args.logs]    # the rig's encoders say which speeds
    guess = args.guess or ("off" if initial is not None else "auto")
    notes: tuple = ()
    if guess == "auto" and initial is not None:
        g = initial_guess(model, logs, free, initial, encoder_zero=args.encoder_zero)
        initial, notes = g.params, g.notes
    elif guess == "off" and initial is None:
        initial = model.published()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # listed in the result and printed below
        problem = IdentificationProblem(model, logs, initial, options, holdout=args.holdout)  # checks everything
        if not args.json:
            sys.stderr.write(f"identify {model.name}: {len(logs)} log(s), {sum(len(lg.t) for lg in logs)} samples, "
                             f"free {', '.join(free)}, compared {', '.join(c.name for c in problem.channels)} ...\n")
        fit = problem.solve()
    notes = notes or fit.guess_notes
    note = (f"fitted by mitigate identify ({fit.status.value}: {fit.message.split('. Try')[0]}) from "
            f"{', '.join(args.logs)}; free: {', '.join(free)}; eps = {fit.eps:.3g} rad/s"
            f"{'' if fit.eps_source == 'given' else ' (from the rig)'}; encoder zero {args.encoder_zero}")
    params = fit.params
    bres = None
    if boot is not None:
        if not args.json:
            sys.stderr.write(f"bootstrap: {boot.replicates} replicate logs ...\n")
        bres = bootstrap(fit, boot)
        if bres.success:
            params = params.with_meta(stderr=tuple((n, float(e)) for n, e in zip(fit.names, bres.error)))
            note += (f"; [stderr] is the parametric-bootstrap RMS error sqrt(bias^2 + sd^2) over "
                     f"{bres.replicates.shape[0]} replicates")
    if args.systematic:
        note += ("; [stderr] is the TOTAL error sqrt(SE^2 + syserr^2 + phase^2), syserr = |theta(eps) - "
                 "theta(eps/2)| (regularisation sensitivity), phase the encoders' unknown phase within a tick at "
                 "power-on (untwisted), SE statistical")
    params.save(out, overwrite=args.force, note=note)
    if plot:
        _plot(fit, plot, args.force)
    pub = model.published()
    # the rig file's value of each free parameter and where it comes from (a publication only if its source says so)
    sources = {n: pub.spec(n).source for n in free if pub.spec(n).source}
    if args.json:
        payload = fit.as_dict()
        payload.update({"out": str(out), "plot": plot, "logs": list(args.logs), "guess_notes": list(notes),
                        "rig_file": {n: pub[n] for n in free}, "rig_file_sources": sources,
                        "bootstrap": bres.as_dict() if bres is not None else None})
        emit_json(payload)
        return 0 if fit.success and (bres is None or bres.success) else 1
    unit = {n: fit.params.spec(n).unit for n in free}
    if bres is not None and bres.success:
        rows = [[n, e, s, b, d, r, i, pub[n], unit[n]] for n, e, s, b, d, r, i in
                zip(fit.names, fit.estimate, fit.stderr, bres.bias, bres.sd, bres.error, fit.initial)]
        head = ["parameter", "estimate", "std. error", "boot. bias", "boot. sd", "RMS error", "initial", "rig file",
                "unit"]
    elif fit.syserr is None:
        off = fit.offset_error if fit.offset_error is not None else [math.nan] * len(fit.names)
        bias = fit.eps_bias if fit.eps_bias is not None else [math.nan] * len(fit.names)
        rows = [[n, e, s, b, o, t, f"{lo:.4g} .. {hi:.4g}", i, pub[n], unit[n]] for n, e, s, b, o, t, (lo, hi), i in
                zip(fit.names, fit.estimate, fit.stderr, bias, off, fit.error, fit.bounds, fit.initial)]
        head = ["parameter", "estimate", "std. error", "eps bias", "enc. phase", "total error", "95 % interval",
                "initial", "rig file", "unit"]
    else:
        rows = [[n, e, s, y, t, h, i, pub[n], unit[n]] for n, e, s, y, t, h, i in
                zip(fit.names, fit.estimate, fit.stderr, fit.syserr, fit.error, fit.interval, fit.initial)]
        head = ["parameter", "estimate", "std. error", "syst. error", "total error", "95 % +-", "initial", "rig file",
                "unit"]
    print(format_table(head, rows))
    if sources:
        print(f"{model.values_label}: " + "; ".join(f"{n} from {src}" for n, src in sources.items()))
    print(f"status: {fit.status.value}: {fit.message} ({fit.iterations} iterations, {fit.wall_time:.1f} s)")
    print(f"method: {fit.method}")
    print(f"friction regularisation: eps = {fit.eps:.3g} rad/s ({fit.eps_source})")
    print(f"integration: {fit.integration}")
    print("NRMSE: " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in fit.nrmse.items()))
    if fit.structure is not None:
        st = fit.structure
        print("residual: " + ", ".join(f"{k} {st.rms[k]:.2g} ({st.slow_rms[k]:.2g} below {st.cutoff[k]:.3g} Hz)"
                                       for k in st.rms)
              + f" noise levels; largest spectral peak {st.peak_frequency:.3g} Hz ({100 * st.peak_share:.0f} % of "
              f"the {st.channel} residual's energy), lag-1 autocorrelation {st.lag1:.2f}; largest continuity gap "
              f"{st.max_gap:.2g} (scaled)" + (f" at t = {st.gap_time:.4g} s, {st.gap_state}" if st.gap_state else ""))
    if fit.weak_directions:
        w = fit.weak_directions[0]
        print(f"conditioning: condition number {fit.condition:.3g} (relative units); weakest direction {w.text} "
              f"(relative standard error {100 * w.rel_stderr:.2g} % along it)")
    for j, zl in enumerate(fit.encoder_zero):
        if zl:
            print(f"encoder zero, log {j + 1}: " + ", ".join(f"{k} {v:+.4g} rad" for k, v in zl.items())
                  + " (the twist at power-on)")
    if fit.input_noise:
        units = dict(zip(model.inputs, model.input_units))
        print("errors in the variables: " + ", ".join(f"{k} {v:.3g} {units[k]} std" for k, v in fit.input_noise.items()))
    for line in notes:
        print(f"guess: {line}")
    if fit.validation is not None:
        print(holdout_line(fit.validation, {c.name: c.unit for c in fit.problem.channels}))
    if bres is not None:
        print(f"bootstrap: {bres.status.value}: {bres.message} ({bres.wall_time:.1f} s)"
              + ("" if bres.success else "; [stderr] keeps the Gauss-Newton standard errors"))
    elif fit.syserr is None:
        print("note: the total error adds to the statistical one the regularisation's first-order bias (eps bias) "
              "and, with --encoder-zero untwisted, what the encoders' unknown phase within a tick at power-on does "
              "(enc. phase); the 95 % interval takes the phase as the bounded (uniform) error it is; --bootstrap 6 "
              "gives error bars from replicates of the exact plant")
    for w in fit.warnings:
        print(f"warning: {w}")
    print(f"wrote {out}" + (f" and {plot}" if plot else ""))
    return 0 if fit.success and (bres is None or bres.success) else 1
