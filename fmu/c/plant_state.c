/*
 * dobkit plant FMU: saved FMU states, shared by the FMI 2 and FMI 3 layers (see plant_state.h).
 */
#include <stdlib.h>
#include <string.h>

#include "plant_state.h"

typedef struct {
    char magic[8];
    PlantData d;
    int mode;             /* a PlantMode; stored as int so that any stored value can be range-checked */
} SavedState;

static int is_saved_state(const void *p)
{
    return p != NULL && memcmp(((const SavedState *)p)->magic, PLANT_STATE_MAGIC, sizeof PLANT_STATE_MAGIC) == 0;
}

int plant_state_save(PlantInstance *inst, void **state, const char *function, const char *argument)
{
    SavedState *s;
    if (!state) return ST_ERROR;
    /* a non-NULL *state must be one of ours to be overwritten in place */
    if (*state && !is_saved_state(*state)) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: *%s is neither NULL nor a state of this FMU", function,
                  argument);
        return ST_ERROR;
    }
    s = *state ? (SavedState *)*state : (SavedState *)calloc(1, sizeof *s);
    if (!s) return ST_ERROR;
    memcpy(s->magic, PLANT_STATE_MAGIC, sizeof s->magic);
    s->d = inst->d;
    s->mode = (int)inst->mode;
    *state = s;
    return ST_OK;
}

int plant_state_load(PlantInstance *inst, const void *state, const char *function)
{
    const SavedState *s = (const SavedState *)state;
    if (!is_saved_state(s)) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: not a state of this FMU", function);
        return ST_ERROR;
    }
    return plant_restore(inst, &s->d, s->mode, function);
}

void plant_state_free(void **state)
{
    if (!state) return;
    free(*state);
    *state = NULL;
}

int plant_state_size(PlantInstance *inst, const void *state, size_t *size, const char *function)
{
    if (!size || !is_saved_state(state)) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: not a state of this FMU", function);
        return ST_ERROR;
    }
    *size = sizeof(SavedState);
    return ST_OK;
}

int plant_state_serialize(PlantInstance *inst, const void *state, void *bytes, size_t size, const char *function)
{
    if (!is_saved_state(state)) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: not a state of this FMU", function);
        return ST_ERROR;
    }
    if (!bytes || size != sizeof(SavedState)) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: buffer of %lu bytes, need %lu", function,
                  (unsigned long)size, (unsigned long)sizeof(SavedState));
        return ST_ERROR;
    }
    memcpy(bytes, state, sizeof(SavedState));
    return ST_OK;
}

int plant_state_deserialize(PlantInstance *inst, const void *bytes, size_t size, void **state,
                            const char *function)
{
    SavedState tmp, *s;
    char msg[512];
    if (!state) return ST_ERROR;
    if (!bytes || size != sizeof(SavedState) || memcmp(bytes, PLANT_STATE_MAGIC, sizeof PLANT_STATE_MAGIC) != 0) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: not a serialized state of this FMU (%lu bytes)", function,
                  (unsigned long)size);
        return ST_ERROR;
    }
    memcpy(&tmp, bytes, sizeof tmp);   /* the byte buffer may be unaligned */
    if (!plant_state_valid(inst, &tmp.d, tmp.mode, msg, sizeof msg)) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: invalid FMU state: %s", function, msg);
        return ST_ERROR;
    }
    s = (SavedState *)calloc(1, sizeof *s);
    if (!s) return ST_ERROR;
    *s = tmp;
    *state = s;
    return ST_OK;
}
