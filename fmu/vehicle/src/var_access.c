#include "var_access.h"

#include <stdio.h>

static const VehicleVarInfo *lookup(unsigned vr, char type) {
    if (vr < 1 || vr > VEHICLE_NVARS) return NULL;
    const VehicleVarInfo *info = &VEHICLE_VAR_INFO[vr - 1];
    return info->type == type ? info : NULL;
}

/* Parameters are fixed once initialized; inputs may be set at any time; outputs never. */
static int settable(const VehicleModel *m, const VehicleVarInfo *info) {
    return info->causality == 'i' || (info->causality == 'p' && !m->initialized);
}

int va_get_real(const VehicleModel *m, unsigned vr, double *value) {
    const VehicleVarInfo *info = lookup(vr, 'R');
    if (!info) return 1;
    *value = *(const double *)((const char *)&m->v + info->offset);
    return 0;
}

int va_get_int(const VehicleModel *m, unsigned vr, int *value) {
    const VehicleVarInfo *info = lookup(vr, 'I');
    if (!info) return 1;
    *value = *(const int *)((const char *)&m->v + info->offset);
    return 0;
}

int va_set_real(VehicleModel *m, unsigned vr, double value) {
    const VehicleVarInfo *info = lookup(vr, 'R');
    if (!info) return 1;
    if (!settable(m, info)) return 2;
    *(double *)((char *)&m->v + info->offset) = value;
    return 0;
}

int va_set_int(VehicleModel *m, unsigned vr, int value) {
    const VehicleVarInfo *info = lookup(vr, 'I');
    if (!info) return 1;
    if (!settable(m, info)) return 2;
    *(int *)((char *)&m->v + info->offset) = value;
    return 0;
}

void va_error(const char *function, unsigned vr, int code, char *msg, size_t len) {
    const char *name = (vr >= 1 && vr <= VEHICLE_NVARS) ? VEHICLE_VAR_INFO[vr - 1].name : "?";
    if (code == 1)
        snprintf(msg, len, "%s: value reference %u (%s) is not a variable of this type", function, vr, name);
    else
        snprintf(msg, len, "%s: %s (value reference %u) cannot be set now (outputs never, "
                 "parameters only before initialization)", function, name, vr);
}
