/* FMI 2.0 Co-Simulation entry points for the vehicle model. Only moves values between
 * the FMI API and VehicleModel; the equations are in vehicle_model.c. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "var_access.h"
#include "vehicle_model.h"

typedef struct {
    VehicleModel model;
    fmi2CallbackFunctions cb;
    char instance_name[128];
    int logging_on;
    int in_init;      /* between EnterInitializationMode and ExitInitializationMode */
    int outputs_dirty;/* an input changed since the outputs were computed */
    int failed;
    int terminated;   /* doStep returned Discard: the model left its domain (fmi2Terminated) */
    VehicleModel preview; /* in Initialization Mode: the model initialised from the current values */
} Instance;

static void log_msg(Instance *c, fmi2Status status, const char *category, const char *fmt, ...) {
    if (!c || !c->cb.logger) return;
    if (status == fmi2OK && !c->logging_on) return;
    char buf[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof(buf), fmt, ap);
    va_end(ap);
    c->cb.logger(c->cb.componentEnvironment, c->instance_name, status, category, "%s", buf);
}

static fmi2Status access_error(Instance *c, const char *function, fmi2ValueReference vr, int code) {
    char msg[256];
    va_error(function, vr, code, msg, sizeof(msg));
    log_msg(c, fmi2Error, "error", "%s", msg);
    return fmi2Error;
}

static void refresh_outputs(Instance *c) {
    if (c->model.initialized && c->outputs_dirty) {
        vm_update_outputs(&c->model);
        c->outputs_dirty = 0;
    }
}

/* The model whose values fmi2Get* reads: in Initialization Mode the outputs (the
 * InitialUnknowns) are those the current parameters initialise to, computed on a copy. */
