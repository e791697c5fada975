"""The glue every exported controller shares, and what a controller kind brings to it.

``<prefix>.c`` is one skeleton for every kind: it holds the estimator's exported defaults, applies
the runtime parameters in ``create``, and runs one DAQ period per ``step`` exactly as the
workbench's closed loop does (:func:`mitigate.closedloop.run_closed_loop`): the estimator's update
on the inputs sent over the last sample (measured normal forces where their load cells read them),
then, while enabled, the controller every ``[control] every`` samples, its action held in between;
a controller switched on starts from its reset state, as a workbench run starts it at
``[control] start``.

A kind describes itself in a :class:`KindExport`: the inputs it sets, the channels it reads, its
runtime parameters, its C sources, and a small C adapter (``adapter(layout)``) that includes its
core's header and defines::

    ctl_mem                                  the controller's memory type
    size_t   ctl_size(const double* par)     bytes for the runtime parameters par[] (0: refused)
    ctl_mem* ctl_init(void* mem, size_t size, const double* par)
    void     ctl_reset(ctl_mem* c)
    void     ctl_call(ctl_mem* c, double t, const double* in, const double* x, const double* prog,
                      double* act, ctl_out* r)

(``in``: this period's in[]; ``x``: the estimator's state after its update; ``prog``: the programme
now, the rig's inputs; ``act``: the commands, out[] order; ``r``: entries, status, failure, solve
time).  :mod:`mitigate.export.nmpc` and :mod:`mitigate.export.laws` are the kinds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

from estimators.online.compiled import EKF_CONFIG, MHE_CONFIG, ekf_config, ekf_functions, mhe_config, mhe_functions
from mitigate.export.interface import Interface, Port, c_name, channel_union

__all__ = ["KindExport", "Layout", "glue_source", "header", "measured_inputs", "c_array", "c_strings",
           "estimator_functions", "estimator_sources", "estimator_title", "is_mhe"]


def is_mhe(est) -> bool:
    """Whether ``est`` is an MHE that runs its compiled update (exported as ``ss_mhe.c``); else an EKF."""
    return getattr(est, "_c", None) is not None and hasattr(est, "gn_step")


def estimator_title(est) -> str:
    """``"an EKF"`` or ``"an MHE (window N)"``: the exported estimator in a title."""
    return f"an MHE (window {est.N})" if is_mhe(est) else "an EKF"


def estimator_functions(est) -> list:
    """The estimator's generated Functions: the MHE's (:func:`mhe_functions`, its EKF's included) or
    the EKF's."""
    return mhe_functions(est) if is_mhe(est) else ekf_functions(est)


def estimator_sources(est) -> tuple[str, ...]:
    """The estimator's C files (in ``estimators/online/csrc``)."""
    return ("ss_ekf.h", "ss_ekf.c") + (("ss_mhe.h", "ss_mhe.c") if is_mhe(est) else ())


def _estimator_c(est, funs: str) -> dict[str, str]:
    """The glue's estimator lines: the EKF's core (``sse_*``) or the MHE's (``ssm_*``, its EKF inside)."""
    fns = estimator_functions(est)
    names = [f"&{funs}_{f.name()}" for f in fns]
    if is_mhe(est):
        gn, ar, es = names[:3]
        ode = names[3] if len(names) > 3 else "NULL"
        return dict(
            include='#include "ss_ekf.h"\n#include "ss_mhe.h"',
            defaults=EKF_CONFIG.c_initialiser("ekf_default", ekf_config(est.ekf))
            + MHE_CONFIG.c_initialiser("mhe_default", mhe_config(est)),
            mem="ssm_mem", info="ssm_info",
            cfg="sse_config ec = ekf_default;\n    ssm_config mc = mhe_default;",
            params="ec.p = par;\n    mc.p = par;",
            size=f"ssm_memsize(&mc, &ec, {gn}, {ar}, {es}, {ode})",
            init=f"ssm_init(block + head + s1, s2, &mc, &ec, {gn}, {ar}, {es}, {ode})",
            reset="ssm_reset", update="ssm_update", x="ssm_x")
    es = names[0]
    ode = names[1] if len(names) > 1 else "NULL"
    return dict(include='#include "ss_ekf.h"', defaults=EKF_CONFIG.c_initialiser("ekf_default", ekf_config(est)),
                mem="sse_mem", info="sse_info", cfg="sse_config ec = ekf_default;", params="ec.p = par;",
                size=f"sse_memsize(&ec, {es}, {ode})", init=f"sse_init(block + head + s1, s2, &ec, {es}, {ode})",
                reset="sse_reset", update="sse_update", x="sse_x")


@dataclass(frozen=True)
class Layout:
    """What an adapter indexes into: the names of in[], of params[] and of the estimator's state,
    and the stem of the generated functions' tables (``<funs>_<function name>``)."""

    inputs: tuple[str, ...]
    params: tuple[str, ...]
    states: tuple[str, ...]
    funs: str


@dataclass(frozen=True)
class KindExport:
    """What one controller kind brings to the shared glue (module docstring).

    Attributes
    ----------
    what : one line naming the controller (the header's and the README's title)
    commands : the rig inputs it sets, in out[] order
    channels : the DAQ channels it reads
    target : it reads ``target_speed`` on a torque drive (the scenario's ``[control] speed``)
    params : its runtime parameters (after the rig's), with units and exported defaults
    functions : CasADi Functions it needs generated (besides the estimator's)
    sources : its C files (cores, config headers), by name
    adapter : ``Layout -> C``: the ctl_* definitions
    qp : it links hpipm and blasfeo (vendored)
    notes : what is fixed at export (the README's list)
    """

    what: str
    commands: tuple[str, ...]
    channels: tuple[str, ...]
    target: bool
    params: tuple[Port, ...]
    functions: tuple
    sources: Mapping[str, str]
    adapter: Callable[[Layout], str]
    qp: bool
    notes: tuple[str, ...]


def measured_inputs(model) -> list[int]:
    """Inputs the estimator takes as measured (a channel of that name that no encoder writes)."""
    return [j for j, n in enumerate(model.inputs) if n in model.measured and model.sensor_of(n) is not None
            and model.sensor_of(n).kind != "encoder"]


def c_array(name: str, values, typ: str = "int") -> str:
    vals = list(values)
    body = ", ".join(str(int(v)) if typ == "int" else repr(float(v)) for v in vals) if vals else "0"
    return f"static const {typ} {name}[{max(len(vals), 1)}] = {{{body}}};"


def c_strings(name: str, values) -> str:
    body = ", ".join('"' + v.replace('"', "'") + '"' for v in values)
    return f"static const char* const {name}[{max(len(values), 1)}] = {{{body or '0'}}};"


def interface(prefix: str, kind: KindExport, model, ekf, params) -> Interface:
    """The layout of in[], out[] and params[] (:mod:`mitigate.export.interface`)."""
    m, em = model, ekf.em
    units = dict(m.output_units())
    chans = channel_union(em.channels, kind.channels, [m.inputs[j] for j in measured_inputs(m)])
    ins = [Port(c, units.get(c, ""), doc="DAQ channel (NaN: missing)") for c in chans]
    ins += [Port(f"programme:{n}", units.get(n, ""), doc="the programme's value now") for n in m.inputs]
    if kind.target and not m.drive.sets_speed:
        ins.append(Port("target_speed", "rad/s", doc="the objective body's target speed (torque drive)"))
    ins.append(Port("enable", "-", doc="non-zero: the controller sets its inputs; zero: the programme does"))
    outs = [Port(n, units.get(n, ""), doc="command") for n in kind.commands]
    outs += [Port(f"estimate:{n}", u, doc="the estimator's state") for n, u in zip(em.names, em.units)]
    pars = [Port(f"rig:{n}", params.spec(n).unit or "", float(params[n]), doc="rig parameter") for n in m.param_names]
    return Interface(prefix, tuple(ins), tuple(outs), tuple(pars) + tuple(kind.params))


def glue_source(prefix: str, kind: KindExport, model, params, ekf, every: int, start_at_rest: bool,
                funs: str) -> tuple[str, str, Interface]:
    """``(<prefix>.c, <prefix>.h, interface)`` of ``kind`` with its EKF on ``model`` with its
    nominal ``params``."""
    m, em = model, ekf.em
    itf = interface(prefix, kind, m, ekf, params)
    in_names = [p.name for p in itf.inputs]
    meas = measured_inputs(m)
    ekf_ch = [in_names.index(c) for c in em.channels]
    defs = "\n".join([
        f"#define NIN {len(itf.inputs)}", f"#define NOUT {len(itf.outputs)}", f"#define NPAR {len(itf.params)}",
        f"#define NU {m.nu}", f"#define NV {len(kind.commands)}", f"#define NXE {em.nx}",
        f"#define NCE {max(len(ekf_ch), 1)}", f"#define NRIGP {len(em.p)}", f"#define EVERY {int(every)}",
        f"#define START_AT_REST {int(bool(start_at_rest))}", f"#define U_DRIVE {m.inputs.index(m.drive_input)}",
        f"#define TARGET_IN {in_names.index('target_speed') if 'target_speed' in in_names else -1}",
        f"#define ENABLE_IN {in_names.index('enable')}",
    ])
    tables = "\n".join([
        c_array("ekf_ch", ekf_ch), c_array("meas_in", [in_names.index(m.inputs[j]) if j in meas else -1
                                                         for j in range(m.nu)]),
        c_array("prog_in", [in_names.index(f"programme:{n}") for n in m.inputs]),
        c_array("cmd_input", [m.inputs.index(n) for n in kind.commands]),
        c_array("param_default", [p.value for p in itf.params], "double"),
        c_strings("param_names", [p.name for p in itf.params]), c_strings("param_units", [p.unit for p in itf.params]),
        c_strings("in_names", in_names), c_strings("in_units", [p.unit for p in itf.inputs]),
        c_strings("out_names", [p.name for p in itf.outputs]), c_strings("out_units", [p.unit for p in itf.outputs]),
    ])
    layout = Layout(tuple(in_names), tuple(p.name for p in itf.params), tuple(em.names), funs)
    e = _estimator_c(ekf, funs)
    src = _GLUE.format(P=prefix.upper(), p=prefix, funs=funs, defs=defs, tables=tables, adapter=kind.adapter(layout),
                       **{f"est_{k}": v for k, v in e.items()})
    return src, header(prefix, itf, kind.what), itf


def header(prefix: str, itf: Interface, what: str) -> str:
    """The public header of an exported controller: the API and the layout of in[], out[], params[]."""
    P = prefix.upper()
    lines = [f"/* {prefix}: {what}.", " * Generated by `mitigate export`; the API is in README.md.", " */",
             f"#ifndef {P}_H", f"#define {P}_H", "", "#ifdef __cplusplus", 'extern "C" {', "#endif", "",
             "#if defined(_WIN32)", f"#define {P}_API __declspec(dllexport)", "#else",
             f'#define {P}_API __attribute__((visibility("default")))', "#endif", "",
             "/* status of a step */", f"enum {{ {P}_OK = 0, {P}_HOLD = 1, {P}_FALLBACK = 2, {P}_FAILED = 3 }};", ""]
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
              " * the one allocation: NULL if it fails or a parameter is not finite or refused */",
              f"{P}_API {prefix}* {prefix}_create(const double* params);",
              "/* one DAQ period at time t [s]: the estimator's update, then (while enabled) the controller;",
              f" * returns {P}_OK, {P}_HOLD (a multi-rate controller held its last action), {P}_FALLBACK or {P}_FAILED */",
              f"{P}_API int {prefix}_step({prefix}* s, double t, const double* in, double* out);",
              "/* back to the state after create (estimator prior, the controller's reset state) */",
              f"{P}_API void {prefix}_reset({prefix}* s);",
              f"{P}_API void {prefix}_destroy({prefix}* s);",
              "/* wall time of the controller's last solve [s] (0 before the first) and of the last step [s] */",
              f"{P}_API double {prefix}_last_solve_time(const {prefix}* s);",
              f"{P}_API double {prefix}_last_step_time(const {prefix}* s);",
              "/* counts since create/reset: steps, fallbacks (estimator or controller), failures */",
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
{est_include}
#include "{funs}_funs.h"

{defs}

{est_defaults}
{tables}

/* what one controller call did */
typedef struct {{
    int n_u;        /* entries of act (0: the programme acts) */
    int status;     /* SS_OK, SS_HOLD or SS_FALLBACK */
    int failure;    /* a failure was answered by the fallback (counted) */
    int solved;     /* solve holds the wall time of a solve this call */
    double solve;   /* [s] */
}} ctl_out;

/* ---- the controller's adapter (mitigate/export/glue.py: ctl_size, ctl_init, ctl_reset, ctl_call) ---- */
{adapter}
/* ---- the shared step ---- */

struct {p} {{
    ctl_mem* ctl;
    {est_mem}* est;
    int started, was_enabled, act_n, act_status;
    long k_ctrl, n_steps, n_fallbacks, n_failures;
    double last_solve, last_step;
    double u_prev[NU], u_est[NU], u[NU], prog[NU], act[NV + 1], ye[NCE];
}};

{P}_API {p}* {p}_create(const double* params) {{
    const double* par = params ? params : param_default;
    {est_cfg}
    size_t s1, s2, head = (sizeof(struct {p}) + 63) / 64 * 64;
    char* block;
    struct {p}* s;
    int i;
    for (i = 0; i < NPAR; i++) if (!isfinite(par[i])) return NULL;
    {est_params}
    s1 = ctl_size(par);
    s2 = {est_size};
    if (!s1 || !s2) return NULL;
    block = (char*)malloc(head + s1 + s2);
    if (!block) return NULL;
    s = (struct {p}*)block;
    memset(s, 0, sizeof(*s));
    s->ctl = ctl_init(block + head, s1, par);
    s->est = {est_init};
    if (!s->ctl || !s->est) {{ free(block); return NULL; }}
    {p}_reset(s);
    return s;
}}

{P}_API void {p}_reset({p}* s) {{
    ctl_reset(s->ctl);
    {est_reset}(s->est);
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
    {est_info} ei;
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
    {est_update}(s->est, s->ye, s->u_est, &ei);
    if (ei.status == SS_FALLBACK) status = {P}_FALLBACK;
    if (ei.failed) s->n_failures++;
    x = {est_x}(s->est);
    for (j = 0; j < NU; j++) s->u[j] = s->prog[j] = in[prog_in[j]];
    enabled = isfinite(in[ENABLE_IN]) && in[ENABLE_IN] != 0.0;
    if (enabled) {{
        if (!s->was_enabled) {{ ctl_reset(s->ctl); s->k_ctrl = 0; s->act_n = -1; }}
        if (s->k_ctrl % EVERY == 0) {{
            ctl_out r = {{0, SS_OK, 0, 0, 0.0}};
            ctl_call(s->ctl, t, in, x, s->prog, s->act, &r);
            s->act_n = r.n_u;
            s->act_status = r.status;
            if (r.solved) s->last_solve = r.solve;
            if (r.failure) s->n_failures++;
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
