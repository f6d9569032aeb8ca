/* FMI 3.0 Co-Simulation entry points for the vehicle model. Only moves values between
 * the FMI API and VehicleModel; the equations are in vehicle_model.c. The entry points
 * this FMU does not support (Model Exchange, Scheduled Execution, clocks, other types)
 * are generated as stubs into fmi3_stubs.c by build.py (vehicle_fmu/). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "var_access.h"
#include "vehicle_model.h"

typedef struct {
    VehicleModel model;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback logger;
    char instance_name[128];
    int logging_on;
    int outputs_dirty;
    int failed;
    int in_init;          /* between EnterInitializationMode and ExitInitializationMode */
    VehicleModel preview; /* in Initialization Mode: the model initialised from the current values */
} Instance;

static void log_msg(Instance *c, fmi3Status status, const char *category, const char *fmt, ...) {
    if (!c || !c->logger) return;
    if (status == fmi3OK && !c->logging_on) return;
    char buf[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof(buf), fmt, ap);
    va_end(ap);
    c->logger(c->env, status, category, buf);
}

static fmi3Status access_error(Instance *c, const char *function, fmi3ValueReference vr, int code) {
    char msg[256];
    va_error(function, vr, code, msg, sizeof(msg));
    log_msg(c, fmi3Error, "error", "%s", msg);
    return fmi3Error;
}

static void refresh_outputs(Instance *c) {
    if (c->model.initialized && c->outputs_dirty) {
        vm_update_outputs(&c->model);
        c->outputs_dirty = 0;
    }
}

/* The model whose values fmi3Get* reads: in Initialization Mode the outputs (the
 * InitialUnknowns) are those the current parameters initialise to, computed on a copy. */
static const VehicleModel *readable(Instance *c, const fmi3ValueReference vr[], size_t n, fmi3Status *status) {
    *status = fmi3OK;
    if (!c->in_init || !va_any_output(vr, n)) {
        refresh_outputs(c);
        return &c->model;
    }
    char msg[512];
    c->preview = c->model;
    if (vm_initialize(&c->preview, c->model.time, msg, sizeof(msg))) {
        log_msg(c, fmi3Error, "error", "the outputs cannot be computed in Initialization Mode: %s", msg);
        *status = fmi3Error;
    }
    return &c->preview;
}

static fmi3Status count_error(Instance *c, const char *function, size_t nvr, size_t nValues) {
    log_msg(c, fmi3Error, "error", "%s: nValues = %zu, but %zu value references were given (this FMU has no "
            "array variables: one value per reference)", function, nValues, nvr);
    return fmi3Error;
}

/* Called by the generated stubs (fmi3_stubs.c) of the functions this FMU does not support. */
fmi3Status vehicle_fmi3_unsupported(fmi3Instance ci, const char *function) {
    log_msg((Instance *)ci, fmi3Error, "error", "%s is not supported by this FMU (Co-Simulation without event "
            "mode; variables of type Float64 and Int32 only)", function);
    return fmi3Error;
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean loggingOn, size_t n, const fmi3String cats[]) {
    (void)n;
    (void)cats;
    ((Instance *)c)->logging_on = loggingOn;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String name, fmi3String token, fmi3String resourcePath,
                                         fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment env, fmi3LogMessageCallback logger,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath;
    (void)visible;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    if (!token || strcmp(token, VEHICLE_INSTANTIATION_TOKEN) != 0) {
        if (logger) logger(env, fmi3Error, "error", "instantiation token does not match this FMU");
        return NULL;
    }
    if (eventModeUsed) {
        if (logger)
            logger(env, fmi3Error, "error", "eventModeUsed = true, but this FMU has no event mode "
                   "(hasEventMode = false in modelDescription.xml)");
        return NULL;
    }
    Instance *c = (Instance *)calloc(1, sizeof(Instance));
    if (!c) return NULL;
    c->env = env;
    c->logger = logger;
    c->logging_on = loggingOn;
    snprintf(c->instance_name, sizeof(c->instance_name), "%s", name ? name : "vehicle");
    vm_set_defaults(&c->model);
    return c;
}

void fmi3FreeInstance(fmi3Instance c) { free(c); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean tolDef, fmi3Float64 tol,
                                       fmi3Float64 start, fmi3Boolean stopDef, fmi3Float64 stop) {
    (void)tolDef;
    (void)tol;
    (void)stopDef;
    (void)stop;
    Instance *ci = (Instance *)c;
    if (!isfinite(start)) {
        log_msg(ci, fmi3Error, "error", "fmi3EnterInitializationMode: start time %g is not finite", start);
        return fmi3Error;
    }
    ci->model.time = start;
    ci->in_init = 1;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance ci) {
    Instance *c = (Instance *)ci;
    char msg[512];
    c->in_init = 0;
    if (vm_initialize(&c->model, c->model.time, msg, sizeof(msg))) {
        log_msg(c, fmi3Error, "error", "%s", msg);
        c->failed = 1;
        return fmi3Error;
    }
    c->outputs_dirty = 0;
    return fmi3OK;
}

