/* The NMPC's step in C (ss_nmpc.h): the one implementation of mitigate/controllers/nmpc's default
 * path (RTI or SQP with hpipm).  It follows the workbench's phases, each a function below:
 *
 *   estimate   servo replicas, held inputs (plan_start)         mitigate/controllers/nmpc/start.py
 *   supervise  speed window, calm schedule, trim, stall guard   mitigate/controllers/nmpc/supervision.py
 *   solve      bounds, shift, linearise, one QP per iteration   mitigate/controllers/nmpc/ocp.py, rti.py, qp.py
 *   guard      first move in its reachable range; fallbacks     mitigate/controllers/nmpc/controller.py
 *
 * The Python modules named there hold the reference implementation (used for the IPOPT and CasADi
 * QP solvers) and the physics notes; tests check this file against them call by call.
 */
#include "ss_nmpc.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp_ipm.h"
#include "hpipm_d_ocp_qp_sol.h"
#include "hpipm_d_cond.h"
#include "hpipm_d_part_cond.h"
#include "hpipm_d_dense_qp.h"
#include "hpipm_d_dense_qp_dim.h"
#include "hpipm_d_dense_qp_sol.h"
#include "hpipm_d_dense_qp_ipm.h"

#define ALIGN SS_BLOCK_ALIGN

struct ssn_mem {
    ssn_config c;                 /* the configuration (arrays point into this memory) */
    ss_call stages, forward;      /* the generated functions' work memory */
    /* plan start */
    int started;                  /* u_prev valid (the first call has been made) */
    int has_t_call, has_t_solve, has_t_plan, has_action, prep_pending, has_plan, has_t_moving;
    double t_call, t_solve, t_plan, t_moving;
    double t_entry;               /* clock at the entry of this call */
    double *u_prev;               /* [nv] last commands */
    double *servo;                /* [ns] servo replicas' forces */
    int servo_init;
    double *dev;                  /* [nu] low-passed deviation of held inputs */
    int *has_dev;                 /* [nu] */
    double *fc;                   /* [nfc] the plan's friction factors */
    double *hold;                 /* [nu] held inputs of this call */
    double *forces;               /* [ns] */
    /* the force band's window (mitigate/controllers/nmpc/band.py) */
    double *fw_f, *fw_p;          /* [ns force_n] applied forces and programmes, ring buffers */
    double *fw_sf, *fw_sp;        /* [force_n] their sums, newest first */
    double *fw_new;               /* [max look_n + 1] sums of the coming samples */
    double *p_last;               /* [ns] the servos' programme at the last call */
    int fw_head, fw_filled;
    /* supervision */
    double *win_speed, *win_nom;  /* [window_n] */
    long win_count;
    double trim;
    /* the held action */
    double *act_u;                /* [nv] */
    int act_n, act_status, act_reason;
    /* OCP */
    int has_X, prepared;
    double *X, *V;                /* [(N+1) nxa], [N nv] */
    double *Xn;                   /* [N nxa] next states from the stage function */
    double *q, *prep_q;           /* [nq] */
    double *plan_u;               /* [N nv] applied inputs of the last plan */
    double *xa0;                  /* [nxa] */
    double *lo, *hi;              /* [nv] bounds of this plan */
    double *lo1, *hi1, *u0, *tail; /* [nv] first move's range, first move, a plan's tail */
    double *lbv, *ubv, *lbw, *ubw, *dg, *reach;   /* [nv], [nv], [N], [N], [ns], [N] */
    double cost;
    int failures;
    /* QP data (stage-major, column-major blocks as CasADi's map writes them) */
    double *A, *B, *b, *Q, *S, *R, *qv, *rv;
    double *lbx0, *ubx0, *lbx, *ubx, *lbu, *ubu, *lg, *ug, *x, *u;
    double *lbx_all, *ubx_all, *pi, *lam_lb, *lam_ub, *lam_lg, *lam_ug, *zero;
    double *QN, *gN;              /* views into Q, qv at stage N */
    double *cstage, *cterm;       /* [1] costs */
    int *idx0, *idxbx, *idxbu, *no_slack;
    int *nx_s, *nu_s, *nbx_s, *nbu_s, *ng_s, *ns_s;
    double **pA, **pB, **pb, **pQ, **pS, **pR, **pq, **pr, **plbx, **pubx, **plbu, **pubu, **pC, **pD, **plg, **pug;
    double **pzero, **px, **pu, **ppi, **plam_lb, **plam_ub, **plam_lg, **plam_ug, **pnull;
    int **pidxbx, **pidxbu, **pidxs;
    double *Cm, *Dm;              /* constant general rows */
    struct d_ocp_qp_dim dim;
    struct d_ocp_qp qp;
    struct d_ocp_qp_sol sol;
    struct d_ocp_qp_ipm_arg arg;
    struct d_ocp_qp_ipm_ws ws;
    /* a condensed QP is made from the OCP QP with x0 eliminated (rdim, rqp, rsol: stage 0 has no state;
       its b, r and general rows take x0's part in the feedback): x0's pinned bounds cost the interior point
       iterations, and acados eliminates it too */
    int *rnx_s, *rnbx_s;
    double *rb0, *rr0, *rlg0, *rug0;   /* [nxa], [nv], [ns], [ns]: stage 0's vectors with x0 folded in */
    double **rpb, **rpr, **rplg, **rpug;
    struct d_ocp_qp_dim rdim;
    struct d_ocp_qp rqp;
    struct d_ocp_qp_sol rsol;
    /* full condensing (qp_cond): the dense QP of the inputs and x0; its left-hand side is built in the
       preparation (d_cond_qp_cond_lhs), its right-hand side, the dense IPM and the expansion in the feedback */
    struct d_dense_qp_dim ddim;
    struct d_dense_qp dqp;
    struct d_dense_qp_sol dsol;
    struct d_dense_qp_ipm_arg darg;
    struct d_dense_qp_ipm_ws dws;
    struct d_cond_qp_arg carg;
    struct d_cond_qp_ws cws;
    /* partial condensing (qp_cond 2): the OCP QP condensed to qp_cond_n stages of blocks, left-hand side in
       the preparation, right-hand side, hpipm's Riccati IPM on the smaller OCP QP and the expansion in the feedback */
    int* bsize;
    struct d_ocp_qp_dim pdim;
    struct d_ocp_qp pqp;
    struct d_ocp_qp_sol psol;
    struct d_ocp_qp_ipm_arg parg;
    struct d_ocp_qp_ipm_ws pws;
    struct d_part_cond_qp_arg pcarg;
    struct d_part_cond_qp_ws pcws;
};

/* ------------------------------------------------------------------ memory layout */
#define DOUBLES(b, n) ((double*)ss_take((b), sizeof(double) * (size_t)((n) > 0 ? (n) : 1)))
#define INTS(b, n) ((int*)ss_take((b), sizeof(int) * (size_t)((n) > 0 ? (n) : 1)))
#define PTRS(b, T, n) ((T**)ss_take((b), sizeof(T*) * (size_t)((n) > 0 ? (n) : 1)))

/* copy the configuration's arrays into the controller's memory */
#define COPY_ARR(b, m, cfg, f, T, n) do { T* d_ = (T*)ss_take((b), sizeof(T) * (size_t)((n) > 0 ? (n) : 1)); \
    if (d_) { memcpy(d_, (cfg)->f, sizeof(T) * (size_t)(n)); (m)->c.f = d_; } } while (0)

static int valid(const ssn_config* c) {
    int k;
    if (c->N < 1 || c->nx < 1 || c->nxa < c->nx || c->nv < 1 || c->nu < 1 || c->window_n < 2) return 0;
    if (c->qp_cond < 0 || c->qp_cond > 2 || (c->qp_cond == 2 && (c->qp_cond_n < 1 || c->qp_cond_n > c->N))) return 0;
    if (c->force_n < 0) return 0;
    for (k = 0; k < c->ns; k++) if (c->look_n[k] < 1) return 0;
    if (c->nq < c->q_fc + c->nfc || c->ns != c->nv - (c->drives ? 1 : 0)) return 0;
    return 1;
}

