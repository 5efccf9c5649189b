/*
 * dobkit FMUs: the FMI 2.0 entry points and helpers that the plant and the controller layer share.
 *
 * fmi2_common.c defines the functions of the standard header that do the same in both FMUs (version
 * strings, debug logging, Real values, status queries, refused directional derivatives); the layer
 * (fmi2_plant.c or fmi2_controller.c) defines the rest and the few hooks below, through which the
 * shared code reaches the layer's instance.
 */
#ifndef DOBKIT_FMI2_COMMON_H
#define DOBKIT_FMI2_COMMON_H

#include "fmi2Functions.h"

#define FMI2_CHECK(c) do { if (!(c)) return fmi2Error; } while (0)

/* Log `message` through the importer's logger, '%' escaped; nothing without a logger. */
void fmi2_log(const fmi2CallbackFunctions *cb, fmi2String instanceName, fmi2Status status, const char *category,
              const char *message);

/* 1 if the importer's GUID is `token`; otherwise log why (as an error, before any instance exists) and 0. */
int fmi2_token_matches(const fmi2CallbackFunctions *functions, fmi2String instanceName, fmi2String fmuGUID,
                       const char *token);

/* ---- hooks each layer defines -------------------------------------------------- */

/* Log (if c is not NULL) that `function` is not supported and return fmi2Error. */
fmi2Status fmi2_layer_refuse(fmi2Component c, const char *function);
/* Switch debug logging of a (non-NULL) instance on or off. */
void fmi2_layer_set_logging(fmi2Component c, int on);
/* Read or write one Real variable: 0 when done, else the failure is logged. */
int fmi2_layer_get_real(fmi2Component c, fmi2ValueReference vr, fmi2Real *value);
int fmi2_layer_set_real(fmi2Component c, fmi2ValueReference vr, fmi2Real value);
/* 1 if the last doStep failed (the instance is in its error state). */
int fmi2_layer_failed(fmi2Component c);
/* The time the instance has reached, s. */
fmi2Real fmi2_layer_time(fmi2Component c);

#endif
