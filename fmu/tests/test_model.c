/* Unit test of the vehicle equations, without any FMI code.
 *
 * Build (tests/test_fmu_c.py does this with the generated header in a temporary folder):
 *   cc -std=c99 -O2 -Wall -Wextra -Werror -Isrc/tirefilter/vehicle_fmu/c -I<gen> \
 *      fmu/tests/test_model.c src/tirefilter/vehicle_fmu/c/vehicle_model.c \
 *      src/tirefilter/vehicle_fmu/c/var_access.c -lm
 *
 * Prints one line per check ("PASS ..." or "FAIL ...") and exits nonzero if any failed.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "vehicle_model.h"

#define STEP 0.01 /* s, communication step used throughout */

static int n_failed = 0;

/* Record and print the result of one check. */
static void check(int ok, const char *name, const char *detail) {
    printf("%s %s%s%s\n", ok ? "PASS" : "FAIL", name, detail[0] ? ": " : "", detail);
    if (!ok) n_failed++;
}

/* |a - b| <= tol |b|, with exact equality accepted (covers b == 0). */
static int rel_close(double a, double b, double tol) { return a == b || fabs(a - b) <= tol * fabs(b); }

/* Defaults with every random quantity switched off: deviations, sensor noise, bias. */
static void set_noise_free(VehicleModel *m) {
    vm_set_defaults(m);
    m->v.stiffness_dev_std = 0.0;
    m->v.sigma_ax = m->v.sigma_ay = m->v.sigma_yaw_rate = 0.0;
    m->v.sigma_omega = m->v.sigma_delta = 0.0;
}

/* Initialize and fail loudly: a model that cannot start makes the check meaningless. */
static int init_model(VehicleModel *m, const char *name) {
    char msg[512];
    if (vm_initialize(m, 0.0, msg, sizeof(msg))) {
        char detail[600];
        snprintf(detail, sizeof(detail), "vm_initialize failed: %s", msg);
        check(0, name, detail);
        return 1;
    }
    return 0;
}

/* Advance n communication steps of STEP from the model's current time. The end time is
 * computed as (k + 1) * STEP from the sample count, as a co-simulation master does. */
static int run_steps(VehicleModel *m, int n, char *msg, size_t len) {
    const long k0 = lround(m->time / STEP);
    for (long k = k0; k < k0 + n; k++)
        if (vm_do_step(m, (double)(k + 1) * STEP, msg, len)) return 1;
    return 0;
}

/* Bitwise comparison of every output variable (only outputs: the struct may hold
 * padding between the Integer and Real fields, which is not part of the result). */
static int outputs_identical(const VehicleModel *a, const VehicleModel *b) {
    for (int i = 0; i < VEHICLE_NVARS; i++) {
        const VehicleVarInfo *info = &VEHICLE_VAR_INFO[i];
        if (info->causality != 'o') continue;
        const size_t size = info->type == 'I' ? sizeof(int) : sizeof(double);
        if (memcmp((const char *)&a->v + info->offset, (const char *)&b->v + info->offset, size) != 0)
            return 0;
    }
    return 1;
}

/* (a) Random numbers: moments of the normals, range of the uniforms. */
static void test_rng(void) {
    VmRng rng;
    char detail[256];
    const int n = 200000;
    double sum = 0.0, sum_sq = 0.0;
    vm_rng_seed(&rng, 12345);
    for (int i = 0; i < n; i++) {
        const double z = vm_rng_normal(&rng);
        sum += z;
        sum_sq += z * z;
    }
    const double mean = sum / n, var = sum_sq / n - mean * mean;
    snprintf(detail, sizeof(detail), "mean %.5f (|.| < 0.01)", mean);
    check(fabs(mean) < 0.01, "rng normal mean", detail);
    snprintf(detail, sizeof(detail), "variance %.5f (|. - 1| < 0.01)", var);
    check(fabs(var - 1.0) < 0.01, "rng normal variance", detail);

    double lo = 2.0, hi = -1.0;
    for (int i = 0; i < n; i++) {
        const double u = vm_rng_uniform(&rng);
        lo = fmin(lo, u);
        hi = fmax(hi, u);
    }
    snprintf(detail, sizeof(detail), "min %.3g, max %.17g", lo, hi);
    check(lo > 0.0 && hi <= 1.0, "rng uniform in (0, 1]", detail);
}

