"""``mitigate modal``: natural frequencies, damping and mode shapes vs the thesis' measured modes."""

from __future__ import annotations

import contextlib
import math

import numpy as np

from mitigate.cliutil import add_command, add_common, emit_json, format_table, quantity, savefig_atomic
from models.files import check_output_dir, output_set
from models.errors import ConfigError
from models.modal import VARIANTS, compare_measured, modes
from models.stability import map_axis, stability_map
from models.rig import load_params
from models.rig import get_model, shipped_rigs

EPILOG = """examples:
  mitigate modal                                 # rig3, all variants, the rig file's values (printed)
  mitigate modal --out out/                      # ... and the mode-shape and stability-map PNGs
  mitigate modal --variant closed --load 20 --omega "30 rpm" --json
  mitigate modal --params fitted.toml --variant free --out out/ --force
  mitigate modal --model models/rigs/four_disc.toml --json
  mitigate modal --model disc --variant closed --load 20

The stability map (with --out) spans the rig's actuated normal-force input over its actuator's
rated range (a servo's n_min..n_max; rig3: the servo pin n2, 0-40 N; --map-input for another) and
0.15-2 times the operating speed; the output says which input and range it used, and whether
that input changes the stability of sliding at all.

Variants: free = mechanical chain (thesis eq. 3-3 + shaft damping, rigid-body 0 Hz mode);
clamped = the drive body held as well; closed = full model with the drive (DC motor + PI
loop) and friction, linearised at steady sliding at --omega with the first contact's normal force
= --load (defaults: the rig file's operating point; rig3: 30 rpm, N1 = 20 N). Quantities are SI
numbers or values with a unit, as in rig files: --omega "30 rpm", --load "0.8 kN".
"""


def register(subparsers) -> None:
    p = add_command(
        subparsers, "modal", help="torsional modes (free / clamped / closed loop) vs the measured 0, 0.396, 1.781 Hz",
        description="Linearised modal analysis of a rig: mode table (model vs measured, error %), PNG of the "
                    "mode shapes and of the stability of steady sliding over (normal force, speed).",
        epilog=EPILOG)
    p.add_argument("--params", metavar="FILE", help="parameter TOML (e.g. fitted by mitigate identify); default: "
                                                    "the rig file's values")
    p.add_argument("--model", default="rig3", metavar="RIG",
                   help=f"a shipped rig ({', '.join(shipped_rigs())}) or a rig file path (default: rig3)")
    p.add_argument("--variant", default="all", choices=(*VARIANTS, "all"), help="variant (default: all)")
    p.add_argument("--load", type=quantity("force", lo=0.0), default=None, metavar="FORCE",
                   help="normal force of the first contact's input at the sliding point, in N or with a unit "
                        "(\"0.8 kN\"; rig3: N1; default: the rig file's operating point)")
    p.add_argument("--omega", type=quantity("speed"), default=None, metavar="SPEED",
                   help="sliding speed, output side, in rad/s or with a unit (\"30 rpm\"; default: the rig file's "
                        "operating point; rig3 30 rpm)")
    p.add_argument("--no-map", action="store_true", help="skip the stability map PNG")
    p.add_argument("--map-input", default=None, metavar="INPUT",
                   help="the normal-force input on the stability map's force axis (default: the rig's actuated one, "
                        "a servo's, over its rated range n_min..n_max)")
    add_common(p, out=False)
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write the mode-shape and stability-map PNGs into DIR (default: print only, write nothing)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def _plot_shapes(results, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4.5 * len(results), 4.2), squeeze=False)
    for ax, r in zip(axes[0], results):
        x = np.arange(len(r.dof_names))
        for f, z, osc, s in zip(r.freq_hz, r.damping, r.oscillatory, r.shapes):
            if f > 20 and r.variant == "closed":  # electrical / PI mode: its shape is not torsional
                continue
            label = "rigid body (0 Hz)" if f == 0 else f"{f:.3f} Hz, zeta {z:.3f}" + ("" if osc else " (real)")
            ax.plot(x, s, marker="o", label=label)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xticks(x, [d.replace("theta_", "").replace("omega_", "") for d in r.dof_names], fontsize=8)
        ax.set_ylabel("normalised amplitude [-]")
        ax.set_title(f"{r.model}: {r.variant}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    try:
        savefig_atomic(fig, path)
    finally:
        plt.close(fig)


def _plot_map(n1, om, M, path, title, load_name):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.8))
    lim = float(np.nanmax(np.abs(M))) or 1.0
    pc = ax.pcolormesh(om * 60 / (2 * math.pi), n1, M, cmap="RdBu_r", vmin=-lim, vmax=lim, shading="nearest")
    ax.contour(om * 60 / (2 * math.pi), n1, M, levels=[0.0], colors="k", linewidths=1.5)
    fig.colorbar(pc, ax=ax, label="largest real part of eigenvalues [1/s]")
    ax.set_xlabel("sliding speed [rpm, output side]")
    ax.set_ylabel(f"{load_name} [N]")
    ax.set_title(title + "\n(red, above/left of the black zero line: steady sliding unstable -> stick-slip)")
    fig.tight_layout()
    try:
        savefig_atomic(fig, path)
    finally:
        plt.close(fig)


