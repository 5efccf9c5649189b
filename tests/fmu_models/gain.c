/*
 * A static gain y = k u as an FMI 2.0 FMU (Model Exchange and Co-Simulation), no states: its output
 * depends directly on its input.
 */
#define MODEL_GUID "{c2b7e9f1-0d4a-4e6b-b3c8-7f1a2d5e9b60}"
#define N_REALS 4
#define N_STATES 0
#define STATE_VRS {0}
#define DER_VRS {0}
#define SETTABLE {0, 1, 0, 1}
#define START {0.0, 0.0, 0.0, 2.0}

#include <stdio.h>

static int evaluate(double t, double *r, char *msg, size_t size)
{
    (void)t; (void)msg; (void)size;
    r[2] = r[3] * r[1];
    return 0;
}

#include "fmi2_frame.inc"
