/*
 * dobkit plant FMU: the FMI 3.0 interface (Model Exchange and Co-Simulation
 * in one binary; Scheduled Execution is not offered).  Every function the
 * standard header declares is defined; those the FMU does not support log
 * why and return fmi3Error.
 *
 * Co-Simulation integrates internally with classical fourth-order Runge-Kutta,
 * n_substeps equal steps per communication step (see plant_model.c, plant_rk4).
 * FMI 3 has no input derivatives: with an intermediate-update callback the
 * FMU asks the importer for the inputs tau[i] (intermediateUpdate) at each
 * new stage time of a step; without one they are held over the step.
 * fmi3GetOutputDerivatives gives the first derivatives of the outputs
 * (maxOutputDerivativeOrder 1).
 */
#include <stdlib.h>

#include "fmi3Functions.h"
#include "fmi3_common.h"
#include "plant_instance.h"
#include "plant_state.h"

typedef struct {
    PlantInstance core;           /* first member: a PlantInstance* is a Fmi3Plant* */
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi3IntermediateUpdateCallback intermediate;   /* NULL: inputs are held over a step */
} Fmi3Plant;

const char PLANT_STATE_MAGIC[8] = "dobkit3";   /* the tag of this binary's saved states (plant_state.c) */

static void emit3(PlantInstance *inst, int status, const char *category, const char *message)
{
    Fmi3Plant *c = (Fmi3Plant *)inst;
    if (c->log) c->log(c->env, (fmi3Status)status, category, message);
}

#define INST(c) ((PlantInstance *)(c))
#define CHECK(c) FMI3_CHECK(c)

/* During a step, before each Runge-Kutta stage at a new time: the importer may set the inputs tau[i]
 * (declared intermediateUpdate) for that time. */
static void ask_for_inputs(void *ctx, double t)
{
    Fmi3Plant *c = (Fmi3Plant *)ctx;
    fmi3Boolean early = fmi3False;
    fmi3Float64 early_time = t;
    c->intermediate(c->env, t, fmi3True, fmi3False, fmi3False, fmi3False, &early, &early_time);
}

fmi3Status fmi3_layer_refuse(fmi3Instance c, const char *function)
{
    if (c) plant_log(INST(c), ST_ERROR, "logStatusError", "%s is not supported by this FMU", function);
    return fmi3Error;
}

/* ---- hooks of the shared entry points (fmi3_common.c) ----------------- */

void fmi3_layer_error(fmi3Instance c, const char *message)
{
    plant_log(INST(c), ST_ERROR, "logStatusError", "%s", message);
}

void fmi3_layer_set_logging(fmi3Instance c, int on) { INST(c)->logging_on = on; }

int fmi3_layer_get_real(fmi3Instance c, fmi3ValueReference vr, fmi3Float64 *value)
{
    return plant_get_real(INST(c), vr, value) != ST_OK;
}

int fmi3_layer_set_real(fmi3Instance c, fmi3ValueReference vr, fmi3Float64 value)
{
    return plant_set_real(INST(c), vr, value) != ST_OK;
}

/* ---- life cycle ---------------------------------------------------------- */

static fmi3Instance instantiate(fmi3String instanceName, fmi3String instantiationToken, fmi3Boolean loggingOn,
                                fmi3InstanceEnvironment env, fmi3LogMessageCallback log, int cosim,
                                fmi3IntermediateUpdateCallback intermediate)
{
    Fmi3Plant *c;
    if (!fmi3_token_matches(env, log, instantiationToken, PLANT_TOKEN)) return NULL;
    c = (Fmi3Plant *)calloc(1, sizeof *c);
    if (!c) return NULL;
    c->env = env;
    c->log = log;
    c->intermediate = intermediate;
    plant_instance_init(&c->core, instanceName, cosim, loggingOn ? 1 : 0, emit3, c);
    if (cosim && intermediate) c->core.input_update = ask_for_inputs;
    return c;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)resourcePath;
    (void)visible;
    return instantiate(instanceName, instantiationToken, loggingOn, instanceEnvironment, logMessage, 0, NULL);
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
    (void)resourcePath;
    (void)visible;
    (void)eventModeUsed;       /* the model has no events: step mode is never left */
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    return instantiate(instanceName, instantiationToken, loggingOn, instanceEnvironment, logMessage, 1,
                       intermediateUpdate);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    CHECK(c);
    return (fmi3Status)plant_enter_initialization(INST(c), startTime);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance c)
{
    CHECK(c);
    return (fmi3Status)plant_exit_initialization(INST(c));
}