fmi3Status fmi3EnterStepMode(fmi3Instance c) {
    (void)c;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance c) {
    (void)c;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance ci) {
    Instance *c = (Instance *)ci;
    vm_set_defaults(&c->model);
    c->failed = 0;
    c->in_init = 0;
    c->outputs_dirty = 0;
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance ci, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues) {
    Instance *c = (Instance *)ci;
    if (nValues != nvr) return count_error(c, "fmi3GetFloat64", nvr, nValues); /* no arrays */
    fmi3Status status;
    const VehicleModel *m = readable(c, vr, nvr, &status);
    if (status != fmi3OK) return status;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] == 0) { /* time */
            values[i] = c->model.time;
            continue;
        }
        const int code = va_get_real(m, vr[i], &values[i]);
        if (code) return access_error(c, "fmi3GetFloat64", vr[i], code);
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance ci, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nValues) {
    Instance *c = (Instance *)ci;
    if (nValues != nvr) return count_error(c, "fmi3SetFloat64", nvr, nValues);
    for (size_t i = 0; i < nvr; i++) {
        const int code = va_set_real(&c->model, vr[i], values[i]);
        if (code) return access_error(c, "fmi3SetFloat64", vr[i], code);
    }
    c->outputs_dirty = 1;
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance ci, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[],
                        size_t nValues) {
    Instance *c = (Instance *)ci;
    if (nValues != nvr) return count_error(c, "fmi3GetInt32", nvr, nValues);
    for (size_t i = 0; i < nvr; i++) {
        int value;
        const int code = va_get_int(&c->model, vr[i], &value);
        if (code) return access_error(c, "fmi3GetInt32", vr[i], code);
        values[i] = value;
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance ci, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 values[],
                        size_t nValues) {
    Instance *c = (Instance *)ci;
    if (nValues != nvr) return count_error(c, "fmi3SetInt32", nvr, nValues);
    for (size_t i = 0; i < nvr; i++) {
        const int code = va_set_int(&c->model, vr[i], values[i]);
        if (code) return access_error(c, "fmi3SetInt32", vr[i], code);
    }
    return fmi3OK;
}

/* ---- FMU state: the whole VehicleModel (RNG included) is plain data -------------------- */

fmi3Status fmi3GetFMUState(fmi3Instance ci, fmi3FMUState *state) {
    Instance *c = (Instance *)ci;
    VehicleModel *copy = *state ? (VehicleModel *)*state : (VehicleModel *)malloc(sizeof(VehicleModel));
    if (!copy) return fmi3Error;
    refresh_outputs(c); /* the state holds the outputs of the inputs set so far */
    *copy = c->model;
    *state = copy;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance ci, fmi3FMUState state) {
    Instance *c = (Instance *)ci;
    if (!state) {
        log_msg(c, fmi3Error, "error", "fmi3SetFMUState: no state given");
        return fmi3Error;
    }
    c->model = *(const VehicleModel *)state;
    c->outputs_dirty = 1; /* recomputed from the restored state and inputs on the next read */
    c->failed = 0;
    c->in_init = 0;
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *state) {
    (void)c;
    if (state) {
        free(*state);
        *state = NULL;
    }
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState state, size_t *size) {
    (void)c;
    (void)state;
    *size = vs_size();
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState state, fmi3Byte bytes[], size_t size) {
    char msg[512];
    if (!state || vs_serialize((const VehicleModel *)state, (unsigned char *)bytes, size, msg, sizeof(msg))) {
        log_msg((Instance *)c, fmi3Error, "error", "%s", state ? msg : "fmi3SerializeFMUState: no state given");
        return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte bytes[], size_t size, fmi3FMUState *state) {
    char msg[512];
    VehicleModel tmp;
    if (vs_deserialize((const unsigned char *)bytes, size, &tmp, msg, sizeof(msg))) {
        log_msg((Instance *)c, fmi3Error, "error", "%s", msg);
        return fmi3Error;
    }
    VehicleModel *copy = (VehicleModel *)malloc(sizeof(VehicleModel));
    if (!copy) return fmi3Error;
    *copy = tmp;
    *state = copy;
    return fmi3OK;
}

/* ---- Co-Simulation -------------------------------------------------------------------- */

fmi3Status fmi3DoStep(fmi3Instance ci, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance *c = (Instance *)ci;
    char msg[512];
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = c->model.time;
    if (c->failed || !c->model.initialized) {
        log_msg(c, fmi3Error, "error", "doStep called on an instance that is not initialized or has failed");
        return fmi3Error;
    }
    if (!isfinite(t) || !isfinite(h) || h < 0.0) {
        log_msg(c, fmi3Error, "error", "doStep refused: communication point %g s and step size %g s must be finite, "
                "the step size not negative", t, h);
        return fmi3Error;
    }
    if (fabs(t - c->model.time) > 1e-9 * fmax(1.0, fabs(t))) {
        log_msg(c, fmi3Error, "error", "doStep at t = %.9g s, but the model is at t = %.9g s", t, c->model.time);
        return fmi3Error;
    }
    if (vm_do_step(&c->model, t + h, msg, sizeof(msg))) {
        c->failed = 1;
        *terminateSimulation = fmi3True;
        *lastSuccessfulTime = c->model.time;
        if (c->model.below_v_min) { /* out of the model's domain: the tool may stop cleanly here */
            vm_update_outputs(&c->model);
            log_msg(c, fmi3Discard, "discard", "%s", msg);
            return fmi3Discard;
        }
        log_msg(c, fmi3Error, "error", "%s", msg);
        return fmi3Error;
    }
    c->outputs_dirty = 0;
    *lastSuccessfulTime = c->model.time;
    return fmi3OK;
}
