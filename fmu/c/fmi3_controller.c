/*
 * dobkit controller FMU: the FMI 3.0 Co-Simulation interface of a scenario's digital controller.
 *
 * The same instance core as FMI 2 (controller_core.c): one fmi3DoStep is one sample tick, its
 * communication step must be the sample period; tau[i], d_hat[i] of tick k are computed from the
 * inputs q[i], dq[i] set at t_k.  The controller has no events, clocks or continuous states: event mode
 * is never needed (eventModeUsed is ignored), Model Exchange and Scheduled Execution are not offered.
 *
 * Every function of the standard header is defined; those the FMU does not support log why and
 * return fmi3Error.
 */
#include <stdlib.h>

#include "fmi3Functions.h"
#include "fmi3_common.h"
#include "controller_core.h"

typedef struct {
    CtrlCore core;                /* first member: a CtrlCore* is a Fmi3Ctrl* */
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
} Fmi3Ctrl;

static void emit3(void *ctx, int status, const char *category, const char *message)
{
    Fmi3Ctrl *c = (Fmi3Ctrl *)ctx;
    if (c->log) c->log(c->env, (fmi3Status)status, category, message);
}

#define C(p) ((CtrlCore *)(p))
#define CHECK(p) FMI3_CHECK(p)

fmi3Status fmi3_layer_refuse(fmi3Instance c, const char *function)
{
    if (c) ctrl_log(C(c), CTRL_ERROR, "%s is not supported by this FMU (Co-Simulation only; no events, clocks "
                    "or FMU state)", function);
    return fmi3Error;
}

/* ---- hooks of the shared entry points (fmi3_common.c) ---------------------------------- */

void fmi3_layer_error(fmi3Instance c, const char *message) { ctrl_log(C(c), CTRL_ERROR, "%s", message); }

void fmi3_layer_set_logging(fmi3Instance c, int on) { C(c)->logging_on = on; }

int fmi3_layer_get_real(fmi3Instance c, fmi3ValueReference vr, fmi3Float64 *value)
{
    return ctrl_get_real(C(c), vr, value) != CTRL_OK;
}

int fmi3_layer_set_real(fmi3Instance c, fmi3ValueReference vr, fmi3Float64 value)
{
    return ctrl_set_real(C(c), vr, value) != CTRL_OK;
}

/* ---- life cycle ---------------------------------------------------------------------- */

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError", "this controller FMU is Co-Simulation only "
                   "(a sampled program has no continuous states); Model Exchange was requested");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate)
{
    Fmi3Ctrl *c;
    (void)resourcePath;
    (void)visible;
    (void)eventModeUsed;       /* the controller has no events: step mode is never left */
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;  /* the inputs are sampled at the start of a step: nothing to ask during it */
    if (!fmi3_token_matches(instanceEnvironment, logMessage, instantiationToken, CTRL_TOKEN)) return NULL;
    c = (Fmi3Ctrl *)calloc(1, sizeof *c);
    if (!c) return NULL;
    c->env = instanceEnvironment;
    c->log = logMessage;
    ctrl_init(&c->core, instanceName, loggingOn ? 1 : 0, emit3, c);
    return c;
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    CHECK(c);
    if (ctrl_setup(C(c), startTime, stopTimeDefined ? 1 : 0, stopTime) != CTRL_OK) return fmi3Error;
    C(c)->mode = CTRL_INITIALIZING;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance c)
{
    CHECK(c);
    C(c)->mode = CTRL_STEPPING;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance c) { return fmi3_layer_refuse(c, "fmi3EnterEventMode"); }

fmi3Status fmi3Terminate(fmi3Instance c)
{
    CHECK(c);
    C(c)->mode = CTRL_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance c)
{
    CHECK(c);
    ctrl_reset(C(c));
    return fmi3OK;
}

/* ---- values ------------------------------------------------------------------------ */

