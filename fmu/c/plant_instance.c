/*
 * dobkit plant FMU: instance life cycle and variable access, independent of
 * the FMI version.  See plant_instance.h.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "plant_instance.h"

static const char *const var_names[N_VARIABLES] = VAR_NAMES;
static const char *const mode_names[MODE_COUNT] = {
    "instantiated", "initialization", "event", "continuous-time", "step", "terminated", "failed"
};

static const char *mode_name(int mode)
{
    return mode >= 0 && mode < MODE_COUNT ? mode_names[mode] : "invalid";
}

static const char *var_name(unsigned vr)
{
    return vr < N_VARIABLES ? var_names[vr] : "?";
}

void plant_instance_reset(PlantInstance *inst)
{
    static const double p0[N_PARAMS] = START_PARAMS;
    static const double x0[NX] = START_X;
    static const int sw0[N_SWITCHES] = START_SWITCHES;

    memset(&inst->d, 0, sizeof inst->d);
    memcpy(inst->d.p, p0, sizeof p0);
    memcpy(inst->d.x, x0, sizeof x0);
    memcpy(inst->d.sw, sw0, sizeof sw0);
    inst->d.n_substeps = START_N_SUBSTEPS;
    inst->mode = MODE_INSTANTIATED;
}

void plant_instance_init(PlantInstance *inst, const char *name, int cosim, int logging_on,
                         PlantEmit emit, void *host)
{
    memset(inst, 0, sizeof *inst);
    snprintf(inst->name, sizeof inst->name, "%s", name ? name : "");
    inst->cosim = cosim;
    inst->logging_on = logging_on;
    inst->emit = emit;
    inst->host = host;
    plant_instance_reset(inst);
}

void plant_log(PlantInstance *inst, int status, const char *category, const char *fmt, ...)
{
    char message[1024];
    va_list ap;

    /* errors and warnings always reach the importer; the rest only with logging on */
    if (!inst || !inst->emit || (status == ST_OK && !inst->logging_on)) return;
    va_start(ap, fmt);
    vsnprintf(message, sizeof message, fmt, ap);
    va_end(ap);
    inst->emit(inst, status, category, message);
}

int plant_allowed(PlantInstance *inst, const char *what, unsigned modes)
{
    if (!inst) return ST_ERROR;
    /* never shift by an out-of-range mode (undefined behaviour) */
    if ((unsigned)inst->mode >= (unsigned)MODE_COUNT) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: the instance is in an invalid mode (%d)", what,
                  (int)inst->mode);
        return ST_ERROR;
    }
    if (modes & IN(inst->mode)) return ST_OK;
    plant_log(inst, ST_ERROR, "logStatusError", "%s is not allowed in %s mode", what, mode_name((int)inst->mode));
    return ST_ERROR;
}

/* ---- variable classes by value reference ------------------------------ */

static int is_state(unsigned vr) { return vr >= VR_Q && vr < VR_Q + NX; }
static int is_input(unsigned vr) { return vr >= VR_TAU && vr < VR_TAU + NU; }
static int is_param(unsigned vr) { return vr >= VR_PARAM && vr < VR_PARAM + N_PARAMS; }
static int is_switch(unsigned vr) { return vr >= VR_SWITCH && vr < VR_SWITCH + N_SWITCHES; }

static int unknown_vr(PlantInstance *inst, unsigned vr, const char *type)
{
    if (vr < N_VARIABLES)
        plant_log(inst, ST_ERROR, "logStatusError", "variable %s (value reference %u) is not of type %s",
                  var_name(vr), vr, type);
    else
        plant_log(inst, ST_ERROR, "logStatusError", "unknown value reference %u", vr);
    return ST_ERROR;
}

static int check_fixed(PlantInstance *inst, unsigned vr)
{
    if (inst->mode == MODE_INSTANTIATED || inst->mode == MODE_INITIALIZATION) return ST_OK;
    plant_log(inst, ST_ERROR, "logStatusError",
              "%s is a fixed parameter: set it before leaving initialization mode (now in %s mode)",
              var_name(vr), mode_name((int)inst->mode));
    return ST_ERROR;
}

