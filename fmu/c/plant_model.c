/*
 * dobkit plant model: rigid-body dynamics of the RRPR arm and its external
 * disturbances.  See plant_model.h.  Pure C99 and libm, no FMI.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "plant_model.h"

void plant_constants(const double *p, PlantConstants *k)
{
    const double l1 = p[P_l1], l2 = p[P_l2];
    const double m34 = p[P_m3] + p[P_m4];
    /* Eq. 5: S1, S2 and k1..k5 from Table 1 (l1, l2 are centre-of-mass distances) */
    const double s1 = p[P_m2] * (l2 * l2 + 4.0 * l1 * l1);
    const double s2 = m34 * (4.0 * l1 * l1 + 4.0 * l2 * l2);
    k->k1 = p[P_I1] + p[P_I2] + p[P_I3] + p[P_I4] + p[P_m1] * l1 * l1 + s1 + s2;
    k->k2 = 2.0 * (2.0 * l1 * l2 * p[P_m2] + 4.0 * l1 * l2 * m34);
    k->k3 = p[P_I2] + p[P_I3] + p[P_I4] + p[P_m2] * l2 * l2 + 4.0 * l2 * l2 * m34;
    k->k4 = m34;
    k->k5 = p[P_I4];
}

static double sign_of(double v)
{
    return (double)((v > 0.0) - (v < 0.0));
}

void plant_disturbance(const PlantData *d, double t, const double *x, double *tau_dis)
{
    const double *p = d->p;
    const double *q = x, *dq = x + 4;
    int i;

    for (i = 0; i < 4; i++) tau_dis[i] = 0.0;

    if (d->sw[SW_PAPER]) {
        /* Eq. 4 as printed: f_r sgn(2t + 1), a constant step for t >= 0 */
        const double s = sign_of(2.0 * t + 1.0);
        for (i = 0; i < 4; i++) tau_dis[i] += p[P_f_r + i] * s;
    }

    if (d->sw[SW_FRICTION]) {
        /* tanh keeps the right-hand side smooth for adaptive solvers */
        const double vs = p[P_friction_velocity];
        for (i = 0; i < 4; i++)
            tau_dis[i] -= p[P_coulomb + i] * tanh(dq[i] / vs) + p[P_viscous + i] * dq[i];
    }

    if (d->sw[SW_TISSUE]) {
        const double a1 = p[P_a1], a2 = p[P_a2];
        const double s1 = sin(q[0]), c1 = cos(q[0]);
        const double s12 = sin(q[0] + q[1]), c12 = cos(q[0] + q[1]);
        /* rows x and y of the kinematic Jacobian (Eq. 8, corrected) */
        const double jx0 = -a1 * s1 - a2 * s12, jx1 = -a2 * s12;
        const double jy0 = a1 * c1 + a2 * c12, jy1 = a2 * c12;
        const double vx = jx0 * dq[0] + jx1 * dq[1];
        const double vy = jy0 * dq[0] + jy1 * dq[1];
        const double vz = -dq[2];
        const double z = p[P_d1] - q[2] - p[P_d4];
        const double depth = p[P_skin_height] - z;
        if (depth > 0.0) {
            /* a spring-damper that pushes but cannot pull, plus in-plane drag */
            double fz = p[P_tissue_stiffness] * depth - p[P_tissue_damping] * vz;
            const double fx = -p[P_tissue_drag] * vx, fy = -p[P_tissue_drag] * vy;
            if (fz < 0.0) fz = 0.0;
            /* tau = J^T F; the z row of J is [0, 0, -1, 0], the roll row carries no force */
            tau_dis[0] += jx0 * fx + jy0 * fy;
            tau_dis[1] += jx1 * fx + jy1 * fy;
            tau_dis[2] += -fz;
        }
    }
}

