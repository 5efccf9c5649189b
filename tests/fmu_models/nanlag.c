/*
 * A first-order lag as an FMI 2.0 FMU whose output derivatives are declared but NaN, as some OpenModelica
 * exports return them (maxOutputDerivativeOrder = 1, status OK):
 *
 *     x' = k (u - x),   output x,   input u (interpolated, canInterpolateInputs),   parameter k (1/s).
 *
 * With k = 5000 /s the frame's Co-Simulation solver (10 RK4 steps per communication step) is unstable at
 * h = 10 ms (k h / 10 = 5, beyond RK4's stability limit of about 2.79) and stable at h = 1 ms.
 */
#define MODEL_GUID "{0b6d2f41-7e35-4c9a-b1d8-5a3c9e7f2064}"
#define N_REALS 5
#define N_STATES 1
#define STATE_VRS {2}
#define DER_VRS {3}
#define SETTABLE {0, 1, 1, 0, 1}
#define START {0.0, 0.0, 0.0, 0.0, 1.0}
#define N_INTERPOLATED 1
#define INTERPOLATED {1}
#define NAN_OUTPUT_DERIVATIVES

#include <stdio.h>

static int evaluate(double t, double *r, char *msg, size_t size)
{
    (void)t; (void)msg; (void)size;
    r[3] = r[4] * (r[1] - r[2]);
    return 0;
}

#include "fmi2_frame.inc"
