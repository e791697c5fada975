/* The laws' steps in C (ss_laws.h).  The references are the Python steps: softspeed.py
 * (SoftSpeed._step_impl), ztorque.py (ZTorque._step_impl), doskil.py (DOSKIL._step_impl), brake.py
 * (BrakeController._step_impl, _filtered), tuning.py (PipeTorque.update, first_order) and
 * setpoint.py (DriveSetpointLaw.stiff_loop); each line below does what its Python line does, in the
 * same order, so that the two agree bit for bit (checked call by call in tests/test_laws_compiled.py). */
#include "ss_laws.h"

#include <math.h>
#include <string.h>

#define ALIGN 64

struct ssl_mem {
    ssl_config c;
    double Ad[4], Bd[4];          /* SoftSpeed's virtual drive over one period (row-major) */
    /* PipeTorque: None is "has_* = 0" */
    int pipe_has_w, pipe_has_value;
    double pipe_w, pipe_acc, pipe_T, pipe_value;
    /* the law's own state */
    int has_w, has_I, has_lp, has_d, has_t;
    double w, I, lp, d, wb, wd, t_prev;
};

/* Python's max(a, b) and min(a, b): the first argument unless the second compares greater (less) */
static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

/* numpy's maximum / minimum / clip on scalars (a NaN propagates) */
static double np_max(double a, double b) { return isnan(a) ? a : (a > b ? a : b); }
static double np_min(double a, double b) { return isnan(a) ? a : (a < b ? a : b); }
static double np_clip(double x, double lo, double hi) { return np_min(np_max(x, lo), hi); }

/* tuning.first_order: one step of a first-order low-pass (tau <= 0: pass through) */
static double first_order(double prev, double x, double dt, double tau) {
    double a;
    if (tau <= 0) return x;
    a = 1.0 - exp(-dt / tau);
    return prev + a * (x - prev);
}

/* exp(A) of an n x n matrix (n <= 4, row-major): scaling and squaring of the Taylor series, kept
   as F = exp(A / 2^s) - I through the squarings ((I + F)^2 - I = 2 F + F F), so that the identity's
   rounding never swamps the small terms (a stiff virtual drive, Kp dt / J_v = 60: 1e-17 of the norm
   where squaring exp itself lost 6e-14).  At a norm <= 1/2 the 18th term is below 1e-20 of the sum. */
static void expm(int n, const double* A, double* E) {
    double X[16], T[16], S[16], F[16], norm = 0.0;
    int i, j, k, s = 0, e;
    for (i = 0; i < n; i++) {
        double r = 0.0;
        for (j = 0; j < n; j++) r += fabs(A[i * n + j]);
        if (r > norm) norm = r;
    }
    if (norm > 0.5) {
        frexp(norm, &e);          /* norm < 2^e */
        s = e + 1;                /* norm / 2^s < 1/2 */
    }
    for (i = 0; i < n * n; i++) {
        X[i] = ldexp(A[i], -s);
        T[i] = (i % (n + 1) == 0) ? 1.0 : 0.0;
        F[i] = 0.0;
    }
    for (k = 1; k <= 18; k++) {
        for (i = 0; i < n; i++)
            for (j = 0; j < n; j++) {
                double acc = 0.0;
                int l;
                for (l = 0; l < n; l++) acc += T[i * n + l] * X[l * n + j];
                S[i * n + j] = acc / (double)k;
            }
        for (i = 0; i < n * n; i++) { T[i] = S[i]; F[i] += S[i]; }
    }
    for (k = 0; k < s; k++) {
        for (i = 0; i < n; i++)
            for (j = 0; j < n; j++) {
                double acc = 0.0;
                int l;
                for (l = 0; l < n; l++) acc += F[i * n + l] * F[l * n + j];
                S[i * n + j] = 2.0 * F[i * n + j] + acc;
            }
        memcpy(F, S, sizeof(double) * (size_t)(n * n));
    }
    for (i = 0; i < n * n; i++) E[i] = F[i] + ((i % (n + 1) == 0) ? 1.0 : 0.0);
}

/* tuning.VirtualDrive: J_v w' = Kp (w_nom - w) + I - T, I' = Ki (w_nom - w), exact over one period */
static void virtual_drive(ssl_mem* m) {
    const ssl_config* c = &m->c;
    double M[16] = {0}, E[16];
    M[0] = -c->Kp / c->J_v;  M[1] = 1.0 / c->J_v;  M[2] = c->Kp / c->J_v;  M[3] = -1.0 / c->J_v;
    M[4] = -c->Ki;           M[5] = 0.0;           M[6] = c->Ki;           M[7] = 0.0;
    {
        int i;
        for (i = 0; i < 8; i++) M[i] *= c->period;
    }
    expm(4, M, E);
    m->Ad[0] = E[0]; m->Ad[1] = E[1]; m->Ad[2] = E[4]; m->Ad[3] = E[5];
    m->Bd[0] = E[2]; m->Bd[1] = E[3]; m->Bd[2] = E[6]; m->Bd[3] = E[7];
}

