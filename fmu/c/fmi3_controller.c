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
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
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
#define CHECK(p) do { if (!(p)) return fmi3Error; } while (0)

static fmi3Status refuse(fmi3Instance c, const char *function)
{
    if (c) ctrl_log(C(c), CTRL_ERROR, "%s is not supported by this FMU (Co-Simulation only; no events, clocks "
                    "or FMU state)", function);
    return fmi3Error;
}

/* ---- common functions ---------------------------------------------------- */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    (void)nCategories;
    (void)categories;
    CHECK(c);
    C(c)->logging_on = loggingOn ? 1 : 0;
    return fmi3OK;
}

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
    char message[1024];
    (void)resourcePath;
    (void)visible;
    (void)eventModeUsed;       /* the controller has no events: step mode is never left */
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;  /* the inputs are sampled at the start of a step: nothing to ask during it */
    if (!instantiationToken || strcmp(instantiationToken, CTRL_TOKEN) != 0) {
        snprintf(message, sizeof message, "instantiationToken mismatch: the importer passed '%s' but this binary "
                 "was built for '%s'; the model description and the binary are not of one export",
                 instantiationToken ? instantiationToken : "(null)", CTRL_TOKEN);
        if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError", message);
        return NULL;
    }
    c = (Fmi3Ctrl *)calloc(1, sizeof *c);
    if (!c) return NULL;
    c->env = instanceEnvironment;
    c->log = logMessage;
    ctrl_init(&c->core, instanceName, loggingOn ? 1 : 0, emit3, c);
    return c;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "Scheduled Execution is not supported by this FMU");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance c) { free(c); }

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

fmi3Status fmi3EnterEventMode(fmi3Instance c) { return refuse(c, "fmi3EnterEventMode"); }

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

static fmi3Status check_scalar(fmi3Instance c, size_t nvr, size_t nValues, const char *function)
{
    if (nvr == nValues) return fmi3OK;
    ctrl_log(C(c), CTRL_ERROR, "%s: all variables are scalars, so nValues (%lu) must equal nValueReferences (%lu)",
             function, (unsigned long)nValues, (unsigned long)nvr);
    return fmi3Error;
}

fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues)
{
    size_t i;
    CHECK(c);
    if (check_scalar(c, nvr, nValues, "fmi3GetFloat64") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++)
        if (ctrl_get_real(C(c), vr[i], &values[i]) != CTRL_OK) return fmi3Error;
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nValues)
{
    size_t i;
    CHECK(c);
    if (check_scalar(c, nvr, nValues, "fmi3SetFloat64") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++)
        if (ctrl_set_real(C(c), vr[i], values[i]) != CTRL_OK) return fmi3Error;
    return fmi3OK;
}

/* The controller has Float64 variables only: an empty request of another type succeeds, any other is an error. */
#define NO_SUCH_TYPE(name, ctype, constness)                                                            \
    fmi3Status name(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, constness ctype values[], \
                    size_t nValues)                                                                      \
    {                                                                                                    \
        (void)vr;                                                                                        \
        (void)values;                                                                                    \
        (void)nValues;                                                                                   \
        CHECK(c);                                                                                        \
        return nvr == 0 ? fmi3OK : refuse(c, #name " (the controller has Float64 variables only)");     \
    }

#define NOCONST
NO_SUCH_TYPE(fmi3GetFloat32, fmi3Float32, NOCONST)
NO_SUCH_TYPE(fmi3GetInt8, fmi3Int8, NOCONST)
NO_SUCH_TYPE(fmi3GetUInt8, fmi3UInt8, NOCONST)
NO_SUCH_TYPE(fmi3GetInt16, fmi3Int16, NOCONST)
NO_SUCH_TYPE(fmi3GetUInt16, fmi3UInt16, NOCONST)
NO_SUCH_TYPE(fmi3GetInt32, fmi3Int32, NOCONST)
NO_SUCH_TYPE(fmi3GetUInt32, fmi3UInt32, NOCONST)
NO_SUCH_TYPE(fmi3GetInt64, fmi3Int64, NOCONST)
NO_SUCH_TYPE(fmi3GetUInt64, fmi3UInt64, NOCONST)
NO_SUCH_TYPE(fmi3GetBoolean, fmi3Boolean, NOCONST)
NO_SUCH_TYPE(fmi3GetString, fmi3String, NOCONST)
NO_SUCH_TYPE(fmi3SetFloat32, fmi3Float32, const)
NO_SUCH_TYPE(fmi3SetInt8, fmi3Int8, const)
NO_SUCH_TYPE(fmi3SetUInt8, fmi3UInt8, const)
NO_SUCH_TYPE(fmi3SetInt16, fmi3Int16, const)
NO_SUCH_TYPE(fmi3SetUInt16, fmi3UInt16, const)
NO_SUCH_TYPE(fmi3SetInt32, fmi3Int32, const)
NO_SUCH_TYPE(fmi3SetUInt32, fmi3UInt32, const)
NO_SUCH_TYPE(fmi3SetInt64, fmi3Int64, const)
NO_SUCH_TYPE(fmi3SetUInt64, fmi3UInt64, const)
NO_SUCH_TYPE(fmi3SetBoolean, fmi3Boolean, const)
NO_SUCH_TYPE(fmi3SetString, fmi3String, const)

fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues)
{
    (void)vr;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    CHECK(c);
    return nvr == 0 ? fmi3OK : refuse(c, "fmi3GetBinary");
}

fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues)
{
    (void)vr;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    CHECK(c);
    return nvr == 0 ? fmi3OK : refuse(c, "fmi3SetBinary");
}

fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
{
    (void)vr;
    (void)values;
    CHECK(c);
    return nvr == 0 ? fmi3OK : refuse(c, "fmi3GetClock");
}

fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[])
{
    (void)vr;
    (void)values;
    CHECK(c);
    return nvr == 0 ? fmi3OK : refuse(c, "fmi3SetClock");
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance c, fmi3ValueReference valueReference,
                                               size_t *nDependencies)
{
    (void)valueReference;
    (void)nDependencies;
    return refuse(c, "fmi3GetNumberOfVariableDependencies (see ModelStructure in modelDescription.xml)");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance c, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    (void)dependent;
    (void)elementIndicesOfDependent;
    (void)independents;
    (void)elementIndicesOfIndependents;
    (void)dependencyKinds;
    (void)nDependencies;
    return refuse(c, "fmi3GetVariableDependencies (see ModelStructure in modelDescription.xml)");
}

/* ---- FMU state, derivatives, configuration, clocks: not offered ---------------------- */

fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState *s) { (void)s; return refuse(c, "fmi3GetFMUState"); }
fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState s) { (void)s; return refuse(c, "fmi3SetFMUState"); }
fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *s) { (void)s; return refuse(c, "fmi3FreeFMUState"); }

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState s, size_t *size)
{
    (void)s;
    (void)size;
    return refuse(c, "fmi3SerializedFMUStateSize");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState s, fmi3Byte b[], size_t size)
{
    (void)s;
    (void)b;
    (void)size;
    return refuse(c, "fmi3SerializeFMUState");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte b[], size_t size, fmi3FMUState *s)
{
    (void)b;
    (void)size;
    (void)s;
    return refuse(c, "fmi3DeserializeFMUState");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity)
{
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    return refuse(c, "fmi3GetDirectionalDerivative");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    return refuse(c, "fmi3GetAdjointDerivative");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) { return refuse(c, "fmi3EnterConfigurationMode"); }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) { return refuse(c, "fmi3ExitConfigurationMode"); }

fmi3Status fmi3GetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    (void)vr;
    (void)nvr;
    (void)intervals;
    (void)qualifiers;
    return refuse(c, "fmi3GetIntervalDecimal");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[])
{
    (void)vr;
    (void)nvr;
    (void)counters;
    (void)resolutions;
    (void)qualifiers;
    return refuse(c, "fmi3GetIntervalFraction");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 shifts[])
{
    (void)vr;
    (void)nvr;
    (void)shifts;
    return refuse(c, "fmi3GetShiftDecimal");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    (void)vr;
    (void)nvr;
    (void)counters;
    (void)resolutions;
    return refuse(c, "fmi3GetShiftFraction");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[])
{
    (void)vr;
    (void)nvr;
    (void)intervals;
    return refuse(c, "fmi3SetIntervalDecimal");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr;
    (void)nvr;
    (void)counters;
    (void)resolutions;
    return refuse(c, "fmi3SetIntervalFraction");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[])
{
    (void)vr;
    (void)nvr;
    (void)shifts;
    return refuse(c, "fmi3SetShiftDecimal");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr;
    (void)nvr;
    (void)counters;
    (void)resolutions;
    return refuse(c, "fmi3SetShiftFraction");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) { return refuse(c, "fmi3EvaluateDiscreteStates"); }

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
    return refuse(c, "fmi3UpdateDiscreteStates");
}

/* ---- Model Exchange: not offered ------------------------------------------------------ */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) { return refuse(c, "fmi3EnterContinuousTimeMode"); }

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)enterEventMode;
    (void)terminateSimulation;
    return refuse(c, "fmi3CompletedIntegratorStep");
}

fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 time) { (void)time; return refuse(c, "fmi3SetTime"); }

fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 x[], size_t nx)
{
    (void)x;
    (void)nx;
    return refuse(c, "fmi3SetContinuousStates");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 d[], size_t nx)
{
    (void)d;
    (void)nx;
    return refuse(c, "fmi3GetContinuousStateDerivatives");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 e[], size_t ni)
{
    (void)e;
    (void)ni;
    return refuse(c, "fmi3GetEventIndicators");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 x[], size_t nx)
{
    (void)x;
    (void)nx;
    return refuse(c, "fmi3GetContinuousStates");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 x[], size_t nx)
{
    (void)x;
    (void)nx;
    return refuse(c, "fmi3GetNominalsOfContinuousStates");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *nEventIndicators)
{
    CHECK(c);
    *nEventIndicators = 0;
    return fmi3OK;
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
    return nvr == 0 ? fmi3OK : refuse(c, "fmi3GetOutputDerivatives (the outputs are held between samples)");
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    int status;
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(c);
    status = ctrl_do_step(C(c), currentCommunicationPoint, communicationStepSize);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = ctrl_time(C(c));
    return (fmi3Status)status;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance c, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    (void)clockReference;
    (void)activationTime;
    return refuse(c, "fmi3ActivateModelPartition (Scheduled Execution)");
}
