/* The FMI 2.0 co-simulation interface of an exported controller (written by `mitigate export --fmu`).
 *
 * One fmi2DoStep of h seconds runs the library's step h / DAQ period times (a whole number, else
 * fmi2Error), each at t = currentCommunicationPoint + k * DAQ period with the inputs as last set.
 * The outputs are those of the last step.  The runtime parameters are fixed: they are set before
 * fmi2ExitInitializationMode, which creates the library with them (the library's one allocation);
 * fmi2Reset destroys it and restores every start value.
 *
 * fmu_config.h (generated per export) names the library (LIB_HEADER, LIB(f)) and gives the layout:
 *   Real value references  [0, N_IN)                 in[]   (inputs)
 *                          [N_IN, N_IN + N_OUT)      out[]  (outputs: the commands, then the estimate)
 *                          VR_SOLVE_TIME             the last OCP solve's wall time [s] (output)
 *                          [VR_PAR, VR_PAR + N_PAR)  params[] (fixed parameters)
 *   Integer value reference VR_STATUS                the last step's status (output)
 * and start_real[], real_names[], cmd_programme[] (the in[] entry of each command's programme
 * value, -1: none).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmu_config.h"
#include LIB_HEADER

#define N_REAL (VR_PAR + N_PAR)

typedef enum { M_INSTANTIATED, M_INITIALIZATION, M_STEP, M_TERMINATED, M_ERROR } mode_t_;

typedef struct {
    LIB_TYPE* lib;
    fmi2CallbackFunctions cb;
    char name[128];
    int logging;
    mode_t_ mode;
    double time;
    int status;
    double r[N_REAL];
} comp;

static void say(comp* c, fmi2Status st, const char* category, const char* fmt, ...) {
    char msg[512];
    va_list ap;
    if (!c || !c->cb.logger) return;
    if (!c->logging && st == fmi2OK) return;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);
    c->cb.logger(c->cb.componentEnvironment, c->name, st, category, "%s", msg);
}

static fmi2Status fail(comp* c, const char* fn, const char* fmt, ...) {
    char msg[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);
    say(c, fmi2Error, "logStatusError", "%s: %s", fn, msg);
    return fmi2Error;
}

static int is_input(fmi2ValueReference vr) { return vr < N_IN; }
static int is_output(fmi2ValueReference vr) { return vr >= N_IN && vr <= VR_SOLVE_TIME; }
static int is_param(fmi2ValueReference vr) { return vr >= VR_PAR && vr < N_REAL; }

/* the outputs before the first step: the commands pass the programme through, no estimate yet */
static void initial_outputs(comp* c) {
    int j;
    for (j = 0; j < N_OUT; j++) c->r[N_IN + j] = 0.0;
    for (j = 0; j < N_CMD; j++) c->r[N_IN + j] = cmd_programme[j] >= 0 ? c->r[cmd_programme[j]] : 0.0;
    c->r[VR_SOLVE_TIME] = 0.0;
    c->status = 0;
}

/* ---- common functions ------------------------------------------------------------------------ */

