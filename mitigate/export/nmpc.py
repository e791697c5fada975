"""The NMPC as an exported kind: its runtime parameters and the C adapter around its core.

The adapter (:mod:`mitigate.export.glue`) holds the NMPC's exported defaults (the C core's
configuration, written by :meth:`models.cbuild.CStruct.c_initialiser` from the workbench's own
resolved controller), applies the runtime parameters (the rig's, the cost's weights, the set-point's
band and rate, the servos' force band, ranges and rates, a torque drive's limit) and hands the core the
estimate in its canonical layout (the rig's states, then the load factors the estimator has).
"""

from __future__ import annotations

from mitigate.controllers.nmpc.compiled import NMPC_CONFIG, NMPC_SOURCES, channels_read, nmpc_config
from mitigate.controllers.nmpc.options import WEIGHT_NAMES
from mitigate.export.glue import KindExport, Layout, c_array, estimator_title
from mitigate.export.interface import Port
from models.cbuild import read_source

__all__ = ["nmpc_export"]


def _params(nmpc) -> tuple[Port, ...]:
    """The NMPC's runtime parameters after the rig's: weights, set-point band and rate, servos, torque limit."""
    w = nmpc.weights
    pars = [Port(f"weight:{n}", "-", float(getattr(w, n)), doc="NMPC cost weight") for n in WEIGHT_NAMES]
    cfg = nmpc.cfg
    drive = nmpc.model.drive
    if nmpc.drives:
        pars.append(Port("setpoint_band", drive.unit, cfg.setpoint_band, doc="the set-point stays within the programme +- this"))
        pars.append(Port("setpoint_rate", drive.rate_unit, cfg.setpoint_rate, doc="the set-point's rate limit"))
    if nmpc.servos:
        pars += [Port("force_band_low", "-", nmpc.force_band[0],
                      doc="a servo force with a positive programme stays above this x programme"),
                 Port("force_band_high", "-", nmpc.force_band[1],
                      doc="a servo force with a positive programme stays below this x programme"),
                 Port("force_window", "s", nmpc.force_window,
                      doc="the band holds the mean force over every window this long (0: every command)")]
    for a, n in zip(nmpc.start.acts, nmpc.servos):
        pars += [Port(f"{n}:n_min", "N", float(a.n_min), doc="servo range"),
                 Port(f"{n}:n_max", "N", float(a.n_max), doc="servo range"),
                 Port(f"{n}:rate_max", "N/s", float(a.rate_max), doc="servo rate limit")]
    if drive.reverses and nmpc.drives:
        pars.append(Port("torque_max", "N m", float(nmpc.context.torque_max), doc="the drive's torque limit"))
    return tuple(pars)


def nmpc_export(nmpc, ekf) -> KindExport:
    """The NMPC (any input set) as an exported kind."""
    m, L = nmpc.model, nmpc.layout
    files = read_source("ss_nmpc.h", "ss_nmpc.c", folder=NMPC_SOURCES)
    files["ss_nmpc_config.h"] = NMPC_CONFIG.header()
    ctrl = nmpc

    def adapter(lay: Layout) -> str:
        par = list(lay.params)
        servo_par = [[par.index(f"{n}:n_min"), par.index(f"{n}:n_max"), par.index(f"{n}:rate_max")] for n in ctrl.servos]
        defs = "\n".join([
            f"#define NX {m.nx}", f"#define NLOAD {len(ctrl.start.load_keys)}", f"#define NCN {max(len(channels_read(ctrl)), 1)}",
            f"#define NQ {L.nq}", f"#define Q_P {L.q_p}", f"#define Q_W {L.q_w}", f"#define NW {len(WEIGHT_NAMES)}",
            f"#define NS {max(L.ns, 1)}", f"#define NSERVO {L.ns}", f"#define DRIVES {int(ctrl.drives)}",
            f"#define W_PAR {par.index('weight:' + WEIGHT_NAMES[0])}",
            f"#define SB_PAR {par.index('setpoint_band') if 'setpoint_band' in par else -1}",
            f"#define SR_PAR {par.index('setpoint_rate') if 'setpoint_rate' in par else -1}",
            f"#define TM_PAR {par.index('torque_max') if 'torque_max' in par else -1}",
            f"#define FB_PAR {par.index('force_band_low') if 'force_band_low' in par else -1}",
        ])
        tables = "\n".join([
            c_array("nmpc_ch", [lay.inputs.index(c) for c in channels_read(ctrl)]),
            c_array("load_src", [lay.states.index(k) if k in lay.states else -1 for k in ctrl.start.load_keys]),
            c_array("servo_par", [x for r in servo_par for x in r]),
            c_array("servo_lag", [float(t) if t > 0 else float(ctrl.cfg.dt) for t in ctrl.spec.taus], "double"),
        ])
        return _ADAPTER.format(defs=defs, tables=tables, nmpc_default=NMPC_CONFIG.c_initialiser("nmpc_default", nmpc_config(ctrl)),
                               stage=f"{lay.funs}_{ctrl.ocp.evaluator.fn.name()}", fwd=f"{lay.funs}_{ctrl.ocp.F.name()}")

    notes = (f"the OCP: horizon {nmpc.spec.horizon}, interval {nmpc.cfg.dt:g} s, {nmpc.nsub} RK4 substeps, friction "
             f"regularisation {nmpc.cfg.eps:.4g} rad/s, inputs {', '.join(nmpc.inputs)}",
             f"the supervision: stick-slip period {nmpc.stick_slip_period:.4g} s, hold gain {nmpc.cfg.hold_gain:g}, "
             f"speed trim {nmpc.supervisor.trim_tau:.4g} s, force filter {nmpc.cfg.force_filter:.4g} s",
             "the cost's scales (the nominal speed, the servos' n_max at export)")
    return KindExport(what=f"the NMPC ({', '.join(nmpc.inputs)}) with {estimator_title(ekf)} on rig {m.name!r}",
                      commands=tuple(nmpc.inputs), channels=channels_read(nmpc), target=True, params=_params(nmpc),
                      functions=(nmpc.ocp.evaluator.fn, nmpc.ocp.F), sources=files, adapter=adapter, qp=True,
                      notes=notes)