/* Solve A y = b for a symmetric positive definite 4x4 A by Cholesky; 0 if not positive definite. */
static int solve_spd4(double A[4][4], const double *b, double *y)
{
    double L[4][4] = {{0.0}};
    double w[4];
    int i, j, k;

    for (j = 0; j < 4; j++) {
        double s = A[j][j];
        for (k = 0; k < j; k++) s -= L[j][k] * L[j][k];
        if (!(s > 0.0)) return 0;
        L[j][j] = sqrt(s);
        for (i = j + 1; i < 4; i++) {
            double r = A[i][j];
            for (k = 0; k < j; k++) r -= L[i][k] * L[j][k];
            L[i][j] = r / L[j][j];
        }
    }
    for (i = 0; i < 4; i++) {
        double s = b[i];
        for (k = 0; k < i; k++) s -= L[i][k] * w[k];
        w[i] = s / L[i][i];
    }
    for (i = 3; i >= 0; i--) {
        double s = w[i];
        for (k = i + 1; k < 4; k++) s -= L[k][i] * y[k];
        y[i] = s / L[i][i];
    }
    return 1;
}

int plant_derivatives(const PlantData *d, double t, const double *x, const double *u, double *dx)
{
    PlantConstants k;
    double M[4][4], rhs[4], tau_dis[4], N[4];
    const double *dq = x + 4;
    const double c2 = cos(x[1]), s2 = sin(x[1]);
    int i;

    plant_constants(d->p, &k);
    memset(M, 0, sizeof M);
    /* Eq. 5 */
    M[0][0] = k.k1 + k.k2 * c2;
    M[0][1] = M[1][0] = k.k3 + 0.5 * k.k2 * c2;
    M[1][1] = k.k3;
    M[2][2] = k.k4;
    M[0][3] = M[3][0] = -k.k5;
    M[1][3] = M[3][1] = -k.k5;
    M[3][3] = k.k5;
    /* Eq. 6: the Coriolis and centrifugal vector N(q, q') q' */
    N[0] = -k.k2 * s2 * dq[1] * (dq[0] + 0.5 * dq[1]);
    N[1] = 0.5 * k.k2 * s2 * dq[0] * dq[0];
    N[2] = 0.0;
    N[3] = 0.0;

    plant_disturbance(d, t, x, tau_dis);
    for (i = 0; i < 4; i++) rhs[i] = u[i] + tau_dis[i] - N[i];
    rhs[2] -= -k.k4 * d->p[P_g]; /* Eq. 7: G = [0, 0, -k4 g, 0] */

    for (i = 0; i < 4; i++) dx[i] = dq[i];
    if (!solve_spd4(M, rhs, dx + 4)) return PLANT_NOT_PD;
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
    double dx[NX], xp[NX], xm[NX], fp[4], fm[4];
    int i, rc;

    if (vr >= VR_Q && vr < VR_Q + 4) {
        *value = d->x[4 + (vr - VR_Q)];
        return PLANT_OK;
    }
    if (!((vr >= VR_DQ && vr < VR_DQ + 4) || (vr >= VR_TAU_DIS && vr < VR_TAU_DIS + 4))) return -1;
    if ((rc = plant_derivatives(d, d->time, d->x, d->u, dx)) != PLANT_OK) return rc;
    if (vr < VR_TAU_DIS) {
        *value = dx[4 + (vr - VR_DQ)];
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
    PlantConstants k;
    double margin;
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
    /* M(q) positive definite for every theta2 (docs/model.md, "Inertia matrix") */
    plant_constants(d->p, &k);
    margin = (k.k1 - k.k3) * (k.k3 - k.k5) - 0.25 * k.k2 * k.k2;
    if (!(k.k1 > k.k3 && k.k3 > k.k5 && margin > 0.0)) {
        snprintf(msg, msg_size,
                 "parameters give an inertia matrix that is not positive definite for every theta2 "
                 "(k1=%g, k2=%g, k3=%g, k5=%g kg m^2; need k1 > k3 > k5 and (k1-k3)(k3-k5) > k2^2/4)",
                 k.k1, k.k2, k.k3, k.k5);
        return 0;
    }
    return 1;
}
