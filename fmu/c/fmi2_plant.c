/*
 * dobkit plant FMU: the FMI 2.0 interface (Model Exchange and Co-Simulation
 * in one binary).  Every function the standard header declares is defined;
 * those the FMU does not support log why and return fmi2Error.
 *
 * Co-Simulation integrates internally with classical fourth-order Runge-Kutta,
 * n_substeps equal steps per communication step (see plant_model.c, plant_rk4).
 * The inputs are held over the step, or follow the slopes set with
 * fmi2SetRealInputDerivatives (canInterpolateInputs; set the value first: fmi2SetReal
 * resets its slope).  fmi2GetRealOutputDerivatives gives the first derivatives
 * of the outputs (maxOutputDerivativeOrder 1).
 */
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"
#include "fmi2_common.h"
#include "plant_instance.h"
#include "plant_state.h"

typedef struct {
    PlantInstance core;           /* first member: a PlantInstance* is a Fmi2Plant* */
    fmi2CallbackFunctions cb;
} Fmi2Plant;

const char PLANT_STATE_MAGIC[8] = "dobkit2";   /* the tag of this binary's saved states (plant_state.c) */

static void emit2(PlantInstance *inst, int status, const char *category, const char *message)
{
    Fmi2Plant *c = (Fmi2Plant *)inst;
    fmi2_log(&c->cb, inst->name, (fmi2Status)status, category, message);
}

#define INST(c) ((PlantInstance *)(c))
#define CHECK(c) FMI2_CHECK(c)

fmi2Status fmi2_layer_refuse(fmi2Component c, const char *function)
{
    if (c) plant_log(INST(c), ST_ERROR, "logStatusError", "%s is not supported by this FMU", function);
    return fmi2Error;
}

/* ---- hooks of the shared entry points (fmi2_common.c) ----------------- */

void fmi2_layer_set_logging(fmi2Component c, int on) { INST(c)->logging_on = on; }

int fmi2_layer_get_real(fmi2Component c, fmi2ValueReference vr, fmi2Real *value)
{
    return plant_get_real(INST(c), vr, value) != ST_OK;
}

int fmi2_layer_set_real(fmi2Component c, fmi2ValueReference vr, fmi2Real value)
{
    return plant_set_real(INST(c), vr, value) != ST_OK;
}

int fmi2_layer_failed(fmi2Component c) { return INST(c)->mode == MODE_FAILED; }

fmi2Real fmi2_layer_time(fmi2Component c) { return INST(c)->d.time; }

/* ---- life cycle ---------------------------------------------------------- */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Fmi2Plant *c;
    char message[1024];
    (void)fmuResourceLocation;
    (void)visible;

    if (!functions) return NULL;
    if (!fmi2_token_matches(functions, instanceName, fmuGUID, PLANT_TOKEN)) return NULL;
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation) {
        snprintf(message, sizeof message, "unknown fmuType %d", (int)fmuType);
        fmi2_log(functions, instanceName, fmi2Error, "logStatusError", message);
        return NULL;
    }
    c = (Fmi2Plant *)calloc(1, sizeof *c);
    if (!c) return NULL;
    c->cb = *functions;
    plant_instance_init(&c->core, instanceName, fmuType == fmi2CoSimulation, loggingOn ? 1 : 0, emit2, c);
    return c;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    CHECK(c);
    if (plant_allowed(INST(c), "fmi2SetupExperiment", IN(MODE_INSTANTIATED)) != ST_OK) return fmi2Error;
    INST(c)->d.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    CHECK(c);
    return (fmi2Status)plant_enter_initialization(INST(c), INST(c)->d.time);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    CHECK(c);
    return (fmi2Status)plant_exit_initialization(INST(c));
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    CHECK(c);
    /* after an error the standard allows only reading, reset and free: terminate is refused */
    if (plant_allowed(INST(c), "fmi2Terminate", ANY_LIVE_MODE) != ST_OK) return fmi2Error;
    INST(c)->mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    CHECK(c);
    plant_instance_reset(INST(c));
    return fmi2OK;
}

/* ---- getting and setting values ----------------------------------------- */

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    size_t i;
    CHECK(c);
    for (i = 0; i < nvr; i++)
        if (plant_get_integer(INST(c), vr[i], &value[i]) != ST_OK) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    size_t i;
    int v;
    CHECK(c);
    for (i = 0; i < nvr; i++) {
        if (plant_get_boolean(INST(c), vr[i], &v) != ST_OK) return fmi2Error;
        value[i] = v ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    (void)vr;
    (void)value;
    CHECK(c);
    return nvr == 0 ? fmi2OK : fmi2_layer_refuse(c, "fmi2GetString (the model has no string variables)");
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    size_t i;
    CHECK(c);
    for (i = 0; i < nvr; i++)
        if (plant_set_integer(INST(c), vr[i], value[i]) != ST_OK) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    size_t i;
    CHECK(c);
    for (i = 0; i < nvr; i++)
        if (plant_set_boolean(INST(c), vr[i], value[i] != fmi2False) != ST_OK) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    (void)vr;
    (void)value;
    CHECK(c);
    return nvr == 0 ? fmi2OK : fmi2_layer_refuse(c, "fmi2SetString (the model has no string variables)");
}

