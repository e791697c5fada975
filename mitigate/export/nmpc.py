"""The exported NMPC with its EKF: the layout of its step and the C glue around the two cores.

The glue (``<prefix>.c``) holds the exported defaults (the C cores' configurations, written by
:meth:`models.cbuild.CStruct.c_initialiser` from the workbench's own resolved controller and filter),
applies the runtime parameters in ``create``, and runs one DAQ period per ``step`` exactly as the
workbench's closed loop does (:func:`mitigate.closedloop.run_closed_loop`): the estimator's update
on the inputs sent over the last sample (measured normal forces where their load cells read them),
then, while enabled, the controller every ``[control] every`` samples, its action held in between.
"""

from __future__ import annotations

import numpy as np

from estimators.online.compiled import EKF_CONFIG, ekf_config, ekf_functions
from mitigate.controllers.nmpc.compiled import NMPC_CONFIG, channels_read, nmpc_config
from mitigate.controllers.nmpc.options import WEIGHT_NAMES
from mitigate.export.interface import Interface, Port, c_name, channel_union
from models.errors import ConfigError

__all__ = ["nmpc_interface", "nmpc_glue", "nmpc_functions"]


def _measured_inputs(model) -> list[int]:
    """Inputs the estimator takes as measured (a channel of that name that no encoder writes)."""
    return [j for j, n in enumerate(model.inputs) if n in model.measured and model.sensor_of(n) is not None
            and model.sensor_of(n).kind != "encoder"]


def nmpc_functions(nmpc, ekf) -> list:
    """Every generated function, in one file: the NMPC's stages and forward step, the EKF's."""
    return [nmpc.ocp.evaluator.fn, nmpc.ocp.F] + ekf_functions(ekf)


def nmpc_interface(prefix: str, nmpc, ekf) -> Interface:
    m = nmpc.model
    units = dict(m.output_units())
    em = ekf.em
    chans = channel_union(em.channels, channels_read(nmpc), [m.inputs[j] for j in _measured_inputs(m)])
    ins = [Port(c, units.get(c, ""), doc="DAQ channel (NaN: missing)") for c in chans]
    ins += [Port(f"programme:{n}", units.get(n, ""), doc="the programme's value now") for n in m.inputs]
    if nmpc._torque_drive:
        ins.append(Port("target_speed", "rad/s", doc="the objective body's target speed (torque drive)"))
    ins.append(Port("enable", "-", doc="non-zero: the controller sets its inputs; zero: the programme does"))
    outs = [Port(n, units.get(n, ""), doc="command") for n in nmpc.inputs]
    outs += [Port(f"estimate:{n}", u, doc="the estimator's state") for n, u in zip(em.names, em.units)]
    p = nmpc.params
    names = list(m.param_names)
    pars = [Port(f"rig:{n}", p.spec(n).unit or "", float(p[n]), doc="rig parameter") for n in names]
    w = nmpc.weights
    pars += [Port(f"weight:{n}", "-", float(getattr(w, n)), doc="NMPC cost weight") for n in WEIGHT_NAMES]
    cfg = nmpc.cfg
    sp = "N m" if nmpc._torque_drive else "rad/s"
    if nmpc.drives:
        pars.append(Port("setpoint_band", sp, cfg.setpoint_band, doc="the set-point stays within the programme +- this"))
        pars.append(Port("setpoint_rate", sp + "/s", cfg.setpoint_rate, doc="the set-point's rate limit"))
    for a, n in zip(nmpc.start.acts, nmpc.servos):
        pars += [Port(f"{n}:n_min", "N", float(a.n_min), doc="servo range"),
                 Port(f"{n}:n_max", "N", float(a.n_max), doc="servo range"),
                 Port(f"{n}:rate_max", "N/s", float(a.rate_max), doc="servo rate limit")]
    if nmpc._torque_drive and nmpc.drives:
        pars.append(Port("torque_max", "N m", float(nmpc.context.torque_max), doc="the drive's torque limit"))
    return Interface(prefix, tuple(ins), tuple(outs), tuple(pars))


def _arr(name: str, values, typ: str = "int") -> str:
    vals = list(values)
    body = ", ".join(str(int(v)) if typ == "int" else repr(float(v)) for v in vals) if vals else "0"
    return f"static const {typ} {name}[{max(len(vals), 1)}] = {{{body}}};"