static const VehicleModel *readable(Instance *c, const fmi2ValueReference vr[], size_t n, fmi2Status *status) {
    *status = fmi2OK;
    if (!c->in_init || !va_any_output(vr, n)) {
        refresh_outputs(c);
        return &c->model;
    }
    char msg[512];
    c->preview = c->model;
    if (vm_initialize(&c->preview, c->model.time, msg, sizeof(msg))) {
        log_msg(c, fmi2Error, "error", "the outputs cannot be computed in Initialization Mode: %s", msg);
        *status = fmi2Error;
    }
    return &c->preview;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t n, const fmi2String cats[]) {
    (void)n;
    (void)cats;
    ((Instance *)c)->logging_on = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)location;
    (void)visible;
    if (type != fmi2CoSimulation) return NULL;
    if (!guid || strcmp(guid, VEHICLE_INSTANTIATION_TOKEN) != 0) {
        if (functions && functions->logger)
            functions->logger(functions->componentEnvironment, name, fmi2Error, "error",
                              "GUID %s does not match %s", guid ? guid : "(null)", VEHICLE_INSTANTIATION_TOKEN);
        return NULL;
    }
    Instance *c = (Instance *)calloc(1, sizeof(Instance));
    if (!c) return NULL;
    if (functions) c->cb = *functions;
    snprintf(c->instance_name, sizeof(c->instance_name), "%s", name ? name : "vehicle");
    c->logging_on = loggingOn;
    vm_set_defaults(&c->model);
    return c;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDef, fmi2Real stop) {
    (void)tolDef;
    (void)tol;
    (void)stopDef;
    (void)stop;
    if (!isfinite(start)) {
        log_msg((Instance *)c, fmi2Error, "error", "fmi2SetupExperiment: start time %g is not finite", start);
        return fmi2Error;
    }
    ((Instance *)c)->model.time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ((Instance *)c)->in_init = 1;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component ci) {
    Instance *c = (Instance *)ci;
    char msg[512];
    c->in_init = 0;
    if (vm_initialize(&c->model, c->model.time, msg, sizeof(msg))) {
        log_msg(c, fmi2Error, "error", "%s", msg);
        c->failed = 1;
        return fmi2Error;
    }
    c->outputs_dirty = 0;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    (void)c;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component ci) {
    Instance *c = (Instance *)ci;
    vm_set_defaults(&c->model);
    c->failed = 0;
    c->terminated = 0;
    c->in_init = 0;
    c->outputs_dirty = 0;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component ci, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *c = (Instance *)ci;
    fmi2Status status;
    const VehicleModel *m = readable(c, vr, n, &status);
    if (status != fmi2OK) return status;
    for (size_t i = 0; i < n; i++) {
        const int code = va_get_real(m, vr[i], &value[i]);
        if (code) return access_error(c, "fmi2GetReal", vr[i], code);
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component ci, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    Instance *c = (Instance *)ci;
    for (size_t i = 0; i < n; i++) {
        const int code = va_get_int(&c->model, vr[i], &value[i]);
        if (code) return access_error(c, "fmi2GetInteger", vr[i], code);
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    (void)vr;
    (void)v;
    if (n == 0) return fmi2OK;
    log_msg((Instance *)c, fmi2Error, "error", "the model has no Boolean variables");
    return fmi2Error;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    (void)vr;
    (void)v;
    if (n == 0) return fmi2OK;
    log_msg((Instance *)c, fmi2Error, "error", "the model has no String variables");
    return fmi2Error;
}


fmi2Status fmi2SetReal(fmi2Component ci, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *c = (Instance *)ci;
    for (size_t i = 0; i < n; i++) {
        const int code = va_set_real(&c->model, vr[i], value[i]);
        if (code) return access_error(c, "fmi2SetReal", vr[i], code);
    }
    c->outputs_dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component ci, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    Instance *c = (Instance *)ci;
    for (size_t i = 0; i < n; i++) {
        const int code = va_set_int(&c->model, vr[i], value[i]);
        if (code) return access_error(c, "fmi2SetInteger", vr[i], code);
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    (void)vr;
    (void)v;
    if (n == 0) return fmi2OK;
    log_msg((Instance *)c, fmi2Error, "error", "the model has no Boolean variables");
    return fmi2Error;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    (void)vr;
    (void)v;
    if (n == 0) return fmi2OK;
    log_msg((Instance *)c, fmi2Error, "error", "the model has no String variables");
    return fmi2Error;
}

/* ---- FMU state: the whole VehicleModel (RNG included) is plain data -------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component ci, fmi2FMUstate *state) {
    Instance *c = (Instance *)ci;
    VehicleModel *copy = *state ? (VehicleModel *)*state : (VehicleModel *)malloc(sizeof(VehicleModel));
    if (!copy) return fmi2Error;
    refresh_outputs(c); /* the state holds the outputs of the inputs set so far */
    *copy = c->model;
    *state = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component ci, fmi2FMUstate state) {
    Instance *c = (Instance *)ci;
    if (!state) {
        log_msg(c, fmi2Error, "error", "fmi2SetFMUstate: no state given");
        return fmi2Error;
    }
    c->model = *(const VehicleModel *)state;
    c->outputs_dirty = 1; /* recomputed from the restored state and inputs on the next read */
    c->failed = 0;
    c->terminated = 0;
    c->in_init = 0;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    if (state) {
        free(*state);
        *state = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)c;
    (void)state;
    *size = vs_size();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    char msg[512];
    if (!state || vs_serialize((const VehicleModel *)state, (unsigned char *)bytes, size, msg, sizeof(msg))) {
        log_msg((Instance *)c, fmi2Error, "error", "%s", state ? msg : "fmi2SerializeFMUstate: no state given");
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    char msg[512];
    VehicleModel tmp;
    if (vs_deserialize((const unsigned char *)bytes, size, &tmp, msg, sizeof(msg))) {
        log_msg((Instance *)c, fmi2Error, "error", "%s", msg);
        return fmi2Error;
    }
    VehicleModel *copy = *state ? (VehicleModel *)*state : (VehicleModel *)malloc(sizeof(VehicleModel));
    if (!copy) return fmi2Error;
    *copy = tmp;
    *state = copy;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                        fmi2Real dz[]) {
    (void)u;
    (void)nu;
    (void)z;
    (void)nz;
    (void)dv;
    (void)dz;
    log_msg((Instance *)c, fmi2Error, "error", "directional derivatives are not provided");
    return fmi2Error;
}

/* ---- Co-Simulation -------------------------------------------------------------------- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)order;
    (void)value;
    if (n == 0) return fmi2OK;
    log_msg((Instance *)c, fmi2Error, "error", "input derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)order;
    (void)value;
    if (n == 0) return fmi2OK;
    log_msg((Instance *)c, fmi2Error, "error", "output derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component ci, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    (void)noSetPrior;
    Instance *c = (Instance *)ci;
    char msg[512];
    if (c->failed || !c->model.initialized) {
        log_msg(c, fmi2Error, "error", "doStep called on an instance that is not initialized or has failed");
        return fmi2Error;
    }
    if (!isfinite(t) || !isfinite(h) || h < 0.0) {
        log_msg(c, fmi2Error, "error", "doStep refused: communication point %g s and step size %g s must be finite, "
                "the step size not negative", t, h);
        return fmi2Error;
    }
    if (fabs(t - c->model.time) > 1e-9 * fmax(1.0, fabs(t))) {
        log_msg(c, fmi2Error, "error", "doStep at t = %.9g s, but the model is at t = %.9g s", t, c->model.time);
        return fmi2Error;
    }
    if (vm_do_step(&c->model, t + h, msg, sizeof(msg))) {
        c->failed = 1;
        if (c->model.below_v_min) { /* out of the model's domain: the tool may stop cleanly here */
            c->terminated = 1;
            vm_update_outputs(&c->model);
            log_msg(c, fmi2Discard, "discard", "%s", msg);
            return fmi2Discard;
        }
        log_msg(c, fmi2Error, "error", "%s", msg);
        return fmi2Error;
    }
    c->outputs_dirty = 0;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    (void)c;
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (s == fmi2LastSuccessfulTime) {
        *value = ((Instance *)c)->model.time;
        return fmi2OK;
    }
    return fmi2Discard;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (s == fmi2Terminated) {
        *value = ((Instance *)c)->terminated ? fmi2True : fmi2False;
        return fmi2OK;
    }
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

/* ---- Model Exchange functions: not supported, exported because loaders expect them ---- */

static fmi2Status me_unsupported(fmi2Component c, const char *function) {
    log_msg((Instance *)c, fmi2Error, "error", "%s: this FMU supports Co-Simulation only", function);
    return fmi2Error;
}

fmi2Status fmi2EnterEventMode(fmi2Component c) { (void)c; return me_unsupported(c, "fmi2EnterEventMode"); }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e) { (void)c; (void)e; return me_unsupported(c, "fmi2NewDiscreteStates"); }
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { (void)c; return me_unsupported(c, "fmi2EnterContinuousTimeMode"); }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean a, fmi2Boolean *b, fmi2Boolean *d) {
    (void)c; (void)a; (void)b; (void)d;
    return me_unsupported(c, "fmi2CompletedIntegratorStep");
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { (void)c; (void)t; return me_unsupported(c, "fmi2SetTime"); }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) { (void)c; (void)x; (void)n; return me_unsupported(c, "fmi2SetContinuousStates"); }
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real d[], size_t n) { (void)c; (void)d; (void)n; return me_unsupported(c, "fmi2GetDerivatives"); }
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real e[], size_t n) { (void)c; (void)e; (void)n; return me_unsupported(c, "fmi2GetEventIndicators"); }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { (void)c; (void)x; (void)n; return me_unsupported(c, "fmi2GetContinuousStates"); }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { (void)c; (void)x; (void)n; return me_unsupported(c, "fmi2GetNominalsOfContinuousStates"); }
