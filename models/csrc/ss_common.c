/* What every compiled step of the workbench shares (ss_common.h). */
#if !defined(_WIN32) && !defined(_POSIX_C_SOURCE)
#define _POSIX_C_SOURCE 200809L
#endif
#include "ss_common.h"

#include <math.h>
#include <stdint.h>
#ifdef _WIN32
#include <windows.h>
#else
#include <time.h>
#endif

#define SS_ALIGN 8

static size_t ss_up(size_t n) { return (n + SS_ALIGN - 1) / SS_ALIGN * SS_ALIGN; }

size_t ss_fn_memsize(const ss_fn* fn) {
    ss_int na = 0, nr = 0, niw = 0, nw = 0;
    if (fn->work) fn->work(&na, &nr, &niw, &nw);
    return ss_up(sizeof(double*) * (size_t)(na + 1)) + ss_up(sizeof(double*) * (size_t)(nr + 1))
         + ss_up(sizeof(ss_int) * (size_t)(niw + 1)) + ss_up(sizeof(double) * (size_t)(nw + 1));
}

void ss_fn_layout(ss_call* c, const ss_fn* fn, char** p) {
    ss_int na = 0, nr = 0, niw = 0, nw = 0;
    if (fn->work) fn->work(&na, &nr, &niw, &nw);
    c->fn = fn;
    c->arg = (const double**)*p;  *p += ss_up(sizeof(double*) * (size_t)(na + 1));
    c->res = (double**)*p;        *p += ss_up(sizeof(double*) * (size_t)(nr + 1));
    c->iw = (ss_int*)*p;          *p += ss_up(sizeof(ss_int) * (size_t)(niw + 1));
    c->w = (double*)*p;           *p += ss_up(sizeof(double) * (size_t)(nw + 1));
}

int ss_fn_eval(ss_call* c) { return c->fn->eval(c->arg, c->res, c->iw, c->w, 0); }

size_t ss_block_up(size_t n) { return (n + SS_BLOCK_ALIGN - 1) / SS_BLOCK_ALIGN * SS_BLOCK_ALIGN; }

void* ss_take(ss_bump* b, size_t bytes) {
    size_t a;
    char* base;
    if (b->count) { b->n += SS_BLOCK_ALIGN + ss_block_up(bytes); return NULL; }   /* the worst alignment */
    base = b->p;
    a = (size_t)((SS_BLOCK_ALIGN - ((size_t)base % SS_BLOCK_ALIGN)) % SS_BLOCK_ALIGN);
    b->p = base + a + ss_block_up(bytes);
    b->n += a + ss_block_up(bytes);
    return (void*)(base + a);
}

double ss_clock(void) {
#ifdef _WIN32
    LARGE_INTEGER f, c;
    QueryPerformanceFrequency(&f);
    QueryPerformanceCounter(&c);
    return (double)c.QuadPart / (double)f.QuadPart;
#else
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
#endif
}

long ss_round(double x) { return (long)nearbyint(x); }