_ADAPTER = r"""#include "ss_nmpc.h"

{defs}

{nmpc_default}
{tables}

typedef ssn_mem ctl_mem;

/* the core's configuration with the runtime parameters (the arrays it points to live here) */
typedef struct {{
    ssn_config c;
    double q0[NQ], lo[NV], hi[NV], rate[NV], nmin[NS], nmax[NS], srate[NS], dg[NS];
}} nmpc_setup;

static void configure(nmpc_setup* b, const double* par) {{
    int i;
    b->c = nmpc_default;
    memcpy(b->q0, nmpc_default.q0, sizeof(b->q0));
    for (i = 0; i < NRIGP; i++) b->q0[Q_P + i] = par[i];
    for (i = 0; i < NW; i++) b->q0[Q_W + i] = par[W_PAR + i];
    memcpy(b->lo, nmpc_default.lo, sizeof(b->lo));
    memcpy(b->hi, nmpc_default.hi, sizeof(b->hi));
    memcpy(b->rate, nmpc_default.rate, sizeof(b->rate));
    if (SB_PAR >= 0) b->c.setpoint_band = par[SB_PAR];
    if (SR_PAR >= 0) b->rate[0] = par[SR_PAR];
    if (TM_PAR >= 0) b->c.torque_max = par[TM_PAR];
    if (FB_PAR >= 0) {{
        b->c.force_lo = par[FB_PAR]; b->c.force_hi = par[FB_PAR + 1];
        b->c.force_n = par[FB_PAR + 2] > 0 ? (int)ss_round(par[FB_PAR + 2] / b->c.dt_daq) : 0;
        if (par[FB_PAR + 2] > 0 && b->c.force_n < 1) b->c.force_n = 1;
    }}
    for (i = 0; i < NSERVO; i++) {{
        int j = DRIVES + i;
        b->nmin[i] = b->lo[j] = par[servo_par[3 * i]];
        b->nmax[i] = b->hi[j] = par[servo_par[3 * i + 1]];
        b->srate[i] = b->rate[j] = par[servo_par[3 * i + 2]];
        b->dg[i] = b->srate[i] * servo_lag[i];
    }}
    b->c.q0 = b->q0; b->c.lo = b->lo; b->c.hi = b->hi; b->c.rate = b->rate;
    if (NSERVO) {{ b->c.servo_nmin = b->nmin; b->c.servo_nmax = b->nmax; b->c.servo_rate = b->srate; b->c.servo_dg = b->dg; }}
}}

static size_t ctl_size(const double* par) {{
    nmpc_setup b;
    configure(&b, par);
    return ssn_memsize(&b.c, &{stage}, &{fwd});
}}

static ctl_mem* ctl_init(void* mem, size_t size, const double* par) {{
    nmpc_setup b;
    configure(&b, par);
    return ssn_init(mem, size, &b.c, &{stage}, &{fwd});
}}

static void ctl_reset(ctl_mem* c) {{ ssn_reset(c); }}

static void ctl_call(ctl_mem* c, double t, const double* in, const double* x, const double* prog, double* act,
                     ctl_out* r) {{
    double xe[NX + NLOAD + 1], yn[NCN];
    ssn_info ni;
    int j;
    for (j = 0; j < NX; j++) xe[j] = x[j];
    for (j = 0; j < NLOAD; j++) xe[NX + j] = load_src[j] >= 0 ? x[load_src[j]] : NAN;
    for (j = 0; j < NCN; j++) yn[j] = nmpc_ch[j] >= 0 ? in[nmpc_ch[j]] : NAN;
    ssn_step(c, t, yn, xe, 1, prog, TARGET_IN >= 0 ? in[TARGET_IN] : 0.0, 0, act, &ni);
    r->n_u = ni.n_u;
    r->status = ni.status;
    r->failure = ni.failure != 0;
    r->solved = ni.planned && !ni.failure;
    r->solve = ni.solve_time;
}}
"""
