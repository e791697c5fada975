/* The EKF's update in C: the fused predict + correct step (CasADi-generated, estimators/online/ekf.py)
 * with what the workbench's EKF does around it -- the input history, the masks of missing channels,
 * the first sample's speeds, the delayed encoders' zeros, the prediction-only fallback.
 *
 * One implementation: the workbench's EKF calls it through ctypes (compile = true), an exported
 * library calls it from its step().  No allocation: sse_memsize() / sse_init() as ss_nmpc.h.
 */
#ifndef SS_EKF_H
#define SS_EKF_H

#include <stddef.h>

#include "ss_common.h"
#include "ss_ekf_config.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    int status;       /* SS_OK, or SS_FALLBACK (prediction only, or the last estimate held) */
    int corrected;    /* a measurement update was applied */
    int missing;      /* channels missing in this sample */
    int failed;       /* the update failed (non-finite, or a generated function's error) */
    int held;         /* the fallback's prediction failed too: the last estimate is held */
} sse_info;

typedef struct sse_mem sse_mem;

/* bytes one filter needs (0: an invalid configuration); ode may be NULL when cfg->n_zero is 0 */
size_t sse_memsize(const sse_config* cfg, const ss_fn* step, const ss_fn* ode);
sse_mem* sse_init(void* mem, size_t size, const sse_config* cfg, const ss_fn* step, const ss_fn* ode);
/* back to the prior (x0, P0) */
void sse_reset(sse_mem* m);
/* restart from x (nx) and P (nx x nx, column-major; NULL: the prior's) */
void sse_set(sse_mem* m, const double* x, const double* P);
/* one DAQ sample: y the channels (cfg->nc; NaN: missing), u the inputs applied over the sample that
   ended now (cfg->nu).  Returns info->status. */
int sse_update(sse_mem* m, const double* y, const double* u, sse_info* info);
/* the estimate (nx) and its covariance (nx x nx, column-major) */
const double* sse_x(const sse_mem* m);
const double* sse_P(const sse_mem* m);
/* the prior mean the first update started from (after the first sample's speeds and zeros) */
const double* sse_x0_used(const sse_mem* m);
/* the input history of the last update (nu * (delay + 1): the newest sample's inputs first) */
const double* sse_uh(const sse_mem* m);

#ifdef __cplusplus
}
#endif
#endif