static int in_range(int ch, int n) { return ch >= 0 && ch < n; }

static int valid(const ssl_config* c) {
    if (!(c->n_ch >= 0 && c->period > 0)) return 0;
    switch (c->law) {
    case SSL_SOFTSPEED:
    case SSL_ZTORQUE:
        if (!in_range(c->ch_drive, c->n_ch) || !in_range(c->ch_torque, c->n_ch)) return 0;
        return c->law == SSL_ZTORQUE || c->torque_drive || c->J_v > 0;
    case SSL_DOSKIL:
        return (c->est_body || in_range(c->ch_body, c->n_ch)) && in_range(c->ch_drive, c->n_ch);
    case SSL_BRAKE:
        /* the relative gain reads the drive body's speed (the brake's constructor refuses it without) */
        return (c->est_body || in_range(c->ch_body, c->n_ch)) && (!(c->gain_relative > 0) || in_range(c->ch_drive, c->n_ch));
    default:
        return 0;
    }
}

size_t ssl_memsize(const ssl_config* cfg) {
    return valid(cfg) ? sizeof(ssl_mem) + ALIGN : 0;
}

ssl_mem* ssl_init(void* mem, size_t size, const ssl_config* cfg) {
    ssl_mem* m;
    size_t a;
    if (!mem || !valid(cfg) || size < ssl_memsize(cfg)) return NULL;
    a = (size_t)((ALIGN - ((size_t)mem % ALIGN)) % ALIGN);
    m = (ssl_mem*)((char*)mem + a);
    memset(m, 0, sizeof(*m));
    m->c = *cfg;
    if (cfg->law == SSL_SOFTSPEED && !cfg->torque_drive) virtual_drive(m);
    ssl_reset(m);
    return m;
}

void ssl_reset(ssl_mem* m) {
    m->pipe_has_w = m->pipe_has_value = 0;
    m->pipe_w = 0.0;
    m->pipe_acc = 0.0;
    m->pipe_T = 0.0;
    m->pipe_value = 0.0;
    m->has_w = m->has_I = m->has_lp = m->has_d = m->has_t = 0;
    m->w = m->I = m->lp = m->d = m->wb = m->wd = m->t_prev = 0.0;
}

const double* ssl_virtual_drive(const ssl_mem* m, int which) { return which ? m->Bd : m->Ad; }

/* a reading that is missing or not finite: the law's fallback (base.reading raises SolverFailure) */
#define READ(v, ch) do { (v) = y[(ch)]; if (!isfinite(v)) { info->missing = (ch); return 0; } } while (0)
/* a speed from the estimate e[i] (a body the rig does not measure): missing or not finite, the fallback */
#define READ_EST(v, i) do { if (!(e && (e_mask & (1 << (i))) && isfinite(e[(i)]))) { info->missing = -2 - (i); return 0; } \
                            (v) = e[(i)]; } while (0)

/* PipeTorque.update: the torque the string loads the drive with [N m]; 0 if a reading is missing */
static int pipe_update(ssl_mem* m, const double* y, double* out, ssl_info* info) {
    const ssl_config* c = &m->c;
    double w, T, est;
    READ(w, c->ch_drive);
    READ(T, c->ch_torque);
    if (c->torque_flip) T = -T;     /* a flange in a shaft whose second node is the drive */
    if (m->pipe_has_w) {
        m->pipe_acc = first_order(m->pipe_acc, (w - m->pipe_w) / c->period, c->period, c->tau_acc);
        /* the torque through the same filter as the acceleration (tuning.py says why) */
        m->pipe_T = first_order(m->pipe_T, T, c->period, c->tau_acc);
    } else {
        m->pipe_T = T;
    }
    m->pipe_w = w;
    m->pipe_has_w = 1;
    est = m->pipe_T - c->pipe_J * m->pipe_acc
        - (c->motor_friction ? c->eta * (c->Tf * tanh(c->eta * w / c->eps_motor) + c->Cm * c->eta * w) : 0.0);
    m->pipe_value = m->pipe_has_value ? first_order(m->pipe_value, est, c->period, c->tau_pipe) : est;
    m->pipe_has_value = 1;
    *out = m->pipe_value;
    return 1;
}

/* DriveSetpointLaw.stiff_loop: a torque drive's Kp e + I within +-torque_max */
static double stiff_loop(ssl_mem* m, double e, double T_pipe) {
    const ssl_config* c = &m->c;
    double lim = c->torque_max, I;
    if (!m->has_I) { m->I = T_pipe; m->has_I = 1; }
    I = m->I + c->Ki * e * c->period;
    if (fabs(c->Kp * e + I) <= lim) m->I = I;
    return np_clip(c->Kp * e + m->I, -lim, lim);
}