/* lay everything out; with b->p == NULL only count */
static ssn_mem* layout(ss_bump* b, const ssn_config* cfg, const ss_fn* stages, const ss_fn* forward) {
    ssn_mem* m = (ssn_mem*)ss_take(b, sizeof(ssn_mem));
    const int N = cfg->N, nxa = cfg->nxa, nv = cfg->nv, ns = cfg->ns, nu = cfg->nu, nq = cfg->nq;
    const int nfc = cfg->nfc, nbx = cfg->drives ? 1 : 0, ng = ns, N1 = N + 1;
    int k;
    if (m) { memset(m, 0, sizeof(*m)); m->c = *cfg; }
    COPY_ARR(b, m, cfg, u_servo, int, ns);
    COPY_ARR(b, m, cfg, i_servo, int, ns);
    COPY_ARR(b, m, cfg, j_cmd, int, ns);
    COPY_ARR(b, m, cfg, look_n, int, ns);
    COPY_ARR(b, m, cfg, held, int, nu);
    COPY_ARR(b, m, cfg, reader_ch, int, nu);
    COPY_ARR(b, m, cfg, load_contact, int, cfg->n_load);
    COPY_ARR(b, m, cfg, contact_x, int, nfc);
    COPY_ARR(b, m, cfg, reader_off, double, nu);
    COPY_ARR(b, m, cfg, reader_gain, double, nu);
    COPY_ARR(b, m, cfg, servo_tau, double, ns);
    COPY_ARR(b, m, cfg, servo_rate, double, ns);
    COPY_ARR(b, m, cfg, servo_nmin, double, ns);
    COPY_ARR(b, m, cfg, servo_nmax, double, ns);
    COPY_ARR(b, m, cfg, servo_dg, double, ns);
    COPY_ARR(b, m, cfg, lo, double, nv);
    COPY_ARR(b, m, cfg, hi, double, nv);
    COPY_ARR(b, m, cfg, rate, double, nv);
    COPY_ARR(b, m, cfg, q0, double, nq);
    {   /* the generated functions' work memory */
        size_t n1 = ss_fn_memsize(stages), n2 = ss_fn_memsize(forward);
        char* p1 = (char*)ss_take(b, n1);
        char* p2 = (char*)ss_take(b, n2);
        if (m) { ss_fn_layout(&m->stages, stages, &p1); ss_fn_layout(&m->forward, forward, &p2); }
    }
#define D(f, n) do { double* t_ = DOUBLES(b, n); if (m) m->f = t_; } while (0)
#define I(f, n) do { int* t_ = INTS(b, n); if (m) m->f = t_; } while (0)
    D(u_prev, nv); D(servo, ns); D(dev, nu); I(has_dev, nu); D(fc, nfc); D(hold, nu); D(forces, ns);
    {
        int look = 1;
        for (k = 0; k < ns; k++) if (cfg->look_n[k] > look) look = cfg->look_n[k];
        D(fw_f, ns * cfg->force_n); D(fw_p, ns * cfg->force_n); D(fw_sf, cfg->force_n); D(fw_sp, cfg->force_n);
        D(fw_new, look + 1); D(p_last, ns);
    }
    D(win_speed, cfg->window_n); D(win_nom, cfg->window_n); D(act_u, nv);
    D(X, N1 * nxa); D(V, N * nv); D(Xn, N * nxa); D(q, nq); D(prep_q, nq); D(plan_u, N * nv); D(xa0, nxa);
    D(lo, nv); D(hi, nv); D(lo1, nv); D(hi1, nv); D(u0, nv); D(tail, nv); D(lbv, nv); D(ubv, nv); D(lbw, N); D(ubw, N); D(dg, ns); D(reach, N);
    D(A, N * nxa * nxa); D(B, N * nxa * nv); D(b, N * nxa); D(Q, N1 * nxa * nxa); D(S, N * nv * nxa);
    D(R, N * nv * nv); D(qv, N1 * nxa); D(rv, N * nv);
    D(lbx0, nxa); D(ubx0, nxa); D(lbx, N * nbx); D(ubx, N * nbx); D(lbu, N * nv); D(ubu, N * nv);
    D(lg, N * ng); D(ug, N * ng); D(x, N1 * nxa); D(u, N * nv);
    D(lbx_all, N1 * nxa); D(ubx_all, N1 * nxa); D(pi, N * nxa);
    D(lam_lb, N1 * (nxa + nbx + nv)); D(lam_ub, N1 * (nxa + nbx + nv)); D(lam_lg, N1 * (ng > 0 ? ng : 1));
    D(lam_ug, N1 * (ng > 0 ? ng : 1)); D(zero, (nxa + nv + 1) * (nxa + nv + 1));
    D(cstage, 1); D(cterm, 1); D(Cm, ng * nxa); D(Dm, ng * nv);
    I(idx0, nxa); I(idxbx, nbx); I(idxbu, nv); I(no_slack, nxa + nbx + nv + ng);
    I(rnx_s, N1); I(rnbx_s, N1); D(rb0, nxa); D(rr0, nv); D(rlg0, ns); D(rug0, ns);
    I(nx_s, N1); I(nu_s, N1); I(nbx_s, N1); I(nbu_s, N1); I(ng_s, N1); I(ns_s, N1);
#undef D
#undef I
#define P(f, T) do { T** t_ = PTRS(b, T, N1); if (m) m->f = t_; } while (0)
    P(pA, double); P(pB, double); P(pb, double); P(pQ, double); P(pS, double); P(pR, double); P(pq, double);
    P(pr, double); P(plbx, double); P(pubx, double); P(plbu, double); P(pubu, double); P(pC, double);
    P(pD, double); P(plg, double); P(pug, double); P(pzero, double); P(px, double); P(pu, double);
    P(ppi, double); P(plam_lb, double); P(plam_ub, double); P(plam_lg, double); P(plam_ug, double);
    P(pnull, double); P(pidxbx, int); P(pidxbu, int); P(pidxs, int);
    P(rpb, double); P(rpr, double); P(rplg, double); P(rpug, double);
#undef P
    /* hpipm's structures */
    {
        void* dmem = ss_take(b, d_ocp_qp_dim_memsize(N));
        if (m) {
            for (k = 0; k <= N; k++) {
                m->nx_s[k] = nxa; m->nu_s[k] = k < N ? nv : 0; m->nbx_s[k] = k == 0 ? nxa : nbx;
                m->nbu_s[k] = k < N ? nv : 0; m->ng_s[k] = k < N ? ng : 0; m->ns_s[k] = 0;
            }
            d_ocp_qp_dim_create(N, &m->dim, dmem);
            d_ocp_qp_dim_set_all(m->nx_s, m->nu_s, m->nbx_s, m->nbu_s, m->ng_s, m->ns_s, &m->dim);
        }
    }
    if (cfg->qp_cond) {   /* the OCP QP with x0 eliminated, which the condensing starts from */
        void* dmem = ss_take(b, d_ocp_qp_dim_memsize(N));
        if (m) {
            for (k = 0; k <= N; k++) { m->rnx_s[k] = k ? nxa : 0; m->rnbx_s[k] = k ? nbx : 0; }
            d_ocp_qp_dim_create(N, &m->rdim, dmem);
            d_ocp_qp_dim_set_all(m->rnx_s, m->nu_s, m->rnbx_s, m->nbu_s, m->ng_s, m->ns_s, &m->rdim);
        }
    }
    return m;
}

/* p rounded up to ALIGN (the sizing functions' temporary allocations, each ALIGN bytes longer) */
static void* aligned_up(void* p) { return (void*)(((size_t)p + ALIGN - 1) / ALIGN * ALIGN); }

/* the condensed (dense) QP's memory for an OCP QP of dimension dim (temporary allocations: sizing only) */
static size_t dense_bytes(const ssn_config* cfg, struct d_ocp_qp_dim* dim) {
    struct d_dense_qp_dim ddim;
    struct d_dense_qp_ipm_arg darg;
    struct d_cond_qp_arg carg;
    size_t n = 0, nd = d_dense_qp_dim_memsize(), nc = d_cond_qp_arg_memsize(), na;
    void *dm = malloc(nd + ALIGN), *cm = malloc(nc + ALIGN), *am = NULL;
    int it = cfg->qp_iter_max;
    if (dm && cm) {
        d_dense_qp_dim_create(&ddim, aligned_up(dm));
        d_cond_qp_compute_dim(dim, &ddim);
        d_cond_qp_arg_create(&carg, aligned_up(cm));
        d_cond_qp_arg_set_default(&carg);
        na = d_dense_qp_ipm_arg_memsize(&ddim);
        am = malloc(na + ALIGN);
        if (am) {
            d_dense_qp_ipm_arg_create(&ddim, &darg, aligned_up(am));
            d_dense_qp_ipm_arg_set_default((enum hpipm_mode)cfg->hpipm_mode, &darg);
            d_dense_qp_ipm_arg_set_iter_max(&it, &darg);
            n = ss_block_up(nd) + ss_block_up(nc) + ss_block_up(d_cond_qp_ws_memsize(dim, &carg))
              + ss_block_up(d_dense_qp_memsize(&ddim)) + ss_block_up(d_dense_qp_sol_memsize(&ddim)) + ss_block_up(na)
              + ss_block_up(d_dense_qp_ipm_ws_memsize(&ddim, &darg)) + 7 * ALIGN;
        }
    }
    free(am); free(cm); free(dm);
    return n;
}

