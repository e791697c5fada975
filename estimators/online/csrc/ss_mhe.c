/* The MHE's update in C (ss_mhe.h); the reference is estimators/online/mhe.py (MHE._update_impl,
 * _internal, _solve, _fallback), checked against it sample by sample (tests/test_mhe_compiled.py). */
#include "ss_mhe.h"

#include <math.h>
#include <string.h>

#define ALIGN SS_BLOCK_ALIGN

struct ssm_mem {
    ssm_config c;
    ss_call gn, arrival;
    sse_mem* ekf;
    int n_win;           /* samples in the window (<= N + 1) */
    int n_xe;            /* EKF estimates kept (<= N + 2): the first one before the window */
    int appended;        /* samples appended since the reset */
    int has_w;           /* a previous solution to warm-start from */
    double *UH, *Y, *M;  /* the window, oldest first: (N + 1) x nuh, x ny, x ny */
    double *XEx, *XEP;   /* the EKF's estimates, oldest first: (N + 2) x nx, x nx*nx */
    double *w, *wn, *Wm, *xbar, *Pbar, *d, *Pw, *yi, *mi, *x, *P;
};

#define COPY_ARR(b, m, cfg, f, T, n) do { T* d_ = (T*)ss_take((b), sizeof(T) * (size_t)((n) > 0 ? (n) : 1)); \
    if (d_) { memcpy(d_, (cfg)->f, sizeof(T) * (size_t)(n)); (m)->c.f = d_; } } while (0)
#define D(f, n) do { double* t_ = (double*)ss_take(b, sizeof(double) * (size_t)((n) > 0 ? (n) : 1)); if (m) m->f = t_; } while (0)

static int valid(const ssm_config* c, const sse_config* e) {
    return c->nx >= 1 && c->N >= 2 && c->max_iter >= 1 && c->ny >= 0 && c->nc >= 0 && c->nuh >= 1
        && c->nw == c->nx * (c->N + 1) && c->nxx == c->nx * c->nx && c->nyc == c->ny * c->nc
        && e->nx == c->nx && e->nc == c->nc && e->nu * (e->delay + 1) == c->nuh;
}

static ssm_mem* layout(ss_bump* b, const ssm_config* cfg, const sse_config* ecfg, const ss_fn* gn, const ss_fn* ar,
                       const ss_fn* es, const ss_fn* eo) {
    ssm_mem* m = (ssm_mem*)ss_take(b, sizeof(ssm_mem));
    const int nx = cfg->nx, ny = cfg->ny, N = cfg->N, nuh = cfg->nuh, nxx = cfg->nxx;
    size_t esize = sse_memsize(ecfg, es, eo);
    if (m) { memset(m, 0, sizeof(*m)); m->c = *cfg; }
    COPY_ARR(b, m, cfg, p, double, cfg->np);
    COPY_ARR(b, m, cfg, q, double, nx);
    COPY_ARR(b, m, cfg, sr, double, ny);
    COPY_ARR(b, m, cfg, lb, double, cfg->nw);
    COPY_ARR(b, m, cfg, ub, double, cfg->nw);
    COPY_ARR(b, m, cfg, T, double, cfg->nyc);
    COPY_ARR(b, m, cfg, dep, int, cfg->nyc);
    COPY_ARR(b, m, cfg, P0, double, nxx);
    {
        char* p1 = (char*)ss_take(b, ss_fn_memsize(gn));
        char* p2 = (char*)ss_take(b, ss_fn_memsize(ar));
        void* pe = ss_take(b, esize);
        if (m) {
            ss_fn_layout(&m->gn, gn, &p1);
            ss_fn_layout(&m->arrival, ar, &p2);
            m->ekf = sse_init(pe, esize, ecfg, es, eo);
        }
    }
    D(UH, (N + 1) * nuh); D(Y, (N + 1) * ny); D(M, (N + 1) * ny);
    D(XEx, (N + 2) * nx); D(XEP, (N + 2) * nxx);
    D(w, cfg->nw); D(wn, cfg->nw); D(Wm, (N + 1) * ny); D(xbar, nx); D(Pbar, nxx); D(d, cfg->nw); D(Pw, nxx);
    D(yi, ny); D(mi, ny); D(x, nx); D(P, nxx);
    return m;
}

