/*
 * A linear spring between two positions, as an FMI 2.0 FMU without continuous states (a static block):
 *
 *     f1 = k (x2 - x1),   f2 = -f1;   inputs x1, x2 (m), parameter k (N/m).
 */
#define MODEL_GUID "{a6f0c1d2-5b3e-4f78-8e19-2c4d6e8f0a13}"
#define N_REALS 6
#define N_STATES 0
#define STATE_VRS {0}
#define DER_VRS {0}
#define SETTABLE {0, 1, 1, 0, 0, 1}
#define START {0.0, 0.0, 0.0, 0.0, 0.0, 4.0}

#include <stdio.h>

static int evaluate(double t, double *r, char *msg, size_t size)
{
    (void)t; (void)msg; (void)size;
    r[3] = r[5] * (r[2] - r[1]);
    r[4] = -r[3];
    return 0;
}

#include "fmi2_frame.inc"
