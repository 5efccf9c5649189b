/*
 * dobkit FMUs: FMI 3.0 entry points shared by the plant and the controller (see fmi3_common.h).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3_common.h"

int fmi3_token_matches(fmi3InstanceEnvironment env, fmi3LogMessageCallback log, fmi3String instantiationToken,
                       const char *token)
{
    char message[1024];
    if (instantiationToken && strcmp(instantiationToken, token) == 0) return 1;
    snprintf(message, sizeof message,
             "instantiationToken mismatch: the importer passed '%s' (from modelDescription.xml) but this "
             "binary was built for '%s'; the model description and the binary do not belong to the same "
             "export", instantiationToken ? instantiationToken : "(null)", token);
    if (log) log(env, fmi3Error, "logStatusError", message);   /* FMI 3 messages are plain text: no escaping */
    return 0;
}

fmi3Status fmi3_check_scalar(fmi3Instance c, size_t nvr, size_t nValues, const char *function)
{
    char message[512];
    if (nvr == nValues) return fmi3OK;
    snprintf(message, sizeof message, "%s: all variables are scalars, so nValues (%lu) must equal "
             "nValueReferences (%lu)", function, (unsigned long)nValues, (unsigned long)nvr);
    fmi3_layer_error(c, message);
    return fmi3Error;
}

void fmi3_step_done(fmi3Float64 time, fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                    fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = time;
}

/* ---- common functions ------------------------------------------------------------ */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    (void)nCategories;
    (void)categories;
    FMI3_CHECK(c);
    fmi3_layer_set_logging(c, loggingOn ? 1 : 0);
    return fmi3OK;
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

fmi3Status fmi3ActivateModelPartition(fmi3Instance c, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    (void)clockReference;
    (void)activationTime;
    return fmi3_layer_refuse(c, "fmi3ActivateModelPartition (Scheduled Execution)");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *nEventIndicators)
{
    FMI3_CHECK(c);
    *nEventIndicators = 0;   /* neither FMU has events */
    return fmi3OK;
}

/* ---- values: Float64 (both FMUs), other types the layer has ----------------------- */

fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues)
{
    size_t i;
    FMI3_CHECK(c);
    if (fmi3_check_scalar(c, nvr, nValues, "fmi3GetFloat64") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++)
        if (fmi3_layer_get_real(c, vr[i], &values[i]) != 0) return fmi3Error;
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nValues)
{
    size_t i;
    FMI3_CHECK(c);
    if (fmi3_check_scalar(c, nvr, nValues, "fmi3SetFloat64") != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++)
        if (fmi3_layer_set_real(c, vr[i], values[i]) != 0) return fmi3Error;
    return fmi3OK;
}

/* Neither FMU has variables of these types (the plant's Int32 and Boolean are in fmi3_plant.c). */
#define NO_VARIABLES "(the model has no variables of this type)"
FMI3_NO_SUCH_TYPE(fmi3GetFloat32, fmi3Float32, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3GetInt8, fmi3Int8, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3GetUInt8, fmi3UInt8, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3GetInt16, fmi3Int16, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3GetUInt16, fmi3UInt16, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3GetUInt32, fmi3UInt32, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3GetInt64, fmi3Int64, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3GetUInt64, fmi3UInt64, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3GetString, fmi3String, FMI3_NOCONST, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetFloat32, fmi3Float32, const, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetInt8, fmi3Int8, const, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetUInt8, fmi3UInt8, const, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetInt16, fmi3Int16, const, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetUInt16, fmi3UInt16, const, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetUInt32, fmi3UInt32, const, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetInt64, fmi3Int64, const, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetUInt64, fmi3UInt64, const, NO_VARIABLES)
FMI3_NO_SUCH_TYPE(fmi3SetString, fmi3String, const, NO_VARIABLES)

fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues)
{
    (void)vr;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    FMI3_CHECK(c);
    return nvr == 0 ? fmi3OK : fmi3_layer_refuse(c, "fmi3GetBinary (the model has no binary variables)");
}

fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues)
{
    (void)vr;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    FMI3_CHECK(c);
    return nvr == 0 ? fmi3OK : fmi3_layer_refuse(c, "fmi3SetBinary (the model has no binary variables)");
}

fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
{
    (void)vr;
    (void)values;
    FMI3_CHECK(c);
    return nvr == 0 ? fmi3OK : fmi3_layer_refuse(c, "fmi3GetClock (the model has no clocks)");
}

fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[])
{
    (void)vr;
    (void)values;
    FMI3_CHECK(c);
    return nvr == 0 ? fmi3OK : fmi3_layer_refuse(c, "fmi3SetClock (the model has no clocks)");
}

/* ---- variable dependencies (given in modelDescription.xml only) ------------------- */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance c, fmi3ValueReference valueReference,
                                               size_t *nDependencies)
{
    (void)valueReference;
    (void)nDependencies;
    return fmi3_layer_refuse(c, "fmi3GetNumberOfVariableDependencies (see ModelStructure in "
                                "modelDescription.xml)");
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
    return fmi3_layer_refuse(c, "fmi3GetVariableDependencies (see ModelStructure in modelDescription.xml)");
}

/* ---- partial derivatives and configuration mode: not offered ---------------------- */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns;
    (void)seed; (void)nSeed; (void)sensitivity; (void)nSensitivity;
    return fmi3_layer_refuse(c, "fmi3GetDirectionalDerivative");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns;
    (void)seed; (void)nSeed; (void)sensitivity; (void)nSensitivity;
    return fmi3_layer_refuse(c, "fmi3GetAdjointDerivative");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c)
{
    return fmi3_layer_refuse(c, "fmi3EnterConfigurationMode (the model has no structural parameters)");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance c)
{
    return fmi3_layer_refuse(c, "fmi3ExitConfigurationMode (the model has no structural parameters)");
}

/* ---- clocks: neither FMU has any -------------------------------------------------- */

fmi3Status fmi3GetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)intervals; (void)qualifiers;
    return fmi3_layer_refuse(c, "fmi3GetIntervalDecimal (the model has no clocks)");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions; (void)qualifiers;
    return fmi3_layer_refuse(c, "fmi3GetIntervalFraction (the model has no clocks)");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    return fmi3_layer_refuse(c, "fmi3GetShiftDecimal (the model has no clocks)");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return fmi3_layer_refuse(c, "fmi3GetShiftFraction (the model has no clocks)");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[])
{
    (void)vr; (void)nvr; (void)intervals;
    return fmi3_layer_refuse(c, "fmi3SetIntervalDecimal (the model has no clocks)");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return fmi3_layer_refuse(c, "fmi3SetIntervalFraction (the model has no clocks)");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    return fmi3_layer_refuse(c, "fmi3SetShiftDecimal (the model has no clocks)");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return fmi3_layer_refuse(c, "fmi3SetShiftFraction (the model has no clocks)");
}
