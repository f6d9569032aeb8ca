/* A plain C FMI 2.0 Co-Simulation host for the estimator FMU (pythonfmu): shows what a
 * native tool needs to run it (README, "What the target machine needs"): libpython
 * preloaded and Python pointed at numpy/scipy. tests/test_estimator_fmu.py runs it.
 *
 *   host_python_fmu <unzipped FMU dir> <modelIdentifier> <guid> <vr_in> <value> <vr_out> <steps>
 *                   [<vr>=<value> ...]
 *
 * Instantiates with the FMU's resource location, default parameters, holds input <vr_in>
 * at <value> (and every further <vr>=<value>), runs <steps> communication steps of 0.01 s
 * and prints the Real output <vr_out> as "final out=<value>" (17 significant digits).
 * Exit status 0 on success.
 *
 * Build: cc -std=c99 -I<fmpy>/c-code host_python_fmu.c -ldl
 */
#define _POSIX_C_SOURCE 200809L

#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

static void log_message(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                        fmi2String message, ...) {
    (void)env;
    va_list ap;
    fprintf(stderr, "[%s] %s (status %d): ", instance ? instance : "?", category ? category : "", (int)status);
    va_start(ap, message);
    vfprintf(stderr, message, ap);
    va_end(ap);
    fputc('\n', stderr);
}

static void *symbol(void *lib, const char *name) {
    void *f = dlsym(lib, name);
    if (!f) fprintf(stderr, "host_python_fmu: %s not found: %s\n", name, dlerror());
    return f;
}

int main(int argc, char **argv) {
    if (argc < 8 || argc > 8 + 16) {
        fprintf(stderr, "usage: %s <unzipped dir> <modelIdentifier> <guid> <vr_in> <value> <vr_out> <steps> "
                "[<vr>=<value> ...]\n", argv[0]);
        return 1;
    }
    fmi2ValueReference vr_more[16];
    fmi2Real value_more[16];
    const size_t n_more = (size_t)(argc - 8);
    for (size_t i = 0; i < n_more; i++) {
        char *end;
        vr_more[i] = (fmi2ValueReference)strtoul(argv[8 + i], &end, 10);
        if (*end != '=') {
            fprintf(stderr, "host_python_fmu: %s is not <vr>=<value>\n", argv[8 + i]);
            return 1;
        }
        value_more[i] = strtod(end + 1, NULL);
    }
    const char *dir = argv[1], *id = argv[2], *guid = argv[3];
    const fmi2ValueReference vr_in = (fmi2ValueReference)strtoul(argv[4], NULL, 10);
    const fmi2Real value = strtod(argv[5], NULL);
    const fmi2ValueReference vr_out = (fmi2ValueReference)strtoul(argv[6], NULL, 10);
    const int steps = atoi(argv[7]);

    char so_path[4096], resources[4096];
    snprintf(so_path, sizeof so_path, "%s/binaries/linux64/%s.so", dir, id);
    snprintf(resources, sizeof resources, "file://%s/resources", dir);
    void *lib = dlopen(so_path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "host_python_fmu: cannot load %s: %s\n", so_path, dlerror());
        return 1;
    }
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)symbol(lib, "fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)symbol(lib, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter = (fmi2EnterInitializationModeTYPE *)symbol(lib, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *exit_init = (fmi2ExitInitializationModeTYPE *)symbol(lib, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE *set_real = (fmi2SetRealTYPE *)symbol(lib, "fmi2SetReal");
    fmi2GetRealTYPE *get_real = (fmi2GetRealTYPE *)symbol(lib, "fmi2GetReal");
    fmi2DoStepTYPE *do_step = (fmi2DoStepTYPE *)symbol(lib, "fmi2DoStep");
    fmi2TerminateTYPE *terminate = (fmi2TerminateTYPE *)symbol(lib, "fmi2Terminate");
    fmi2FreeInstanceTYPE *free_instance = (fmi2FreeInstanceTYPE *)symbol(lib, "fmi2FreeInstance");
    if (!instantiate || !setup || !enter || !exit_init || !set_real || !get_real || !do_step || !terminate ||
        !free_instance)
        return 1;

    fmi2CallbackFunctions callbacks = {log_message, calloc, free, NULL, NULL};
    fmi2Component c = instantiate("estimator", fmi2CoSimulation, guid, resources, &callbacks, fmi2False, fmi2True);
    if (!c) {
        fprintf(stderr, "host_python_fmu: fmi2Instantiate failed\n");
        return 1;
    }
    int ok = setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) == fmi2OK && enter(c) == fmi2OK && exit_init(c) == fmi2OK;
    if (!ok) fprintf(stderr, "host_python_fmu: initialization failed\n");
    double out = 0.0;
    for (int k = 0; ok && k < steps; k++) {
        if (set_real(c, &vr_in, 1, &value) != fmi2OK || (n_more && set_real(c, vr_more, n_more, value_more) != fmi2OK) ||
            do_step(c, k * 0.01, 0.01, fmi2True) != fmi2OK)
            ok = 0;
    }
    if (ok && get_real(c, &vr_out, 1, &out) != fmi2OK) ok = 0;
    if (ok) terminate(c);
    free_instance(c);
    if (!ok) return 1;
    printf("final out=%.17g\n", out);
    return 0;
}
