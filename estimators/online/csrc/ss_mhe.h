/* The MHE's update in C: the window's Gauss-Newton step (CasADi-generated, estimators/online/mhe.py)
 * with what the workbench's MHE does around it -- the EKF alongside (ss_ekf.h), the window's ring
 * of input histories, internal measurements and masks, the EKF-style arrival prior, the warm start,
 * the projection onto the state bounds and the fallback to the EKF's estimate.
 *
 * One implementation: the workbench's MHE calls it through ctypes (compile = true), an exported
 * library calls it from its step().  No allocation: ssm_memsize() / ssm_init() as ss_ekf.h.
 */
#ifndef SS_MHE_H
#define SS_MHE_H

#include <stddef.h>

#include "ss_common.h"
#include "ss_ekf.h"
#include "ss_mhe_config.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    int status;       /* SS_OK (the window's solve, or the EKF's estimate while the window fills), or
                         SS_FALLBACK (the EKF's estimate: its update or the window's solve failed) */
    int filling;      /* samples in the window while it fills (0: full, the estimate is the MHE's) */
    int failed;       /* 1: the EKF alongside fell back; 2: a generated function's error; 3: a
                         non-finite Gauss-Newton step; 4: the Hessian not positive definite */
    sse_info ekf;     /* the EKF alongside's update */
} ssm_info;

typedef struct ssm_mem ssm_mem;

/* bytes one MHE needs (0: an invalid configuration); ekf_ode may be NULL as in sse_memsize */
size_t ssm_memsize(const ssm_config* cfg, const sse_config* ekf_cfg, const ss_fn* gn, const ss_fn* arrival,
                   const ss_fn* ekf_step, const ss_fn* ekf_ode);
ssm_mem* ssm_init(void* mem, size_t size, const ssm_config* cfg, const sse_config* ekf_cfg, const ss_fn* gn,
                  const ss_fn* arrival, const ss_fn* ekf_step, const ss_fn* ekf_ode);
/* back to the prior: an empty window, the EKF at its prior */
void ssm_reset(ssm_mem* m);
/* one DAQ sample: y the channels (cfg->nc; NaN: missing), u the inputs applied over the sample that
   ended now.  Returns info->status. */
int ssm_update(ssm_mem* m, const double* y, const double* u, ssm_info* info);
/* the estimate (nx) and its covariance (nx x nx, column-major) */
const double* ssm_x(const ssm_mem* m);
const double* ssm_P(const ssm_mem* m);
/* the EKF alongside */
sse_mem* ssm_ekf(ssm_mem* m);

#ifdef __cplusplus
}
#endif
#endif
