/*
 * The bouncing ball of ball.c as an FMI 3.0 Model Exchange FMU (ball_equations.inc): its event indicator is
 * the declared variable z (h while the ball flies), and fmi3UpdateDiscreteStates re-initialises v and h at an
 * impact (valuesOfContinuousStatesChanged).
 */
#define MODEL_TOKEN "{2d6a9c13-7e48-4f05-b1a2-94c3e8d07f61}"

#include "ball_equations.inc"

#define N_FLOATS BALL_N_REALS
#define N_INTS 0
#define N_STATES 2
#define STATE_VRS BALL_STATE_VRS
#define DER_VRS BALL_DER_VRS
#define SETTABLE BALL_SETTABLE
#define START BALL_START
#define INT_START {0}

static int evaluate(double t, double *r, const long long *n, char *msg, size_t size)
{
    (void)t; (void)n;
    return ball_equations(r, msg, size);
}

#include "fmi3_frame.inc"
