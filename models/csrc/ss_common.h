/* What every compiled step of the workbench shares: CasADi-generated functions, statuses, time. */
#ifndef SS_COMMON_H
#define SS_COMMON_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* CasADi's integer type in generated code (casadi_int) */
typedef long long ss_int;

/* a CasADi-generated function: its evaluation and its work sizes */
typedef struct {
    int (*eval)(const double** arg, double** res, ss_int* iw, double* w, int mem);
    int (*work)(ss_int* sz_arg, ss_int* sz_res, ss_int* sz_iw, ss_int* sz_w);
} ss_fn;

/* statuses of a step (models.Status: OK, HOLD, FALLBACK; FAILED ends a run) */
enum { SS_OK = 0, SS_HOLD = 1, SS_FALLBACK = 2, SS_FAILED = 3 };

/* work memory of one generated function, laid out by ss_fn_layout */
typedef struct {
    const ss_fn* fn;
    const double** arg;
    double** res;
    ss_int* iw;
    double* w;
} ss_call;

/* bytes ss_fn_layout needs for fn */
size_t ss_fn_memsize(const ss_fn* fn);
/* lay out fn's work memory at *p (advanced past it) */
void ss_fn_layout(ss_call* c, const ss_fn* fn, char** p);
/* evaluate: the first arguments/results are set by the caller in c->arg / c->res */
int ss_fn_eval(ss_call* c);

/* One memory block laid out by successive ss_take() calls, each SS_BLOCK_ALIGN-aligned (the cores'
 * memsize/init pattern: no allocation after init).  With count = 1 the bump only measures: ss_take
 * returns NULL and adds the worst case to n; with count = 0 it hands out p and advances it. */
#define SS_BLOCK_ALIGN 64
typedef struct { char* p; size_t n; int count; } ss_bump;
/* n rounded up to whole SS_BLOCK_ALIGN units */
size_t ss_block_up(size_t n);
void* ss_take(ss_bump* b, size_t bytes);

/* a monotonic clock [s] */
double ss_clock(void);

/* round half to even, as Python's round() */
long ss_round(double x);

#ifdef __cplusplus
}
#endif
#endif