int plant_get_real(PlantInstance *inst, unsigned vr, double *value)
{
    double buf[NX];
    int rc;

    if (vr == VR_TIME) {
        *value = inst->d.time;
    } else if (is_state(vr)) {
        *value = inst->d.x[vr - VR_Q];
    } else if (vr >= VR_DER_Q && vr < VR_DER_Q + NX) {
        rc = plant_derivatives(&inst->d, inst->d.time, inst->d.x, inst->d.u, buf);
        if (rc != PLANT_OK) {
            plant_log(inst, ST_ERROR, "logStatusError", "cannot evaluate %s at t = %.17g s: %s", var_name(vr),
                      inst->d.time, rc == PLANT_NOT_PD ? "inertia matrix not positive definite"
                                                       : "non-finite result");
            return ST_ERROR;
        }
        *value = buf[vr - VR_DER_Q];
    } else if (is_input(vr)) {
        *value = inst->d.u[vr - VR_TAU];
    } else if (vr >= VR_TAU_DIS && vr < VR_TAU_DIS + NU) {
        plant_disturbance(&inst->d, inst->d.time, inst->d.x, buf);
        *value = buf[vr - VR_TAU_DIS];
#if N_CALCULATED_PARAMS > 0
    } else if (vr >= VR_K && vr < VR_K + N_CALCULATED_PARAMS) {
        double k[N_CALCULATED_PARAMS];
        plant_calculated_parameters(inst->d.p, k);
        *value = k[vr - VR_K];
#endif
    } else if (is_param(vr)) {
        *value = inst->d.p[vr - VR_PARAM];
    } else {
        return unknown_vr(inst, vr, "Real/Float64");
    }
    return ST_OK;
}

int plant_set_real(PlantInstance *inst, unsigned vr, double value)
{
    if (plant_allowed(inst, "setting a real variable", ANY_LIVE_MODE) != ST_OK) return ST_ERROR;
    if (is_input(vr)) {
        inst->d.u[vr - VR_TAU] = value;
        inst->d.du[vr - VR_TAU] = 0.0;   /* a new value without a slope is held over the step */
    } else if (is_param(vr)) {
        if (check_fixed(inst, vr) != ST_OK) return ST_ERROR;
        inst->d.p[vr - VR_PARAM] = value;
    } else if (is_state(vr)) {
        /* start values of the states; later only through set_states (Model Exchange) */
        if (inst->mode != MODE_INSTANTIATED && inst->mode != MODE_INITIALIZATION) {
            plant_log(inst, ST_ERROR, "logStatusError",
                      "the start value of %s can only be set before leaving initialization mode", var_name(vr));
            return ST_ERROR;
        }
        inst->d.x[vr - VR_Q] = value;
    } else if (vr < N_VARIABLES && !is_switch(vr) && vr != VR_N_SUBSTEPS) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s (value reference %u) is computed by the model and "
                  "cannot be set", var_name(vr), vr);
        return ST_ERROR;
    } else {
        return unknown_vr(inst, vr, "Real/Float64");
    }
    return ST_OK;
}

int plant_get_integer(PlantInstance *inst, unsigned vr, int *value)
{
    if (vr != VR_N_SUBSTEPS) return unknown_vr(inst, vr, "Integer/Int32");
    *value = inst->d.n_substeps;
    return ST_OK;
}

int plant_set_integer(PlantInstance *inst, unsigned vr, int value)
{
    if (plant_allowed(inst, "setting an integer variable", ANY_LIVE_MODE) != ST_OK) return ST_ERROR;
    if (vr != VR_N_SUBSTEPS) return unknown_vr(inst, vr, "Integer/Int32");
    if (check_fixed(inst, vr) != ST_OK) return ST_ERROR;
    inst->d.n_substeps = value;
    return ST_OK;
}

int plant_get_boolean(PlantInstance *inst, unsigned vr, int *value)
{
    if (!is_switch(vr)) return unknown_vr(inst, vr, "Boolean");
    *value = inst->d.sw[vr - VR_SWITCH];
    return ST_OK;
}

int plant_set_boolean(PlantInstance *inst, unsigned vr, int value)
{
    if (plant_allowed(inst, "setting a boolean variable", ANY_LIVE_MODE) != ST_OK) return ST_ERROR;
    if (!is_switch(vr)) return unknown_vr(inst, vr, "Boolean");
    if (check_fixed(inst, vr) != ST_OK) return ST_ERROR;
    inst->d.sw[vr - VR_SWITCH] = value ? 1 : 0;
    return ST_OK;
}

/* ---- life cycle -------------------------------------------------------- */

int plant_enter_initialization(PlantInstance *inst, double start_time)
{
    if (plant_allowed(inst, "entering initialization mode", IN(MODE_INSTANTIATED)) != ST_OK) return ST_ERROR;
    inst->d.time = start_time;
    inst->mode = MODE_INITIALIZATION;
    return ST_OK;
}

