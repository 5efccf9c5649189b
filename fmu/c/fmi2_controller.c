/*
 * dobkit controller FMU: the FMI 2.0 Co-Simulation interface of a scenario's digital controller.
 *
 * One doStep is one sample tick of the controller (the communication step must be its sample period).
 * At tick k (t_k = k Ts) the outputs tau[i], d_hat[i] are those of the monolithic sampled loop
 * (blocks/hybrid.py, tick_outputs): they are computed from the inputs q[i], dq[i] set at t_k, the
 * controller's state and the reference row k, so a Gauss-Seidel master (set q, dq; read tau; step the
 * plant with tau held) reproduces the sampled run.  doStep then applies the tick's updates (encoder,
 * observer, delay buffer) and moves to t_{k+1}.  The maths of a tick is generated from the kernels
 * (controller_tick.c); the reference is a table of one row per tick (controller_reference.c).
 *
 * Every function of the standard header is defined; Model Exchange and FMU-state functions log why
 * they are refused and return fmi2Error.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "controller_config.h"
#include "controller_tick.h"

#define N CTRL_N
#define NOUT (3 * CTRL_N)
#define NE ((CTRL_N + 1) * (CTRL_N + 1))
#define XSIZE (CTRL_NX > 0 ? CTRL_NX : 1)

extern const double CTRL_REF[];

typedef enum { MODE_INSTANTIATED, MODE_INIT, MODE_STEP, MODE_TERMINATED, MODE_FAILED } Mode;

typedef struct {
    char name[256];
    fmi2CallbackFunctions cb;
    int logging_on;
    Mode mode;
    long k;                       /* tick number: time = k Ts */
    double in[2 * N];             /* q, dq */
    double theta[CTRL_NTHETA];
    double x[XSIZE];
    double out[NOUT];             /* tau, d_hat, tau_cmd at tick k */
    int started, outputs_valid;
} Ctrl;

static const int TUNABLE_THETA[N_TUNABLE] = CTRL_TUNABLE_THETA;
static const char *TUNABLE_NAMES[N_TUNABLE] = CTRL_TUNABLE_NAMES;
static const double THETA0[CTRL_NTHETA] = CTRL_THETA0;

static void log_message(Ctrl *c, fmi2Status status, const char *category, const char *format, ...)
{
    char text[1024], safe[2100];
    size_t i, j = 0;
    va_list args;
    if (!c->cb.logger) return;
    if (status == fmi2OK && !c->logging_on) return;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    for (i = 0; text[i] && j + 2 < sizeof safe; i++) {   /* the logger reads a printf format: escape '%' */
        if (text[i] == '%') safe[j++] = '%';
        safe[j++] = text[i];
    }
    safe[j] = '\0';
    c->cb.logger(c->cb.componentEnvironment, c->name, status, category, safe);
}

#define C(p) ((Ctrl *)(p))
#define CHECK(p) do { if (!(p)) return fmi2Error; } while (0)

static fmi2Status refuse(fmi2Component c, const char *function)
{
    if (c) log_message(C(c), fmi2Error, "logStatusError", "%s is not supported by this FMU (Co-Simulation "
                       "only, no FMU state)", function);
    return fmi2Error;
}

static fmi2Status fail(Ctrl *c, const char *format, const char *detail)
{
    log_message(c, fmi2Error, "logStatusError", format, detail);
    return fmi2Error;
}

/* ---- one tick --------------------------------------------------------------- */

static double tick_time(const Ctrl *c) { return (double)c->k * CTRL_PERIOD; }