FMI2_Export const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char* fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t n,
                                           const fmi2String categories[]) {
    (void)n; (void)categories;
    if (!c) return fmi2Error;
    ((comp*)c)->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

FMI2_Export fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                          fmi2String fmuResourceLocation, const fmi2CallbackFunctions* functions,
                                          fmi2Boolean visible, fmi2Boolean loggingOn) {
    comp* c;
    (void)fmuResourceLocation; (void)visible;
    if (!functions || !functions->logger) return NULL;
    if (fmuType != fmi2CoSimulation) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                          "fmi2Instantiate: this FMU is for co-simulation only");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, FMU_GUID) != 0) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                          "fmi2Instantiate: GUID %s does not match this binary's %s", fmuGUID ? fmuGUID : "(null)",
                          FMU_GUID);
        return NULL;
    }
    c = (comp*)calloc(1, sizeof(comp));
    if (!c) return NULL;
    c->cb = *functions;
    snprintf(c->name, sizeof(c->name), "%s", instanceName ? instanceName : "");
    c->logging = loggingOn ? 1 : 0;
    memcpy(c->r, start_real, sizeof(c->r));
    initial_outputs(c);
    c->mode = M_INSTANTIATED;
    return c;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) {
    comp* s = (comp*)c;
    if (!s) return;
    if (s->lib) LIB(destroy)(s->lib);
    free(s);
}

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                                           fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    comp* s = (comp*)c;
    (void)toleranceDefined; (void)tolerance; (void)stopTimeDefined; (void)stopTime;
    if (!s) return fmi2Error;
    if (s->mode != M_INSTANTIATED) return fail(s, "fmi2SetupExperiment", "only after fmi2Instantiate");
    s->time = startTime;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    comp* s = (comp*)c;
    if (!s) return fmi2Error;
    if (s->mode != M_INSTANTIATED) return fail(s, "fmi2EnterInitializationMode", "only after fmi2Instantiate");
    s->mode = M_INITIALIZATION;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    comp* s = (comp*)c;
    int i;
    if (!s) return fmi2Error;
    if (s->mode != M_INITIALIZATION) return fail(s, "fmi2ExitInitializationMode", "only in initialization mode");
    for (i = 0; i < N_PAR; i++)
        if (!isfinite(s->r[VR_PAR + i])) {
            s->mode = M_ERROR;
            return fail(s, "fmi2ExitInitializationMode", "parameter %s = %g is not finite", real_names[VR_PAR + i],
                        s->r[VR_PAR + i]);
        }
    s->lib = LIB(create)(s->r + VR_PAR);
    if (!s->lib) {
        s->mode = M_ERROR;
        return fail(s, "fmi2ExitInitializationMode", "the library's create() refused the parameters");
    }
    initial_outputs(s);
    s->mode = M_STEP;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component c) {
    comp* s = (comp*)c;
    if (!s) return fmi2Error;
    if (s->mode != M_STEP && s->mode != M_ERROR) return fail(s, "fmi2Terminate", "only after initialization");
    s->mode = M_TERMINATED;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Reset(fmi2Component c) {
    comp* s = (comp*)c;
    if (!s) return fmi2Error;
    if (s->lib) LIB(destroy)(s->lib);
    s->lib = NULL;
    memcpy(s->r, start_real, sizeof(s->r));
    initial_outputs(s);
    s->time = 0.0;
    s->mode = M_INSTANTIATED;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    comp* s = (comp*)c;
    size_t i;
    if (!s) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] >= N_REAL) return fail(s, "fmi2GetReal", "no Real variable has value reference %u", vr[i]);
        value[i] = s->r[vr[i]];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      fmi2Integer value[]) {
    comp* s = (comp*)c;
    size_t i;
    if (!s) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_STATUS) return fail(s, "fmi2GetInteger", "no Integer variable has value reference %u", vr[i]);
        value[i] = s->status;
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      fmi2Boolean value[]) {
    (void)vr; (void)value;
    return nvr ? fail((comp*)c, "fmi2GetBoolean", "this FMU has no Boolean variable") : fmi2OK;
}

FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)vr; (void)value;
    return nvr ? fail((comp*)c, "fmi2GetString", "this FMU has no String variable") : fmi2OK;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                   const fmi2Real value[]) {
    comp* s = (comp*)c;
    size_t i;
    if (!s) return fmi2Error;
    if (s->mode == M_TERMINATED || s->mode == M_ERROR) return fail(s, "fmi2SetReal", "the FMU is terminated");
    for (i = 0; i < nvr; i++) {
        fmi2ValueReference v = vr[i];
        if (v >= N_REAL) return fail(s, "fmi2SetReal", "no Real variable has value reference %u", v);
        if (is_output(v)) return fail(s, "fmi2SetReal", "%s is an output", real_names[v]);
        if (is_param(v) && s->mode == M_STEP)
            return fail(s, "fmi2SetReal", "%s is a fixed parameter: set it before fmi2ExitInitializationMode "
                        "(or after fmi2Reset)", real_names[v]);
        if (!is_input(v) && !is_param(v)) return fail(s, "fmi2SetReal", "value reference %u cannot be set", v);
        s->r[v] = value[i];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Integer value[]) {
    (void)vr; (void)value;
    return nvr ? fail((comp*)c, "fmi2SetInteger", "this FMU has no Integer input or parameter") : fmi2OK;
}

FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Boolean value[]) {
    (void)vr; (void)value;
    return nvr ? fail((comp*)c, "fmi2SetBoolean", "this FMU has no Boolean variable") : fmi2OK;
}

FMI2_Export fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                     const fmi2String value[]) {
    (void)vr; (void)value;
    return nvr ? fail((comp*)c, "fmi2SetString", "this FMU has no String variable") : fmi2OK;
}

/* canGetAndSetFMUstate = false, providesDirectionalDerivative = false */
FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* st) {
    (void)st; return fail((comp*)c, "fmi2GetFMUstate", "not supported (canGetAndSetFMUstate = false)");
}
FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate st) {
    (void)st; return fail((comp*)c, "fmi2SetFMUstate", "not supported (canGetAndSetFMUstate = false)");
}
FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* st) {
    (void)st; return fail((comp*)c, "fmi2FreeFMUstate", "not supported (canGetAndSetFMUstate = false)");
}
FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate st, size_t* size) {
    (void)st; (void)size; return fail((comp*)c, "fmi2SerializedFMUstateSize", "not supported");
}
FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate st, fmi2Byte b[], size_t size) {
    (void)st; (void)b; (void)size; return fail((comp*)c, "fmi2SerializeFMUstate", "not supported");
}
FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate* st) {
    (void)b; (void)size; (void)st; return fail((comp*)c, "fmi2DeSerializeFMUstate", "not supported");
}
FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                                    const fmi2ValueReference k[], size_t nk, const fmi2Real dk[],
                                                    fmi2Real du[]) {
    (void)u; (void)nu; (void)k; (void)nk; (void)dk; (void)du;
    return fail((comp*)c, "fmi2GetDirectionalDerivative", "not supported (providesDirectionalDerivative = false)");
}

