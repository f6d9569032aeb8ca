/* A minimal FMI 2.0 Co-Simulation host in plain C: shows that the vehicle FMU runs
 * without Python (tests/test_fmu_c.py compares its result with fmpy's).
 *
 *   host_fmi2 <binaries/linux64/TirefilterVehicle.so> <guid> <vr_delta> <vr_yaw_rate>
 *
 * Loads the library with dlopen, instantiates with default parameters, holds the steer
 * angle delta = 0.02 rad and runs 500 communication steps of 0.01 s, printing t and the
 * yaw rate on the last line as "final t=<t> yaw_rate=<value>" (17 significant digits, so
 * the value round-trips exactly). Exit status 0 on success, 1 on any failure.
 *
 * Build: cc -std=c99 -I<fmpy>/c-code host_fmi2.c -ldl
 */
#define _POSIX_C_SOURCE 200809L /* dlopen, dlsym, dlerror */

#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h" /* from fmpy's c-code folder: types and function types only */

#define STEP_SIZE 0.01 /* s */
#define N_STEPS 500
#define DELTA 0.02 /* rad */

/* The FMU reports errors through this callback; print them so a failure says why. */
static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env;
    va_list ap;
    fprintf(stderr, "[%s] %s (status %d): ", instance ? instance : "?", category ? category : "", (int)status);
    va_start(ap, message);
    vfprintf(stderr, message, ap);
    va_end(ap);
    fputc('\n', stderr);
}

/* Look up one entry point; NULL (after a message) if the library lacks it. */
static void *symbol(void *lib, const char *name) {
    void *f = dlsym(lib, name);
    if (!f) fprintf(stderr, "host_fmi2: %s not found: %s\n", name, dlerror());
    return f;
}

/* Parse a value reference argument; returns 0 on success. */
static int parse_vr(const char *text, fmi2ValueReference *vr) {
    char *end;
    const unsigned long value = strtoul(text, &end, 10);
    if (end == text || *end != '\0') return 1;
    *vr = (fmi2ValueReference)value;
    return 0;
}

int main(int argc, char **argv) {
    if (argc != 5) {
        fprintf(stderr, "usage: %s <path/to/binaries/linux64/Model.so> <guid> <vr_delta> <vr_yaw_rate>\n",
                argv[0]);
        return 1;
    }
    const char *so_path = argv[1], *guid = argv[2];
    fmi2ValueReference vr_delta, vr_yaw_rate;
    if (parse_vr(argv[3], &vr_delta) || parse_vr(argv[4], &vr_yaw_rate)) {
        fprintf(stderr, "host_fmi2: value references must be unsigned integers\n");
        return 1;
    }

    void *lib = dlopen(so_path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "host_fmi2: cannot load %s: %s\n", so_path, dlerror());
        return 1;
    }

    /* Object pointer -> function pointer conversion: allowed by POSIX for dlsym results. */
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)symbol(lib, "fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup_experiment = (fmi2SetupExperimentTYPE *)symbol(lib, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter_init =
        (fmi2EnterInitializationModeTYPE *)symbol(lib, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *exit_init =
        (fmi2ExitInitializationModeTYPE *)symbol(lib, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE *set_real = (fmi2SetRealTYPE *)symbol(lib, "fmi2SetReal");
    fmi2GetRealTYPE *get_real = (fmi2GetRealTYPE *)symbol(lib, "fmi2GetReal");
    fmi2DoStepTYPE *do_step = (fmi2DoStepTYPE *)symbol(lib, "fmi2DoStep");
    fmi2TerminateTYPE *terminate = (fmi2TerminateTYPE *)symbol(lib, "fmi2Terminate");
    fmi2FreeInstanceTYPE *free_instance = (fmi2FreeInstanceTYPE *)symbol(lib, "fmi2FreeInstance");
    if (!instantiate || !setup_experiment || !enter_init || !exit_init || !set_real || !get_real || !do_step ||
        !terminate || !free_instance) {
        dlclose(lib);
        return 1;
    }

    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = instantiate("vehicle", fmi2CoSimulation, guid, "", &callbacks, fmi2False, fmi2False);
    if (!c) {
        fprintf(stderr, "host_fmi2: fmi2Instantiate failed\n");
        dlclose(lib);
        return 1;
    }

    double t = 0.0, yaw_rate = 0.0;
    const fmi2Real delta = DELTA;
    /* default parameters: only the start time is set before initialization */
    const int initialized = setup_experiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) == fmi2OK &&
                            enter_init(c) == fmi2OK && exit_init(c) == fmi2OK;
    int ok = initialized;
    if (!ok) fprintf(stderr, "host_fmi2: initialization failed\n");

    /* Communication points are k * h, not an accumulated sum, as fmpy-based callers do. */
    for (int k = 0; ok && k < N_STEPS; k++) {
        t = k * STEP_SIZE;
        if (set_real(c, &vr_delta, 1, &delta) != fmi2OK || do_step(c, t, STEP_SIZE, fmi2True) != fmi2OK) {
            fprintf(stderr, "host_fmi2: step from t = %.4f s failed\n", t);
            ok = 0;
        }
        t += STEP_SIZE;
    }
    if (ok && get_real(c, &vr_yaw_rate, 1, &yaw_rate) != fmi2OK) {
        fprintf(stderr, "host_fmi2: fmi2GetReal(yaw_rate) failed\n");
        ok = 0;
    }

    if (initialized) terminate(c); /* fmi2Terminate is only allowed after initialization */
    free_instance(c);
    dlclose(lib);
    if (!ok) return 1;
    printf("final t=%.17g yaw_rate=%.17g\n", t, yaw_rate);
    return 0;
}
