/*
 * dobkit plant FMU: one model instance and its life cycle, shared by the
 * FMI 2.0 (fmi2_plant.c) and FMI 3.0 (fmi3_plant.c) interfaces.
 *
 * Variables are addressed by value reference (plant_config.h).  Status codes
 * are numbered as in both standards: OK 0, Warning 1, Discard 2, Error 3, Fatal 4.
 */
#ifndef DOBKIT_PLANT_INSTANCE_H
#define DOBKIT_PLANT_INSTANCE_H

#include <stddef.h>

#include "plant_model.h"

enum { ST_OK = 0, ST_WARNING = 1, ST_DISCARD = 2, ST_ERROR = 3, ST_FATAL = 4 };

typedef enum {
    MODE_INSTANTIATED,    /* start values and parameters may be set */
    MODE_INITIALIZATION,  /* parameters may still be set; outputs may be read */
    MODE_EVENT,           /* Model Exchange event mode */
    MODE_CONTINUOUS,      /* Model Exchange continuous-time mode */
    MODE_STEP,            /* Co-Simulation step mode */
    MODE_TERMINATED,
    MODE_FAILED,          /* after an error: only reading, reset and free are allowed */
    MODE_COUNT            /* number of modes: a valid mode m has 0 <= m < MODE_COUNT */
} PlantMode;

typedef struct PlantInstance PlantInstance;

/* Delivers one log message to the importer (each FMI version has its own callback). */
typedef void (*PlantEmit)(PlantInstance *inst, int status, const char *category, const char *message);

struct PlantInstance {
    PlantData d;
    PlantMode mode;
    int cosim;            /* 1 for Co-Simulation, 0 for Model Exchange */
    int logging_on;
    char name[128];
    PlantEmit emit;
    void *host;           /* the FMI layer's own data (callbacks) */
    PlantInputUpdate input_update;  /* FMI 3: asks the importer for intermediate inputs during a step */
};

void plant_instance_init(PlantInstance *inst, const char *name, int cosim, int logging_on,
                         PlantEmit emit, void *host);
void plant_instance_reset(PlantInstance *inst);

void plant_log(PlantInstance *inst, int status, const char *category, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;

/* Guard: is the call `what` allowed in the current mode?  Logs and returns ST_ERROR if not. */
int plant_allowed(PlantInstance *inst, const char *what, unsigned modes);
#define IN(mode) (1u << (unsigned)(mode))   /* only for the MODE_* constants (all < 32) */

/*
 * A saved or deserialized FMU state comes from outside (a file, another
 * process): check it fully before it becomes the instance's state.  Returns
 * ST_OK and copies it in, or logs what is wrong (prefixed by `what`) and
 * returns ST_ERROR leaving the instance unchanged.
 */
int plant_restore(PlantInstance *inst, const PlantData *d, int mode, const char *what);
/* The same checks without logging or copying: 1 if valid, else 0 and the reason in msg. */
int plant_state_valid(const PlantInstance *inst, const PlantData *d, int mode, char *msg, size_t msg_size);
#define ANY_LIVE_MODE (IN(MODE_INSTANTIATED) | IN(MODE_INITIALIZATION) | IN(MODE_EVENT) | \
                       IN(MODE_CONTINUOUS) | IN(MODE_STEP))

int plant_get_real(PlantInstance *inst, unsigned vr, double *value);
int plant_set_real(PlantInstance *inst, unsigned vr, double value);
int plant_get_integer(PlantInstance *inst, unsigned vr, int *value);
int plant_set_integer(PlantInstance *inst, unsigned vr, int value);
int plant_get_boolean(PlantInstance *inst, unsigned vr, int *value);
int plant_set_boolean(PlantInstance *inst, unsigned vr, int value);

int plant_enter_initialization(PlantInstance *inst, double start_time);
int plant_exit_initialization(PlantInstance *inst);
int plant_set_time(PlantInstance *inst, double t);
int plant_set_states(PlantInstance *inst, const double *x, size_t nx);
int plant_get_states(PlantInstance *inst, double *x, size_t nx);
int plant_get_derivatives(PlantInstance *inst, double *dx, size_t nx);
int plant_get_nominals(PlantInstance *inst, double *nominal, size_t nx);
int plant_do_step(PlantInstance *inst, double t, double h);

/* FMI 2 input derivatives: order 1 of an input sets its slope over the coming step (setting the input resets
 * it to zero, a zero-order hold). */
int plant_set_input_derivative(PlantInstance *inst, unsigned vr, int order, double value);
/* FMI 2/3 output derivatives: order 1 of q[i], dq[i], tau_dis[i] at the current communication point. */
int plant_get_output_derivative(PlantInstance *inst, unsigned vr, int order, double *value);

#endif
