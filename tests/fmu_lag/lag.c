/*
 * A first-order lag as an FMI 2.0 FMU (Model Exchange and Co-Simulation),
 * written for dobkit's tests independently of the plant FMU:
 *
 *     x' = (u - x) / T,   outputs x and e = u - x.
 *
 * Co-Simulation advances with the exact solution for an input held over the
 * step, x(t + h) = u + (x(t) - u) exp(-h / T).  Any state beyond |x| > x_max
 * is reported as an error (so the tests can provoke an error status).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define LAG_GUID "{5f0c9b0e-7a31-4d7e-9c55-1a2b3c4d5e6f}"
enum { VR_TIME, VR_X, VR_DER_X, VR_U, VR_E, VR_T, VR_XMAX, N_VR };

typedef struct {
    double v[N_VR];
    int cosim;
    fmi2CallbackFunctions cb;
    char name[64];
} Lag;

static void say(Lag *m, fmi2Status s, const char *text)
{
    if (m->cb.logger) m->cb.logger(m->cb.componentEnvironment, m->name, s, "logStatusError", text);
}

static fmi2Status check_bound(Lag *m)
{
    char text[160];
    if (fabs(m->v[VR_X]) <= m->v[VR_XMAX]) return fmi2OK;
    snprintf(text, sizeof text, "x = %g exceeds x_max = %g at t = %g s", m->v[VR_X], m->v[VR_XMAX], m->v[VR_TIME]);
    say(m, fmi2Error, text);
    return fmi2Error;
}

static double value(Lag *m, fmi2ValueReference vr)
{
    if (vr == VR_DER_X) return (m->v[VR_U] - m->v[VR_X]) / m->v[VR_T];
    if (vr == VR_E) return m->v[VR_U] - m->v[VR_X];
    return m->v[vr];
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[])
{
    (void)c; (void)on; (void)n; (void)cat;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging)
{
    Lag *m;
    (void)res; (void)visible; (void)logging;
    if (!cb || !guid || strcmp(guid, LAG_GUID) != 0) return NULL;
    m = (Lag *)calloc(1, sizeof *m);
    if (!m) return NULL;
    m->cb = *cb;
    m->cosim = type == fmi2CoSimulation;
    snprintf(m->name, sizeof m->name, "%s", name ? name : "lag");
    m->v[VR_T] = 0.5;
    m->v[VR_XMAX] = 1e10;
    return m;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0, fmi2Boolean sd,
                               fmi2Real t1)
{
    (void)td; (void)tol; (void)sd; (void)t1;
    ((Lag *)c)->v[VR_TIME] = t0;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    Lag *m = (Lag *)c;
    if (!(m->v[VR_T] > 0.0)) {
        say(m, fmi2Error, "T must be > 0");
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real val[])
{
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] >= N_VR) return fmi2Error;
        val[i] = value((Lag *)c, vr[i]);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real val[])
{
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] != VR_X && vr[i] != VR_U && vr[i] != VR_T && vr[i] != VR_XMAX) return fmi2Error;
        ((Lag *)c)->v[vr[i]] = val[i];
    }
    return fmi2OK;
}

#define NO_VARIABLES(fn, type)                                                                     \
    fmi2Status fn(fmi2Component c, const fmi2ValueReference vr[], size_t n, type val[])            \
    {                                                                                              \
        (void)c; (void)vr; (void)val;                                                              \
        return n == 0 ? fmi2OK : fmi2Error;                                                        \
    }
NO_VARIABLES(fmi2GetInteger, fmi2Integer)
NO_VARIABLES(fmi2GetBoolean, fmi2Boolean)
NO_VARIABLES(fmi2GetString, fmi2String)
NO_VARIABLES(fmi2SetInteger, const fmi2Integer)
NO_VARIABLES(fmi2SetBoolean, const fmi2Boolean)
NO_VARIABLES(fmi2SetString, const fmi2String)

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n)
{
    (void)c; (void)s; (void)n;
    return fmi2Error;
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n)
{
    (void)c; (void)s; (void)b; (void)n;
    return fmi2Error;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s)
{
    (void)c; (void)b; (void)n; (void)s;
    return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference k[], size_t nk, const fmi2Real dk[],
                                        fmi2Real du[])
{
    (void)c; (void)u; (void)nu; (void)k; (void)nk; (void)dk; (void)du;
    return fmi2Error;
}

fmi2Status fmi2EnterEventMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info)
{
    (void)c;
    memset(info, 0, sizeof *info);
#ifdef LAG_TIME_EVENT
    /* test variant (compiled via a file that defines LAG_TIME_EVENT): announce a time event at t = 1 s */
    info->nextEventTimeDefined = fmi2True;
    info->nextEventTime = 1.0;
#endif
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean nosave, fmi2Boolean *event,
                                       fmi2Boolean *stop)
{
    (void)c; (void)nosave;
    *event = fmi2False;
    *stop = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t)
{
    ((Lag *)c)->v[VR_TIME] = t;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n)
{
    if (n != 1) return fmi2Error;
    ((Lag *)c)->v[VR_X] = x[0];
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n)
{
    if (n != 1) return fmi2Error;
    dx[0] = value((Lag *)c, VR_DER_X);
    return check_bound((Lag *)c);
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n)
{
    (void)c; (void)z;
    return n == 0 ? fmi2OK : fmi2Error;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n)
{
    if (n != 1) return fmi2Error;
    x[0] = ((Lag *)c)->v[VR_X];
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n)
{
    (void)c;
    if (n != 1) return fmi2Error;
    x[0] = 1.0;
    return fmi2OK;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer o[], const fmi2Real v[])
{
    (void)c; (void)vr; (void)n; (void)o; (void)v;
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer o[], fmi2Real v[])
{
    (void)c; (void)vr; (void)n; (void)o; (void)v;
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean nosave)
{
    Lag *m = (Lag *)c;
    const double u = m->v[VR_U];
    (void)nosave;
    m->v[VR_X] = u + (m->v[VR_X] - u) * exp(-h / m->v[VR_T]);
    m->v[VR_TIME] = t + h;
    return check_bound(m);
}

fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v)
{
    (void)c; (void)k; (void)v;
    return fmi2Error;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v)
{
    (void)c; (void)k; (void)v;
    return fmi2Error;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v)
{
    (void)c; (void)k; (void)v;
    return fmi2Error;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v)
{
    (void)c; (void)k; (void)v;
    return fmi2Error;
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v)
{
    (void)c; (void)k; (void)v;
    return fmi2Error;
}
