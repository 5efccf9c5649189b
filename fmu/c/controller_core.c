/*
 * dobkit controller FMU: one instance of the sampled controller (see controller_core.h).
 * The maths of a tick is generated from the kernels (controller_tick.c); the reference is a table of
 * one row per tick (controller_reference.c).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "controller_core.h"
#include "controller_tick.h"

#define N CTRL_N
#define NOUT (3 * CTRL_N)
#define NE ((CTRL_N + 1) * (CTRL_N + 1))

extern const double CTRL_REF[];

static const int TUNABLE_THETA[N_TUNABLE] = CTRL_TUNABLE_THETA;
static const char *TUNABLE_NAMES[N_TUNABLE] = CTRL_TUNABLE_NAMES;
static const double THETA0[CTRL_NTHETA] = CTRL_THETA0;

void ctrl_log(CtrlCore *c, int status, const char *format, ...)
{
    char text[1024];
    va_list args;
    if (!c->emit || (status == CTRL_OK && !c->logging_on)) return;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    c->emit(c->ctx, status, status == CTRL_OK ? "logAll" : "logStatusError", text);
}

void ctrl_reset(CtrlCore *c)
{
    c->mode = CTRL_INSTANTIATED;
    c->k = 0;
    c->started = c->outputs_valid = 0;
    memset(c->in, 0, sizeof c->in);
    memset(c->x, 0, sizeof c->x);
    memset(c->out, 0, sizeof c->out);
    memcpy(c->theta, THETA0, sizeof THETA0);
}

void ctrl_init(CtrlCore *c, const char *name, int logging_on, CtrlEmit emit, void *ctx)
{
    snprintf(c->name, sizeof c->name, "%s", name ? name : "controller");
    c->logging_on = logging_on;
    c->emit = emit;
    c->ctx = ctx;
    ctrl_reset(c);
}

double ctrl_time(const CtrlCore *c) { return (double)c->k * CTRL_PERIOD; }

static const double *reference_row(const CtrlCore *c)
{
    return CTRL_REF + (size_t)c->k * (size_t)(3 * N);
}

static int compute_outputs(CtrlCore *c)
{
    int i, j;
    if (c->outputs_valid) return CTRL_OK;
    if (c->k >= CTRL_NTICKS) {
        ctrl_log(c, CTRL_ERROR, "the reference table ends at t = %.17g s (reference_end, the scenario's "
                 "simulation.t_final); tick %ld is past it", CTRL_REFERENCE_END, c->k);
        return CTRL_ERROR;
    }
    if (!c->started) {
        /* the first tick: states from the first inputs, the delay buffer holding the first command
         * (blocks.digital_loop.sampled_initial_state) */
        ctrl_start(c->in, c->theta, c->x);
        if (CTRL_BUF_LEN > 0) {
            ctrl_outputs(ctrl_time(c), c->x, c->in, reference_row(c), c->theta, c->out);
            for (i = 0; i < CTRL_BUF_LEN; i += N)
                for (j = 0; j < N; j++) c->x[CTRL_BUF_START + i + j] = c->out[2 * N + j];
        }
        c->started = 1;
    }
    ctrl_outputs(ctrl_time(c), c->x, c->in, reference_row(c), c->theta, c->out);
    for (i = 0; i < NOUT; i++)
        if (!isfinite(c->out[i])) {
            ctrl_log(c, CTRL_ERROR, "the controller's output %d is not finite at t = %.17g s", i, ctrl_time(c));
            return CTRL_ERROR;
        }
    c->outputs_valid = 1;
    return CTRL_OK;
}

static int tick_update(CtrlCore *c)
{
    double e[NE], a[NE], xn[CTRL_NX > 0 ? CTRL_NX : 1];
    if (compute_outputs(c) != CTRL_OK) return CTRL_ERROR;
    memset(e, 0, sizeof e);
    memset(a, 0, sizeof a);
#if CTRL_ZOH
    ctrl_zoh_matrix(ctrl_time(c), c->x, c->in, reference_row(c), c->theta, a);
    if (dk_expm(N + 1, a, e) != 0) {
        ctrl_log(c, CTRL_ERROR, "the observer's zero-order-hold matrix is not finite at t = %.17g s", ctrl_time(c));
        return CTRL_ERROR;
    }
#endif
    ctrl_update(ctrl_time(c), c->x, c->in, reference_row(c), c->theta, e, xn);
    memcpy(c->x, xn, sizeof(double) * (size_t)CTRL_NX);
    c->k += 1;
    c->outputs_valid = 0;
    return CTRL_OK;
}