/* the partially condensed QP's memory (qp_cond_n stages) for an OCP QP of dimension dim (sizing only) */
static size_t part_bytes(const ssn_config* cfg, struct d_ocp_qp_dim* dim) {
    const int N2 = cfg->qp_cond_n;
    struct d_ocp_qp_dim pdim;
    struct d_ocp_qp_ipm_arg parg;
    struct d_part_cond_qp_arg pcarg;
    size_t n = 0, nd = d_ocp_qp_dim_memsize(N2), nc = d_part_cond_qp_arg_memsize(N2), na;
    int* bs = (int*)malloc(sizeof(int) * (size_t)(N2 + 1));
    void *dm = malloc(nd + ALIGN), *cm = malloc(nc + ALIGN), *am = NULL;
    int it = cfg->qp_iter_max;
    if (bs && dm && cm) {
        d_part_cond_qp_compute_block_size(cfg->N, N2, bs);
        d_ocp_qp_dim_create(N2, &pdim, aligned_up(dm));
        d_part_cond_qp_compute_dim(dim, bs, &pdim);
        d_part_cond_qp_arg_create(N2, &pcarg, aligned_up(cm));
        d_part_cond_qp_arg_set_default(&pcarg);
        na = d_ocp_qp_ipm_arg_memsize(&pdim);
        am = malloc(na + ALIGN);
        if (am) {
            d_ocp_qp_ipm_arg_create(&pdim, &parg, aligned_up(am));
            d_ocp_qp_ipm_arg_set_default((enum hpipm_mode)cfg->hpipm_mode, &parg);
            d_ocp_qp_ipm_arg_set_iter_max(&it, &parg);
            n = ss_block_up(sizeof(int) * (size_t)(N2 + 1)) + ss_block_up(nd) + ss_block_up(nc)
              + ss_block_up(d_part_cond_qp_ws_memsize(dim, bs, &pdim, &pcarg))
              + ss_block_up(d_ocp_qp_memsize(&pdim)) + ss_block_up(d_ocp_qp_sol_memsize(&pdim)) + ss_block_up(na)
              + ss_block_up(d_ocp_qp_ipm_ws_memsize(&pdim, &parg)) + 8 * ALIGN;
        }
    }
    free(am); free(cm); free(dm); free(bs);
    return n;
}

/* hpipm's memory after the dimension (the workspace's size needs an argument, which needs memory:
   sized here with a temporary allocation; ssn_memsize is part of creating a controller, never of a step) */
static size_t hpipm_bytes(const ssn_config* cfg) {
    const int N = cfg->N, nbx = cfg->drives ? 1 : 0;
    size_t n = 0, nd = d_ocp_qp_dim_memsize(N), na;
    int* dims = (int*)malloc(sizeof(int) * 6u * (size_t)(N + 1));
    void* dmem = malloc(nd + ALIGN);
    void* amem = NULL;
    struct d_ocp_qp_dim dim;
    struct d_ocp_qp_ipm_arg arg;
    int k;
    if (!dims || !dmem) { free(dims); free(dmem); return 0; }
    for (k = 0; k <= N; k++) {
        dims[k] = cfg->nxa;
        dims[(N + 1) + k] = k < N ? cfg->nv : 0;
        dims[2 * (N + 1) + k] = k == 0 ? cfg->nxa : nbx;
        dims[3 * (N + 1) + k] = k < N ? cfg->nv : 0;
        dims[4 * (N + 1) + k] = k < N ? cfg->ns : 0;
        dims[5 * (N + 1) + k] = 0;
    }
    d_ocp_qp_dim_create(N, &dim, aligned_up(dmem));
    d_ocp_qp_dim_set_all(dims, dims + (N + 1), dims + 2 * (N + 1), dims + 3 * (N + 1), dims + 4 * (N + 1),
                         dims + 5 * (N + 1), &dim);
    na = d_ocp_qp_ipm_arg_memsize(&dim);
    amem = malloc(na + ALIGN);
    if (amem) {
        d_ocp_qp_ipm_arg_create(&dim, &arg, aligned_up(amem));
        int it = cfg->qp_iter_max;
        d_ocp_qp_ipm_arg_set_default((enum hpipm_mode)cfg->hpipm_mode, &arg);
        d_ocp_qp_ipm_arg_set_iter_max(&it, &arg);   /* the workspace keeps per-iteration statistics */
        n = ss_block_up(d_ocp_qp_memsize(&dim)) + ss_block_up(d_ocp_qp_sol_memsize(&dim)) + ss_block_up(na)
          + ss_block_up(d_ocp_qp_ipm_ws_memsize(&dim, &arg)) + 5 * ALIGN;
        if (cfg->qp_cond) {
            void* rmem = malloc(nd + ALIGN);
            struct d_ocp_qp_dim rdim;
            size_t nc = 0;
            if (rmem) {
                dims[0] = 0; dims[2 * (N + 1)] = 0;          /* stage 0 without x0 */
                d_ocp_qp_dim_create(N, &rdim, aligned_up(rmem));
                d_ocp_qp_dim_set_all(dims, dims + (N + 1), dims + 2 * (N + 1), dims + 3 * (N + 1), dims + 4 * (N + 1),
                                     dims + 5 * (N + 1), &rdim);
                nc = cfg->qp_cond == 1 ? dense_bytes(cfg, &rdim) : part_bytes(cfg, &rdim);
                if (nc) nc += ss_block_up(d_ocp_qp_memsize(&rdim)) + ss_block_up(d_ocp_qp_sol_memsize(&rdim)) + 2 * ALIGN;
            }
            free(rmem);
            n = nc ? n + nc : 0;
        }
    }
    free(amem); free(dmem); free(dims);
    return n;
}

size_t ssn_memsize(const ssn_config* cfg, const ss_fn* stages, const ss_fn* forward) {
    ss_bump b = {NULL, 0, 1};
    size_t h;
    if (!valid(cfg)) return 0;
    layout(&b, cfg, stages, forward);
    h = hpipm_bytes(cfg);
    return h ? b.n + h + ALIGN : 0;
}

static void set_pointers(ssn_mem* m) {
    const ssn_config* c = &m->c;
    const int N = c->N, nxa = c->nxa, nv = c->nv, ns = c->ns, nbx = c->drives ? 1 : 0, nb = nxa + nbx + nv;
    int k;
    for (k = 0; k < nxa; k++) m->idx0[k] = k;
    if (nbx) m->idxbx[0] = c->i_wprev;
    for (k = 0; k < nv; k++) m->idxbu[k] = k;
    for (k = 0; k < nxa + nbx + nv + ns; k++) m->no_slack[k] = -1;
    for (k = 0; k < ns; k++) {
        int i;
        for (i = 0; i < nxa; i++) m->Cm[i * ns + k] = 0.0;
        for (i = 0; i < nv; i++) m->Dm[i * ns + k] = 0.0;
        m->Cm[c->i_servo[k] * ns + k] = -1.0;       /* column-major (ns x nxa) */
        m->Dm[c->j_cmd[k] * ns + k] = 1.0;
    }
    for (k = 0; k <= N; k++) {
        int st = k < N;
        m->pA[k] = st ? m->A + (size_t)k * nxa * nxa : m->zero;
        m->pB[k] = st ? m->B + (size_t)k * nxa * nv : m->zero;
        m->pb[k] = st ? m->b + (size_t)k * nxa : m->zero;
        m->pQ[k] = m->Q + (size_t)k * nxa * nxa;
        m->pS[k] = st ? m->S + (size_t)k * nv * nxa : m->zero;
        m->pR[k] = st ? m->R + (size_t)k * nv * nv : m->zero;
        m->pq[k] = m->qv + (size_t)k * nxa;
        m->pr[k] = st ? m->rv + (size_t)k * nv : m->zero;
        m->pidxbx[k] = k == 0 ? m->idx0 : m->idxbx;
        m->plbx[k] = m->lbx_all + (size_t)k * nxa;
        m->pubx[k] = m->ubx_all + (size_t)k * nxa;
        m->pidxbu[k] = st ? m->idxbu : (int*)m->zero;
        m->plbu[k] = st ? m->lbu + (size_t)k * nv : m->zero;
        m->pubu[k] = st ? m->ubu + (size_t)k * nv : m->zero;
        m->pC[k] = st && ns ? m->Cm : m->zero;
        m->pD[k] = st && ns ? m->Dm : m->zero;
        m->plg[k] = st && ns ? m->lg + (size_t)k * ns : m->zero;
        m->pug[k] = st && ns ? m->ug + (size_t)k * ns : m->zero;
        m->pzero[k] = m->zero;
        m->pidxs[k] = m->no_slack;
        m->px[k] = m->x + (size_t)k * nxa;
        m->pu[k] = st ? m->u + (size_t)k * nv : m->zero;
        m->ppi[k] = st ? m->pi + (size_t)k * nxa : m->zero;
        m->plam_lb[k] = m->lam_lb + (size_t)k * nb;
        m->plam_ub[k] = m->lam_ub + (size_t)k * nb;
        m->plam_lg[k] = m->lam_lg + (size_t)k * (ns > 0 ? ns : 1);
        m->plam_ug[k] = m->lam_ug + (size_t)k * (ns > 0 ? ns : 1);
        m->pnull[k] = NULL;
    }
    for (k = 0; k <= N; k++) {
        m->rpb[k] = k ? m->pb[k] : m->rb0;
        m->rpr[k] = k ? m->pr[k] : m->rr0;
        m->rplg[k] = k || !ns ? m->plg[k] : m->rlg0;
        m->rpug[k] = k || !ns ? m->pug[k] : m->rug0;
    }
    m->QN = m->Q + (size_t)N * nxa * nxa;
    m->gN = m->qv + (size_t)N * nxa;
}

