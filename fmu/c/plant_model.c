/*
 * dobkit plant model: the arm's dynamics and its external disturbances, around the maths that
 * fmu.generated writes into plant_generated.h from the same kernels the Python blocks and the compiled
 * engine run.  This file keeps what is not maths: the model switches, RK4 stepping, the input hold,
 * output derivatives and the parameter checks.  See plant_model.h.  Pure C99 and libm, no FMI.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "plant_model.h"
#include "plant_generated.h"

/* The bit mask of the switched-on disturbance models: bit j is switch j (SW_*), as fmu.generated numbers them. */
static int model_mask(const PlantData *d)
{
    int j, mask = 0;
    for (j = 0; j < N_SWITCHES; j++)
        if (d->sw[j]) mask |= 1 << j;
    return mask;
}

void plant_calculated_parameters(const double *p, double *out)
{
    plant_calculated(p, out);
}

void plant_disturbance(const PlantData *d, double t, const double *x, double *tau_dis)
{
    double theta[N_THETA];
    plant_theta(d->p, theta);
    PLANT_TAU_DIS[model_mask(d)](t, x, d->u, theta, tau_dis);
}

int plant_end_stops(const PlantData *d, const double *x, double *f)
{
#if N_STOPS > 0
    static const int joint[N_STOPS] = STOP_JOINT;
    static const int has_lower[N_STOPS] = STOP_HAS_LOWER;
    static const int has_upper[N_STOPS] = STOP_HAS_UPPER;
    static const double lower[N_STOPS] = STOP_LOWER;
    static const double upper[N_STOPS] = STOP_UPPER;
    static const int stiffness[N_STOPS] = STOP_STIFFNESS;
    static const int damping[N_STOPS] = STOP_DAMPING;
    int s, i, acting = 0;

    for (i = 0; i < NU; i++) f[i] = 0.0;
    for (s = 0; s < N_STOPS; s++) {
        const int j = joint[s];
        const double q = x[j], dq = x[N_JOINTS + j], k = d->p[stiffness[s]], c = d->p[damping[s]];
        double force;
        if (has_upper[s] && q > upper[s]) {
            force = -k * (q - upper[s]) - c * dq;
            if (force > 0.0) force = 0.0;        /* a stop pushes; it never pulls a leaving joint back */
        } else if (has_lower[s] && q < lower[s]) {
            force = k * (lower[s] - q) - c * dq;
            if (force < 0.0) force = 0.0;
        } else {
            continue;
        }
        f[j] = force;
        acting = 1;
    }
    return acting;
#else
    int i;
    (void)d;
    (void)x;
    for (i = 0; i < NU; i++) f[i] = 0.0;
    return 0;
#endif
}

int plant_derivatives(const PlantData *d, double t, const double *x, const double *u, double *dx)
{
    double theta[N_THETA], stop[NU], force[NU];
    int i;

    plant_theta(d->p, theta);
    /* inside every range no stop acts and the arm's dynamics run on u itself, operation for operation */
    if (plant_end_stops(d, x, stop)) {
        for (i = 0; i < NU; i++) force[i] = u[i] + stop[i];
        u = force;
    }
    plant_update(model_mask(d), t, x, u, theta, dx);
    for (i = 0; i < NX; i++)
        if (!isfinite(dx[i])) return PLANT_NONFINITE;
    return PLANT_OK;
}

/* The input at stage time t of a step that started at t0 with input u0 (see plant_rk4). */
static void stage_input(PlantData *d, double t0, const double *u0, double t, PlantInputUpdate update, void *ctx,
                        double *u)
{
    int i;
    if (update) {
        update(ctx, t);
        for (i = 0; i < NU; i++) u[i] = d->u[i];
    } else {
        for (i = 0; i < NU; i++) u[i] = u0[i] + (t - t0) * d->du[i];
    }
}