int plant_exit_initialization(PlantInstance *inst)
{
    char msg[512];

    if (plant_allowed(inst, "exiting initialization mode", IN(MODE_INITIALIZATION)) != ST_OK) return ST_ERROR;
    if (!plant_parameters_valid(&inst->d, msg, sizeof msg)) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s", msg);
        inst->mode = MODE_FAILED;
        return ST_ERROR;
    }
    inst->mode = inst->cosim ? MODE_STEP : MODE_EVENT;
    return ST_OK;
}

#define ME_MODES (IN(MODE_INITIALIZATION) | IN(MODE_EVENT) | IN(MODE_CONTINUOUS))

int plant_set_time(PlantInstance *inst, double t)
{
    if (plant_allowed(inst, "setting the time", ME_MODES) != ST_OK) return ST_ERROR;
    inst->d.time = t;
    return ST_OK;
}

static int check_nx(PlantInstance *inst, size_t nx, const char *what)
{
    if (nx == NX) return ST_OK;
    plant_log(inst, ST_ERROR, "logStatusError", "%s: expected %d continuous states, got %lu", what, NX,
              (unsigned long)nx);
    return ST_ERROR;
}

int plant_set_states(PlantInstance *inst, const double *x, size_t nx)
{
    if (plant_allowed(inst, "setting the continuous states", ME_MODES) != ST_OK) return ST_ERROR;
    if (check_nx(inst, nx, "set continuous states") != ST_OK) return ST_ERROR;
    memcpy(inst->d.x, x, sizeof inst->d.x);
    return ST_OK;
}

int plant_get_states(PlantInstance *inst, double *x, size_t nx)
{
    if (check_nx(inst, nx, "get continuous states") != ST_OK) return ST_ERROR;
    memcpy(x, inst->d.x, sizeof inst->d.x);
    return ST_OK;
}

int plant_get_derivatives(PlantInstance *inst, double *dx, size_t nx)
{
    int rc, i;

    if (plant_allowed(inst, "getting the state derivatives", ME_MODES) != ST_OK) return ST_ERROR;
    if (check_nx(inst, nx, "get derivatives") != ST_OK) return ST_ERROR;
    rc = plant_derivatives(&inst->d, inst->d.time, inst->d.x, inst->d.u, dx);
    if (rc == PLANT_NOT_PD) {
        plant_log(inst, ST_ERROR, "logStatusError", "inertia matrix is not positive definite at t = %.17g s "
                  "(theta2 = %g rad)", inst->d.time, inst->d.x[1]);
        return ST_ERROR;
    }
    if (rc != PLANT_OK) {
        for (i = 0; i < NX && isfinite(dx[i]); i++) {}
        plant_log(inst, ST_ERROR, "logStatusError", "non-finite derivative der(%s) at t = %.17g s",
                  var_name(VR_Q + (unsigned)(i < NX ? i : 0)), inst->d.time);
        return ST_ERROR;
    }
    return ST_OK;
}

int plant_get_nominals(PlantInstance *inst, double *nominal, size_t nx)
{
    size_t i;
    if (check_nx(inst, nx, "get nominals") != ST_OK) return ST_ERROR;
    for (i = 0; i < nx; i++) nominal[i] = 1.0;
    return ST_OK;
}

int plant_do_step(PlantInstance *inst, double t, double h)
{
    int rc, bad;
    const double t0 = inst->d.time;

    if (plant_allowed(inst, "doStep", IN(MODE_STEP)) != ST_OK) return ST_ERROR;
    if (!(h > 0.0) || !isfinite(h)) {
        plant_log(inst, ST_ERROR, "logStatusError", "communication step size must be > 0, got %g s", h);
        return ST_ERROR;
    }
    if (fabs(t - t0) > 1e-9 * (1.0 + fabs(t0))) {
        plant_log(inst, ST_ERROR, "logStatusError", "doStep from t = %.17g s but the FMU is at t = %.17g s",
                  t, t0);
        return ST_ERROR;
    }
    inst->d.time = t;
    rc = plant_rk4(&inst->d, h, inst->d.n_substeps, &bad, inst->input_update, inst->host);
    if (rc != PLANT_OK) {
        inst->mode = MODE_FAILED;
        if (rc == PLANT_NOT_PD)
            plant_log(inst, ST_ERROR, "logStatusError", "step from t = %.17g s: inertia matrix not positive "
                      "definite", t);
        else
            plant_log(inst, ST_ERROR, "logStatusError", "step from t = %.17g s (h = %g s): the state %s "
                      "became non-finite", t, h, bad >= 0 && bad < NX ? var_name(VR_Q + (unsigned)bad) : "derivative");
        return ST_ERROR;
    }
    return ST_OK;
}

