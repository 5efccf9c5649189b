/*
 * dobkit plant model: an arm of n joints (the paper's 4-DOF RRPR of Verma, Chauhan & Gupta 2019 first)
 *
 *     M(q) q'' + N(q, q') q' + G(q) = tau + tau_dis
 *
 * with q the joint positions (rad, m) and the external disturbance tau_dis the sum of the selected
 * models (paper Eq. 4 step, smoothed Coulomb + viscous friction, skin contact); beyond a joint's range
 * an end stop's force adds to tau.  The maths is generated
 * per export into plant_generated.h (fmu.generated) from the kernels of blocks/kernels.
 *
 * This file knows nothing about FMI.  The variable layout (value references,
 * parameter indices, start values) comes from plant_config.h, which dobkit
 * writes at export time.
 */
#ifndef DOBKIT_PLANT_MODEL_H
#define DOBKIT_PLANT_MODEL_H

#include "plant_config.h"

/* Everything that defines the model's behaviour: saved and restored as the FMU state. */
typedef struct {
    double time;              /* s */
    double x[NX];             /* q[0..n-1], dq[0..n-1] */
    double u[NU];             /* tau[0..n-1]: N m (revolute), N (prismatic) */
    double du[NU];            /* their time derivatives over the coming step (FMI 2 input derivatives), per s */
    double p[N_PARAMS];       /* real parameters, indexed by P_* */
    int n_substeps;           /* RK4 sub-steps per co-simulation step */
    int sw[N_SWITCHES];       /* disturbance model switches, indexed by SW_* */
} PlantData;

/* Model-level result codes (the FMI layer maps them to statuses). */
enum { PLANT_OK = 0, PLANT_NOT_PD = 1, PLANT_NONFINITE = 2 };

/* The calculated parameters (for the paper's arm k1..k5 of Eq. 5-7) from the real parameters p. */
void plant_calculated_parameters(const double *p, double *out);

/* External disturbance tau_dis at time t and state x. */
void plant_disturbance(const PlantData *d, double t, const double *x, double *tau_dis);

/*
 * End-stop forces f (N m, N) at state x: a spring-damper beyond each bounded joint's range that pushes,
 * never pulls (fmu/end_stops.py); zero inside.  Returns 1 if any joint is beyond its range, else 0.
 */
int plant_end_stops(const PlantData *d, const double *x, double *f);

/* State derivative dx = [dq, M^-1 (u + f_stop + tau_dis - N q' - G)]; returns a PLANT_* code. */
int plant_derivatives(const PlantData *d, double t, const double *x, const double *u, double *dx);

/*
 * Lets the importer set the inputs for time t during a step (FMI 3 intermediate update): called before
 * each Runge-Kutta stage at a new time, it may change d->u.
 */
typedef void (*PlantInputUpdate)(void *ctx, double t);

/*
 * Advance d->x from d->time by h with n classical RK4 steps.  The input at a stage time t is
 * d->u + (t - d->time) d->du (first-order hold; a zero-order hold when du is zero), or, when `update`
 * is given, whatever the importer sets from `update(ctx, t)`.  On return d->u holds the input at the
 * end of the step.
 */
int plant_rk4(PlantData *d, double h, int n, int *bad_index, PlantInputUpdate update, void *ctx);

/*
 * First time derivative of the output with value reference vr (q[i], dq[i] or tau_dis[i]) at the
 * current time, state and input: exact for q (dq) and dq (the acceleration); for tau_dis a central
 * difference along the motion.  Returns a PLANT_* code, or -1 if vr is not an output.
 */
int plant_output_derivative(const PlantData *d, unsigned vr, double *value);

/* Non-zero if the parameters describe a physical arm; fills msg with the first problem. */
int plant_parameters_valid(const PlantData *d, char *msg, unsigned long msg_size);

#endif
