/*
 * A stair as an FMI 2.0 Model Exchange FMU with time events and no continuous states:
 *
 *     counter = number of whole seconds elapsed: it steps by 1 at t = 1, 2, ... s,
 *
 * each step announced by the event iteration before it (nextEventTime); at the step to 9 (t = 9 s) the FMU
 * asks to end the simulation (terminateSimulation).
 */
#define MODEL_GUID "{b41e7d02-5a9c-4f36-8d1b-c07e3a6f2958}"
#define N_REALS 2
#define N_STATES 0
#define STATE_VRS {0}
#define DER_VRS {0}
#define SETTABLE {0, 0}
#define START {0.0, 0.0}
#define LAST_STEP 9.0
#define TIME_SLACK 1e-9     /* s: an importer that lands a hair before the announced time still steps */

#include <stdio.h>

static int evaluate(double t, double *r, char *msg, size_t size)
{
    (void)t; (void)r; (void)msg; (void)size;
    return 0;
}

#define HAS_EVENT_UPDATE

static void event_update(double t, double *r, int *states_changed, int *terminate, int *next_defined,
                         double *next_time)
{
    (void)states_changed;
    if (t + TIME_SLACK >= r[1] + 1.0) r[1] += 1.0;    /* the announced time has come */
    if (r[1] >= LAST_STEP) {
        *terminate = 1;
    } else {
        *next_defined = 1;
        *next_time = r[1] + 1.0;        /* whole seconds: exact in floating point */
    }
}

#include "fmi2_frame.inc"
