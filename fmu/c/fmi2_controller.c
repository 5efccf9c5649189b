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
#include <stdlib.h>

#include "fmi2Functions.h"
#include "fmi2_common.h"
#include "controller_core.h"

typedef struct {
    CtrlCore core;                /* first member: a CtrlCore* is a Fmi2Ctrl* */
    fmi2CallbackFunctions cb;
} Fmi2Ctrl;

static void emit2(void *ctx, int status, const char *category, const char *message)
{
    Fmi2Ctrl *c = (Fmi2Ctrl *)ctx;
    fmi2_log(&c->cb, c->core.name, (fmi2Status)status, category, message);
}

#define C(p) ((CtrlCore *)(p))
#define CHECK(p) FMI2_CHECK(p)

fmi2Status fmi2_layer_refuse(fmi2Component c, const char *function)
{
    if (c) ctrl_log(C(c), CTRL_ERROR, "%s is not supported by this FMU (Co-Simulation only, no FMU state)",
                    function);
    return fmi2Error;
}

/* ---- hooks of the shared entry points (fmi2_common.c) ---------------------------------- */

void fmi2_layer_set_logging(fmi2Component c, int on) { C(c)->logging_on = on; }

int fmi2_layer_get_real(fmi2Component c, fmi2ValueReference vr, fmi2Real *value)
{
    return ctrl_get_real(C(c), vr, value) != CTRL_OK;
}

int fmi2_layer_set_real(fmi2Component c, fmi2ValueReference vr, fmi2Real value)
{
    return ctrl_set_real(C(c), vr, value) != CTRL_OK;
}

int fmi2_layer_failed(fmi2Component c) { return C(c)->mode == CTRL_FAILED; }

fmi2Real fmi2_layer_time(fmi2Component c) { return ctrl_time(C(c)); }

/* ---- life cycle --------------------------------------------------------------------- */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Fmi2Ctrl *c;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    if (!fmi2_token_matches(functions, instanceName, fmuGUID, CTRL_TOKEN)) return NULL;
    if (fmuType != fmi2CoSimulation) {
        fmi2_log(functions, instanceName, fmi2Error, "logStatusError", "this controller FMU is Co-Simulation "
                 "only (a sampled program has no continuous states); Model Exchange was requested");
        return NULL;
    }
    c = (Fmi2Ctrl *)calloc(1, sizeof *c);
    if (!c) return NULL;
    c->cb = *functions;
    ctrl_init(&c->core, instanceName, loggingOn ? 1 : 0, emit2, c);
    return c;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    CHECK(c);
    return (fmi2Status)ctrl_setup(C(c), startTime, stopTimeDefined != fmi2False, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    CHECK(c);
    C(c)->mode = CTRL_INITIALIZING;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    CHECK(c);
    C(c)->mode = CTRL_STEPPING;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    CHECK(c);
    C(c)->mode = CTRL_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    CHECK(c);
    ctrl_reset(C(c));
    return fmi2OK;
}

/* ---- values --------------------------------------------------------------------- */

static fmi2Status no_values(fmi2Component c, size_t nvr, const char *function)
{
    CHECK(c);
    if (nvr == 0) return fmi2OK;
    ctrl_log(C(c), CTRL_ERROR, "%s: the controller has only Real variables", function);
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

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    (void)s;
    return fmi2_layer_refuse(c, "fmi2GetFMUstate");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s)
{
    (void)s;
    return fmi2_layer_refuse(c, "fmi2SetFMUstate");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    (void)s;
    return fmi2_layer_refuse(c, "fmi2FreeFMUstate");
}


fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size)
{
    (void)s;
    (void)size;
    return fmi2_layer_refuse(c, "fmi2SerializedFMUstateSize");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size)
{
    (void)s;
    (void)b;
    (void)size;
    return fmi2_layer_refuse(c, "fmi2SerializeFMUstate");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s)
{
    (void)b;
    (void)size;
    (void)s;
    return fmi2_layer_refuse(c, "fmi2DeSerializeFMUstate");
}

/* ---- Model Exchange: not offered ------------------------------------------------------ */

fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2_layer_refuse(c, "fmi2EnterEventMode"); }

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e)
{
    (void)e;
    return fmi2_layer_refuse(c, "fmi2NewDiscreteStates");
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2_layer_refuse(c, "fmi2EnterContinuousTimeMode"); }

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean n, fmi2Boolean *e, fmi2Boolean *t)
{
    (void)n;
    (void)e;
    (void)t;
    return fmi2_layer_refuse(c, "fmi2CompletedIntegratorStep");
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { (void)t; return fmi2_layer_refuse(c, "fmi2SetTime"); }

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx)
{
    (void)x;
    (void)nx;
    return fmi2_layer_refuse(c, "fmi2SetContinuousStates");
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real d[], size_t nx)
{
    (void)d;
    (void)nx;
    return fmi2_layer_refuse(c, "fmi2GetDerivatives");
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real e[], size_t ni)
{
    (void)e;
    (void)ni;
    return fmi2_layer_refuse(c, "fmi2GetEventIndicators");
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    (void)x;
    (void)nx;
    return fmi2_layer_refuse(c, "fmi2GetContinuousStates");
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    (void)x;
    (void)nx;
    return fmi2_layer_refuse(c, "fmi2GetNominalsOfContinuousStates");
}

/* ---- Co-Simulation ---------------------------------------------------------------------- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    CHECK(c);
    return nvr == 0 ? fmi2OK : fmi2_layer_refuse(c, "fmi2SetRealInputDerivatives (the controller samples its inputs)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    CHECK(c);
    if (nvr == 0) return fmi2OK;
    return fmi2_layer_refuse(c, "fmi2GetRealOutputDerivatives (the outputs are held between samples)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(c);
    return (fmi2Status)ctrl_do_step(C(c), currentCommunicationPoint, communicationStepSize);
}
