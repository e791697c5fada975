/* The EKF's update in C (ss_ekf.h); the reference is estimators/online/ekf.py (EKF._update_impl,
 * _initial_speeds, _delayed_zeros, _push_input, _fallback), checked against it call by call. */
#include "ss_ekf.h"

#include <math.h>
#include <string.h>

#define ALIGN SS_BLOCK_ALIGN

struct sse_mem {
    sse_config c;
    ss_call step, ode;
    int has_ode;
    int started;       /* the first sample has been processed */
    double *x, *P, *xn, *Pn, *uh, *ym, *mask, *rate;
    double *x0_used;
};

#define COPY_ARR(b, m, cfg, f, T, n) do { T* d_ = (T*)ss_take((b), sizeof(T) * (size_t)((n) > 0 ? (n) : 1)); \
    if (d_) { memcpy(d_, (cfg)->f, sizeof(T) * (size_t)(n)); (m)->c.f = d_; } } while (0)
#define D(f, n) do { double* t_ = (double*)ss_take(b, sizeof(double) * (size_t)((n) > 0 ? (n) : 1)); if (m) m->f = t_; } while (0)

static int valid(const sse_config* c) {
    return c->nx >= 1 && c->nc >= 0 && c->nu >= 1 && c->delay >= 0 && c->n_rig >= 1 && c->n_rig <= c->nx;
}

static sse_mem* layout(ss_bump* b, const sse_config* cfg, const ss_fn* step, const ss_fn* ode) {
    sse_mem* m = (sse_mem*)ss_take(b, sizeof(sse_mem));
    const int nx = cfg->nx, nc = cfg->nc, nuh = cfg->nu * (cfg->delay + 1);
    if (m) { memset(m, 0, sizeof(*m)); m->c = *cfg; }
    COPY_ARR(b, m, cfg, p, double, cfg->np);
    COPY_ARR(b, m, cfg, q, double, nx);
    COPY_ARR(b, m, cfg, r, double, cfg->ny);
    COPY_ARR(b, m, cfg, x0, double, nx);
    COPY_ARR(b, m, cfg, P0, double, nx * nx);
    COPY_ARR(b, m, cfg, init_ch, int, cfg->n_init);
    COPY_ARR(b, m, cfg, init_state, int, cfg->n_init);
    COPY_ARR(b, m, cfg, zero_state, int, cfg->n_zero);
    COPY_ARR(b, m, cfg, zero_twist, int, cfg->n_zero);
    {
        char* p1 = (char*)ss_take(b, ss_fn_memsize(step));
        char* p2 = ode ? (char*)ss_take(b, ss_fn_memsize(ode)) : NULL;
        if (m) {
            ss_fn_layout(&m->step, step, &p1);
            if (ode) { ss_fn_layout(&m->ode, ode, &p2); m->has_ode = 1; }
        }
    }
    D(x, nx); D(P, nx * nx); D(xn, nx); D(Pn, nx * nx); D(uh, nuh); D(ym, nc); D(mask, nc);
    D(rate, cfg->n_rig); D(x0_used, nx);
    return m;
}

size_t sse_memsize(const sse_config* cfg, const ss_fn* step, const ss_fn* ode) {
    ss_bump b = {NULL, 0, 1};
    if (!valid(cfg) || (cfg->n_zero > 0 && !ode)) return 0;
    layout(&b, cfg, step, ode);
    return b.n + ALIGN;
}

sse_mem* sse_init(void* mem, size_t size, const sse_config* cfg, const ss_fn* step, const ss_fn* ode) {
    ss_bump b = {(char*)mem, 0, 0};
    sse_mem* m;
    if (!mem || size < sse_memsize(cfg, step, ode)) return NULL;
    m = layout(&b, cfg, step, ode);
    sse_reset(m);
    return m;
}

void sse_reset(sse_mem* m) { sse_set(m, m->c.x0, NULL); }

void sse_set(sse_mem* m, const double* x, const double* P) {
    const int nx = m->c.nx;
    memcpy(m->x, x, sizeof(double) * nx);
    memcpy(m->P, P ? P : m->c.P0, sizeof(double) * nx * nx);
    memcpy(m->x0_used, m->x, sizeof(double) * nx);
    m->started = 0;
}

