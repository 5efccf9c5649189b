/*
 * dobkit plant FMU: saved FMU states (get, set, free, serialize, deserialize), the same for FMI 2 and FMI 3.
 *
 * A state is the model data and the mode it was in, behind a magic tag; its serialized form is the same
 * bytes, so a deserialized state is checked field by field before use (plant_state_valid).  Each function
 * returns ST_OK or logs what is wrong (prefixed by `function`, the FMI function's name) and returns
 * ST_ERROR.
 */
#ifndef DOBKIT_PLANT_STATE_H
#define DOBKIT_PLANT_STATE_H

#include <stddef.h>

#include "plant_instance.h"

/* The tag of this binary's states ("dobkit2", "dobkit3"): defined by the FMI layer, so that a state of
 * one FMI version is not taken for one of the other. */
extern const char PLANT_STATE_MAGIC[8];

/* Save the instance into *state: a new allocation if *state is NULL, else the state of this FMU it is,
 * overwritten (`argument` names state in the message if it is neither). */
int plant_state_save(PlantInstance *inst, void **state, const char *function, const char *argument);
/* Restore the instance from a state of this FMU. */
int plant_state_load(PlantInstance *inst, const void *state, const char *function);
/* Free *state (NULL is allowed) and set it to NULL. */
void plant_state_free(void **state);
/* The size of a serialized state, bytes. */
int plant_state_size(PlantInstance *inst, const void *state, size_t *size, const char *function);
/* Write a state into `bytes`, which must have exactly the serialized size. */
int plant_state_serialize(PlantInstance *inst, const void *state, void *bytes, size_t size, const char *function);
/* A new state from serialized `bytes` (always a new allocation: the caller's old *state is neither read nor
 * freed). */
int plant_state_deserialize(PlantInstance *inst, const void *bytes, size_t size, void **state,
                            const char *function);

#endif
