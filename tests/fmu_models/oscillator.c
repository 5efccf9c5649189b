/*
 * A harmonic oscillator written as Modelica tools write a second-order equation, as an FMI 2.0 FMU:
 * states x and der(x), whose derivative is named der(der(x)):
 *
 *     der(der(x)) = -w^2 x,   output x.
 *
 * The name der(der(x)) is outside the grammar of the structured naming convention that fmpy's validation
 * checks, although the FMU is correct.
 */
#define MODEL_GUID "{5e9d0a7b-3c2f-41e8-a6b4-0f8c1e2d3a95}"
#define N_REALS 5
#define N_STATES 2
#define STATE_VRS {1, 2}
#define DER_VRS {2, 3}
#define SETTABLE {0, 1, 1, 0, 1}
#define START {0.0, 1.0, 0.0, 0.0, 2.0}

#include <stdio.h>

static int evaluate(double t, double *r, char *msg, size_t size)
{
    (void)t; (void)msg; (void)size;
    r[3] = -r[4] * r[4] * r[1];
    return 0;
}

#include "fmi2_frame.inc"