static fmi2Status compute_outputs(Ctrl *c)
{
    const double *ref;
    int i, j;
    if (c->outputs_valid) return fmi2OK;
    if (c->k >= CTRL_NTICKS) {
        log_message(c, fmi2Error, "logStatusError", "the reference table ends at t = %.17g s (reference_end, "
                    "the scenario's simulation.t_final); tick %ld is past it", CTRL_REFERENCE_END, c->k);
        return fmi2Error;
    }
    ref = CTRL_REF + (size_t)c->k * (size_t)(3 * N);
    if (!c->started) {
        /* the first tick: states from the first inputs, the delay buffer holding the first command */
        ctrl_start(c->in, c->theta, c->x);
        if (CTRL_BUF_LEN > 0) {
            ctrl_outputs(tick_time(c), c->x, c->in, ref, c->theta, c->out);
            for (i = 0; i < CTRL_BUF_LEN; i += N)
                for (j = 0; j < N; j++) c->x[CTRL_BUF_START + i + j] = c->out[2 * N + j];
        }
        c->started = 1;
    }
    ctrl_outputs(tick_time(c), c->x, c->in, ref, c->theta, c->out);
    for (i = 0; i < NOUT; i++)
        if (!isfinite(c->out[i])) {
            log_message(c, fmi2Error, "logStatusError", "the controller's output %d is not finite at t = %.17g s",
                        i, tick_time(c));
            return fmi2Error;
        }
    c->outputs_valid = 1;
    return fmi2OK;
}

static fmi2Status tick_update(Ctrl *c)
{
    double e[NE], a[NE], xn[XSIZE];
    const double *ref;
    if (compute_outputs(c) != fmi2OK) return fmi2Error;
    ref = CTRL_REF + (size_t)c->k * (size_t)(3 * N);
    memset(e, 0, sizeof e);
#if CTRL_ZOH
    ctrl_zoh_matrix(tick_time(c), c->x, c->in, ref, c->theta, a);
    if (dk_expm(N + 1, a, e) != 0) {
        log_message(c, fmi2Error, "logStatusError", "the observer's zero-order-hold matrix is not finite at "
                    "t = %.17g s", tick_time(c));
        return fmi2Error;
    }
#else
    (void)a;
#endif
    ctrl_update(tick_time(c), c->x, c->in, ref, c->theta, e, xn);
    memcpy(c->x, xn, sizeof(double) * (size_t)CTRL_NX);
    c->k += 1;
    c->outputs_valid = 0;
    return fmi2OK;
}