/* ---- FMU state ----------------------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    CHECK(c);
    return (fmi2Status)plant_state_save(INST(c), FMUstate, "fmi2GetFMUstate", "FMUstate");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    CHECK(c);
    return (fmi2Status)plant_state_load(INST(c), FMUstate, "fmi2SetFMUstate");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    CHECK(c);
    plant_state_free(FMUstate);
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size)
{
    CHECK(c);
    return (fmi2Status)plant_state_size(INST(c), FMUstate, size, "fmi2SerializedFMUstateSize");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    CHECK(c);
    return (fmi2Status)plant_state_serialize(INST(c), FMUstate, serializedState, size, "fmi2SerializeFMUstate");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    CHECK(c);
    return (fmi2Status)plant_state_deserialize(INST(c), serializedState, size, FMUstate, "fmi2DeSerializeFMUstate");
}

/* ---- Model Exchange ------------------------------------------------------ */

static fmi2Status require_me(fmi2Component c, const char *function)
{
    CHECK(c);
    if (INST(c)->cosim) {
        plant_log(INST(c), ST_ERROR, "logStatusError", "%s is a Model Exchange function; this instance is "
                  "Co-Simulation", function);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2EnterEventMode(fmi2Component c)
{
    if (require_me(c, "fmi2EnterEventMode") != fmi2OK) return fmi2Error;
    if (plant_allowed(INST(c), "fmi2EnterEventMode", IN(MODE_EVENT) | IN(MODE_CONTINUOUS)) != ST_OK)
        return fmi2Error;
    INST(c)->mode = MODE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo)
{
    if (require_me(c, "fmi2NewDiscreteStates") != fmi2OK) return fmi2Error;
    if (plant_allowed(INST(c), "fmi2NewDiscreteStates", IN(MODE_EVENT)) != ST_OK) return fmi2Error;
    /* the model has no discrete states and no events */
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c)
{
    if (require_me(c, "fmi2EnterContinuousTimeMode") != fmi2OK) return fmi2Error;
    if (plant_allowed(INST(c), "fmi2EnterContinuousTimeMode", IN(MODE_EVENT)) != ST_OK) return fmi2Error;
    INST(c)->mode = MODE_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    if (require_me(c, "fmi2CompletedIntegratorStep") != fmi2OK) return fmi2Error;
    if (plant_allowed(INST(c), "fmi2CompletedIntegratorStep", IN(MODE_CONTINUOUS)) != ST_OK) return fmi2Error;
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time)
{
    if (require_me(c, "fmi2SetTime") != fmi2OK) return fmi2Error;
    return (fmi2Status)plant_set_time(INST(c), time);
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx)
{
    if (require_me(c, "fmi2SetContinuousStates") != fmi2OK) return fmi2Error;
    return (fmi2Status)plant_set_states(INST(c), x, nx);
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx)
{
    if (require_me(c, "fmi2GetDerivatives") != fmi2OK) return fmi2Error;
    return (fmi2Status)plant_get_derivatives(INST(c), derivatives, nx);
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni)
{
    (void)eventIndicators;
    if (require_me(c, "fmi2GetEventIndicators") != fmi2OK) return fmi2Error;
    if (ni == 0) return fmi2OK;
    plant_log(INST(c), ST_ERROR, "logStatusError", "the model has no event indicators, %lu requested",
              (unsigned long)ni);
    return fmi2Error;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    if (require_me(c, "fmi2GetContinuousStates") != fmi2OK) return fmi2Error;
    return (fmi2Status)plant_get_states(INST(c), x, nx);
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx)
{
    if (require_me(c, "fmi2GetNominalsOfContinuousStates") != fmi2OK) return fmi2Error;
    return (fmi2Status)plant_get_nominals(INST(c), x_nominal, nx);
}

/* ---- Co-Simulation ------------------------------------------------------- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    size_t i;
    CHECK(c);
    if (!INST(c)->cosim) return fmi2_layer_refuse(c, "fmi2SetRealInputDerivatives on a Model Exchange instance");
    for (i = 0; i < nvr; i++)
        if (plant_set_input_derivative(INST(c), vr[i], order[i], value[i]) != ST_OK) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    size_t i;
    CHECK(c);
    if (!INST(c)->cosim) return fmi2_layer_refuse(c, "fmi2GetRealOutputDerivatives on a Model Exchange instance");
    for (i = 0; i < nvr; i++)
        if (plant_get_output_derivative(INST(c), vr[i], order[i], &value[i]) != ST_OK) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(c);
    if (!INST(c)->cosim) {
        plant_log(INST(c), ST_ERROR, "logStatusError", "fmi2DoStep: this instance is Model Exchange");
        return fmi2Error;
    }
    return (fmi2Status)plant_do_step(INST(c), currentCommunicationPoint, communicationStepSize);
}