int plant_set_input_derivative(PlantInstance *inst, unsigned vr, int order, double value)
{
    if (plant_allowed(inst, "setting input derivatives", IN(MODE_INITIALIZATION) | IN(MODE_STEP)) != ST_OK)
        return ST_ERROR;
    if (!is_input(vr)) {
        plant_log(inst, ST_ERROR, "logStatusError", "input derivatives: %s (value reference %u) is not an input",
                  var_name(vr), vr);
        return ST_ERROR;
    }
    if (order != 1) {
        plant_log(inst, ST_ERROR, "logStatusError", "input derivatives: order %d of %s requested; this FMU "
                  "interpolates inputs linearly (order 1 only)", order, var_name(vr));
        return ST_ERROR;
    }
    if (!isfinite(value)) {
        plant_log(inst, ST_ERROR, "logStatusError", "input derivatives: d%s/dt = %g is not finite", var_name(vr),
                  value);
        return ST_ERROR;
    }
    inst->d.du[vr - VR_TAU] = value;
    return ST_OK;
}

int plant_get_output_derivative(PlantInstance *inst, unsigned vr, int order, double *value)
{
    int rc;

    if (order != 1) {
        plant_log(inst, ST_ERROR, "logStatusError", "output derivatives: order %d of %s requested; "
                  "maxOutputDerivativeOrder is 1", order, var_name(vr));
        return ST_ERROR;
    }
    rc = plant_output_derivative(&inst->d, vr, value);
    if (rc == -1) {
        plant_log(inst, ST_ERROR, "logStatusError", "output derivatives: %s (value reference %u) is not an "
                  "output", var_name(vr), vr);
        return ST_ERROR;
    }
    if (rc != PLANT_OK) {
        plant_log(inst, ST_ERROR, "logStatusError", "output derivative of %s at t = %.17g s: %s", var_name(vr),
                  inst->d.time, rc == PLANT_NOT_PD ? "inertia matrix not positive definite" : "non-finite result");
        return ST_ERROR;
    }
    return ST_OK;
}

/* ---- restoring a saved state -------------------------------------------- */

int plant_state_valid(const PlantInstance *inst, const PlantData *d, int mode, char *msg, size_t msg_size)
{
    int i;

    if (mode < 0 || mode >= MODE_COUNT) {
        snprintf(msg, msg_size, "mode %d is not a valid instance mode (0 to %d)", mode, MODE_COUNT - 1);
        return 0;
    }
    if (inst->cosim ? (mode == MODE_EVENT || mode == MODE_CONTINUOUS) : mode == MODE_STEP) {
        snprintf(msg, msg_size, "a state in %s mode belongs to a %s instance, this one is %s", mode_name(mode),
                 inst->cosim ? "Model Exchange" : "Co-Simulation",
                 inst->cosim ? "Co-Simulation" : "Model Exchange");
        return 0;
    }
    if (!isfinite(d->time)) {
        snprintf(msg, msg_size, "time %g is not finite", d->time);
        return 0;
    }
    for (i = 0; i < N_SWITCHES; i++) {
        if (d->sw[i] != 0 && d->sw[i] != 1) {
            snprintf(msg, msg_size, "disturbance switch %d is %d, expected 0 or 1", i, d->sw[i]);
            return 0;
        }
    }
    /* past initialization the parameters were checked once; a restored state must pass the same checks */
    if (mode == MODE_EVENT || mode == MODE_CONTINUOUS || mode == MODE_STEP || mode == MODE_TERMINATED) {
        if (!plant_parameters_valid(d, msg, (unsigned long)msg_size)) return 0;
    }
    return 1;
}

int plant_restore(PlantInstance *inst, const PlantData *d, int mode, const char *what)
{
    char msg[512];

    if (!plant_state_valid(inst, d, mode, msg, sizeof msg)) {
        plant_log(inst, ST_ERROR, "logStatusError", "%s: invalid FMU state: %s", what, msg);
        return ST_ERROR;
    }
    inst->d = *d;
    inst->mode = (PlantMode)mode;
    return ST_OK;
}
