"""SoftSpeed, Z-Torque, D-OSKIL and the brake as exported kinds: their runtime parameters and the
C adapter around their core (``mitigate/controllers/csrc/ss_laws.c``, the one the workbench runs).

The adapter holds the law's exported configuration (:meth:`models.cbuild.CStruct.c_initialiser` of
``law.c_config()``: every value the workbench's law resolved from the rig), writes the runtime
parameters into it, and hands the core its channels from in[], the target speed (a speed drive's
programmed set-point, a torque drive's ``target_speed``), the programme of its own input, and --
the brake, and D-OSKIL on a body the rig does not measure -- its speeds from the estimate.  A law that does not read the estimate still publishes
it in out[].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from mitigate.controllers.compiled import LAW_CONFIG, LAW_SOURCES
from mitigate.export.glue import KindExport, Layout, c_array, estimator_title
from mitigate.export.interface import Port
from models.cbuild import read_source

__all__ = ["law_export", "RUNTIME"]


@dataclass(frozen=True)
class Runtime:
    """A runtime parameter of a law: its name in params[] (the law's option or derived name), the
    C configuration's field, its unit (the law's ``derived_units`` where it declares one), and when
    the law has it (``config -> bool``)."""

    name: str
    field: str
    unit: str
    doc: str
    when: Callable[[dict], bool] = lambda c: True


def _speed(c: dict) -> bool:
    return not c["torque_drive"]


def _torque(c: dict) -> bool:
    return bool(c["torque_drive"])


_PIPE = (Runtime("tau_acc", "tau_acc", "s", "low-pass of the drive's acceleration and torque"),)

#: each law's runtime parameters (after the rig's)
RUNTIME: dict[str, tuple[Runtime, ...]] = {
    "softspeed": (
        Runtime("Kp", "Kp", "N m s/rad", "the virtual drive's damper (a torque drive: the loop's P gain)"),
        Runtime("Ki", "Ki", "N m/rad", "the virtual drive's integral gain (a torque drive: the loop's)"),
        Runtime("J_v", "J_v", "kg m^2", "the virtual drive's inertia", _speed),
        Runtime("band", "band", "rad/s", "the set-point within the programme +- band (0: the programme's speed)", _speed),
        Runtime("tau_torque", "tau_pipe", "s", "low-pass of the pipe-torque estimate"),
        *_PIPE,
        Runtime("torque_max", "torque_max", "N m", "the drive's torque limit", _torque)),
    "ztorque": (
        Runtime("gain", "gain", "rad/(N m s)", "z / Z: set-point per N m of high-passed pipe torque"),
        Runtime("tau_hp", "tau_hp", "s", "high-pass time constant of the pipe torque"),
        Runtime("tau_lp", "tau_pipe", "s", "low-pass of the pipe-torque estimate"),
        *_PIPE,
        Runtime("band", "band", "rad/s", "the set-point within the programme +- band (0: the programme's speed)", _speed),
        Runtime("Kp", "Kp", "N m s/rad", "the speed loop's P gain", _torque),
        Runtime("Ki", "Ki", "N m/rad", "the speed loop's integral gain", _torque),
        Runtime("torque_max", "torque_max", "N m", "the drive's torque limit", _torque)),
    "doskil": (
        Runtime("gain", "gain", "N s/rad", "k_n: force per rad/s of the body running ahead of the top"),
        Runtime("tau", "tau", "s", "low-pass of the measured speed difference"),
        Runtime("n_min", "n_min", "N", "force range"),
        Runtime("n_max", "n_max", "N", "force range")),
    "brake": (
        Runtime("gain_overspeed", "gain", "N s/rad", "pin force per rad/s above the target speed"),
        Runtime("gain_relative", "gain_relative", "N s/rad",
                "pin force per rad/s above the drive body's speed (> 0 needs that speed's channel)"),
        Runtime("deadband", "deadband", "rad/s", "speed error ignored"),
        Runtime("filter_tau", "tau", "s", "low-pass of the speeds (0: none)"),
        Runtime("n_max", "n_max", "N", "largest pin force")),
}

_TITLES = {"softspeed": "SoftSpeed", "ztorque": "Z-Torque", "doskil": "D-OSKIL", "brake": "the semi-active brake"}


def law_export(law, ekf) -> KindExport:
    """A law (its compiled core's configuration) as an exported kind."""
    m = law.context.model
    config, channels, estimates = law.c_config()
    runtime = [r for r in RUNTIME[law.kind] if r.when(config)]
    units = getattr(law, "derived_units", {})
    params = tuple(Port(r.name, units.get(r.name, r.unit), float(config[r.field]), doc=r.doc) for r in runtime)
    files = read_source("ss_laws.h", "ss_laws.c", folder=LAW_SOURCES)
    files["ss_laws_config.h"] = LAW_CONFIG.header()
    (command,) = law.actuated_inputs()

    def adapter(lay: Layout) -> str:
        est = [lay.states.index(n) if n in lay.states else -1 for n in estimates] + [-1, -1]
        sets = "\n".join(f"    c->{r.field} = par[{lay.params.index(r.name)}];" for r in runtime)
        defs = "\n".join([f"#define NCL {len(channels)}", f"#define LAW_INPUT {m.inputs.index(command)}"])
        tables = "\n".join([c_array("law_ch", [lay.inputs.index(ch) for ch in channels]), c_array("est_src", est[:2])])
        return _ADAPTER.format(defs=defs, tables=tables, sets=sets,
                               law_default=LAW_CONFIG.c_initialiser("law_default", config))

    what = f"{_TITLES[law.kind]} ({command}) with {estimator_title(ekf)} on rig {m.name!r}"
    uses_estimate = (law.kind == "brake" and config["use_estimate"]) or config["est_body"]
    notes = (f"the law's structure: it reads {', '.join(channels)}"
             + (" and the estimate's " + ", ".join(n for n in estimates if n in ekf.em.names) if uses_estimate else "")
             + (", the drive is a torque drive (the law is its speed loop)" if config["torque_drive"] else ""),
             "its derived values not in params[] (from the rig at export): " +
             ", ".join(f"{n} = {v:.4g}" for n, v in law.tuning_values().items() if n not in {r.name for r in runtime})
             if set(law.tuning_values()) - {r.name for r in runtime} else "every derived value is in params[]")
    return KindExport(what=what, commands=(command,), channels=channels,
                      target=law.kind in ("softspeed", "ztorque", "brake"), params=params, functions=(),
                      sources=files, adapter=adapter, qp=False, notes=notes)


_ADAPTER = r"""#include "ss_laws.h"

{defs}

{law_default}
{tables}

typedef ssl_mem ctl_mem;

/* the core's configuration with the runtime parameters */
static void configure(ssl_config* c, const double* par) {{
    *c = law_default;
{sets}
}}

static size_t ctl_size(const double* par) {{
    ssl_config c;
    configure(&c, par);
    return ssl_memsize(&c);
}}

static ctl_mem* ctl_init(void* mem, size_t size, const double* par) {{
    ssl_config c;
    configure(&c, par);
    return ssl_init(mem, size, &c);
}}

static void ctl_reset(ctl_mem* c) {{ ssl_reset(c); }}

static void ctl_call(ctl_mem* c, double t, const double* in, const double* x, const double* prog, double* act,
                     ctl_out* r) {{
    double y[NCL > 0 ? NCL : 1], e[2] = {{0.0, 0.0}}, t0 = ss_clock();
    int j, mask = 0;
    ssl_info li;
    for (j = 0; j < NCL; j++) y[j] = in[law_ch[j]];
    for (j = 0; j < 2; j++) if (est_src[j] >= 0) {{ e[j] = x[est_src[j]]; mask |= 1 << j; }}
    /* the target speed: a torque drive's target_speed, a speed drive's programmed set-point */
    ssl_step(c, t, y, e, mask, TARGET_IN >= 0 ? in[TARGET_IN] : prog[U_DRIVE], prog[LAW_INPUT], act, &li);
    r->n_u = li.n_u;
    r->status = li.status;
    r->failure = li.missing >= 0;
    r->solved = 1;
    r->solve = ss_clock() - t0;
}}
"""