/* ---- common functions --------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    (void)nCategories;
    (void)categories;
    CHECK(c);
    C(c)->logging_on = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Ctrl *c;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    c = (Ctrl *)calloc(1, sizeof *c);
    if (!c) return NULL;
    c->cb = *functions;
    snprintf(c->name, sizeof c->name, "%s", instanceName ? instanceName : "controller");
    if (!fmuGUID || strcmp(fmuGUID, CTRL_TOKEN) != 0) {
        log_message(c, fmi2Error, "logStatusError", "GUID mismatch: the importer passed '%s' but this binary was "
                    "built for '" CTRL_TOKEN "'; the model description and the binary are not of one export",
                    fmuGUID ? fmuGUID : "(null)");
        free(c);
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        log_message(c, fmi2Error, "logStatusError", "this controller FMU is Co-Simulation only (a sampled "
                    "program has no continuous states); Model Exchange was requested");
        free(c);
        return NULL;
    }
    c->logging_on = loggingOn ? 1 : 0;
    memcpy(c->theta, THETA0, sizeof THETA0);
    c->mode = MODE_INSTANTIATED;
    return c;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    CHECK(c);
    if (startTime != 0.0) {
        log_message(C(c), fmi2Error, "logStatusError", "fmi2SetupExperiment: startTime = %.17g s; the "
                    "controller's reference starts at t = 0 (startTime must be 0)", startTime);
        return fmi2Error;
    }
    if (stopTimeDefined && stopTime > CTRL_REFERENCE_END * (1.0 + 1e-12)) {
        log_message(C(c), fmi2Error, "logStatusError", "fmi2SetupExperiment: stopTime = %.17g s is past the end "
                    "of the reference table, t = %.17g s (reference_end)", stopTime, CTRL_REFERENCE_END);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    CHECK(c);
    C(c)->mode = MODE_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    CHECK(c);
    C(c)->mode = MODE_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    CHECK(c);
    C(c)->mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    Ctrl *p = C(c);
    CHECK(c);
    p->mode = MODE_INSTANTIATED;
    p->k = 0;
    p->started = p->outputs_valid = 0;
    memset(p->in, 0, sizeof p->in);
    memset(p->x, 0, sizeof p->x);
    memcpy(p->theta, THETA0, sizeof THETA0);
    return fmi2OK;
}

/* ---- values --------------------------------------------------------------------- */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    size_t i;
    Ctrl *p = C(c);
    CHECK(c);
    for (i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];
        if (r < VR_TAU) {
            value[i] = p->in[r];
        } else if (r < VR_PARAM) {
            if (compute_outputs(p) != fmi2OK) return fmi2Error;
            value[i] = p->out[r - VR_TAU];
        } else if (r < VR_PARAM + N_TUNABLE) {
            value[i] = p->theta[TUNABLE_THETA[r - VR_PARAM]];
        } else if (r == VR_SAMPLE_PERIOD) {
            value[i] = CTRL_PERIOD;
        } else if (r == VR_REFERENCE_END) {
            value[i] = CTRL_REFERENCE_END;
        } else {
            log_message(p, fmi2Error, "logStatusError", "fmi2GetReal: unknown value reference %u", (unsigned)r);
            return fmi2Error;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    size_t i;
    Ctrl *p = C(c);
    CHECK(c);
    for (i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];
        if (!isfinite(value[i])) {
            log_message(p, fmi2Error, "logStatusError", "fmi2SetReal: value reference %u: %g is not a finite "
                        "number", (unsigned)r, value[i]);
            return fmi2Error;
        }
        if (r < VR_TAU) {
            p->in[r] = value[i];
        } else if (r >= VR_PARAM && r < VR_PARAM + N_TUNABLE) {
            p->theta[TUNABLE_THETA[r - VR_PARAM]] = value[i];
        } else {
            log_message(p, fmi2Error, "logStatusError", "fmi2SetReal: value reference %u is not an input or a "
                        "tunable parameter (inputs q[i], dq[i]; parameters %s ...)", (unsigned)r,
                        TUNABLE_NAMES[0]);
            return fmi2Error;
        }
        p->outputs_valid = 0;
    }
    return fmi2OK;
}

static fmi2Status no_values(fmi2Component c, size_t nvr, const char *function)
{
    CHECK(c);
    if (nvr == 0) return fmi2OK;
    log_message(C(c), fmi2Error, "logStatusError", "%s: the controller has only Real variables", function);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    (void)vr;
    (void)value;
    return no_values(c, nvr, "fmi2GetInteger");
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    (void)vr;
    (void)value;
    return no_values(c, nvr, "fmi2GetBoolean");
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    (void)vr;
    (void)value;
    return no_values(c, nvr, "fmi2GetString");
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    (void)vr;
    (void)value;
    return no_values(c, nvr, "fmi2SetInteger");
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    (void)vr;
    (void)value;
    return no_values(c, nvr, "fmi2SetBoolean");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    (void)vr;
    (void)value;
    return no_values(c, nvr, "fmi2SetString");
}

/* ---- FMU state and derivatives: not offered ------------------------------------------ */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)s; return refuse(c, "fmi2GetFMUstate"); }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)s; return refuse(c, "fmi2SetFMUstate"); }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)s; return refuse(c, "fmi2FreeFMUstate"); }

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size)
{
    (void)s;
    (void)size;
    return refuse(c, "fmi2SerializedFMUstateSize");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size)
{
    (void)s;
    (void)b;
    (void)size;
    return refuse(c, "fmi2SerializeFMUstate");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s)
{
    (void)b;
    (void)size;
    (void)s;
    return refuse(c, "fmi2DeSerializeFMUstate");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference k[], size_t nk, const fmi2Real dk[],
                                        fmi2Real du[])
{
    (void)u;
    (void)nu;
    (void)k;
    (void)nk;
    (void)dk;
    (void)du;
    return refuse(c, "fmi2GetDirectionalDerivative");
}

