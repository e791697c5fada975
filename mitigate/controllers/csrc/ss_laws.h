/* The drilling industry's laws and the brake in C: SoftSpeed, Z-Torque, D-OSKIL and the semi-active
 * brake, one step each.
 *
 * One implementation of each law (mitigate/controllers/softspeed.py, ztorque.py, doskil.py,
 * brake.py): the workbench calls it through ctypes (implementation = "c", the default), an exported
 * library (mitigate export) calls it from its step().  Generic over the rig: which law, which
 * channels it reads and every gain, limit and filter time come in an ssl_config (ss_laws_config.h,
 * generated from one declaration in mitigate/controllers/compiled.py); the configuration holds
 * numbers only, so one library serves every law on every rig.  No allocation: ssl_memsize() says
 * how much memory one law needs, ssl_init() lays it out in memory the caller owns.
 *
 * The Python steps are the reference: every operation is written in the same order, so the two
 * agree to the last bit, except SoftSpeed's virtual drive, whose exact discretisation (a matrix
 * exponential) is computed here at ssl_init and by scipy in Python (agreement to ~1e-15).
 */
#ifndef SS_LAWS_H
#define SS_LAWS_H

#include <stddef.h>

#include "ss_common.h"
#include "ss_laws_config.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ssl_config.law */
enum { SSL_SOFTSPEED = 1, SSL_ZTORQUE = 2, SSL_DOSKIL = 3, SSL_BRAKE = 4 };

/* what one call did */
typedef struct {
    int status;      /* SS_OK, or SS_FALLBACK: a reading the law needs is missing, the programme acts */
    int n_u;         /* 1: u holds the command; 0: the programme (the fallback) */
    int missing;     /* the y index of the missing reading (-1: none; -2 - i: the estimate e[i]) */
} ssl_info;

typedef struct ssl_mem ssl_mem;

/* bytes of memory one law of this configuration needs (0: an invalid configuration) */
size_t ssl_memsize(const ssl_config* cfg);

/* lay out a law in mem (ssl_memsize bytes, any alignment); the configuration is copied.
   Returns the law, or NULL if the memory is too small or the configuration invalid. */
ssl_mem* ssl_init(void* mem, size_t size, const ssl_config* cfg);

/* forget everything learnt (filters, integrators, the virtual drive): the state before a run */
void ssl_reset(ssl_mem* m);

/* One call of the law at time t [s].
 *   y       the DAQ channels the configuration reads (cfg->n_ch; NaN or inf: missing)
 *   e       speeds from the state estimate: e[0] the servo's body's, e[1] the drive body's (the brake's;
 *           D-OSKIL's e[0] when cfg->est_body)
 *           [rad/s] (NULL: none)
 *   e_mask  bit 0: e[0] is there, bit 1: e[1] is there
 *   w_nom   the target speed now [rad/s] (a speed drive: its programmed set-point; a torque drive:
 *           the scenario's [control] speed)
 *   u_prog  the programme's value of the law's input now (D-OSKIL modulates around it)
 *   u       out: the command of the law's input (when info->n_u is 1)
 * Returns info->status. */
int ssl_step(ssl_mem* m, double t, const double* y, const double* e, int e_mask, double w_nom, double u_prog,
             double* u, ssl_info* info);

/* SoftSpeed's virtual drive over one call period (row-major 2 x 2): z+ = Ad z + Bd (w_nom, T_pipe) */
const double* ssl_virtual_drive(const ssl_mem* m, int which);   /* 0: Ad, 1: Bd */

#ifdef __cplusplus
}
#endif
#endif