def run(args) -> int:
    model = get_model(args.model)
    params = load_params(args.params, model) if args.params else model.published()
    variants = list(VARIANTS) if args.variant == "all" else [args.variant]
    out = check_output_dir(args.out) if args.out is not None else None
    loads = [n for n, k in zip(model.inputs, model.input_kinds) if k == "force"]
    do_map = out is not None and (not args.no_map) and model.drive.sets_speed and bool(loads)
    axis = None
    if do_map or args.map_input is not None:
        try:
            axis = map_axis(model, params, args.map_input)      # refused before anything is written
        except ConfigError as exc:
            raise ConfigError(str(exc).replace("the stability map's input", "--map-input", 1)) from None
    with contextlib.ExitStack() as stack:
        w = None
        if out is not None:
            shapes_png = out / f"modal_{model.cname}.png"
            map_png = out / f"stability_map_{model.cname}.png"
            w = stack.enter_context(output_set(out, [shapes_png.name] + ([map_png.name] if do_map else []),
                                               force=args.force))
        payload, lines = _analyse(args, model, params, variants, out, w, do_map, axis)
    if args.json:
        emit_json(payload)
    else:
        measured = model.spec.extra.get("measured_modes_hz", ())
        print(f"modal analysis of {model.name} ({args.params or model.values_label})"
              + (f"; measured: {', '.join(f'{f:g}' for f in measured)} Hz" if measured else ""))
        print("\n".join(lines))
        if do_map:
            print("\n" + payload["stability_map"]["text"])
        if out is not None:
            print(f"\nwrote {payload['png']}" + (f" and {payload['stability_map']['png']}" if do_map else ""))
    return 0


def _analyse(args, model, params, variants, out, w, do_map, axis):
    """The modes (and, with ``w``, the PNGs written into the output set): ``(payload, lines)``."""

    results = [modes(model, params, v, omega=args.omega, load=args.load) for v in variants]
    measured = model.spec.extra.get("measured_modes_hz", ())
    payload = {"model": model.name, "rig": model.key, "params": args.params or model.values_label,
               "measured_hz": list(measured), "variants": {}}
    lines = []
    for r in results:
        cmp = compare_measured(r)
        payload["variants"][r.variant] = {
            **r.as_dict(), "stable": bool(r.max_real < 0),
            "comparison": [{"mode": c[0], "model_hz": c[1], "measured_hz": c[2], "error_percent": c[3]} for c in cmp],
        }
        lines.append(f"\n{model.name} / {r.variant}: all modes (max real part {r.max_real:+.4g} 1/s, "
                     f"{'stable' if r.max_real < 0 else 'UNSTABLE'}; {r.message})")
        lines.append(format_table(["f_n [Hz]", "f_d [Hz]", "zeta [-]", "kind", "shape on " + ",".join(r.dof_names)],
                                  [[f, fd, z, "oscillatory" if o else ("rigid" if f == 0 else "real"),
                                    "[" + ", ".join(f"{v:+.3f}" for v in s) + "]"]
                                   for f, fd, z, o, s in zip(r.freq_hz, r.damped_hz, r.damping, r.oscillatory,
                                                             r.shapes)]))
        if cmp:
            lines.append(format_table(["mode", "model [Hz]", "measured [Hz]", "error [%]"],
                                      [list(c) for c in cmp]))
    if w is not None:
        _plot_shapes(results, w.path(f"modal_{model.cname}.png"),
                     f"Mode shapes of {model.name} ({args.params or model.values_label})")
        payload["png"] = str(w.final(f"modal_{model.cname}.png"))
    if do_map:
        from models.modal import operating_point
        u_op, _ = operating_point(model, params)
        w_op = float(u_op[model.inputs.index(model.drive_input)])
        if w_op == 0:
            raise ConfigError(f"rig {model.name!r}: its operating point's speed is 0 rad/s; the stability map spans "
                              "0.15-2 times a non-zero one (give [rig] operating_point)")
        n1 = np.linspace(axis.lo, axis.hi, 21)
        om = np.linspace(0.15 * w_op, 2.0 * w_op, 23)   # >= 10 eps: the regularisation does not set the slope
        M = stability_map(model, params, n1, om, input=axis.input)
        name = f"stability_map_{model.cname}.png"
        _plot_map(n1, om, M, w.path(name), f"Stability of steady sliding, {model.name}", axis.input)
        # does the input change the stability at all? A Coulomb contact's force does not: its friction does
        # not fall with speed, so the slope, and the linearisation, do not depend on it (only the
        # regularisation's tail does: 0.00014 1/s on a caliper bench whose map spans +-1.5 1/s)
        spread = float(np.max(np.ptp(M, axis=0)))
        inert = spread <= 1e-3 * float(np.max(np.abs(M)))
        rpm = 60 / (2 * math.pi)
        text = (f"stability map: {axis.input} over {axis.lo:g}-{axis.hi:g} N ({axis.source}) x {model.drive_input} "
                f"over {om[0]:.4g}-{om[-1]:.4g} rad/s ({om[0] * rpm:.3g}-{om[-1] * rpm:.3g} rpm, 0.15-2 x the operating "
                f"point); steady sliding is unstable at {int(np.sum(M > 0))} of {M.size} points"
                + (f"; {axis.input} does not change the stability of sliding over this range (largest change of the "
                   f"real part {spread:.2g} 1/s)" if inert else ""))
        payload["stability_map"] = {"png": str(w.final(name)), "load": axis.input, "range": [axis.lo, axis.hi],
                                    "range_source": axis.source, "values": n1, "omega": om, "max_real": M,
                                    "load_changes_stability": not inert, "text": text}
    return payload, lines