const double* sse_x(const sse_mem* m) { return m->x; }
const double* sse_P(const sse_mem* m) { return m->P; }
const double* sse_x0_used(const sse_mem* m) { return m->x0_used; }
const double* sse_uh(const sse_mem* m) { return m->uh; }

/* the fused step: (x, P, uh, y, m, p, q, r) -> (x_next, P_next) */
static int fused(sse_mem* m, const double* ym, const double* mask) {
    ss_call* f = &m->step;
    f->arg[0] = m->x; f->arg[1] = m->P; f->arg[2] = m->uh; f->arg[3] = ym; f->arg[4] = mask;
    f->arg[5] = m->c.p; f->arg[6] = m->c.q; f->arg[7] = m->c.r;
    f->res[0] = m->xn; f->res[1] = m->Pn;
    return ss_fn_eval(f);
}

static int all_finite(const double* v, int n) {
    double s = 0.0;
    int i;
    for (i = 0; i < n; i++) s += v[i];
    return isfinite(s);
}

int sse_update(sse_mem* m, const double* y, const double* u, sse_info* info) {
    const sse_config* c = &m->c;
    const int nx = c->nx, nc = c->nc, nu = c->nu;
    int j, ok;
    memset(info, 0, sizeof(*info));
    for (j = 0; j < nc; j++) {
        int present = isfinite(y[j]);
        m->mask[j] = present ? 1.0 : 0.0;
        m->ym[j] = present ? y[j] : 0.0;
        if (!present) info->missing++;
    }
    if (!m->started) {
        if (c->init_speeds)   /* the first sample's measured speeds replace the at-rest prior's zeros */
            for (j = 0; j < c->n_init; j++)
                if (m->mask[c->init_ch[j]] != 0.0) m->x[c->init_state[j]] = y[c->init_ch[j]];
        if (c->n_zero > 0 && c->delay > 0 && m->has_ode) {   /* delayed encoders: the zeros' prior */
            ss_call* f = &m->ode;
            f->arg[0] = m->x; f->arg[1] = u; f->arg[2] = c->p;
            f->res[0] = m->rate;
            if (ss_fn_eval(f) == 0)
                for (j = 0; j < c->n_zero; j++)
                    m->x[c->zero_state[j]] = m->x[c->zero_twist[j]] - c->delay * c->dt * m->rate[c->zero_twist[j]];
        }
        memcpy(m->x0_used, m->x, sizeof(double) * nx);
        for (j = 0; j <= c->delay; j++) memcpy(m->uh + (size_t)j * nu, u, sizeof(double) * nu);
        m->started = 1;
    } else if (c->delay) {
        memmove(m->uh + nu, m->uh, sizeof(double) * (size_t)(nu * c->delay));
        memcpy(m->uh, u, sizeof(double) * nu);
    } else {
        memcpy(m->uh, u, sizeof(double) * nu);
    }
    ok = fused(m, m->ym, m->mask) == 0 && all_finite(m->xn, nx) && all_finite(m->Pn, nx * nx);
    if (ok) {
        memcpy(m->x, m->xn, sizeof(double) * nx);
        memcpy(m->P, m->Pn, sizeof(double) * nx * nx);
        info->corrected = info->missing < nc;
        info->status = SS_OK;
        return SS_OK;
    }
    /* the fallback: prediction only (every mask 0); else the last estimate held */
    info->failed = 1;
    for (j = 0; j < nc; j++) { m->ym[j] = 0.0; m->mask[j] = 0.0; }
    if (fused(m, m->ym, m->mask) == 0 && all_finite(m->xn, nx) && all_finite(m->Pn, nx * nx)) {
        memcpy(m->x, m->xn, sizeof(double) * nx);
        memcpy(m->P, m->Pn, sizeof(double) * nx * nx);
    } else {
        info->held = 1;
    }
    info->status = SS_FALLBACK;
    return SS_FALLBACK;
}
