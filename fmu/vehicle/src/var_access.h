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
/* A message for a failed access, naming the variable. */
void va_error(const char *function, unsigned vr, int code, char *msg, size_t len);

#endif