size_t ssm_memsize(const ssm_config* cfg, const sse_config* ekf_cfg, const ss_fn* gn, const ss_fn* arrival,
                   const ss_fn* ekf_step, const ss_fn* ekf_ode) {
    ss_bump b = {NULL, 0, 1};
    if (!valid(cfg, ekf_cfg) || sse_memsize(ekf_cfg, ekf_step, ekf_ode) == 0) return 0;
    layout(&b, cfg, ekf_cfg, gn, arrival, ekf_step, ekf_ode);
    return b.n + ALIGN;
}

ssm_mem* ssm_init(void* mem, size_t size, const ssm_config* cfg, const sse_config* ekf_cfg, const ss_fn* gn,
                  const ss_fn* arrival, const ss_fn* ekf_step, const ss_fn* ekf_ode) {
    ss_bump b = {(char*)mem, 0, 0};
    ssm_mem* m;
    if (!mem || size < ssm_memsize(cfg, ekf_cfg, gn, arrival, ekf_step, ekf_ode)) return NULL;
    m = layout(&b, cfg, ekf_cfg, gn, arrival, ekf_step, ekf_ode);
    if (!m->ekf) return NULL;
    ssm_reset(m);
    return m;
}

void ssm_reset(ssm_mem* m) {
    const int nx = m->c.nx;
    sse_reset(m->ekf);
    m->n_win = 0;
    m->appended = 0;
    m->has_w = 0;
    /* the EKF estimate before the window: the prior (replaced by the first update's x0_used) */
    memcpy(m->XEx, sse_x(m->ekf), sizeof(double) * nx);
    memcpy(m->XEP, m->c.P0, sizeof(double) * m->c.nxx);
    m->n_xe = 1;
    memcpy(m->x, sse_x(m->ekf), sizeof(double) * nx);
    memcpy(m->P, sse_P(m->ekf), sizeof(double) * m->c.nxx);
}

const double* ssm_x(const ssm_mem* m) { return m->x; }
const double* ssm_P(const ssm_mem* m) { return m->P; }
sse_mem* ssm_ekf(ssm_mem* m) { return m->ekf; }

/* append one entry of n doubles to an oldest-first array holding *count of at most cap entries */
static void push(double* a, int* count, int cap, int n, const double* v) {
    if (*count == cap) {
        memmove(a, a + n, sizeof(double) * (size_t)(n * (cap - 1)));
        (*count)--;
    }
    memcpy(a + (size_t)(*count) * n, v, sizeof(double) * (size_t)n);
    (*count)++;
}

static int all_finite(const double* v, int n) {
    double s = 0.0;
    int i;
    for (i = 0; i < n; i++) s += v[i];
    return isfinite(s);
}

/* the EKF's estimate as the MHE's, with the window's last node restarted from it */
static int from_ekf(ssm_mem* m, ssm_info* info, int failed) {
    const int nx = m->c.nx;
    memcpy(m->x, sse_x(m->ekf), sizeof(double) * nx);
    memcpy(m->P, sse_P(m->ekf), sizeof(double) * m->c.nxx);
    if (failed) {
        if (m->has_w) memcpy(m->w + m->c.nw - nx, m->x, sizeof(double) * nx);
        info->failed = failed;
        info->status = SS_FALLBACK;
    } else {
        info->status = SS_OK;
    }
    return info->status;
}