int plant_rk4(PlantData *d, double h, int n, int *bad_index, PlantInputUpdate update, void *ctx)
{
    double k1[NX], k2[NX], k3[NX], k4[NX], xt[NX], u0[NU], ua[NU], um[NU], ub[NU];
    const double dt = h / n;
    const double t0 = d->time;
    int step, i, rc;

    *bad_index = -1;
    memcpy(u0, d->u, sizeof u0);
    memcpy(ub, u0, sizeof ub);
    for (step = 0; step < n; step++) {
        /* time of this sub-step from its index, so rounding does not accumulate */
        const double t = t0 + step * dt;
        memcpy(ua, ub, sizeof ua);           /* the input at t: the end of the previous sub-step */
        stage_input(d, t0, u0, t + 0.5 * dt, update, ctx, um);
        stage_input(d, t0, u0, step + 1 == n ? t0 + h : t + dt, update, ctx, ub);
        if ((rc = plant_derivatives(d, t, d->x, ua, k1)) != PLANT_OK) return rc;
        for (i = 0; i < NX; i++) xt[i] = d->x[i] + 0.5 * dt * k1[i];
        if ((rc = plant_derivatives(d, t + 0.5 * dt, xt, um, k2)) != PLANT_OK) return rc;
        for (i = 0; i < NX; i++) xt[i] = d->x[i] + 0.5 * dt * k2[i];
        if ((rc = plant_derivatives(d, t + 0.5 * dt, xt, um, k3)) != PLANT_OK) return rc;
        for (i = 0; i < NX; i++) xt[i] = d->x[i] + dt * k3[i];
        if ((rc = plant_derivatives(d, t + dt, xt, ub, k4)) != PLANT_OK) return rc;
        for (i = 0; i < NX; i++) {
            d->x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            if (!isfinite(d->x[i])) {
                *bad_index = i;
                return PLANT_NONFINITE;
            }
        }
    }
    memcpy(d->u, ub, sizeof ub);
    d->time = t0 + h;
    return PLANT_OK;
}

int plant_output_derivative(const PlantData *d, unsigned vr, double *value)
{
    double dx[NX], xp[NX], xm[NX], fp[NU], fm[NU];
    int i, rc;

    if (vr >= VR_Q && vr < VR_Q + N_JOINTS) {
        *value = d->x[N_JOINTS + (vr - VR_Q)];
        return PLANT_OK;
    }
    if (!((vr >= VR_DQ && vr < VR_DQ + N_JOINTS) || (vr >= VR_TAU_DIS && vr < VR_TAU_DIS + NU))) return -1;
    if ((rc = plant_derivatives(d, d->time, d->x, d->u, dx)) != PLANT_OK) return rc;
    if (vr < VR_TAU_DIS) {
        *value = dx[N_JOINTS + (vr - VR_DQ)];
        return PLANT_OK;
    }
    {
        /* d tau_dis / dt along the motion: a central difference with a step that keeps the error near 1e-9 */
        const double delta = 1e-5;
        for (i = 0; i < NX; i++) {
            xp[i] = d->x[i] + delta * dx[i];
            xm[i] = d->x[i] - delta * dx[i];
        }
        plant_disturbance(d, d->time + delta, xp, fp);
        plant_disturbance(d, d->time - delta, xm, fm);
        *value = (fp[vr - VR_TAU_DIS] - fm[vr - VR_TAU_DIS]) / (2.0 * delta);
    }
    return isfinite(*value) ? PLANT_OK : PLANT_NONFINITE;
}

int plant_parameters_valid(const PlantData *d, char *msg, unsigned long msg_size)
{
    static const char *const names[N_PARAMS] = PARAM_NAMES;
    static const int positive[N_PARAMS] = PARAM_POSITIVE;
    static const int nonnegative[N_PARAMS] = PARAM_NONNEGATIVE;
    int i;

    for (i = 0; i < N_PARAMS; i++) {
        const double v = d->p[i];
        if (!isfinite(v)) {
            snprintf(msg, msg_size, "parameter %s must be finite, got %g", names[i], v);
            return 0;
        }
        if (positive[i] && !(v > 0.0)) {
            snprintf(msg, msg_size, "parameter %s must be > 0, got %g", names[i], v);
            return 0;
        }
        if (nonnegative[i] && v < 0.0) {
            snprintf(msg, msg_size, "parameter %s must be >= 0, got %g", names[i], v);
            return 0;
        }
    }
    if (d->n_substeps < 1) {
        snprintf(msg, msg_size, "parameter n_substeps must be >= 1, got %d", d->n_substeps);
        return 0;
    }
    /* the arm's own conditions (for the paper's arm: M(q) positive definite for every theta2) */
    return plant_arm_valid(d->p, d->sw, msg, msg_size);
}