/* (b) Straight driving without noise: no lateral motion may appear, not even roundoff. */
static void test_straight(void) {
    const char *name = "straight driving keeps vy = r = 0 for 5 s";
    VehicleModel m;
    char msg[512], detail[600];
    set_noise_free(&m);
    m.v.vx0 = 22.0;
    m.v.delta = 0.0;
    m.v.drive_torque = 0.0;
    m.v.brake_torque = 0.0;
    if (init_model(&m, name)) return;
    int ok = m.v.vy == 0.0 && m.v.yaw_rate == 0.0;
    for (int k = 0; ok && k < 500; k++) {
        if (vm_do_step(&m, (k + 1) * STEP, msg, sizeof(msg))) {
            snprintf(detail, sizeof(detail), "vm_do_step failed: %s", msg);
            check(0, name, detail);
            return;
        }
        ok = m.v.vy == 0.0 && m.v.yaw_rate == 0.0;
    }
    snprintf(detail, sizeof(detail), "t = %.2f s, vx = %.6f, vy = %g, r = %g", m.time, m.v.vx, m.v.vy,
             m.v.yaw_rate);
    check(ok && fabs(m.time - 5.0) < 1e-12, name, detail);
}

/* A hand-picked state away from equilibrium: cornering, with some wheel slip. */
static void hand_picked_state(const VehicleModel *m, double x[VM_NX]) {
    memset(x, 0, VM_NX * sizeof(double));
    x[X_VX] = 18.5;
    x[X_VY] = 0.37;
    x[X_R] = 0.21;
    x[X_WF] = 1.01 * x[X_VX] / m->v.wheel_radius;
    x[X_WR] = 0.99 * x[X_VX] / m->v.wheel_radius;
    x[X_PSI] = 0.3;
    x[X_ALT] = 0.4;
}

/* (c) Linear tires: slip angles and lateral forces from the derivative function. */
static void test_linear_tires(void) {
    const char *name = "linear tires: slip angles and lateral forces";
    VehicleModel m;
    double x[VM_NX], dx[VM_NX];
    VmAux a;
    char detail[512];
    set_noise_free(&m);
    m.v.tire_model = 0;
    if (init_model(&m, name)) return;
    m.v.delta = 0.043;
    hand_picked_state(&m, x);
    vm_derivatives(&m, x, dx, &a);

    const double vx = x[X_VX], vy = x[X_VY], r = x[X_R], d = m.v.delta;
    const double alpha_f = d - atan((vy + m.v.lf * r) / vx);
    const double alpha_r = -atan((vy - m.v.lr * r) / vx);
    const double Fy_f = m.v.Cf_y * alpha_f, Fy_r = m.v.Cr_y * alpha_r;
    const double tol = 1e-12;

    snprintf(detail, sizeof(detail), "alpha_f %.17g vs %.17g, alpha_r %.17g vs %.17g", a.alpha_f, alpha_f,
             a.alpha_r, alpha_r);
    check(rel_close(a.alpha_f, alpha_f, tol) && rel_close(a.alpha_r, alpha_r, tol), "linear tires: slip angles",
          detail);
    snprintf(detail, sizeof(detail), "Fy_f %.17g vs %.17g, Fy_r %.17g vs %.17g", a.Fy_f, Fy_f, a.Fy_r, Fy_r);
    check(rel_close(a.Fy_f, Fy_f, tol) && rel_close(a.Fy_r, Fy_r, tol), "linear tires: Fy = C alpha", detail);

    /* The yaw equation (1c) with these forces, as a consistency check of the wiring. */
    const double r_dot = (m.v.lf * (a.Fy_f * cos(d) + a.Fx_f * sin(d)) - m.v.lr * a.Fy_r) / m.v.yaw_inertia;
    snprintf(detail, sizeof(detail), "r' %.17g vs %.17g", dx[X_R], r_dot);
    check(rel_close(dx[X_R], r_dot, tol), "linear tires: yaw equation (1c)", detail);
}

/* (d) Traction positive: a front wheel turning faster than the car pushes it forward. */
static void test_slip_sign(void) {
    const char *name = "wheel slip sign: Rw omega_f > vx gives Fx_f > 0";
    VehicleModel m;
    double x[VM_NX], dx[VM_NX];
    VmAux a;
    char detail[256];
    set_noise_free(&m);
    if (init_model(&m, name)) return;
    hand_picked_state(&m, x);
    x[X_WF] = 1.05 * x[X_VX] / m.v.wheel_radius;
    vm_derivatives(&m, x, dx, &a);
    snprintf(detail, sizeof(detail), "lambda_f = %.4g, Fx_f = %.6g N", a.lambda_f, a.Fx_f);
    check(a.lambda_f > 0.0 && a.Fx_f > 0.0, name, detail);
}