/* the window's Gauss-Newton solve (MHE._solve): 0, or the failure code */
static int solve(ssm_mem* m) {
    const ssm_config* c = &m->c;
    const int nx = c->nx, ny = c->ny, N = c->N, nw = c->nw, nxx = c->nxx;
    const double* xe = sse_x(m->ekf);
    int i, j, it;
    ss_call* f;
    /* warm start: the previous solution shifted by one node, the new node the EKF's */
    if (!m->has_w) {
        memcpy(m->w, m->XEx + nx, sizeof(double) * (size_t)nw);
        m->has_w = 1;
    } else {
        memmove(m->w, m->w + nx, sizeof(double) * (size_t)(nw - nx));
        memcpy(m->w + nw - nx, xe, sizeof(double) * nx);
    }
    /* the arrival prior: the EKF's estimate before the window, propagated */
    f = &m->arrival;
    f->arg[0] = m->XEx; f->arg[1] = m->XEP; f->arg[2] = m->UH; f->arg[3] = c->p;
    f->res[0] = m->xbar; f->res[1] = m->Pbar;
    if (ss_fn_eval(f) != 0) return 2;
    for (i = 0; i < N + 1; i++)
        for (j = 0; j < ny; j++) m->Wm[i * ny + j] = m->M[i * ny + j] / c->sr[j];
    memcpy(m->wn, m->w, sizeof(double) * (size_t)nw);
    f = &m->gn;
    for (it = 0; it < c->max_iter; it++) {
        f->arg[0] = m->wn; f->arg[1] = m->xbar; f->arg[2] = m->Pbar; f->arg[3] = m->UH; f->arg[4] = m->Y;
        f->arg[5] = m->Wm; f->arg[6] = c->p; f->arg[7] = c->q;
        f->res[0] = m->d; f->res[1] = m->Pw;
        if (ss_fn_eval(f) != 0) return 2;
        if (!all_finite(m->d, nw)) return 3;
        for (i = 0; i < nw; i++) {
            double v = m->wn[i] + m->d[i];
            m->wn[i] = v < c->lb[i] ? c->lb[i] : (v > c->ub[i] ? c->ub[i] : v);
        }
    }
    memcpy(m->w, m->wn, sizeof(double) * (size_t)nw);
    for (i = 0; i < nx; i++)
        for (j = 0; j < nx; j++) m->P[i + j * nx] = 0.5 * (m->Pw[i + j * nx] + m->Pw[j + i * nx]);
    for (i = 0; i < nx; i++)
        if (!(m->P[i + i * nx] > 0.0)) return 4;
    memcpy(m->x, m->w + nw - nx, sizeof(double) * nx);
    (void)nxx;
    return 0;
}

int ssm_update(ssm_mem* m, const double* y, const double* u, ssm_info* info) {
    const ssm_config* c = &m->c;
    const int nx = c->nx, ny = c->ny, nc = c->nc, N = c->N;
    int i, j, code;
    memset(info, 0, sizeof(*info));
    sse_update(m->ekf, y, u, &info->ekf);      /* runs every step (fallback, warm start) */
    if (info->ekf.status == SS_FALLBACK) return from_ekf(m, info, 1);
    /* internal measurements (a linear map of the channels, missing ones as 0) and their masks */
    for (j = 0; j < ny; j++) {
        double s = 0.0, all = 1.0;
        for (i = 0; i < nc; i++) {
            int present = isfinite(y[i]);
            s += c->T[j + i * ny] * (present ? y[i] : 0.0);
            if (c->dep[j + i * ny] && !present) all = 0.0;
        }
        m->yi[j] = s;
        m->mi[j] = all;
    }
    if (m->appended == 0)     /* the EKF's prior of the first update (it may take the measured speeds) */
        memcpy(m->XEx, sse_x0_used(m->ekf), sizeof(double) * nx);
    {
        int nw_ = m->n_win, nm = m->n_win, nu_ = m->n_win, nxp = m->n_xe;
        push(m->UH, &nu_, N + 1, c->nuh, sse_uh(m->ekf));
        push(m->Y, &nw_, N + 1, ny, m->yi);
        push(m->M, &nm, N + 1, ny, m->mi);
        push(m->XEx, &m->n_xe, N + 2, nx, sse_x(m->ekf));
        push(m->XEP, &nxp, N + 2, c->nxx, sse_P(m->ekf));
        m->n_win = nw_;
    }
    m->appended++;
    if (m->n_win < N + 1) {
        info->filling = m->n_win;
        return from_ekf(m, info, 0);
    }
    code = solve(m);
    if (code) return from_ekf(m, info, code);
    info->status = SS_OK;
    return SS_OK;
}