int ctrl_setup(CtrlCore *c, double start_time, int stop_defined, double stop_time)
{
    if (start_time != 0.0) {
        ctrl_log(c, CTRL_ERROR, "startTime = %.17g s refused: the controller's reference starts at t = 0 "
                 "(startTime must be 0)", start_time);
        return CTRL_ERROR;
    }
    if (stop_defined && stop_time > CTRL_REFERENCE_END * (1.0 + 1e-12)) {
        ctrl_log(c, CTRL_ERROR, "stopTime = %.17g s is past the end of the reference table, t = %.17g s "
                 "(reference_end, the scenario's simulation.t_final)", stop_time, CTRL_REFERENCE_END);
        return CTRL_ERROR;
    }
    return CTRL_OK;
}

int ctrl_get_real(CtrlCore *c, unsigned vr, double *value)
{
    if (vr < VR_TAU) {
        *value = c->in[vr];
    } else if (vr < VR_PARAM) {
        if (compute_outputs(c) != CTRL_OK) return CTRL_ERROR;
        *value = c->out[vr - VR_TAU];
    } else if (vr < VR_PARAM + N_TUNABLE) {
        *value = c->theta[TUNABLE_THETA[vr - VR_PARAM]];
    } else if (vr == VR_SAMPLE_PERIOD) {
        *value = CTRL_PERIOD;
    } else if (vr == VR_REFERENCE_END) {
        *value = CTRL_REFERENCE_END;
    } else if (vr == VR_TIME) {
        *value = ctrl_time(c);
    } else {
        ctrl_log(c, CTRL_ERROR, "get: unknown value reference %u", vr);
        return CTRL_ERROR;
    }
    return CTRL_OK;
}

int ctrl_set_real(CtrlCore *c, unsigned vr, double value)
{
    if (!isfinite(value)) {
        ctrl_log(c, CTRL_ERROR, "set: value reference %u: %g is not a finite number", vr, value);
        return CTRL_ERROR;
    }
    if (vr < VR_TAU) {
        c->in[vr] = value;
    } else if (vr >= VR_PARAM && vr < VR_PARAM + N_TUNABLE) {
        c->theta[TUNABLE_THETA[vr - VR_PARAM]] = value;
    } else {
        ctrl_log(c, CTRL_ERROR, "set: value reference %u is not an input (q[i], dq[i]) or a tunable parameter "
                 "(%s ... %s)", vr, TUNABLE_NAMES[0], TUNABLE_NAMES[N_TUNABLE - 1]);
        return CTRL_ERROR;
    }
    c->outputs_valid = 0;
    return CTRL_OK;
}

int ctrl_do_step(CtrlCore *c, double t, double h)
{
    if (c->mode != CTRL_STEPPING) {
        ctrl_log(c, CTRL_ERROR, "doStep is allowed after initialization only (and not after an error)");
        return CTRL_ERROR;
    }
    if (!(fabs(h - CTRL_PERIOD) <= 1e-9 * CTRL_PERIOD)) {
        ctrl_log(c, CTRL_ERROR, "doStep: communication step %.17g s refused: this controller runs at its sample "
                 "period Ts = %.17g s (%.17g Hz), so every step must be one sample, h = Ts", h, CTRL_PERIOD,
                 1.0 / CTRL_PERIOD);
        return CTRL_ERROR;
    }
    if (!(fabs(t - ctrl_time(c)) <= 1e-6 * CTRL_PERIOD)) {
        ctrl_log(c, CTRL_ERROR, "doStep: currentCommunicationPoint %.17g s is not the controller's time %.17g s "
                 "(tick %ld of period %.17g s)", t, ctrl_time(c), c->k, CTRL_PERIOD);
        return CTRL_ERROR;
    }
    if (c->k + 1 >= CTRL_NTICKS) {
        ctrl_log(c, CTRL_ERROR, "doStep at t = %.17g s: the reference table ends at t = %.17g s (reference_end, "
                 "the scenario's simulation.t_final)", ctrl_time(c), CTRL_REFERENCE_END);
        return CTRL_ERROR;
    }
    if (tick_update(c) != CTRL_OK) {
        c->mode = CTRL_FAILED;
        return CTRL_ERROR;
    }
    return CTRL_OK;
}
