/*
 * dobkit FMUs: FMI 2.0 entry points shared by the plant and the controller (see fmi2_common.h).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_common.h"
#include "fmi_log.h"

void fmi2_log(const fmi2CallbackFunctions *cb, fmi2String instanceName, fmi2Status status, const char *category,
              const char *message)
{
    char safe[FMI_LOG_SIZE];
    if (!cb->logger) return;
    fmi_escape_percent(message, safe, sizeof safe);
    cb->logger(cb->componentEnvironment, instanceName, status, category, safe);
}

int fmi2_token_matches(const fmi2CallbackFunctions *functions, fmi2String instanceName, fmi2String fmuGUID,
                       const char *token)
{
    char message[1024];
    if (fmuGUID && strcmp(fmuGUID, token) == 0) return 1;
    snprintf(message, sizeof message,
             "GUID mismatch: the importer passed '%s' (from modelDescription.xml) but this binary was built "
             "for '%s'; the model description and the binary do not belong to the same export",
             fmuGUID ? fmuGUID : "(null)", token);
    fmi2_log(functions, instanceName, fmi2Error, "logStatusError", message);
    return 0;
}

/* ---- common functions ------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    (void)nCategories;
    (void)categories;
    FMI2_CHECK(c);
    fmi2_layer_set_logging(c, loggingOn ? 1 : 0);
    return fmi2OK;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

/* ---- Real values (each layer defines the other types) ------------------------------ */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    size_t i;
    FMI2_CHECK(c);
    for (i = 0; i < nvr; i++)
        if (fmi2_layer_get_real(c, vr[i], &value[i]) != 0) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    size_t i;
    FMI2_CHECK(c);
    for (i = 0; i < nvr; i++)
        if (fmi2_layer_set_real(c, vr[i], value[i]) != 0) return fmi2Error;
    return fmi2OK;
}

/* ---- directional derivatives: not offered ------------------------------------------ */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return fmi2_layer_refuse(c, "fmi2GetDirectionalDerivative");
}

/* ---- Co-Simulation status: doStep never returns pending ----------------------------- */

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    FMI2_CHECK(c);
    if (s == fmi2DoStepStatus) {
        *value = fmi2_layer_failed(c) ? fmi2Error : fmi2OK;
        return fmi2OK;
    }
    return fmi2_layer_refuse(c, "fmi2GetStatus for this status kind");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    FMI2_CHECK(c);
    if (s == fmi2LastSuccessfulTime) {
        *value = fmi2_layer_time(c);
        return fmi2OK;
    }
    return fmi2_layer_refuse(c, "fmi2GetRealStatus for this status kind");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s;
    (void)value;
    return fmi2_layer_refuse(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    FMI2_CHECK(c);
    if (s == fmi2Terminated) {
        *value = fmi2False;
        return fmi2OK;
    }
    return fmi2_layer_refuse(c, "fmi2GetBooleanStatus for this status kind");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s;
    (void)value;
    return fmi2_layer_refuse(c, "fmi2GetStringStatus");
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    return fmi2_layer_refuse(c, "fmi2CancelStep (doStep never returns fmi2Pending)");
}