/* The controller has Float64 variables only (fmi3_common.c refuses the types neither FMU has). */
#define FLOAT64_ONLY "(the controller has Float64 variables only)"
FMI3_NO_SUCH_TYPE(fmi3GetInt32, fmi3Int32, FMI3_NOCONST, FLOAT64_ONLY)
FMI3_NO_SUCH_TYPE(fmi3GetBoolean, fmi3Boolean, FMI3_NOCONST, FLOAT64_ONLY)
FMI3_NO_SUCH_TYPE(fmi3SetInt32, fmi3Int32, const, FLOAT64_ONLY)
FMI3_NO_SUCH_TYPE(fmi3SetBoolean, fmi3Boolean, const, FLOAT64_ONLY)

/* ---- FMU state, derivatives, configuration, clocks: not offered ---------------------- */

fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState *s)
{
    (void)s;
    return fmi3_layer_refuse(c, "fmi3GetFMUState");
}

fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState s)
{
    (void)s;
    return fmi3_layer_refuse(c, "fmi3SetFMUState");
}

fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *s)
{
    (void)s;
    return fmi3_layer_refuse(c, "fmi3FreeFMUState");
}


fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState s, size_t *size)
{
    (void)s;
    (void)size;
    return fmi3_layer_refuse(c, "fmi3SerializedFMUStateSize");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState s, fmi3Byte b[], size_t size)
{
    (void)s;
    (void)b;
    (void)size;
    return fmi3_layer_refuse(c, "fmi3SerializeFMUState");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte b[], size_t size, fmi3FMUState *s)
{
    (void)b;
    (void)size;
    (void)s;
    return fmi3_layer_refuse(c, "fmi3DeserializeFMUState");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) { return fmi3_layer_refuse(c, "fmi3EvaluateDiscreteStates"); }

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime)
{
    (void)discreteStatesNeedUpdate;
    (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined;
    (void)nextEventTime;
    return fmi3_layer_refuse(c, "fmi3UpdateDiscreteStates");
}

/* ---- Model Exchange: not offered ------------------------------------------------------ */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) { return fmi3_layer_refuse(c, "fmi3EnterContinuousTimeMode"); }

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)enterEventMode;
    (void)terminateSimulation;
    return fmi3_layer_refuse(c, "fmi3CompletedIntegratorStep");
}

fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 time) { (void)time; return fmi3_layer_refuse(c, "fmi3SetTime"); }

fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 x[], size_t nx)
{
    (void)x;
    (void)nx;
    return fmi3_layer_refuse(c, "fmi3SetContinuousStates");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 d[], size_t nx)
{
    (void)d;
    (void)nx;
    return fmi3_layer_refuse(c, "fmi3GetContinuousStateDerivatives");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 e[], size_t ni)
{
    (void)e;
    (void)ni;
    return fmi3_layer_refuse(c, "fmi3GetEventIndicators");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 x[], size_t nx)
{
    (void)x;
    (void)nx;
    return fmi3_layer_refuse(c, "fmi3GetContinuousStates");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 x[], size_t nx)
{
    (void)x;
    (void)nx;
    return fmi3_layer_refuse(c, "fmi3GetNominalsOfContinuousStates");
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t *nContinuousStates)
{
    CHECK(c);
    *nContinuousStates = 0;
    return fmi3OK;
}

/* ---- Co-Simulation ---------------------------------------------------------------------- */

fmi3Status fmi3EnterStepMode(fmi3Instance c)
{
    CHECK(c);
    C(c)->mode = CTRL_STEPPING;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)
{
    (void)vr;
    (void)orders;
    (void)values;
    (void)nValues;
    CHECK(c);
    return nvr == 0 ? fmi3OK : fmi3_layer_refuse(c, "fmi3GetOutputDerivatives (the outputs are held between samples)");
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    int status;
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(c);
    status = ctrl_do_step(C(c), currentCommunicationPoint, communicationStepSize);
    fmi3_step_done(ctrl_time(C(c)), eventHandlingNeeded, terminateSimulation, earlyReturn, lastSuccessfulTime);
    return (fmi3Status)status;
}

