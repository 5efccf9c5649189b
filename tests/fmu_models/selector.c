/*
 * An adder or subtracter chosen by an enumeration parameter, as an FMI 3.0 FMU without states:
 *
 *     y = a + b  (mode = add, 1)   or   y = a - b  (mode = subtract, 2).
 *
 * FMI 3 enumerations are Int64: the importer sets mode with fmi3SetInt64 (fmi3SetInt32 is refused).
 */
#define MODEL_TOKEN "{7b3f9e21-6c0d-4a85-9e2b-1d4f8a6c3e07}"
#define N_FLOATS 4
#define N_INTS 1
#define N_STATES 0
#define STATE_VRS {0}
#define DER_VRS {0}
#define SETTABLE {0, 1, 1, 0}
#define START {0.0, 0.0, 0.0, 0.0}
#define INT_START {1}

#include <stdio.h>

static int evaluate(double t, double *r, const long long *n, char *msg, size_t size)
{
    (void)t;
    if (n[0] != 1 && n[0] != 2) {
        snprintf(msg, size, "mode = %lld is not an item of the enumeration (1 add, 2 subtract)", n[0]);
        return 1;
    }
    r[3] = n[0] == 1 ? r[1] + r[2] : r[1] - r[2];
    return 0;
}

#include "fmi3_frame.inc"