/* (e) Same seed, same noise: bit-identical outputs; another seed: different outputs. */
static void test_determinism(void) {
    const char *name = "determinism";
    VehicleModel a, b, c;
    char msg[512], detail[600];
    vm_set_defaults(&a); /* default noise is on: stiffness deviations and IMU noise */
    a.v.seed = 42;
    a.v.sigma_omega = 0.01;
    a.v.bias_q_yaw_rate = 1e-8;
    a.v.delta = 0.02;
    b = a;
    c = a;
    c.v.seed = 43;
    if (init_model(&a, name) || init_model(&b, name) || init_model(&c, name)) return;
    if (run_steps(&a, 1000, msg, sizeof(msg)) || run_steps(&b, 1000, msg, sizeof(msg)) ||
        run_steps(&c, 1000, msg, sizeof(msg))) {
        snprintf(detail, sizeof(detail), "vm_do_step failed: %s", msg);
        check(0, name, detail);
        return;
    }
    snprintf(detail, sizeof(detail), "t = %.2f s, yaw_rate_meas %.17g vs %.17g", a.time, a.v.yaw_rate_meas,
             b.v.yaw_rate_meas);
    check(outputs_identical(&a, &b), "determinism: same seed, bit-identical outputs after 1000 steps", detail);
    snprintf(detail, sizeof(detail), "yaw_rate_meas %.17g (seed 42) vs %.17g (seed 43)", a.v.yaw_rate_meas,
             c.v.yaw_rate_meas);
    check(!outputs_identical(&a, &c) && a.v.yaw_rate_meas != c.v.yaw_rate_meas,
          "determinism: a different seed gives different outputs", detail);
}

/* (f) The model is plain data: a struct copy is a complete snapshot (what fmi2GetFMUstate
 * relies on). */
static void test_state_copy(void) {
    const char *name = "state copy: copy after 100 steps, both identical after 100 more";
    VehicleModel m;
    char msg[512], detail[600];
    vm_set_defaults(&m);
    m.v.delta = 0.03;
    if (init_model(&m, name)) return;
    if (run_steps(&m, 100, msg, sizeof(msg))) {
        snprintf(detail, sizeof(detail), "vm_do_step failed: %s", msg);
        check(0, name, detail);
        return;
    }
    VehicleModel copy = m;
    if (run_steps(&m, 100, msg, sizeof(msg)) || run_steps(&copy, 100, msg, sizeof(msg))) {
        snprintf(detail, sizeof(detail), "vm_do_step failed: %s", msg);
        check(0, name, detail);
        return;
    }
    snprintf(detail, sizeof(detail), "t = %.2f / %.2f s, sample %lld / %lld", m.time, copy.time,
             (long long)m.sample_index, (long long)copy.sample_index);
    check(outputs_identical(&m, &copy) && m.time == copy.time, name, detail);
}

/* (g) Range checks name the offending variable. */
static void test_check(void) {
    VehicleModel m;
    char msg[512] = "", detail[600];

    vm_set_defaults(&m);
    m.v.mass = -1.0;
    int rc = vm_check(&m, 0, msg, sizeof(msg));
    snprintf(detail, sizeof(detail), "rc %d, \"%s\"", rc, msg);
    check(rc != 0 && strstr(msg, "mass") != NULL, "vm_check rejects mass = -1", detail);

    vm_set_defaults(&m);
    m.v.delta = 2.0;
    msg[0] = '\0';
    rc = vm_check(&m, 1, msg, sizeof(msg));
    snprintf(detail, sizeof(detail), "rc %d, \"%s\"", rc, msg);
    check(rc != 0 && strstr(msg, "delta") != NULL, "vm_check rejects delta = 2.0 rad", detail);

    vm_set_defaults(&m);
    rc = vm_check(&m, 0, msg, sizeof(msg));
    check(rc == 0, "vm_check accepts the defaults", rc ? msg : "");
}

/* (h) Braking to a stop leaves the model's range of validity: vm_do_step must fail and
 * say so instead of integrating through standstill. */
static void test_stop(void) {
    const char *name = "braking to a stop fails with a v_min message";
    VehicleModel m;
    char msg[512] = "", detail[700];
    set_noise_free(&m);
    m.v.brake_torque = 20000.0;
    if (init_model(&m, name)) return;
    int rc = 0, k;
    for (k = 0; k < 6000 && rc == 0; k++) rc = vm_do_step(&m, (k + 1) * STEP, msg, sizeof(msg));
    snprintf(detail, sizeof(detail), "rc %d after %d steps, vx = %.4g: \"%s\"", rc, k, m.x[X_VX], msg);
    check(rc != 0 && strstr(msg, "v_min") != NULL, name, detail);
}

int main(void) {
    test_rng();
    test_straight();
    test_linear_tires();
    test_slip_sign();
    test_determinism();
    test_state_copy();
    test_check();
    test_stop();
    if (n_failed) {
        printf("%d check(s) FAILED\n", n_failed);
        return 1;
    }
    printf("all checks passed\n");
    return 0;
}