def _strings(name: str, values) -> str:
    body = ", ".join('"' + v.replace('"', "'") + '"' for v in values)
    return f"static const char* const {name}[{max(len(values), 1)}] = {{{body or '0'}}};"


def nmpc_glue(prefix: str, nmpc, ekf, every: int, start_at_rest: bool, funs: str) -> tuple[str, str, Interface]:
    """``(<prefix>.c, <prefix>.h, interface)`` for an NMPC with its EKF."""
    m, em = nmpc.model, ekf.em
    if list(em.p) != list(nmpc.params.vector()):
        raise ConfigError("export: the estimator's and the controller's rig parameters differ; export needs one set")
    itf = nmpc_interface(prefix, nmpc, ekf)
    P = prefix.upper()
    ncfg, ecfg = nmpc_config(nmpc), ekf_config(ekf)
    in_names = [p.name for p in itf.inputs]
    ekf_ch = [in_names.index(c) for c in em.channels]
    nmpc_ch = [in_names.index(c) for c in channels_read(nmpc)]
    meas = _measured_inputs(m)
    meas_in = [in_names.index(m.inputs[j]) if j in meas else -1 for j in range(m.nu)]
    prog_in = [in_names.index(f"programme:{n}") for n in m.inputs]
    target_in = in_names.index("target_speed") if "target_speed" in in_names else -1
    enable_in = in_names.index("enable")
    cmd_input = [m.inputs.index(n) for n in nmpc.inputs]
    load_src = [em.names.index(k) if k in em.names else -1 for k in nmpc.start.load_keys]
    L = nmpc.layout
    n_rig_p = len(em.p)
    # where each runtime parameter goes
    par = [p.name for p in itf.params]
    servo_lag = [float(t) if t > 0 else float(nmpc.cfg.dt) for t in nmpc.spec.taus]
    servo_par = [[par.index(f"{n}:n_min"), par.index(f"{n}:n_max"), par.index(f"{n}:rate_max")] for n in nmpc.servos]
    sb = par.index("setpoint_band") if "setpoint_band" in par else -1
    sr = par.index("setpoint_rate") if "setpoint_rate" in par else -1
    tm = par.index("torque_max") if "torque_max" in par else -1
    fn_stage, fn_fwd = nmpc.ocp.evaluator.fn.name(), nmpc.ocp.F.name()
    efns = ekf_functions(ekf)
    fn_ekf = efns[0].name()
    fn_ode = efns[1].name() if len(efns) > 1 else None
    nv, nu, nxe, ns = L.nv, m.nu, em.nx, L.ns
    defs = "\n".join([
        f"#define NIN {len(itf.inputs)}", f"#define NOUT {len(itf.outputs)}", f"#define NPAR {len(itf.params)}",
        f"#define NU {nu}", f"#define NV {nv}", f"#define NS {max(ns, 1)}", f"#define NSERVO {ns}",
        f"#define NXE {nxe}", f"#define NX {m.nx}", f"#define NLOAD {len(load_src)}",
        f"#define NCE {max(len(ekf_ch), 1)}", f"#define NCN {max(len(nmpc_ch), 1)}", f"#define NRIGP {n_rig_p}",
        f"#define NQ {L.nq}", f"#define Q_P {L.q_p}", f"#define Q_W {L.q_w}", f"#define EVERY {int(every)}",
        f"#define START_AT_REST {int(bool(start_at_rest))}", f"#define U_DRIVE {L.u_drive}",
        f"#define TARGET_IN {target_in}", f"#define ENABLE_IN {enable_in}", f"#define DRIVES {int(nmpc.drives)}",
        f"#define SB_PAR {sb}", f"#define SR_PAR {sr}", f"#define TM_PAR {tm}",
    ])
    tables = "\n".join([
        _arr("ekf_ch", ekf_ch), _arr("nmpc_ch", nmpc_ch), _arr("meas_in", meas_in), _arr("prog_in", prog_in),
        _arr("cmd_input", cmd_input), _arr("load_src", load_src), _arr("servo_par", [x for r in servo_par for x in r]),
        _arr("servo_lag", servo_lag, "double"),
        _arr("param_default", [p.value for p in itf.params], "double"),
        _strings("param_names", [p.name for p in itf.params]), _strings("param_units", [p.unit for p in itf.params]),
        _strings("in_names", in_names), _strings("in_units", [p.unit for p in itf.inputs]),
        _strings("out_names", [p.name for p in itf.outputs]), _strings("out_units", [p.unit for p in itf.outputs]),
    ])
    src = _GLUE.format(P=P, p=prefix, funs=funs, defs=defs, tables=tables,
                       nmpc_default=NMPC_CONFIG.c_initialiser("nmpc_default", ncfg),
                       ekf_default=EKF_CONFIG.c_initialiser("ekf_default", ecfg),
                       stage=f"{funs}_{fn_stage}", fwd=f"{funs}_{fn_fwd}", ekfstep=f"{funs}_{fn_ekf}",
                       ode=f"&{funs}_{fn_ode}" if fn_ode else "NULL")
    hdr = header(prefix, itf, f"NMPC ({', '.join(nmpc.inputs)}) with an EKF on rig {m.name!r}")
    return src, hdr, itf


