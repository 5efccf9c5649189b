/*
 * dobkit controller FMU: one instance of the sampled controller, independent of the FMI version.
 *
 * At tick k (t_k = k Ts) the outputs tau[i], d_hat[i] are those of the monolithic sampled loop
 * (blocks/hybrid.py, tick_outputs): computed from the inputs q[i], dq[i] set at t_k, the controller's
 * state and the reference row k.  A step applies the tick's updates (encoder, observer, delay buffer)
 * and moves to t_{k+1}; it must be one sample long.  The FMI layers (fmi2_controller.c,
 * fmi3_controller.c) map their calls onto these functions; statuses are 0 (OK) and 3 (error), as in
 * both standards.
 */
#ifndef DOBKIT_CONTROLLER_CORE_H
#define DOBKIT_CONTROLLER_CORE_H

#include "controller_config.h"

#define CTRL_OK 0
#define CTRL_ERROR 3

typedef void (*CtrlEmit)(void *ctx, int status, const char *category, const char *message);

typedef enum { CTRL_INSTANTIATED, CTRL_INITIALIZING, CTRL_STEPPING, CTRL_TERMINATED, CTRL_FAILED } CtrlMode;

typedef struct {
    char name[256];
    int logging_on;
    CtrlEmit emit;
    void *ctx;
    CtrlMode mode;
    long k;                               /* tick number: time = k Ts */
    double in[2 * CTRL_N];                /* q, dq */
    double theta[CTRL_NTHETA];
    double x[CTRL_NX > 0 ? CTRL_NX : 1];
    double out[3 * CTRL_N];               /* tau, d_hat, tau_cmd at tick k */
    int started, outputs_valid;
} CtrlCore;

void ctrl_init(CtrlCore *c, const char *name, int logging_on, CtrlEmit emit, void *ctx);
void ctrl_reset(CtrlCore *c);
void ctrl_log(CtrlCore *c, int status, const char *format, ...);
int ctrl_setup(CtrlCore *c, double start_time, int stop_defined, double stop_time);
int ctrl_get_real(CtrlCore *c, unsigned vr, double *value);
int ctrl_set_real(CtrlCore *c, unsigned vr, double value);
int ctrl_do_step(CtrlCore *c, double t, double h);
double ctrl_time(const CtrlCore *c);

#endif
