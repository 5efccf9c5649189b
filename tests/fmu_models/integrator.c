/*
 * The first two moments of its input, as an FMI 2.0 Co-Simulation FMU that interpolates its input
 * (canInterpolateInputs):
 *
 *     I0' = u,   I1' = t u,   outputs I0 and I1;   input u.
 *
 * With u linear in time over each step (a first-order hold) the integrands are polynomials of degree 1
 * and 2, which the frame's RK4 integrates exactly: the outputs tell exactly what input the FMU received.
 */
#define MODEL_GUID "{e41f7c93-2a6b-4d0e-8f35-9b7c1a2d4e68}"
#define N_REALS 6
#define N_STATES 2
#define STATE_VRS {2, 3}
#define DER_VRS {4, 5}
#define SETTABLE {0, 1, 1, 1, 0, 0}
#define START {0.0, 0.0, 0.0, 0.0, 0.0, 0.0}
#define N_INTERPOLATED 1
#define INTERPOLATED {1}

#include <stdio.h>

static int evaluate(double t, double *r, char *msg, size_t size)
{
    (void)msg; (void)size;
    r[4] = r[1];
    r[5] = t * r[1];
    return 0;
}

#include "fmi2_frame.inc"
