/*
 * A bouncing ball as an FMI 2.0 Model Exchange FMU with a state event (ball_equations.inc):
 * h0 = 1 m, g = 9.81 m/s^2, e = 0.7; at each impact fmi2NewDiscreteStates re-initialises v (and h) and says
 * so (valuesOfContinuousStatesChanged); once the rebound speed is below v_min = 0.1 m/s the ball rests.
 */
#define MODEL_GUID "{8f2c4a61-93d7-4b0e-a5c8-2e61f7d90b34}"

#include "ball_equations.inc"

#define N_REALS BALL_N_REALS
#define N_STATES 2
#define STATE_VRS BALL_STATE_VRS
#define DER_VRS BALL_DER_VRS
#define SETTABLE BALL_SETTABLE
#define START BALL_START

static int evaluate(double t, double *r, char *msg, size_t size)
{
    (void)t;
    return ball_equations(r, msg, size);
}

#include "fmi2_frame.inc"