def header(prefix: str, itf: Interface, what: str) -> str:
    """The public header of an exported controller: the API and the layout of in[], out[], params[]."""
    P = prefix.upper()
    lines = [f"/* {prefix}: {what}.", " * Generated by `mitigate export`; the API is in README.md.", " */",
             f"#ifndef {P}_H", f"#define {P}_H", "", "#ifdef __cplusplus", 'extern "C" {', "#endif", "",
             "#if defined(_WIN32)", f"#define {P}_API __declspec(dllexport)", "#else",
             f'#define {P}_API __attribute__((visibility("default")))', "#endif", "",
             f"/* status of a step */", f"enum {{ {P}_OK = 0, {P}_HOLD = 1, {P}_FALLBACK = 2, {P}_FAILED = 3 }};", ""]
    for title, ports in (("in[]", itf.inputs), ("out[]", itf.outputs), ("params[]", itf.params)):
        tag = {"in[]": "IN", "out[]": "OUT", "params[]": "PAR"}[title]
        lines.append(f"/* {title}: {len(ports)} entries */")
        lines.append(f"#define {P}_N_{tag} {len(ports)}")
        for i, p in enumerate(ports):
            dflt = f", default {p.value!r}" if tag == "PAR" else ""
            lines.append(f"#define {P}_{tag}_{c_name(p.name)} {i}   /* {p.name} [{p.unit or '-'}]{dflt}: {p.doc} */")
        lines.append("")
    lines += [f"typedef struct {prefix} {prefix};", "",
              f"/* a controller with the runtime parameters params[{P}_N_PAR] (NULL: the exported defaults);",
              " * the one allocation: NULL if it fails or a parameter is not finite */",
              f"{P}_API {prefix}* {prefix}_create(const double* params);",
              "/* one DAQ period at time t [s]: the estimator's update, then (while enabled) the controller;",
              f" * returns {P}_OK, {P}_HOLD (the last plan held between OCP intervals), {P}_FALLBACK or {P}_FAILED */",
              f"{P}_API int {prefix}_step({prefix}* s, double t, const double* in, double* out);",
              "/* back to the state after create (estimator prior, no plan) */",
              f"{P}_API void {prefix}_reset({prefix}* s);",
              f"{P}_API void {prefix}_destroy({prefix}* s);",
              "/* wall time of the last OCP solve [s] (0 before the first) and of the last step [s] */",
              f"{P}_API double {prefix}_last_solve_time(const {prefix}* s);",
              f"{P}_API double {prefix}_last_step_time(const {prefix}* s);",
              "/* counts since create/reset: steps, fallbacks (estimator or controller), solver failures */",
              f"{P}_API long {prefix}_count(const {prefix}* s, int which);   /* 0 steps, 1 fallbacks, 2 failures */",
              "/* the layout's names and units, and the exported defaults */",
              f"{P}_API const char* {prefix}_in_name(int i);", f"{P}_API const char* {prefix}_in_unit(int i);",
              f"{P}_API const char* {prefix}_out_name(int i);", f"{P}_API const char* {prefix}_out_unit(int i);",
              f"{P}_API const char* {prefix}_param_name(int i);", f"{P}_API const char* {prefix}_param_unit(int i);",
              f"{P}_API double {prefix}_param_default(int i);", "",
              "#ifdef __cplusplus", "}", "#endif", "#endif", ""]
    return "\n".join(lines)