static int softspeed(ssl_mem* m, const double* y, double w_nom, double* u, ssl_info* info) {
    const ssl_config* c = &m->c;
    double T_pipe, w_meas, band, w, I, lo, hi;
    if (!pipe_update(m, y, &T_pipe, info)) return 0;
    READ(w_meas, c->ch_drive);
    if (c->torque_drive) { *u = stiff_loop(m, w_nom - w_meas, T_pipe); return 1; }
    if (!m->has_w) { m->w = w_meas; m->I = T_pipe; m->has_w = 1; }   /* bumpless: where the drive is, loaded */
    band = c->band != 0.0 ? c->band : fabs(w_nom);
    w = (m->Ad[0] * m->w + m->Ad[1] * m->I) + (m->Bd[0] * w_nom + m->Bd[1] * T_pipe);
    I = (m->Ad[2] * m->w + m->Ad[3] * m->I) + (m->Bd[2] * w_nom + m->Bd[3] * T_pipe);
    lo = py_max(0.0, w_nom - band);
    hi = w_nom + band;
    if (lo <= w && w <= hi) m->I = I;          /* the integral holds while the set-point is at the band's edge */
    m->w = np_clip(w, lo, hi);
    *u = m->w;
    return 1;
}

static int ztorque(ssl_mem* m, const double* y, double w_nom, double* u, ssl_info* info) {
    const ssl_config* c = &m->c;
    double T, hp, band, w_meas;
    if (!pipe_update(m, y, &T, info)) return 0;
    m->lp = m->has_lp ? first_order(m->lp, T, c->period, c->tau_hp) : T;
    m->has_lp = 1;
    hp = T - m->lp;
    if (c->torque_drive) {
        READ(w_meas, c->ch_drive);
        *u = stiff_loop(m, w_nom - w_meas - c->gain * hp, T);
        return 1;
    }
    band = c->band != 0.0 ? c->band : fabs(w_nom);
    *u = np_clip(w_nom - c->gain * hp, py_max(0.0, w_nom - band), w_nom + band);
    return 1;
}

static int doskil(ssl_mem* m, const double* y, const double* e, int e_mask, double u_prog, double* u,
                  ssl_info* info) {
    const ssl_config* c = &m->c;
    double wb, wt, d;
    if (c->est_body) READ_EST(wb, 0);
    else READ(wb, c->ch_body);
    READ(wt, c->ch_drive);
    d = wb - wt;
    m->d = m->has_d ? first_order(m->d, d, c->period, c->tau) : d;
    m->has_d = 1;
    *u = np_clip(u_prog + c->gain * m->d, c->n_min, c->n_max);
    return 1;
}

static int brake(ssl_mem* m, double t, const double* y, const double* e, int e_mask, double w_nom, double* u,
                 ssl_info* info) {
    const ssl_config* c = &m->c;
    double wb, wd = 0.0, n;
    if (c->use_estimate && e && (e_mask & 1)) wb = e[0];
    else if (c->est_body) READ_EST(wb, 0);
    else READ(wb, c->ch_body);
    if (c->gain_relative > 0) {
        if (c->use_estimate && e && (e_mask & 2)) wd = e[1];
        else READ(wd, c->ch_drive);
    }
    if (!m->has_w || c->tau <= 0) {
        m->wb = wb;
        m->wd = wd;
    } else {
        double h = m->has_t ? py_max(t - m->t_prev, c->period) : c->period;
        double a = 1.0 - exp(-h / c->tau);
        m->wb = m->wb + a * (wb - m->wb);
        m->wd = m->wd + a * (wd - m->wd);
    }
    m->has_w = 1;
    m->t_prev = t;
    m->has_t = 1;
    n = c->gain * py_max(0.0, m->wb - w_nom - c->deadband) + c->gain_relative * py_max(0.0, m->wb - m->wd - c->deadband);
    *u = py_min(py_max(n, 0.0), c->n_max);
    return 1;
}

int ssl_step(ssl_mem* m, double t, const double* y, const double* e, int e_mask, double w_nom, double u_prog,
             double* u, ssl_info* info) {
    int ok = 0;
    info->missing = -1;
    switch (m->c.law) {
    case SSL_SOFTSPEED: ok = softspeed(m, y, w_nom, u, info); break;
    case SSL_ZTORQUE: ok = ztorque(m, y, w_nom, u, info); break;
    case SSL_DOSKIL: ok = doskil(m, y, e, e_mask, u_prog, u, info); break;
    case SSL_BRAKE: ok = brake(m, t, y, e, e_mask, w_nom, u, info); break;
    default: break;
    }
    info->n_u = ok;
    info->status = ok ? SS_OK : SS_FALLBACK;
    return info->status;
}