/* ---- Model Exchange: not offered ------------------------------------------------------ */

fmi2Status fmi2EnterEventMode(fmi2Component c) { return refuse(c, "fmi2EnterEventMode"); }

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e)
{
    (void)e;
    return refuse(c, "fmi2NewDiscreteStates");
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return refuse(c, "fmi2EnterContinuousTimeMode"); }

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean n, fmi2Boolean *e, fmi2Boolean *t)
{
    (void)n;
    (void)e;
    (void)t;
    return refuse(c, "fmi2CompletedIntegratorStep");
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { (void)t; return refuse(c, "fmi2SetTime"); }

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx)
{
    (void)x;
    (void)nx;
    return refuse(c, "fmi2SetContinuousStates");
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real d[], size_t nx)
{
    (void)d;
    (void)nx;
    return refuse(c, "fmi2GetDerivatives");
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real e[], size_t ni)
{
    (void)e;
    (void)ni;
    return refuse(c, "fmi2GetEventIndicators");
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    (void)x;
    (void)nx;
    return refuse(c, "fmi2GetContinuousStates");
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    (void)x;
    (void)nx;
    return refuse(c, "fmi2GetNominalsOfContinuousStates");
}

/* ---- Co-Simulation ---------------------------------------------------------------------- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    CHECK(c);
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2SetRealInputDerivatives (the controller samples its inputs)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    CHECK(c);
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2GetRealOutputDerivatives (the outputs are held between samples)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    Ctrl *p = C(c);
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(c);
    if (p->mode != MODE_STEP) {
        log_message(p, fmi2Error, "logStatusError", "fmi2DoStep is allowed after fmi2ExitInitializationMode only");
        return fmi2Error;
    }
    if (!(fabs(communicationStepSize - CTRL_PERIOD) <= 1e-9 * CTRL_PERIOD)) {
        log_message(p, fmi2Error, "logStatusError", "fmi2DoStep: communication step %.17g s refused: this "
                    "controller runs at its sample period Ts = %.17g s (%.17g Hz), so every step must be one "
                    "sample, h = Ts", communicationStepSize, CTRL_PERIOD, 1.0 / CTRL_PERIOD);
        return fmi2Error;
    }
    if (!(fabs(currentCommunicationPoint - tick_time(p)) <= 1e-6 * CTRL_PERIOD)) {
        log_message(p, fmi2Error, "logStatusError", "fmi2DoStep: currentCommunicationPoint %.17g s is not the "
                    "controller's time %.17g s (tick %ld of period %.17g s)", currentCommunicationPoint,
                    tick_time(p), p->k, CTRL_PERIOD);
        return fmi2Error;
    }
    if (p->k + 1 >= CTRL_NTICKS) {
        log_message(p, fmi2Error, "logStatusError", "fmi2DoStep at t = %.17g s: the reference table ends at "
                    "t = %.17g s (reference_end, the scenario's simulation.t_final)", tick_time(p),
                    CTRL_REFERENCE_END);
        return fmi2Error;
    }
    if (tick_update(p) != fmi2OK) {
        p->mode = MODE_FAILED;
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { return refuse(c, "fmi2CancelStep (doStep never returns pending)"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    CHECK(c);
    if (s == fmi2DoStepStatus) {
        *value = C(c)->mode == MODE_FAILED ? fmi2Error : fmi2OK;
        return fmi2OK;
    }
    return refuse(c, "fmi2GetStatus for this status kind");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    CHECK(c);
    if (s == fmi2LastSuccessfulTime) {
        *value = tick_time(C(c));
        return fmi2OK;
    }
    return refuse(c, "fmi2GetRealStatus for this status kind");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s;
    (void)value;
    return refuse(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    CHECK(c);
    if (s == fmi2Terminated) {
        *value = fmi2False;
        return fmi2OK;
    }
    return refuse(c, "fmi2GetBooleanStatus for this status kind");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s;
    (void)value;
    return refuse(c, "fmi2GetStringStatus");
}