fmi3Status fmi3EnterEventMode(fmi3Instance c)
{
    CHECK(c);
    if (plant_allowed(INST(c), "fmi3EnterEventMode", IN(MODE_EVENT) | IN(MODE_CONTINUOUS) | IN(MODE_STEP))
        != ST_OK)
        return fmi3Error;
    INST(c)->mode = MODE_EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance c)
{
    CHECK(c);
    /* after an error the standard allows only reading, reset and free: terminate is refused */
    if (plant_allowed(INST(c), "fmi3Terminate", ANY_LIVE_MODE) != ST_OK) return fmi3Error;
    INST(c)->mode = MODE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance c)
{
    CHECK(c);
    plant_instance_reset(INST(c));
    return fmi3OK;
}

/* ---- getting and setting values ----------------------------------------- */

fmi3Status fmi3GetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[],
                        size_t nValues)
{
    size_t i;
    int v;
    CHECK(c);
    if (fmi3_check_scalar(c, nvr, nValues, "fmi3GetInt32") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        if (plant_get_integer(INST(c), vr[i], &v) != ST_OK) return fmi3Error;
        values[i] = (fmi3Int32)v;
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 values[],
                        size_t nValues)
{
    size_t i;
    CHECK(c);
    if (fmi3_check_scalar(c, nvr, nValues, "fmi3SetInt32") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++)
        if (plant_set_integer(INST(c), vr[i], (int)values[i]) != ST_OK) return fmi3Error;
    return fmi3OK;
}

fmi3Status fmi3GetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Boolean values[],
                          size_t nValues)
{
    size_t i;
    int v;
    CHECK(c);
    if (fmi3_check_scalar(c, nvr, nValues, "fmi3GetBoolean") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        if (plant_get_boolean(INST(c), vr[i], &v) != ST_OK) return fmi3Error;
        values[i] = v ? fmi3True : fmi3False;
    }
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Boolean values[],
                          size_t nValues)
{
    size_t i;
    CHECK(c);
    if (fmi3_check_scalar(c, nvr, nValues, "fmi3SetBoolean") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++)
        if (plant_set_boolean(INST(c), vr[i], values[i] ? 1 : 0) != ST_OK) return fmi3Error;
    return fmi3OK;
}

/* ---- variable dependencies (given in modelDescription.xml only) --------- */

/* ---- FMU state ----------------------------------------------------------- */

fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState *FMUState)
{
    CHECK(c);
    return (fmi3Status)plant_state_save(INST(c), FMUState, "fmi3GetFMUState", "FMUState");
}

fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState FMUState)
{
    CHECK(c);
    return (fmi3Status)plant_state_load(INST(c), FMUState, "fmi3SetFMUState");
}

fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *FMUState)
{
    CHECK(c);
    plant_state_free(FMUState);
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState FMUState, size_t *size)
{
    CHECK(c);
    return (fmi3Status)plant_state_size(INST(c), FMUState, size, "fmi3SerializedFMUStateSize");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState FMUState, fmi3Byte serializedState[], size_t size)
{
    CHECK(c);
    return (fmi3Status)plant_state_serialize(INST(c), FMUState, serializedState, size, "fmi3SerializeFMUState");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState)
{
    CHECK(c);
    return (fmi3Status)plant_state_deserialize(INST(c), serializedState, size, FMUState, "fmi3DeserializeFMUState");
}

/* ---- partial derivatives, configuration, clocks: not provided ----------- */

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c)
{
    CHECK(c);
    return fmi3OK; /* no discrete states */
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime)
{
    CHECK(c);
    if (plant_allowed(INST(c), "fmi3UpdateDiscreteStates", IN(MODE_EVENT)) != ST_OK) return fmi3Error;
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = fmi3False;
    if (nextEventTime) *nextEventTime = 0.0;
    return fmi3OK;
}