_GLUE = r"""/* {p}: the exported controller's step (generated by `mitigate export`; see README.md). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "{p}.h"
#include "ss_common.h"
#include "ss_ekf.h"
#include "ss_nmpc.h"
#include "{funs}_funs.h"

{defs}

{nmpc_default}
{ekf_default}
{tables}

struct {p} {{
    ssn_mem* nmpc;
    sse_mem* ekf;
    int started, was_enabled, act_n, act_status;
    long k_ctrl, n_steps, n_fallbacks, n_failures;
    double last_solve, last_step;
    double u_prev[NU], u_est[NU], u[NU], prog[NU], act[NV], ye[NCE], yn[NCN], xe[NX + NLOAD + 1];
}};

{P}_API {p}* {p}_create(const double* params) {{
    const double* par = params ? params : param_default;
    double q0[NQ], lo[NV], hi[NV], rate[NV], nmin[NS], nmax[NS], srate[NS], dg[NS];
    ssn_config nc = nmpc_default;
    sse_config ec = ekf_default;
    size_t s1, s2, head = (sizeof(struct {p}) + 63) / 64 * 64;
    char* block;
    struct {p}* s;
    int i;
    for (i = 0; i < NPAR; i++) if (!isfinite(par[i])) return NULL;
    memcpy(q0, nmpc_default.q0, sizeof(q0));
    for (i = 0; i < NRIGP; i++) q0[Q_P + i] = par[i];
    for (i = 0; i < 8; i++) q0[Q_W + i] = par[NRIGP + i];
    memcpy(lo, nmpc_default.lo, sizeof(lo));
    memcpy(hi, nmpc_default.hi, sizeof(hi));
    memcpy(rate, nmpc_default.rate, sizeof(rate));
    if (SB_PAR >= 0) nc.setpoint_band = par[SB_PAR];
    if (SR_PAR >= 0) rate[0] = par[SR_PAR];
    if (TM_PAR >= 0) nc.torque_max = par[TM_PAR];
    for (i = 0; i < NSERVO; i++) {{
        int j = DRIVES + i;
        nmin[i] = lo[j] = par[servo_par[3 * i]];
        nmax[i] = hi[j] = par[servo_par[3 * i + 1]];
        srate[i] = rate[j] = par[servo_par[3 * i + 2]];
        dg[i] = srate[i] * servo_lag[i];
    }}
    nc.q0 = q0; nc.lo = lo; nc.hi = hi; nc.rate = rate;
    if (NSERVO) {{ nc.servo_nmin = nmin; nc.servo_nmax = nmax; nc.servo_rate = srate; nc.servo_dg = dg; }}
    ec.p = par;
    s1 = ssn_memsize(&nc, &{stage}, &{fwd});
    s2 = sse_memsize(&ec, &{ekfstep}, {ode});
    if (!s1 || !s2) return NULL;
    block = (char*)malloc(head + s1 + s2);
    if (!block) return NULL;
    s = (struct {p}*)block;
    memset(s, 0, sizeof(*s));
    s->nmpc = ssn_init(block + head, s1, &nc, &{stage}, &{fwd});
    s->ekf = sse_init(block + head + s1, s2, &ec, &{ekfstep}, {ode});
    if (!s->nmpc || !s->ekf) {{ free(block); return NULL; }}
    {p}_reset(s);
    return s;
}}

{P}_API void {p}_reset({p}* s) {{
    ssn_reset(s->nmpc);
    sse_reset(s->ekf);
    s->started = s->was_enabled = 0;
    s->act_n = -1;
    s->act_status = {P}_OK;
    s->k_ctrl = s->n_steps = s->n_fallbacks = s->n_failures = 0;
    s->last_solve = s->last_step = 0.0;
}}

{P}_API void {p}_destroy({p}* s) {{ free(s); }}

{P}_API int {p}_step({p}* s, double t, const double* in, double* out) {{
    double t0 = ss_clock();
    const double* x;
    sse_info ei;
    ssn_info ni;
    int j, status = {P}_OK, enabled;
    if (!s->started) {{   /* the inputs over the sample before the first: the programme (at rest: no drive) */
        for (j = 0; j < NU; j++) s->u_prev[j] = in[prog_in[j]];
        if (START_AT_REST) s->u_prev[U_DRIVE] = 0.0;
        s->started = 1;
    }}
    /* the estimator: the inputs sent over the last sample, measured forces where their cells read them */
    for (j = 0; j < NU; j++) {{
        s->u_est[j] = s->u_prev[j];
        if (meas_in[j] >= 0 && isfinite(in[meas_in[j]])) s->u_est[j] = in[meas_in[j]];
    }}
    for (j = 0; j < NCE; j++) s->ye[j] = ekf_ch[j] >= 0 ? in[ekf_ch[j]] : NAN;
    sse_update(s->ekf, s->ye, s->u_est, &ei);
    if (ei.status == SS_FALLBACK) status = {P}_FALLBACK;
    if (ei.failed) s->n_failures++;
    x = sse_x(s->ekf);
    for (j = 0; j < NU; j++) s->u[j] = s->prog[j] = in[prog_in[j]];
    enabled = isfinite(in[ENABLE_IN]) && in[ENABLE_IN] != 0.0;
    if (enabled) {{
        if (!s->was_enabled) {{ ssn_reset(s->nmpc); s->k_ctrl = 0; s->act_n = -1; }}
        if (s->k_ctrl % EVERY == 0) {{
            for (j = 0; j < NX; j++) s->xe[j] = x[j];
            for (j = 0; j < NLOAD; j++) s->xe[NX + j] = load_src[j] >= 0 ? x[load_src[j]] : NAN;
            for (j = 0; j < NCN; j++) s->yn[j] = nmpc_ch[j] >= 0 ? in[nmpc_ch[j]] : NAN;
            ssn_step(s->nmpc, t, s->yn, s->xe, 1, s->prog, TARGET_IN >= 0 ? in[TARGET_IN] : 0.0, 0, s->act, &ni);
            s->act_n = ni.n_u;
            s->act_status = ni.status;
            if (ni.planned && !ni.failure) s->last_solve = ni.solve_time;
            if (ni.failure) s->n_failures++;
        }}
        s->k_ctrl++;
        if (s->act_n > 0) for (j = 0; j < NV; j++) s->u[cmd_input[j]] = s->act[j];
        if (s->act_status == SS_FALLBACK) status = {P}_FALLBACK;
        else if (s->act_status == SS_HOLD && status == {P}_OK) status = {P}_HOLD;
    }}
    s->was_enabled = enabled;
    for (j = 0; j < NU; j++) s->u_prev[j] = s->u[j];
    for (j = 0; j < NV; j++) out[j] = s->u[cmd_input[j]];
    for (j = 0; j < NXE; j++) out[NV + j] = x[j];
    for (j = 0; j < NOUT; j++) if (!isfinite(out[j])) status = {P}_FAILED;
    if (status == {P}_FAILED) for (j = 0; j < NV; j++) out[j] = s->prog[cmd_input[j]];
    if (status == {P}_FALLBACK) s->n_fallbacks++;
    s->n_steps++;
    s->last_step = ss_clock() - t0;
    return status;
}}

{P}_API double {p}_last_solve_time(const {p}* s) {{ return s->last_solve; }}
{P}_API double {p}_last_step_time(const {p}* s) {{ return s->last_step; }}
{P}_API long {p}_count(const {p}* s, int which) {{
    return which == 0 ? s->n_steps : which == 1 ? s->n_fallbacks : which == 2 ? s->n_failures : -1;
}}
{P}_API const char* {p}_in_name(int i) {{ return i >= 0 && i < NIN ? in_names[i] : NULL; }}
{P}_API const char* {p}_in_unit(int i) {{ return i >= 0 && i < NIN ? in_units[i] : NULL; }}
{P}_API const char* {p}_out_name(int i) {{ return i >= 0 && i < NOUT ? out_names[i] : NULL; }}
{P}_API const char* {p}_out_unit(int i) {{ return i >= 0 && i < NOUT ? out_units[i] : NULL; }}
{P}_API const char* {p}_param_name(int i) {{ return i >= 0 && i < NPAR ? param_names[i] : NULL; }}
{P}_API const char* {p}_param_unit(int i) {{ return i >= 0 && i < NPAR ? param_units[i] : NULL; }}
{P}_API double {p}_param_default(int i) {{ return i >= 0 && i < NPAR ? param_default[i] : NAN; }}
"""