/* an interior-point argument of hpipm's family P (d_ocp_qp or d_dense_qp): the configured mode, the
   iteration limit and one tolerance for all four residuals */
#define SET_IPM_ARG(P, arg, cfg, it, tol) do { \
        P##_ipm_arg_set_default((enum hpipm_mode)(cfg)->hpipm_mode, (arg)); P##_ipm_arg_set_iter_max(&(it), (arg)); \
        P##_ipm_arg_set_tol_stat(&(tol), (arg)); P##_ipm_arg_set_tol_eq(&(tol), (arg)); \
        P##_ipm_arg_set_tol_ineq(&(tol), (arg)); P##_ipm_arg_set_tol_comp(&(tol), (arg)); \
        if ((cfg)->qp_mu0 > 0.0) { double mu0_ = (cfg)->qp_mu0; P##_ipm_arg_set_mu0(&mu0_, (arg)); } } while (0)

ssn_mem* ssn_init(void* mem, size_t size, const ssn_config* cfg, const ss_fn* stages, const ss_fn* forward) {
    ss_bump b = {(char*)mem, 0, 0};
    ssn_mem* m;
    void *qmem, *smem, *amem, *wmem;
    int it = cfg->qp_iter_max;
    double tol = cfg->qp_tol;
    if (!mem || !valid(cfg) || size < ssn_memsize(cfg, stages, forward)) return NULL;
    m = layout(&b, cfg, stages, forward);
    qmem = ss_take(&b, d_ocp_qp_memsize(&m->dim));
    smem = ss_take(&b, d_ocp_qp_sol_memsize(&m->dim));
    amem = ss_take(&b, d_ocp_qp_ipm_arg_memsize(&m->dim));
    d_ocp_qp_create(&m->dim, &m->qp, qmem);
    d_ocp_qp_sol_create(&m->dim, &m->sol, smem);
    d_ocp_qp_ipm_arg_create(&m->dim, &m->arg, amem);
    SET_IPM_ARG(d_ocp_qp, &m->arg, cfg, it, tol);
    wmem = ss_take(&b, d_ocp_qp_ipm_ws_memsize(&m->dim, &m->arg));
    if (b.n > size) return NULL;
    d_ocp_qp_ipm_ws_create(&m->dim, &m->arg, &m->ws, wmem);
    if (cfg->qp_cond) {
        void* p = ss_take(&b, d_ocp_qp_memsize(&m->rdim));
        d_ocp_qp_create(&m->rdim, &m->rqp, p);
        p = ss_take(&b, d_ocp_qp_sol_memsize(&m->rdim));
        d_ocp_qp_sol_create(&m->rdim, &m->rsol, p);
    }
    if (cfg->qp_cond == 2) {
        const int N2 = cfg->qp_cond_n;
        void* p = ss_take(&b, sizeof(int) * (size_t)(N2 + 1));
        m->bsize = (int*)p;
        d_part_cond_qp_compute_block_size(cfg->N, N2, m->bsize);
        p = ss_take(&b, d_ocp_qp_dim_memsize(N2));
        d_ocp_qp_dim_create(N2, &m->pdim, p);
        d_part_cond_qp_compute_dim(&m->rdim, m->bsize, &m->pdim);
        p = ss_take(&b, d_part_cond_qp_arg_memsize(N2));
        d_part_cond_qp_arg_create(N2, &m->pcarg, p);
        d_part_cond_qp_arg_set_default(&m->pcarg);
        p = ss_take(&b, d_part_cond_qp_ws_memsize(&m->rdim, m->bsize, &m->pdim, &m->pcarg));
        d_part_cond_qp_ws_create(&m->rdim, m->bsize, &m->pdim, &m->pcarg, &m->pcws, p);
        p = ss_take(&b, d_ocp_qp_memsize(&m->pdim));
        d_ocp_qp_create(&m->pdim, &m->pqp, p);
        p = ss_take(&b, d_ocp_qp_sol_memsize(&m->pdim));
        d_ocp_qp_sol_create(&m->pdim, &m->psol, p);
        p = ss_take(&b, d_ocp_qp_ipm_arg_memsize(&m->pdim));
        d_ocp_qp_ipm_arg_create(&m->pdim, &m->parg, p);
        SET_IPM_ARG(d_ocp_qp, &m->parg, cfg, it, tol);
        p = ss_take(&b, d_ocp_qp_ipm_ws_memsize(&m->pdim, &m->parg));
        if (b.n > size) return NULL;
        d_ocp_qp_ipm_ws_create(&m->pdim, &m->parg, &m->pws, p);
    }
    if (cfg->qp_cond == 1) {
        void* p = ss_take(&b, d_dense_qp_dim_memsize());
        d_dense_qp_dim_create(&m->ddim, p);
        d_cond_qp_compute_dim(&m->rdim, &m->ddim);
        p = ss_take(&b, d_cond_qp_arg_memsize());
        d_cond_qp_arg_create(&m->carg, p);
        d_cond_qp_arg_set_default(&m->carg);
        p = ss_take(&b, d_cond_qp_ws_memsize(&m->rdim, &m->carg));
        d_cond_qp_ws_create(&m->rdim, &m->carg, &m->cws, p);
        p = ss_take(&b, d_dense_qp_memsize(&m->ddim));
        d_dense_qp_create(&m->ddim, &m->dqp, p);
        p = ss_take(&b, d_dense_qp_sol_memsize(&m->ddim));
        d_dense_qp_sol_create(&m->ddim, &m->dsol, p);
        p = ss_take(&b, d_dense_qp_ipm_arg_memsize(&m->ddim));
        d_dense_qp_ipm_arg_create(&m->ddim, &m->darg, p);
        SET_IPM_ARG(d_dense_qp, &m->darg, cfg, it, tol);
        p = ss_take(&b, d_dense_qp_ipm_ws_memsize(&m->ddim, &m->darg));
        if (b.n > size) return NULL;
        d_dense_qp_ipm_ws_create(&m->ddim, &m->darg, &m->dws, p);
    }
    set_pointers(m);
    /* the structure once: the bounds' indices, the servo rows, no slacks (the data are set per solve) */
    d_ocp_qp_set_all(m->pA, m->pB, m->pb, m->pQ, m->pS, m->pR, m->pq, m->pr, m->pidxbx, m->plbx, m->pubx,
                     m->pidxbu, m->plbu, m->pubu, m->pC, m->pD, m->plg, m->pug, m->pzero, m->pzero, m->pzero,
                     m->pzero, m->pidxs, m->pidxs, m->pzero, m->pzero, &m->qp);
    if (cfg->qp_cond)
        d_ocp_qp_set_all(m->pA, m->pB, m->rpb, m->pQ, m->pS, m->pR, m->pq, m->rpr, m->pidxbx, m->plbx, m->pubx,
                         m->pidxbu, m->plbu, m->pubu, m->pC, m->pD, m->rplg, m->rpug, m->pzero, m->pzero, m->pzero,
                         m->pzero, m->pidxs, m->pidxs, m->pzero, m->pzero, &m->rqp);
    ssn_reset(m);
    return m;
}

void ssn_reset(ssn_mem* m) {
    const ssn_config* c = &m->c;
    int k;
    m->started = m->has_t_call = m->has_t_solve = m->has_t_plan = m->has_action = 0;
    m->prep_pending = m->has_plan = m->has_t_moving = m->servo_init = 0;
    m->has_X = m->prepared = 0;
    m->fw_head = m->fw_filled = 0;
    for (k = 0; k < c->nu; k++) { m->dev[k] = 0.0; m->has_dev[k] = 0; }
    for (k = 0; k < c->nfc; k++) m->fc[k] = 1.0;
    for (k = 0; k < c->window_n; k++) { m->win_speed[k] = NAN; m->win_nom[k] = NAN; }
    m->win_count = 0;
    m->trim = 0.0;
    m->failures = 0;
    m->cost = NAN;
}

const double* ssn_plan(const ssn_mem* m) { return m->has_plan ? m->plan_u : NULL; }
const double* ssn_last_q(const ssn_mem* m) { return m->has_plan || m->has_t_solve ? m->q : NULL; }
int ssn_failures(const ssn_mem* m) { return m->failures; }

/* ------------------------------------------------------------------ small helpers */
static double clip(double v, double lo, double hi) {   /* numpy.clip: minimum(maximum(v, lo), hi) */
    v = v < lo ? lo : v;
    return v > hi ? hi : v;
}
static double dmax(double a, double b) { return a < b ? b : a; }
static double dmin(double a, double b) { return a > b ? b : a; }

/* ------------------------------------------------------------------ estimate: the plan's start */
static double measured(const ssn_mem* m, int j, const double* y, double fallback) {
    const ssn_config* c = &m->c;
    int ch = c->reader_ch[j];
    double v = ch >= 0 ? y[ch] : NAN;
    if (!isfinite(v)) return fallback;
    return (v - c->reader_off[j]) / c->reader_gain[j];
}

static void first_commands(ssn_mem* m, const double* y, const double* u_prog) {
    const ssn_config* c = &m->c;
    int k, j0 = c->drives ? 1 : 0;
    if (c->drives) m->u_prev[0] = u_prog[c->u_drive];
    for (k = 0; k < c->ns; k++) m->u_prev[j0 + k] = measured(m, c->u_servo[k], y, u_prog[c->u_servo[k]]);
}

static void servo_step(const ssn_config* c, int k, double* force, double command, double dt) {
    double target = isfinite(command) ? clip(command, c->servo_nmin[k], c->servo_nmax[k]) : *force;
    double alpha = c->servo_tau[k] > 0 ? 1.0 - exp(-dt / c->servo_tau[k]) : 1.0;
    double delta = alpha * (target - *force);
    double lim = c->servo_rate[k] * dt;
    *force += clip(delta, -lim, lim);
}

static void servo_forces(ssn_mem* m, long steps, const double* y, const double* u_prog) {
    const ssn_config* c = &m->c;
    int k, j0 = c->drives ? 1 : 0;
    long s;
    const int W = c->force_n;
    if (!m->servo_init) {
        for (k = 0; k < c->ns; k++) {
            int j = c->u_servo[k], i;
            m->servo[k] = clip(measured(m, j, y, u_prog[j]), c->servo_nmin[k], c->servo_nmax[k]);
            for (i = 0; i < W; i++) { m->fw_f[k * W + i] = m->servo[k]; m->fw_p[k * W + i] = u_prog[j]; }
        }
        m->fw_head = 0; m->fw_filled = W > 0;
        m->servo_init = 1;
    } else {
        for (s = 0; s < steps; s++) {
            for (k = 0; k < c->ns; k++) servo_step(c, k, &m->servo[k], m->u_prev[j0 + k], c->dt_daq);
            if (W > 0) {   /* band.ForceHistory.push */
                m->fw_head = (m->fw_head + 1) % W;
                for (k = 0; k < c->ns; k++) {
                    m->fw_f[k * W + m->fw_head] = m->servo[k];
                    m->fw_p[k * W + m->fw_head] = m->p_last[k];
                }
            }
        }
    }
    for (k = 0; k < c->ns; k++) { m->forces[k] = m->servo[k]; m->p_last[k] = u_prog[c->u_servo[k]]; }
}

static void held_inputs(ssn_mem* m, double elapsed, const double* y, const double* u_prog) {
    /* the programme with every held measured input moved by its low-passed deviation */
    const ssn_config* c = &m->c;
    double a = c->tau_force > 0 ? 1.0 - exp(-elapsed / c->tau_force) : 1.0;
    int j;
    for (j = 0; j < c->nu; j++) {
        m->hold[j] = u_prog[j];
        if (!c->held[j] || c->reader_ch[j] < 0) continue;
        {
            double v = measured(m, j, y, NAN);
            if (isfinite(v)) {
                if (!m->has_dev[j]) { m->dev[j] = v - m->hold[j]; m->has_dev[j] = 1; }
                else m->dev[j] = m->dev[j] + a * (v - m->hold[j] - m->dev[j]);
            }
            if (m->has_dev[j]) m->hold[j] += m->dev[j];
        }
    }
}

/* ------------------------------------------------------------------ supervise */
static void observe(ssn_mem* m, double t, double speed, double nominal) {
    const ssn_config* c = &m->c;
    const int n = c->window_n;
    long k = m->win_count % n;
    m->win_speed[k] = speed;
    m->win_nom[k] = nominal;
    m->win_count++;
    if (!m->has_t_moving || fabs(speed) > c->sliding_fraction * fabs(nominal)) { m->t_moving = t; m->has_t_moving = 1; }
    if (c->trim_tau > 0 && nominal != 0 && m->win_count >= n) {
        double sum = 0.0, var = 0.0, mean, osc, lo = INFINITY, lim;
        int i;
        for (i = 0; i < n; i++) sum += m->win_speed[i];
        mean = sum / n;
        for (i = 0; i < n; i++) { double d = m->win_speed[i] - mean; var += d * d; lo = dmin(lo, fabs(m->win_speed[i])); }
        osc = sqrt(2.0) * sqrt(var / n) / fabs(nominal);
        if (lo > c->sliding_fraction * fabs(nominal) && osc < c->calm_lo
            && fabs(nominal - mean) > c->trim_deadband * fabs(nominal)) {
            lim = c->trim_limit * fabs(nominal);
            m->trim = dmin(dmax(m->trim + c->call_period / c->trim_tau * (nominal - mean), -lim), lim);
        }
    }
}

static void decide(ssn_mem* m, double nominal, ssn_info* info) {
    const ssn_config* c = &m->c;
    double f = 1.0, sev = INFINITY;
    if (c->hold_gain != 1.0 && m->win_count >= c->window_n / 2) {
        long n = m->win_count < c->window_n ? m->win_count : c->window_n, i;
        double s2 = 0.0, g;
        for (i = 0; i < n; i++) {
            double nom = m->win_nom[i], d = nom != 0 ? (m->win_speed[i] - nom) / fabs(nom) : INFINITY;
            if (!isfinite(d)) d = 1e6;
            s2 += d * d;
        }
        sev = sqrt(2.0 * (s2 / n));
        g = log(dmax(sev, 1e-300) / c->calm_lo) / log(c->calm_hi / c->calm_lo);
        g = dmin(dmax(g, 0.0), 1.0);
        f = pow(c->hold_gain, 1.0 - g);
    }
    info->weight_factor = f;
    info->severity = sev;
    info->nominal = nominal;
    info->trim = m->trim;
    info->target = nominal + m->trim;
}

static int stalled(const ssn_mem* m, double t, double planned, double programme) {
    const ssn_config* c = &m->c;
    if (!c->drives || !m->has_t_moving) return 0;
    return t - m->t_moving >= c->period && fabs(planned) < c->sliding_fraction * fabs(programme);
}

/* ------------------------------------------------------------------ the OCP */
static void applied(const ssn_mem* m, const double* xa, const double* v, double* out) {
    int j;
    for (j = 0; j < m->c.nv; j++) out[j] = v[j];
    if (m->c.drives) out[0] = xa[m->c.i_wprev] + v[0];
}

static int forward_step(ssn_mem* m, const double* xa, const double* v, const double* q, double* xn) {
    ss_call* f = &m->forward;
    f->arg[0] = xa; f->arg[1] = v; f->arg[2] = q;
    f->res[0] = xn;
    return ss_fn_eval(f);
}

static int initialise(ssn_mem* m, const double* xa0, const double* q) {
    const ssn_config* c = &m->c;
    const int N = c->N, nxa = c->nxa, nv = c->nv;
    int k;
    double* v = m->V;
    memcpy(m->X, xa0, sizeof(double) * nxa);
    for (k = 0; k < nv; k++) v[k] = 0.0;
    for (k = 0; k < c->ns; k++) v[c->j_cmd[k]] = xa0[c->i_servo[k]];
    for (k = 0; k < N; k++) {
        if (k > 0) memcpy(m->V + (size_t)k * nv, v, sizeof(double) * nv);
        if (forward_step(m, m->X + (size_t)k * nxa, v, q, m->X + (size_t)(k + 1) * nxa)) return SSF_EVAL;
    }
    m->has_X = 1;
    m->prepared = 0;
    return SSF_NONE;
}

static void shift(ssn_mem* m, long steps) {
    const ssn_config* c = &m->c;
    const int N = c->N, nxa = c->nxa, nv = c->nv;
    int s, k;
    m->prepared = 0;
    if (!m->has_X || steps <= 0) return;
    s = steps < N ? (int)steps : N;
    memmove(m->X, m->X + (size_t)s * nxa, sizeof(double) * (size_t)(N + 1 - s) * nxa);
    for (k = N + 1 - s; k <= N; k++) memcpy(m->X + (size_t)k * nxa, m->X + (size_t)(N - s) * nxa, sizeof(double) * nxa);
    memcpy(m->tail, m->V + (size_t)(N - 1) * nv, sizeof(double) * nv);
    if (c->drives) m->tail[0] = 0.0;
    memmove(m->V, m->V + (size_t)s * nv, sizeof(double) * (size_t)(N - s) * nv);
    for (k = N - s; k < N; k++) memcpy(m->V + (size_t)k * nv, m->tail, sizeof(double) * nv);
}

/* the QP's matrices and gradients go to hpipm when they are made (in the preparation), so a feedback
   call only sets the bounds (which hold the new initial state) and solves */
static void pack_data(ssn_mem* m) {
    const int N = m->c.N;
    struct d_ocp_qp* qp = m->c.qp_cond ? &m->rqp : &m->qp;
    int k;
    for (k = 0; k < N; k++) {
        d_ocp_qp_set_A(k, m->pA[k], qp);
        d_ocp_qp_set_B(k, m->pB[k], qp);
        d_ocp_qp_set_b(k, m->pb[k], qp);
        d_ocp_qp_set_S(k, m->pS[k], qp);
        d_ocp_qp_set_R(k, m->pR[k], qp);
        d_ocp_qp_set_r(k, m->pr[k], qp);
    }
    for (k = 0; k <= N; k++) {
        d_ocp_qp_set_Q(k, m->pQ[k], qp);
        d_ocp_qp_set_q(k, m->pq[k], qp);
    }
}

static void pack_bounds(ssn_mem* m) {
    const ssn_config* c = &m->c;
    const int N = c->N;
    struct d_ocp_qp* qp = c->qp_cond ? &m->rqp : &m->qp;
    int k;
    for (k = 0; k <= N; k++) {
        if ((k == 0 && !c->qp_cond) || (k > 0 && c->drives)) {
            d_ocp_qp_set_lbx(k, m->plbx[k], qp);
            d_ocp_qp_set_ubx(k, m->pubx[k], qp);
        }
        if (k < N) {
            d_ocp_qp_set_lbu(k, m->plbu[k], qp);
            d_ocp_qp_set_ubu(k, m->pubu[k], qp);
            if (c->ns) {   /* a condensed QP's stage 0 rows have x0 folded in (fold_x0) */
                d_ocp_qp_set_lg(k, c->qp_cond ? m->rplg[k] : m->plg[k], qp);
                d_ocp_qp_set_ug(k, c->qp_cond ? m->rpug[k] : m->pug[k], qp);
            }
        }
    }
}

static int linearise(ssn_mem* m, const double* q) {
    const ssn_config* c = &m->c;
    const int N = c->N, nxa = c->nxa;
    ss_call* f = &m->stages;
    int k, i, r;
    f->arg[0] = m->X; f->arg[1] = m->V; f->arg[2] = m->X + (size_t)N * nxa; f->arg[3] = q;
    f->res[0] = m->Xn; f->res[1] = m->A; f->res[2] = m->B; f->res[3] = m->Q; f->res[4] = m->S; f->res[5] = m->R;
    f->res[6] = m->qv; f->res[7] = m->rv; f->res[8] = m->cstage; f->res[9] = m->QN; f->res[10] = m->gN;
    f->res[11] = m->cterm;
    r = ss_fn_eval(f);
    if (r) return SSF_EVAL;
    for (k = 0; k < N; k++)
        for (i = 0; i < nxa; i++)
            m->b[(size_t)k * nxa + i] = m->Xn[(size_t)k * nxa + i] - m->X[(size_t)(k + 1) * nxa + i];
    m->cost = m->cstage[0] + m->cterm[0];
    pack_data(m);
    /* full condensing: the dense Hessian and constraint matrices now, in the preparation */
    if (c->qp_cond == 1) d_cond_qp_cond_lhs(&m->rqp, &m->dqp, &m->carg, &m->cws);
    else if (c->qp_cond == 2) d_part_cond_qp_cond_lhs(&m->rqp, &m->pqp, &m->pcarg, &m->pcws);
    return SSF_NONE;
}

static void limits_and_bounds(ssn_mem* m) {
    /* the plan's absolute bounds from xa0 (OCPSolver.bounds): a bound a rate-limited move cannot reach
       yet is widened to what it can reach, so the QP is always feasible */
    const ssn_config* c = &m->c;
    const int N = c->N;
    int k;
    double dw = c->drives ? c->rate[0] * c->dt : 0.0;
    for (k = 0; k < N; k++) m->reach[k] = dw * (double)(k + 1);
    for (k = 0; k < c->ns; k++) m->dg[k] = c->servo_dg[k];
    if (c->drives) {
        double w0 = m->xa0[c->i_wprev];
        m->lbv[0] = -dw; m->ubv[0] = dw;
        for (k = 0; k < N; k++) {
            m->lbw[k] = dmin(m->lo[0], w0 + m->reach[k]);
            m->ubw[k] = dmax(m->hi[0], w0 - m->reach[k]);
        }
    }
    for (k = 0; k < c->ns; k++) {
        int jc = c->j_cmd[k];
        double s0 = m->xa0[c->i_servo[k]];
        m->lbv[jc] = dmin(m->lo[jc], s0 + m->dg[k]);
        m->ubv[jc] = dmax(m->hi[jc], s0 - m->dg[k]);
    }
}

/* x0 eliminated (a condensed QP): stage 0's dynamics offset, input gradient and general rows take
   the fixed state step dx0 = lbx0 (b0 + A0 dx0, r0 + S0 dx0, lg0 - C dx0, ug0 - C dx0) */
static void fold_x0(ssn_mem* m) {
    const ssn_config* c = &m->c;
    const int nxa = c->nxa, nv = c->nv, ns = c->ns;
    const double* dx = m->lbx0;
    int i, j;
    for (i = 0; i < nxa; i++) {
        double v = m->b[i];
        for (j = 0; j < nxa; j++) v += m->A[(size_t)j * nxa + i] * dx[j];
        m->rb0[i] = v;
    }
    for (i = 0; i < nv; i++) {
        double v = m->rv[i];
        for (j = 0; j < nxa; j++) v += m->S[(size_t)j * nv + i] * dx[j];
        m->rr0[i] = v;
    }
    for (i = 0; i < ns; i++) {
        double v = 0.0;
        for (j = 0; j < nxa; j++) v += m->Cm[(size_t)j * ns + i] * dx[j];
        m->rlg0[i] = m->lg[i] - v;
        m->rug0[i] = m->ug[i] - v;
    }
    d_ocp_qp_set_b(0, m->rb0, &m->rqp);
    d_ocp_qp_set_r(0, m->rr0, &m->rqp);
}

static int qp_step(ssn_mem* m, ssn_info* info) {
    const ssn_config* c = &m->c;
    const int N = c->N, nxa = c->nxa, nv = c->nv, ns = c->ns;
    int k, i, st, it;
    for (i = 0; i < nxa; i++) { m->lbx0[i] = m->xa0[i] - m->X[i]; m->ubx0[i] = m->lbx0[i]; }
    for (k = 0; k < N; k++)
        for (i = 0; i < nv; i++) {
            m->lbu[(size_t)k * nv + i] = m->lbv[i] - m->V[(size_t)k * nv + i];
            m->ubu[(size_t)k * nv + i] = m->ubv[i] - m->V[(size_t)k * nv + i];
        }
    if (c->drives)
        for (k = 0; k < N; k++) {
            m->lbx[k] = m->lbw[k] - m->X[(size_t)(k + 1) * nxa + c->i_wprev];
            m->ubx[k] = m->ubw[k] - m->X[(size_t)(k + 1) * nxa + c->i_wprev];
        }
    for (k = 0; k < N; k++)
        for (i = 0; i < ns; i++) {
            double g = m->V[(size_t)k * nv + c->j_cmd[i]] - m->X[(size_t)k * nxa + c->i_servo[i]];
            m->lg[(size_t)k * ns + i] = -m->dg[i] - g;
            m->ug[(size_t)k * ns + i] = m->dg[i] - g;
        }
    /* stage 0 bounds every state (x0 = lbx0 = ubx0), stages 1..N the set-point's previous value */
    for (i = 0; i < nxa; i++) { m->lbx_all[i] = m->lbx0[i]; m->ubx_all[i] = m->ubx0[i]; }
    if (c->drives)
        for (k = 1; k <= N; k++) { m->lbx_all[(size_t)k * nxa] = m->lbx[k - 1]; m->ubx_all[(size_t)k * nxa] = m->ubx[k - 1]; }
    if (c->qp_cond) fold_x0(m);
    pack_bounds(m);
    if (c->qp_cond == 2) {
        d_part_cond_qp_cond_rhs(&m->rqp, &m->pqp, &m->pcarg, &m->pcws);
        d_ocp_qp_ipm_solve(&m->pqp, &m->psol, &m->parg, &m->pws);
        d_ocp_qp_ipm_get_status(&m->pws, &st);
        d_ocp_qp_ipm_get_iter(&m->pws, &it);
        if (st == 0) d_part_cond_qp_expand_sol(&m->rqp, &m->psol, &m->rsol, &m->pcarg, &m->pcws);
    } else if (c->qp_cond == 1) {
        d_cond_qp_cond_rhs(&m->rqp, &m->dqp, &m->carg, &m->cws);
        d_dense_qp_ipm_solve(&m->dqp, &m->dsol, &m->darg, &m->dws);
        d_dense_qp_ipm_get_status(&m->dws, &st);
        d_dense_qp_ipm_get_iter(&m->dws, &it);
        if (st == 0) d_cond_qp_expand_sol(&m->rqp, &m->dsol, &m->rsol, &m->carg, &m->cws);
    } else {
        d_ocp_qp_ipm_solve(&m->qp, &m->sol, &m->arg, &m->ws);
        d_ocp_qp_ipm_get_status(&m->ws, &st);
        d_ocp_qp_ipm_get_iter(&m->ws, &it);
    }
    info->qp_iterations = it;
    if (st != 0) { info->fail_detail = st; return SSF_QP; }
    d_ocp_qp_sol_get_all(c->qp_cond ? &m->rsol : &m->sol, m->pu, m->px, m->pnull, m->pnull, m->ppi, m->plam_lb,
                         m->plam_ub, m->plam_lg, m->plam_ug, m->pnull, m->pnull);
    if (c->qp_cond) for (i = 0; i < nxa; i++) m->x[i] = m->lbx0[i];     /* x0 was eliminated: its step is fixed */
    return SSF_NONE;
}

static int check(ssn_mem* m, ssn_info* info) {
    const ssn_config* c = &m->c;
    const int N = c->N, nxa = c->nxa, nv = c->nv;
    double viol = 0.0, scale = 1.0, sum = 0.0;
    int k, i;
    for (k = 0; k < (N + 1) * nxa; k++) sum += m->X[k];
    for (k = 0; k < N * nv; k++) sum += m->V[k];
    if (!isfinite(sum)) return SSF_PLAN;
    for (i = 0; i < nxa; i++) viol = dmax(viol, fabs(m->X[i] - m->xa0[i]));
    for (k = 0; k < N; k++)
        for (i = 0; i < nv; i++) {
            double v = m->V[(size_t)k * nv + i];
            viol = dmax(viol, dmax(m->lbv[i] - v, v - m->ubv[i]));
        }
    if (c->drives)
        for (k = 0; k < N; k++) {
            double w = m->X[(size_t)(k + 1) * nxa + c->i_wprev];
            viol = dmax(viol, dmax(m->lbw[k] - w, w - m->ubw[k]));
        }
    for (k = 0; k < N; k++)
        for (i = 0; i < c->ns; i++)
            viol = dmax(viol, fabs(m->V[(size_t)k * nv + c->j_cmd[i]] - m->X[(size_t)k * nxa + c->i_servo[i]]) - m->dg[i]);
    for (i = 0; i < nxa; i++) scale = dmax(scale, fabs(m->xa0[i]));
    for (i = 0; i < nv; i++) scale = dmax(scale, fabs(m->ubv[i]));
    if (viol > 1e-4 * scale) { info->violation = viol; return SSF_BOUNDS; }
    return SSF_NONE;
}

/* one solve (OCPSolver.solve + GaussNewtonSolver._solve_impl): RTI (one QP) or SQP */
static int solve_ocp(ssn_mem* m, ssn_info* info) {
    const ssn_config* c = &m->c;
    const int N = c->N, nxa = c->nxa, nv = c->nv;
    int it, r, nmax = c->iterate ? c->sqp_max_iter : 1, k;
    double t0 = ss_clock(), step = 0.0;
    if (!m->has_X && (r = initialise(m, m->xa0, m->q))) return r;
    limits_and_bounds(m);
    info->converged = c->iterate ? 0 : 1;
    for (it = 1; it <= nmax; it++) {
        if (!(it == 1 && m->prepared) && (r = linearise(m, m->q))) return r;
        m->prepared = 0;
        if ((r = qp_step(m, info))) return r;
        step = 0.0;
        for (k = 0; k < (N + 1) * nxa; k++) { m->X[k] += m->x[k]; step = dmax(step, fabs(m->x[k])); }
        for (k = 0; k < N * nv; k++) { m->V[k] += m->u[k]; step = dmax(step, fabs(m->u[k])); }
        info->iterations = it;
        if (c->iterate && step < c->sqp_tol) { info->converged = 1; break; }
    }
    info->last_step = step;
    if ((r = check(m, info))) return r;
    m->prepared = 0;
    for (k = 0; k < N; k++) applied(m, m->X + (size_t)k * nxa, m->V + (size_t)k * nv, m->plan_u + (size_t)k * nv);
    info->cost = m->cost;
    info->solve_time = ss_clock() - t0;
    return SSF_NONE;
}

static void prepare(ssn_mem* m) {
    /* RTI preparation: shift by one interval and linearise there, with q as known now */
    if (!m->has_X) return;
    shift(m, 1);
    if (linearise(m, m->prep_q)) { m->has_X = 0; m->prepared = 0; return; }   /* the next plan starts afresh */
    m->prepared = 1;
}

/* mitigate/controllers/nmpc/band.py: every window ending in the next look_n samples keeps its force's
   sum at least (upper: at most) ratio x its programme's sum, the command c held */
static int window_ok(ssn_mem* m, int k, double c0, double s0, double p, double ratio, int upper) {
    const ssn_config* c = &m->c;
    const int w = c->force_n;
    double alpha = c->servo_tau[k] > 0 ? 1.0 - exp(-c->dt_daq / c->servo_tau[k]) : 1.0;
    double step = c->servo_rate[k] * c->dt_daq;
    double target = clip(c0, c->servo_nmin[k], c->servo_nmax[k]), s = s0;
    int j;
    m->fw_new[0] = 0.0;
    for (j = 1; j <= c->look_n[k]; j++) {
        int n_new = j < w ? j : w, n_old = w - n_new;
        double f, tot;
        s += clip(alpha * (target - s), -step, step);
        m->fw_new[j] = m->fw_new[j - 1] + s;
        f = (n_old > 0 ? m->fw_sf[n_old - 1] : 0.0) + (m->fw_new[j] - m->fw_new[j - n_new]);
        tot = (n_old > 0 ? m->fw_sp[n_old - 1] : 0.0) + (double)n_new * p;
        if (upper ? f > ratio * tot : f < ratio * tot) return 0;
    }
    return 1;
}

#define BISECTIONS 52

/* band._end: from the near end of the range towards the far one, the first command that keeps every
   window on the right side of ratio x its programme (the far end when none does) */
static double window_end(ssn_mem* m, int k, double s0, double p, double ratio, int upper, double near, double far) {
    double a = near, b = far, mid;
    int it;
    if (window_ok(m, k, near, s0, p, ratio, upper)) return near;
    if (!window_ok(m, k, far, s0, p, ratio, upper)) return far;
    for (it = 0; it < BISECTIONS; it++) {
        mid = 0.5 * (a + b);
        if (window_ok(m, k, mid, s0, p, ratio, upper)) b = mid; else a = mid;
    }
    return b;
}

static void window_bounds(ssn_mem* m, int k, double p, double* lo, double* hi) {
    const ssn_config* c = &m->c;
    const int w = c->force_n;
    double s0, acc_f = 0.0, acc_p = 0.0, c_lo, c_hi = *hi;
    int i;
    for (i = 0; i < w; i++) {   /* newest first */
        int idx = (m->fw_head - i + w) % w;
        acc_f += m->fw_f[k * w + idx]; m->fw_sf[i] = acc_f;
        acc_p += m->fw_p[k * w + idx]; m->fw_sp[i] = acc_p;
    }
    s0 = m->fw_f[k * w + m->fw_head];
    c_lo = window_end(m, k, s0, p, c->force_lo, 0, *lo, *hi);
    if (isfinite(c->force_hi)) c_hi = window_end(m, k, s0, p, c->force_hi, 1, *hi, *lo);
    if (c_lo > c_hi) c_lo = c_hi = 0.5 * (c_lo + c_hi);
    *lo = c_lo; *hi = c_hi;
}

static void command_bounds(ssn_mem* m, const double* u_prog) {
    const ssn_config* c = &m->c;
    int j;
    for (j = 0; j < c->nv; j++) { m->lo[j] = c->lo[j]; m->hi[j] = c->hi[j]; }
    if (c->drives) {
        double s = u_prog[c->u_drive], band = c->setpoint_band;
        m->lo[0] = s - band; m->hi[0] = s + band;
        if (!c->reverses) {       /* a speed set-point does not reverse the rotation */
            if (s >= 0) m->lo[0] = dmax(m->lo[0], 0.0); else m->hi[0] = dmin(m->hi[0], 0.0);
        } else {                  /* [drive] torque_max */
            m->lo[0] = dmax(m->lo[0], -c->torque_max); m->hi[0] = dmin(m->hi[0], c->torque_max);
        }
    }
    for (j = 0; j < c->ns; j++) {  /* a servo force with a positive programme stays in its band */
        int jc = c->j_cmd[j];
        double p = u_prog[c->u_servo[j]], a, b;
        if (!(p > 0)) continue;
        if (c->force_n > 0 && m->fw_filled) { window_bounds(m, j, p, &m->lo[jc], &m->hi[jc]); continue; }
        a = dmax(m->lo[jc], c->force_lo * p); b = dmin(m->hi[jc], c->force_hi * p);
        if (a > b) a = b = dmin(dmax(p, m->lo[jc]), m->hi[jc]);   /* the band is outside the servo's range */
        m->lo[jc] = a; m->hi[jc] = b;
    }
}

/* ------------------------------------------------------------------ the step */
static void hold_action(ssn_mem* m, const double* u, int n, int status, int reason, const double* u_prog) {
    const ssn_config* c = &m->c;
    int j;
    m->has_action = 1;
    m->act_n = n; m->act_status = status; m->act_reason = reason;
    for (j = 0; j < c->nv; j++) m->act_u[j] = n ? u[j] : 0.0;
    if (n) for (j = 0; j < c->nv; j++) m->u_prev[j] = u[j];
    else {
        if (c->drives) m->u_prev[0] = u_prog[c->u_drive];
        for (j = 0; j < c->ns; j++) m->u_prev[(c->drives ? 1 : 0) + j] = u_prog[c->u_servo[j]];
    }
}

static int emit(ssn_mem* m, int status, const double* u_prog, double* u, ssn_info* info) {
    const ssn_config* c = &m->c;
    int j;
    info->status = status;
    info->reason = m->act_reason;
    info->held_status = m->act_status;
    info->n_u = m->act_n;
    for (j = 0; j < c->nv; j++) u[j] = m->act_u[j];
    if (!m->act_n) {   /* the programme */
        if (c->drives) u[0] = u_prog[c->u_drive];
        for (j = 0; j < c->ns; j++) u[(c->drives ? 1 : 0) + j] = u_prog[c->u_servo[j]];
    }
    info->step_time = ss_clock() - m->t_entry;
    return status;
}

static int fallback(ssn_mem* m, double t, const double* u_prog, double* u, ssn_info* info) {
    /* the previous plan shifted to now, else the programme */
    const ssn_config* c = &m->c;
    m->failures++;
    m->has_X = 0; m->prepared = 0;   /* never warm-start from a failed iterate */
    if (m->has_plan) {
        long j = ss_round((t - m->t_plan) / c->dt);
        if (j >= 0 && j < c->N) {
            int i;
            command_bounds(m, u_prog);
            for (i = 0; i < c->nv; i++) m->u0[i] = clip(m->plan_u[(size_t)j * c->nv + i], m->lo[i], m->hi[i]);
            info->shifted_index = (int)j;
            hold_action(m, m->u0, c->nv, SS_FALLBACK, SSN_SHIFTED, u_prog);
            return emit(m, SS_FALLBACK, u_prog, u, info);
        }
        m->has_plan = 0;
    }
    hold_action(m, NULL, 0, SS_FALLBACK, SSN_PROGRAMME, u_prog);
    return emit(m, SS_FALLBACK, u_prog, u, info);
}

int ssn_step(ssn_mem* m, double t, const double* y, const double* xe, int observe_speed, const double* u_prog,
             double target, int flags, double* u, ssn_info* info) {
    const ssn_config* c = &m->c;
    const int nx = c->nx, nv = c->nv;
    double nominal, elapsed, sum;
    long steps;
    int k, r, due;
    memset(info, 0, sizeof(*info));
    m->t_entry = ss_clock();
    info->weight_factor = 1.0;
    info->severity = INFINITY;
    nominal = c->has_speed0 ? c->speed0 : c->torque_drive ? target : u_prog[c->u_drive];
    /* estimate: the plan's start */
    if (!m->started) { first_commands(m, y, u_prog); m->started = 1; }
    elapsed = m->has_t_call ? dmax(t - m->t_call, 0.0) : c->dt_daq;
    steps = m->has_t_call ? ss_round((t - m->t_call) / c->dt_daq) : 0;
    servo_forces(m, steps, y, u_prog);
    held_inputs(m, elapsed, y, u_prog);
    m->t_call = t; m->has_t_call = 1;
    /* supervise */
    if (xe && observe_speed) observe(m, t, xe[c->i_speed], nominal);
    due = !m->has_t_solve || !m->has_action || t - m->t_solve >= c->dt - 0.5 * c->dt_daq;
    if (!due) {
        if (m->prep_pending) { m->prep_pending = 0; prepare(m); info->prepared = 1; }
        return emit(m, SS_HOLD, u_prog, u, info);
    }
    steps = m->has_t_solve ? ss_round((t - m->t_solve) / c->dt) : 1;
    if (steps < 1) steps = 1;
    m->t_solve = t; m->has_t_solve = 1;
    info->planned = 1;
    decide(m, nominal, info);
    /* solve */
    if (flags & SSN_INJECT) { info->failure = SSF_INJECTED; return fallback(m, t, u_prog, u, info); }
    if (flags & SSN_BAD_ESTIMATE) { info->failure = SSF_BAD_ESTIMATE; return fallback(m, t, u_prog, u, info); }
    if (!xe) { info->failure = SSF_NO_ESTIMATE; return fallback(m, t, u_prog, u, info); }
    sum = 0.0;
    for (k = 0; k < nx; k++) sum += xe[k];
    if (!isfinite(sum)) { info->failure = SSF_STATE; return fallback(m, t, u_prog, u, info); }
    if (c->use_load) {
        double slide = c->sliding_fraction * fabs(nominal);
        for (k = 0; k < c->n_load; k++) {
            int i = c->load_contact[k];
            double v = xe[nx + k];
            if (isfinite(v) && fabs(xe[c->contact_x[i]]) > slide) m->fc[i] = dmin(dmax(v, c->load_min), c->load_max);
        }
    }
    sum = 0.0;
    for (k = 0; k < c->nu; k++) sum += m->hold[k];
    if (!isfinite(sum)) { info->failure = SSF_HOLD; return fallback(m, t, u_prog, u, info); }
    for (k = 0; k < nx; k++) m->xa0[k] = xe[k];
    for (k = 0; k < c->ns; k++) m->xa0[c->i_servo[k]] = c->model_servo ? m->forces[k] : m->u_prev[c->j_cmd[k]];
    if (c->drives) m->xa0[c->i_wprev] = m->u_prev[0];
    for (k = 0; k < c->nq; k++) m->q[k] = c->q0[k];
    for (k = 0; k < c->nu; k++) m->q[c->q_hold + k] = m->hold[k];
    m->q[c->q_nom] = info->target;
    for (k = 0; k < c->nfc; k++) m->q[c->q_fc + k] = c->use_load ? m->fc[k] : 1.0;
    for (k = 0; k < c->ns; k++) {
        double lo = c->servo_nmin[k];
        m->q[c->q_lin + k] = m->hold[c->u_servo[k]] <= lo + 1e-9 * dmax(fabs(lo), 1.0) ? 1.0 : 0.0;
    }
    {
        double f = info->weight_factor;
        m->q[c->q_ref] *= f;
        m->q[c->q_dref] *= f;
        m->q[c->q_force] *= c->drives ? f * f : f;   /* pin only: the servo is all it has */
    }
    if (m->has_X && !(m->prepared && steps == 1)) shift(m, m->prepared ? steps - 1 : steps);   /* prepare() shifted by one */
    command_bounds(m, u_prog);
    if ((r = solve_ocp(m, info))) { info->failure = r; return fallback(m, t, u_prog, u, info); }
    /* guard */
    m->has_plan = 1; m->t_plan = t; m->has_t_plan = 1;
    if (c->prepare_ahead) { memcpy(m->prep_q, m->q, sizeof(double) * c->nq); m->prep_pending = 1; }
    {   /* OCPSolver.first_range: the first move within its reachable range (QP-tolerance excursions only) */
        double* u0 = m->u0;
        int j;
        for (j = 0; j < nv; j++) { m->lo1[j] = m->lbv[j]; m->hi1[j] = m->ubv[j]; }
        for (k = 0; k < c->ns; k++) {
            int jc = c->j_cmd[k];
            double s0 = m->xa0[c->i_servo[k]];
            m->lo1[jc] = dmax(m->lbv[jc], s0 - m->dg[k]);
            m->hi1[jc] = dmin(m->ubv[jc], s0 + m->dg[k]);
        }
        if (c->drives) {
            double w0 = m->xa0[c->i_wprev];
            m->lo1[0] = dmax(m->lbw[0], w0 + m->lbv[0]);
            m->hi1[0] = dmin(m->ubw[0], w0 + m->ubv[0]);
        }
        for (j = 0; j < nv; j++) u0[j] = clip(m->plan_u[j], m->lo1[j], m->hi1[j]);
        if (c->drives && stalled(m, t, u0[0], u_prog[c->u_drive])) {
            hold_action(m, NULL, 0, SS_FALLBACK, SSN_STALL, u_prog);
            return emit(m, SS_FALLBACK, u_prog, u, info);
        }
        hold_action(m, u0, nv, SS_OK, SSN_PLAN, u_prog);
    }
    return emit(m, SS_OK, u_prog, u, info);
}