/* ---- model exchange: not provided (a co-simulation FMU) -------------------------------------- */

#define NOT_ME(fn) return fail((comp*)c, fn, "this FMU is for co-simulation only")
FMI2_Export fmi2Status fmi2EnterEventMode(fmi2Component c) { NOT_ME("fmi2EnterEventMode"); }
FMI2_Export fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo* e) { (void)e; NOT_ME("fmi2NewDiscreteStates"); }
FMI2_Export fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { NOT_ME("fmi2EnterContinuousTimeMode"); }
FMI2_Export fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean a, fmi2Boolean* e, fmi2Boolean* t) {
    (void)a; (void)e; (void)t; NOT_ME("fmi2CompletedIntegratorStep");
}
FMI2_Export fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { (void)t; NOT_ME("fmi2SetTime"); }
FMI2_Export fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    (void)x; (void)n; NOT_ME("fmi2SetContinuousStates");
}
FMI2_Export fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real d[], size_t n) {
    (void)d; (void)n; NOT_ME("fmi2GetDerivatives");
}
FMI2_Export fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real e[], size_t n) {
    (void)e; (void)n; NOT_ME("fmi2GetEventIndicators");
}
FMI2_Export fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    (void)x; (void)n; NOT_ME("fmi2GetContinuousStates");
}
FMI2_Export fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    (void)x; (void)n; NOT_ME("fmi2GetNominalsOfContinuousStates");
}

/* ---- co-simulation ----------------------------------------------------------------------------- */

FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                                   const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return fail((comp*)c, "fmi2SetRealInputDerivatives", "not supported (canInterpolateInputs = false)");
}

FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                                    const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return fail((comp*)c, "fmi2GetRealOutputDerivatives", "not supported (maxOutputDerivativeOrder = 0)");
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    comp* s = (comp*)c;
    double periods, in[N_IN], out[N_OUT];
    long n, k;
    int st = 0;
    (void)noSetPrior;
    if (!s) return fmi2Error;
    if (s->mode != M_STEP) return fail(s, "fmi2DoStep", "only after fmi2ExitInitializationMode");
    periods = h / FMU_DT;
    n = (long)floor(periods + 0.5);
    if (!(n >= 1) || fabs(periods - (double)n) > 1e-6)
        return fail(s, "fmi2DoStep", "communicationStepSize = %.17g s is not a whole number of DAQ periods "
                    "(%.17g s)", h, FMU_DT);
    if (fabs(t - s->time) > 1e-6 * FMU_DT)
        return fail(s, "fmi2DoStep", "currentCommunicationPoint = %.17g s, but the FMU is at %.17g s", t, s->time);
    memcpy(in, s->r, sizeof(in));
    for (k = 0; k < n; k++) st = LIB(step)(s->lib, t + (double)k * FMU_DT, in, out);
    memcpy(s->r + N_IN, out, sizeof(out));
    s->r[VR_SOLVE_TIME] = LIB(last_solve_time)(s->lib);
    s->status = st;
    s->time = t + h;
    if (st == LIB_FAILED) {
        say(s, fmi2Warning, "logStatusWarning", "fmi2DoStep: the step at t = %g s failed (a non-finite output): "
            "the commands are the programme's", t + (double)(n - 1) * FMU_DT);
        return fmi2Warning;
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c) {
    return fail((comp*)c, "fmi2CancelStep", "not supported (canRunAsynchronuously = false)");
}

FMI2_Export fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status* value) {
    (void)k; (void)value;
    return fail((comp*)c, "fmi2GetStatus", "no asynchronous step (canRunAsynchronuously = false)");
}

FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real* value) {
    comp* s = (comp*)c;
    if (!s) return fmi2Error;
    if (k != fmi2LastSuccessfulTime) return fail(s, "fmi2GetRealStatus", "only fmi2LastSuccessfulTime");
    *value = s->time;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer* value) {
    (void)k; (void)value;
    return fail((comp*)c, "fmi2GetIntegerStatus", "no integer status");
}

FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean* value) {
    comp* s = (comp*)c;
    if (!s) return fmi2Error;
    if (k != fmi2Terminated) return fail(s, "fmi2GetBooleanStatus", "only fmi2Terminated");
    *value = fmi2False;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String* value) {
    (void)k; (void)value;
    return fail((comp*)c, "fmi2GetStringStatus", "no string status");
}
