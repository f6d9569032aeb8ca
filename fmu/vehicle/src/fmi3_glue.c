/* FMI 3.0 Co-Simulation entry points for the vehicle model. Only moves values between
 * the FMI API and VehicleModel; the equations are in vehicle_model.c. The entry points
 * this FMU does not support (Model Exchange, Scheduled Execution, clocks, other types)
 * are generated as stubs into fmi3_stubs.c by fmu/build.py. */
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
    (void)eventModeUsed;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    if (!token || strcmp(token, VEHICLE_INSTANTIATION_TOKEN) != 0) {
        if (logger) logger(env, fmi3Error, "error", "instantiation token does not match this FMU");
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
    ((Instance *)c)->model.time = start;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance ci) {
    Instance *c = (Instance *)ci;
    char msg[512];
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
    c->outputs_dirty = 0;
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance ci, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues) {
    Instance *c = (Instance *)ci;
    if (nValues != nvr) return fmi3Error; /* no arrays */
    refresh_outputs(c);
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] == 0) { /* time */
            values[i] = c->model.time;
            continue;
        }
        const int code = va_get_real(&c->model, vr[i], &values[i]);
        if (code) return access_error(c, "fmi3GetFloat64", vr[i], code);
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance ci, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nValues) {
    Instance *c = (Instance *)ci;
    if (nValues != nvr) return fmi3Error;
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
    if (nValues != nvr) return fmi3Error;
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
    if (nValues != nvr) return fmi3Error;
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
    *copy = c->model;
    *state = copy;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance ci, fmi3FMUState state) {
    Instance *c = (Instance *)ci;
    if (!state) return fmi3Error;
    c->model = *(const VehicleModel *)state;
    c->outputs_dirty = 0;
    c->failed = 0;
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
    *size = sizeof(VehicleModel);
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState state, fmi3Byte bytes[], size_t size) {
    (void)c;
    if (size < sizeof(VehicleModel)) return fmi3Error;
    memcpy(bytes, state, sizeof(VehicleModel));
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte bytes[], size_t size, fmi3FMUState *state) {
    (void)c;
    if (size != sizeof(VehicleModel)) return fmi3Error;
    VehicleModel *copy = (VehicleModel *)malloc(sizeof(VehicleModel));
    if (!copy) return fmi3Error;
    memcpy(copy, bytes, sizeof(VehicleModel));
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
    if (fabs(t - c->model.time) > 1e-9 * fmax(1.0, fabs(t))) {
        log_msg(c, fmi3Error, "error", "doStep at t = %.9g s, but the model is at t = %.9g s", t, c->model.time);
        return fmi3Error;
    }
    if (vm_do_step(&c->model, t + h, msg, sizeof(msg))) {
        log_msg(c, fmi3Error, "error", "%s", msg);
        c->failed = 1;
        *terminateSimulation = fmi3True;
        *lastSuccessfulTime = c->model.time;
        return fmi3Error;
    }
    c->outputs_dirty = 0;
    *lastSuccessfulTime = c->model.time;
    return fmi3OK;
}
