/* Table-driven access to the model's variables by value reference, shared by the FMI 2.0
 * and FMI 3.0 glue. */
#ifndef TIREFILTER_VAR_ACCESS_H
#define TIREFILTER_VAR_ACCESS_H

#include "vehicle_model.h"

/* Return codes: 0 ok, 1 no such variable of that type, 2 not settable now. */
int va_get_real(const VehicleModel *m, unsigned vr, double *value);
int va_get_int(const VehicleModel *m, unsigned vr, int *value);
int va_set_real(VehicleModel *m, unsigned vr, double value);
int va_set_int(VehicleModel *m, unsigned vr, int value);
/* Whether any of the value references is an output. */
int va_any_output(const unsigned *vr, size_t n);
/* A message for a failed access, naming the variable. */
void va_error(const char *function, unsigned vr, int code, char *msg, size_t len);

/* Serialized FMU state: a header (magic "TFVSTATE", format version, total size, a hash of
 * the instantiation token, an FNV-1a 64 checksum of the payload) and the VehicleModel.
 * vs_deserialize refuses, with a message, bytes whose header or checksum do not match. */
#define VS_MAGIC "TFVSTATE"
#define VS_FORMAT 1u
#define VS_HEADER_SIZE 40u
size_t vs_size(void);
int vs_serialize(const VehicleModel *m, unsigned char *bytes, size_t size, char *msg, size_t len);
int vs_deserialize(const unsigned char *bytes, size_t size, VehicleModel *m, char *msg, size_t len);
uint64_t vs_fnv1a(const void *data, size_t n);

#endif
