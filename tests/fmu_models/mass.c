/*
 * A point mass pushed by a force, as an FMI 2.0 FMU (Model Exchange and Co-Simulation):
 *
 *     x' = v,   v' = F / m,   outputs x and v;   inputs F (N) and m (kg).
 *
 * The outputs need no input, but the equations divide by the input m: evaluated with m = 0 the FMU
 * returns an error status and explains it as Modelica-generated FMUs do.
 */
#define MODEL_GUID "{3d8e2b64-1f0a-4c3e-9a57-6b1d2c9e0f41}"
#define N_REALS 7
#define N_STATES 2
#define STATE_VRS {1, 2}
#define DER_VRS {3, 4}
#define SETTABLE {0, 1, 1, 0, 0, 1, 1}
#define START {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0}

#include <stdio.h>

static int evaluate(double t, double *r, char *msg, size_t size)
{
    if (r[6] == 0.0) {
        snprintf(msg, size, "division by zero at time %g, (a=%g) / (b=%g), where divisor b expression is: m", t,
                 r[5], r[6]);
        return 1;
    }
    r[3] = r[2];
    r[4] = r[5] / r[6];
    return 0;
}

#include "fmi2_frame.inc"
