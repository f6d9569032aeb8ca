/* Vehicle equations: single-track chassis, wheel spin, tires, sensors.
 *
 * No FMI code here: this file and vehicle_model.c are unit-tested on their own
 * (fmu/tests/test_model.c). The FMI 2.0 and 3.0 glue only moves values in and out of
 * VehicleModel and calls vm_initialize / vm_do_step.
 *
 * Equations (docs/vehicle_model.md):
 *   m (vx' - vy r) = Fxf cos d - Fyf sin d + Fxr - F_roll - F_drag          (stiffness paper, eq. 1a)
 *   m (vy' + vx r) = Fyf cos d + Fxf sin d + Fyr - m g sin(bank)            (eq. 1b + bank)
 *   I r'           = lf (Fyf cos d + Fxf sin d) - lr Fyr                    (eq. 1c)
 *   Iw_i w_i'      = T_drive,i - T_brake,i tanh(w_i / w_eps) - Rw Fx_i        (wheel spin)
 *   a_lt'          = (a^X - a_lt) / tau                                      (load-transfer lag)
 * slip angles alpha_f = d - atan((vy + lf r)/vx), alpha_r = -atan((vy - lr r)/vx),
 * wheel slip lambda = (Rw w - vx) / max(vx, Rw w) (paper eq. 3, traction positive).
 */
#ifndef TIREFILTER_VEHICLE_MODEL_H
#define TIREFILTER_VEHICLE_MODEL_H

#include <stddef.h>
#include <stdint.h>

#include "vehicle_vars.h" /* generated from variables.py (vehicle_fmu/) */

#define VM_GRAVITY 9.80665

/* continuous states */
enum { X_VX, X_VY, X_R, X_WF, X_WR, X_PX, X_PY, X_PSI, X_ALT, VM_NX };

/* per-sample random draws */
enum { DEV_FY, DEV_RY, DEV_FX, DEV_RX, VM_NDEV };
enum { NOISE_AX, NOISE_AY, NOISE_R, NOISE_WF, NOISE_WR, NOISE_DELTA, VM_NNOISE };

typedef struct {
    uint64_t s[4]; /* xoshiro256** state */
} VmRng;

/* The whole model state: plain data, so FMU state get/set is a struct copy. */
typedef struct {
    VehicleVars v;          /* parameters, inputs, outputs (generated struct) */
    double x[VM_NX];        /* continuous state */
    double time;            /* s */
    double start_time;      /* s, time of sample 0 */
    int64_t sample_index;   /* index k of the sample that holds at `time` */
    double dev[VM_NDEV];    /* relative stiffness deviations of sample k */
    double noise[VM_NNOISE];/* standard-normal sensor noise of sample k */
    double bias[3];         /* ax, ay, yaw-rate bias of sample k */
    VmRng rng;
    int initialized;
    int below_v_min;        /* the last vm_do_step stopped because vx fell below v_min */
} VehicleModel;

/* Algebraic quantities at one instant (forces, slips, stiffness). */
typedef struct {
    double alpha_f, alpha_r, lambda_f, lambda_r;
    double Fz_f, Fz_r, Fx_f, Fx_r, Fy_f, Fy_r;
    double ax, ay;           /* specific force at the CG */
    double Cf_y, Cr_y, Cf_x, Cr_x;             /* effective stiffness */
    double Cf_y_mean, Cr_y_mean, Cf_x_mean, Cr_x_mean;
} VmAux;

/* Random numbers (exposed for tests). */
void vm_rng_seed(VmRng *rng, uint64_t seed);
double vm_rng_uniform(VmRng *rng);  /* in (0, 1] */
double vm_rng_normal(VmRng *rng);

/* Start values of every parameter and input, from the variable table. */
void vm_set_defaults(VehicleModel *m);

/* Check parameters and inputs; on failure write a message naming the variable and
 * return nonzero. */
int vm_check(const VehicleModel *m, int inputs_only, char *msg, size_t len);

/* Right-hand side f(x) at the current inputs and sample, and the algebraic quantities. */
void vm_derivatives(const VehicleModel *m, const double x[VM_NX], double dx[VM_NX], VmAux *aux);

/* Set up the state from the parameters: seed, initial state and bias draws, sample 0,
 * outputs. Returns nonzero (with a message) on bad parameters. */
int vm_initialize(VehicleModel *m, double start_time, char *msg, size_t len);

/* Integrate from m->time to t_end with RK4 steps of at most max_step, breaking at sample
 * boundaries, where new deviations, noise and bias increments are drawn. Returns nonzero
 * with a message on failure (state left at the last good step; below_v_min set when the
 * speed fell below v_min). A non-finite t_end or one before m->time is refused. */
int vm_do_step(VehicleModel *m, double t_end, char *msg, size_t len);

/* Recompute every output from the state (after inputs changed, for example); the
 * sensor outputs only at a sample instant (they are held in between). */
void vm_update_outputs(VehicleModel *m);

/* Whether m->time is the sample instant of m->sample_index. */
int vm_at_sample(const VehicleModel *m);

#endif
