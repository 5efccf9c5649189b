/*
 * dobkit FMUs: the FMI 3.0 entry points and helpers that the plant and the controller layer share.
 *
 * fmi3_common.c defines the functions of the standard header that do the same in both FMUs (version,
 * debug logging, Float64 values, refused variable types, dependencies, partial derivatives,
 * configuration mode, clocks and Scheduled Execution); the layer (fmi3_plant.c or fmi3_controller.c)
 * defines the rest and the few hooks below, through which the shared code reaches the layer's instance.
 */
#ifndef DOBKIT_FMI3_COMMON_H
#define DOBKIT_FMI3_COMMON_H

#include "fmi3Functions.h"

#define FMI3_CHECK(c) do { if (!(c)) return fmi3Error; } while (0)

/* 1 if the importer's instantiationToken is `token`; otherwise log why (as an error, before any instance
 * exists) and 0. */
int fmi3_token_matches(fmi3InstanceEnvironment env, fmi3LogMessageCallback log, fmi3String instantiationToken,
                       const char *token);

/* fmi3OK if nValues equals nvr (every variable is a scalar); otherwise log why and fmi3Error. */
fmi3Status fmi3_check_scalar(fmi3Instance c, size_t nvr, size_t nValues, const char *function);

/* Fill the optional outputs of fmi3DoStep for a step that ended at `time` (s) without an event, a request
 * to terminate or an early return (neither FMU has events). */
void fmi3_step_done(fmi3Float64 time, fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                    fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime);

/* Defines `name`, a getter (constness empty) or setter (constness const) of a type the FMU has no
 * variables of: an empty request succeeds, any other is refused with `why` after the function name. */
#define FMI3_NO_SUCH_TYPE(name, ctype, constness, why)                                                   \
    fmi3Status name(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, constness ctype values[], \
                    size_t nValues)                                                                      \
    {                                                                                                    \
        (void)vr;                                                                                        \
        (void)values;                                                                                    \
        (void)nValues;                                                                                   \
        FMI3_CHECK(c);                                                                                   \
        return nvr == 0 ? fmi3OK : fmi3_layer_refuse(c, #name " " why);                                \
    }
#define FMI3_NOCONST

/* ---- hooks each layer defines -------------------------------------------------- */

/* Log (if c is not NULL) that `function` is not supported and return fmi3Error. */
fmi3Status fmi3_layer_refuse(fmi3Instance c, const char *function);
/* Log `message` as an error of a (non-NULL) instance. */
void fmi3_layer_error(fmi3Instance c, const char *message);
/* Switch debug logging of a (non-NULL) instance on or off. */
void fmi3_layer_set_logging(fmi3Instance c, int on);
/* Read or write one Float64 variable: 0 when done, else the failure is logged. */
int fmi3_layer_get_real(fmi3Instance c, fmi3ValueReference vr, fmi3Float64 *value);
int fmi3_layer_set_real(fmi3Instance c, fmi3ValueReference vr, fmi3Float64 value);

#endif
