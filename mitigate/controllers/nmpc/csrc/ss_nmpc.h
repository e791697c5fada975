/* The NMPC's step in C: estimate -> supervise -> solve (RTI, hpipm) -> guard.
 *
 * One implementation of the workbench's NMPC (mitigate/controllers/nmpc/): the workbench calls it
 * through ctypes, an exported library (mitigate export) calls it from its step().  Generic over the
 * rig: the dimensions, index tables and numbers come in an ssn_config (ss_nmpc_config.h, generated
 * from one declaration in mitigate/controllers/nmpc/compiled.py); the rig's stage functions are
 * CasADi-generated C passed as function pointers.  No allocation: ssn_memsize() says how much memory
 * one controller needs, ssn_init() lays it out in memory the caller owns.
 */
#ifndef SS_NMPC_H
#define SS_NMPC_H

#include <stddef.h>

#include "ss_common.h"
#include "ss_nmpc_config.h"

#ifdef __cplusplus
extern "C" {
#endif

/* why an action is what it is */
enum ssn_reason {
    SSN_PLAN = 0,        /* the first move of a new plan */
    SSN_STALL = 1,       /* the stall guard: the programme */
    SSN_SHIFTED = 2,     /* a failure: the previous plan shifted to now */
    SSN_PROGRAMME = 3    /* a failure and no plan left: the programme */
};

/* what failed in this call's solve (0: nothing) */
enum ssn_failure {
    SSF_NONE = 0,
    SSF_NO_ESTIMATE = 1,      /* no state estimate */
    SSF_STATE = 2,            /* non-finite or short state estimate */
    SSF_HOLD = 3,             /* non-finite held input */
    SSF_QP = 4,               /* the QP solver failed (detail: hpipm's status) */
    SSF_PLAN = 5,             /* non-finite plan */
    SSF_BOUNDS = 6,           /* the plan violates its bounds (violation) */
    SSF_EVAL = 7,             /* a generated function returned an error */
    SSF_INJECTED = 8,         /* a test asked for a failure */
    SSF_BAD_ESTIMATE = 9      /* the caller says the estimate is of another rig */
};

/* flags of ssn_step */
enum { SSN_INJECT = 1, SSN_BAD_ESTIMATE = 2 };

/* what one call did (the workbench formats its messages from it) */
typedef struct {
    int status;          /* SS_OK, SS_HOLD or SS_FALLBACK */
    int reason;          /* enum ssn_reason of the (held) action */
    int held_status;     /* the held action's status (a HOLD's message names it) */
    int n_u;             /* entries of the action (0: the programme) */
    int planned;         /* this call tried to plan */
    int prepared;        /* this call ran the RTI preparation */
    int failure;         /* enum ssn_failure of this call (0: none) */
    int fail_detail;     /* hpipm's status for SSF_QP */
    int shifted_index;   /* the plan interval of a shifted plan */
    int iterations;      /* Gauss-Newton iterations of this plan */
    int qp_iterations;   /* interior-point iterations of its last QP */
    int converged;       /* sqp: converged; rti: 1 */
    double violation;    /* SSF_BOUNDS: by how much */
    double last_step;    /* sqp: the last step's size */
    double cost;         /* the plan's cost at the last linearisation */
    double solve_time;   /* wall time of the solve [s] (0 when this call did not plan) */
    double step_time;    /* wall time of this whole call [s] */
    double weight_factor, severity, nominal, trim, target;   /* the supervision's decision */
} ssn_info;

typedef struct ssn_mem ssn_mem;

/* bytes of memory one controller of this configuration needs (0: an invalid configuration) */
size_t ssn_memsize(const ssn_config* cfg, const ss_fn* stages, const ss_fn* forward);

/* lay out a controller in mem (ssn_memsize bytes, any alignment); the configuration is copied.
   Returns the controller, or NULL if the memory is too small or the configuration invalid. */
ssn_mem* ssn_init(void* mem, size_t size, const ssn_config* cfg, const ss_fn* stages, const ss_fn* forward);

/* forget everything learnt (plan, supervision, servo replicas) */
void ssn_reset(ssn_mem* m);

/* One controller call at time t [s].
 *   y        the DAQ channels the configuration reads (cfg->n_ch; NaN: missing)
 *   xe       the estimate in the canonical layout: the rig's nx states, then one load factor per
 *            cfg->n_load (NaN: none), or NULL (no estimate)
 *   observe  1: xe carries the objective body's speed (the supervision records it)
 *   u_prog   the programme's inputs now (cfg->nu, the rig's input order)
 *   target   a torque drive's target speed now [rad/s] (ignored otherwise)
 *   flags    SSN_INJECT: fail this call's solve (tests); SSN_BAD_ESTIMATE: the estimate is of
 *            another rig (its caller checked its names)
 *   u        out: the action, cfg->nv entries (the commanded inputs: set-point first); when
 *            info->n_u is 0 the action is the programme and u holds the programme's values
 * Returns info->status. */
int ssn_step(ssn_mem* m, double t, const double* y, const double* xe, int observe, const double* u_prog,
             double target, int flags, double* u, ssn_info* info);

/* the last plan (N x nv commanded inputs, stage-major) and the OCP parameters it was solved with
   (nq); NULL before the first plan */
const double* ssn_plan(const ssn_mem* m);
const double* ssn_last_q(const ssn_mem* m);
/* counters since the last reset: solver failures */
int ssn_failures(const ssn_mem* m);

#ifdef __cplusplus
}
#endif
#endif
