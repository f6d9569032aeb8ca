#include "var_access.h"

#include <stdio.h>
#include <string.h>

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

int va_any_output(const unsigned *vr, size_t n) {
    for (size_t i = 0; i < n; i++)
        if (vr[i] >= 1 && vr[i] <= VEHICLE_NVARS && VEHICLE_VAR_INFO[vr[i] - 1].causality == 'o') return 1;
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

/* ---- serialized FMU state -------------------------------------------------------------- */

uint64_t vs_fnv1a(const void *data, size_t n) {
    const unsigned char *p = (const unsigned char *)data;
    uint64_t h = 0xcbf29ce484222325ULL;
    for (size_t i = 0; i < n; i++) {
        h ^= p[i];
        h *= 0x100000001b3ULL;
    }
    return h;
}

size_t vs_size(void) { return VS_HEADER_SIZE + sizeof(VehicleModel); }

/* header layout: magic[8] | uint32 format | uint32 reserved (0) | uint64 total size |
 * uint64 token hash | uint64 payload checksum; host byte order */
int vs_serialize(const VehicleModel *m, unsigned char *bytes, size_t size, char *msg, size_t len) {
    if (size < vs_size()) {
        snprintf(msg, len, "serialize FMU state: buffer of %zu bytes, the state needs %zu", size, vs_size());
        return 1;
    }
    const uint32_t format = VS_FORMAT, reserved = 0;
    const uint64_t total = vs_size(), token = vs_fnv1a(VEHICLE_INSTANTIATION_TOKEN, strlen(VEHICLE_INSTANTIATION_TOKEN));
    const uint64_t checksum = vs_fnv1a(m, sizeof(*m));
    memcpy(bytes, VS_MAGIC, 8);
    memcpy(bytes + 8, &format, 4);
    memcpy(bytes + 12, &reserved, 4);
    memcpy(bytes + 16, &total, 8);
    memcpy(bytes + 24, &token, 8);
    memcpy(bytes + 32, &checksum, 8);
    memcpy(bytes + VS_HEADER_SIZE, m, sizeof(*m));
    return 0;
}

int vs_deserialize(const unsigned char *bytes, size_t size, VehicleModel *m, char *msg, size_t len) {
    uint32_t format;
    uint64_t total, token, checksum;
    if (!bytes || size < VS_HEADER_SIZE || memcmp(bytes, VS_MAGIC, 8) != 0) {
        snprintf(msg, len, "deserialize FMU state: %zu bytes that do not start with the magic \"%s\" of a "
                 "TirefilterVehicle state", size, VS_MAGIC);
        return 1;
    }
    memcpy(&format, bytes + 8, 4);
    memcpy(&total, bytes + 16, 8);
    memcpy(&token, bytes + 24, 8);
    memcpy(&checksum, bytes + 32, 8);
    if (format != VS_FORMAT) {
        snprintf(msg, len, "deserialize FMU state: format version %u, this FMU reads version %u", (unsigned)format,
                 VS_FORMAT);
        return 1;
    }
    if (total != size || size != vs_size()) {
        snprintf(msg, len, "deserialize FMU state: %zu bytes given, the header says %llu, this FMU's state has %zu",
                 size, (unsigned long long)total, vs_size());
        return 1;
    }
    if (token != vs_fnv1a(VEHICLE_INSTANTIATION_TOKEN, strlen(VEHICLE_INSTANTIATION_TOKEN))) {
        snprintf(msg, len, "deserialize FMU state: written by a TirefilterVehicle FMU with another variable table "
                 "(instantiation token %s expected)", VEHICLE_INSTANTIATION_TOKEN);
        return 1;
    }
    if (checksum != vs_fnv1a(bytes + VS_HEADER_SIZE, sizeof(VehicleModel))) {
        snprintf(msg, len, "deserialize FMU state: checksum mismatch, the state is corrupt");
        return 1;
    }
    memcpy(m, bytes + VS_HEADER_SIZE, sizeof(*m));
    return 0;
}