/* ---- Model Exchange ------------------------------------------------------ */

static fmi3Status require_me(fmi3Instance c, const char *function)
{
    CHECK(c);
    if (INST(c)->cosim) {
        plant_log(INST(c), ST_ERROR, "logStatusError", "%s is a Model Exchange function; this instance is "
                  "Co-Simulation", function);
        return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c)
{
    if (require_me(c, "fmi3EnterContinuousTimeMode") != fmi3OK) return fmi3Error;
    if (plant_allowed(INST(c), "fmi3EnterContinuousTimeMode", IN(MODE_EVENT)) != ST_OK) return fmi3Error;
    INST(c)->mode = MODE_CONTINUOUS;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    if (require_me(c, "fmi3CompletedIntegratorStep") != fmi3OK) return fmi3Error;
    if (plant_allowed(INST(c), "fmi3CompletedIntegratorStep", IN(MODE_CONTINUOUS)) != ST_OK) return fmi3Error;
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 time)
{
    if (require_me(c, "fmi3SetTime") != fmi3OK) return fmi3Error;
    return (fmi3Status)plant_set_time(INST(c), time);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates)
{
    if (require_me(c, "fmi3SetContinuousStates") != fmi3OK) return fmi3Error;
    return (fmi3Status)plant_set_states(INST(c), continuousStates, nContinuousStates);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 derivatives[], size_t nContinuousStates)
{
    if (require_me(c, "fmi3GetContinuousStateDerivatives") != fmi3OK) return fmi3Error;
    return (fmi3Status)plant_get_derivatives(INST(c), derivatives, nContinuousStates);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 eventIndicators[], size_t nEventIndicators)
{
    (void)eventIndicators;
    if (require_me(c, "fmi3GetEventIndicators") != fmi3OK) return fmi3Error;
    if (nEventIndicators == 0) return fmi3OK;
    plant_log(INST(c), ST_ERROR, "logStatusError", "the model has no event indicators, %lu requested",
              (unsigned long)nEventIndicators);
    return fmi3Error;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 continuousStates[], size_t nContinuousStates)
{
    if (require_me(c, "fmi3GetContinuousStates") != fmi3OK) return fmi3Error;
    return (fmi3Status)plant_get_states(INST(c), continuousStates, nContinuousStates);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 nominals[], size_t nContinuousStates)
{
    if (require_me(c, "fmi3GetNominalsOfContinuousStates") != fmi3OK) return fmi3Error;
    return (fmi3Status)plant_get_nominals(INST(c), nominals, nContinuousStates);
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t *nContinuousStates)
{
    CHECK(c);
    *nContinuousStates = NX;
    return fmi3OK;
}

/* ---- Co-Simulation ------------------------------------------------------- */

fmi3Status fmi3EnterStepMode(fmi3Instance c)
{
    CHECK(c);
    if (!INST(c)->cosim) return fmi3_layer_refuse(c, "fmi3EnterStepMode on a Model Exchange instance");
    if (plant_allowed(INST(c), "fmi3EnterStepMode", IN(MODE_EVENT) | IN(MODE_STEP)) != ST_OK) return fmi3Error;
    INST(c)->mode = MODE_STEP;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)
{
    size_t i;
    CHECK(c);
    if (!INST(c)->cosim) return fmi3_layer_refuse(c, "fmi3GetOutputDerivatives on a Model Exchange instance");
    if (fmi3_check_scalar(c, nvr, nValues, "fmi3GetOutputDerivatives") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++)
        if (plant_get_output_derivative(INST(c), vr[i], (int)orders[i], &values[i]) != ST_OK) return fmi3Error;
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    fmi3Status status;
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(c);
    if (!INST(c)->cosim) return fmi3_layer_refuse(c, "fmi3DoStep on a Model Exchange instance");
    status = (fmi3Status)plant_do_step(INST(c), currentCommunicationPoint, communicationStepSize);
    fmi3_step_done(INST(c)->d.time, eventHandlingNeeded, terminateSimulation, earlyReturn, lastSuccessfulTime);
    return status;
}

