/* Vehicle equations. See vehicle_model.h and docs/vehicle_model.md. No FMI code. */
#include "vehicle_model.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#define WHEEL_OMEGA_EPS 0.5 /* rad/s, smoothing of the brake torque sign */

/* ---- random numbers: splitmix64 seeding, xoshiro256** (Blackman & Vigna 2018) ---------- */

static uint64_t splitmix64(uint64_t *x) {
    uint64_t z = (*x += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

static uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

void vm_rng_seed(VmRng *rng, uint64_t seed) {
    uint64_t x = seed;
    for (int i = 0; i < 4; i++) rng->s[i] = splitmix64(&x);
}

static uint64_t rng_next(VmRng *rng) {
    uint64_t *s = rng->s;
    const uint64_t result = rotl(s[1] * 5, 7) * 9;
    const uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

double vm_rng_uniform(VmRng *rng) { return ((rng_next(rng) >> 11) + 1) * 0x1.0p-53; }

double vm_rng_normal(VmRng *rng) {
    /* Box-Muller, one normal per pair of uniforms: a fixed number of draws per call keeps
     * the stream aligned whatever the parameters are. */
    const double u1 = vm_rng_uniform(rng), u2 = vm_rng_uniform(rng);
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

/* ---- parameters ---------------------------------------------------------------------- */

static double var_value(const VehicleModel *m, const VehicleVarInfo *info) {
    const char *base = (const char *)&m->v;
    if (info->type == 'I') return (double)*(const int *)(base + info->offset);
    return *(const double *)(base + info->offset);
}

void vm_set_defaults(VehicleModel *m) {
    memset(m, 0, sizeof(*m));
    char *base = (char *)&m->v;
    for (int i = 0; i < VEHICLE_NVARS; i++) {
        const VehicleVarInfo *info = &VEHICLE_VAR_INFO[i];
        if (info->causality == 'o') continue;
        if (info->type == 'I')
            *(int *)(base + info->offset) = (int)info->start;
        else
            *(double *)(base + info->offset) = info->start;
    }
}

int vm_check(const VehicleModel *m, int inputs_only, char *msg, size_t len) {
    for (int i = 0; i < VEHICLE_NVARS; i++) {
        const VehicleVarInfo *info = &VEHICLE_VAR_INFO[i];
        if (info->causality == 'o' || (inputs_only && info->causality != 'i')) continue;
        const double value = var_value(m, info);
        if (!isfinite(value)) {
            snprintf(msg, len, "%s %s = %g is not finite", info->causality == 'i' ? "input" : "parameter",
                     info->name, value);
            return 1;
        }
        if ((info->has_min && value < info->min) || (info->has_max && value > info->max)) {
            snprintf(msg, len, "%s %s = %g is outside [%g, %g] %s",
                     info->causality == 'i' ? "input" : "parameter", info->name, value,
                     info->has_min ? info->min : -INFINITY, info->has_max ? info->max : INFINITY,
                     info->unit);
            return 1;
        }
    }
    return 0;
}

/* ---- tires --------------------------------------------------------------------------- */

static double magic_formula(double B, double C, double D, double E, double s) {
    const double Bs = B * s;
    return D * sin(C * atan(Bs - E * (Bs - atan(Bs))));
}

/* Axle forces from slip angle and wheel slip. dev_y, dev_x are relative stiffness
 * deviations, mu_scale the surface scale. Linear: F = s (1 + dev) C slip. Pacejka: the
 * stiffness factor B carries the deviation (initial slope scales, peak does not), the
 * whole force is scaled by the surface; combined slip by the weighting functions
 * G_x,alpha and G_y,kappa of Pacejka (2006), Sec. 4.3.2. */
static void axle_forces(const VehicleVars *v, double Cy, double Cx, double Fz, double alpha,
                        double lambda, double dev_y, double dev_x, double surface, double *Fy,
                        double *Fx, double *Cy_eff, double *Cx_eff, double *Cy_mean,
                        double *Cx_mean) {
    if (v->tire_model == 0) {
        *Cy_mean = surface * Cy;
        *Cx_mean = surface * Cx;
        *Cy_eff = *Cy_mean * (1.0 + dev_y);
        *Cx_eff = *Cx_mean * (1.0 + dev_x);
        *Fy = *Cy_eff * alpha;
        *Fx = *Cx_eff * lambda;
        return;
    }
    const double By = v->pac_B_y * (1.0 + dev_y), Bx = v->pac_B_x * (1.0 + dev_x);
    const double Dy = v->pac_mu_y * Fz, Dx = v->pac_mu_x * Fz;
    const double Fy0 = magic_formula(By, v->pac_C_y, Dy, v->pac_E_y, alpha);
    const double Fx0 = magic_formula(Bx, v->pac_C_x, Dx, v->pac_E_x, lambda);
    const double Byk = v->pac_rBy1 * cos(atan(v->pac_rBy2 * alpha));
    const double Bxa = v->pac_rBx1 * cos(atan(v->pac_rBx2 * lambda));
    const double Gyk = cos(v->pac_Cyk * atan(Byk * lambda));
    const double Gxa = cos(v->pac_Cxa * atan(Bxa * alpha));
    *Fy = surface * Fy0 * Gyk;
    *Fx = surface * Fx0 * Gxa;
    *Cy_mean = surface * v->pac_B_y * v->pac_C_y * Dy;
    *Cx_mean = surface * v->pac_B_x * v->pac_C_x * Dx;
    *Cy_eff = *Cy_mean * (1.0 + dev_y);
    *Cx_eff = *Cx_mean * (1.0 + dev_x);
}

static double wheel_slip(double vx, double Rw_omega) {
    /* the stiffness paper's eq. (3) with traction positive (docs/design.md sign conventions) */
    const double den = fmax(fabs(vx), fabs(Rw_omega));
    return den > 0.0 ? (Rw_omega - vx) / den : 0.0;
}

/* ---- dynamics ------------------------------------------------------------------------ */

void vm_derivatives(const VehicleModel *m, const double x[VM_NX], double dx[VM_NX], VmAux *a) {
    const VehicleVars *v = &m->v;
    const double vx = x[X_VX], vy = x[X_VY], r = x[X_R];
    const double d = v->delta, cd = cos(d), sd = sin(d);
    const double L = v->lf + v->lr, Rw = v->wheel_radius, g = VM_GRAVITY;

    a->alpha_f = d - atan((vy + v->lf * r) / vx);
    a->alpha_r = -atan((vy - v->lr * r) / vx);
    a->lambda_f = wheel_slip(vx, Rw * x[X_WF]);
    a->lambda_r = wheel_slip(vx, Rw * x[X_WR]);

    /* static loads plus lagged longitudinal load transfer */
    a->Fz_f = fmax(0.0, v->mass * (g * v->lr - v->cg_height * x[X_ALT]) / L);
    a->Fz_r = fmax(0.0, v->mass * (g * v->lf + v->cg_height * x[X_ALT]) / L);

    axle_forces(v, v->Cf_y, v->Cf_x, a->Fz_f, a->alpha_f, a->lambda_f, m->dev[DEV_FY],
                m->dev[DEV_FX], v->surface, &a->Fy_f, &a->Fx_f, &a->Cf_y, &a->Cf_x,
                &a->Cf_y_mean, &a->Cf_x_mean);
    axle_forces(v, v->Cr_y, v->Cr_x, a->Fz_r, a->alpha_r, a->lambda_r, m->dev[DEV_RY],
                m->dev[DEV_RX], v->surface, &a->Fy_r, &a->Fx_r, &a->Cr_y, &a->Cr_x,
                &a->Cr_y_mean, &a->Cr_x_mean);

    const double F_resist = v->rolling_resistance * v->mass * g * tanh(vx) + v->drag_coefficient * vx * fabs(vx);
    const double FX = a->Fx_f * cd - a->Fy_f * sd + a->Fx_r - F_resist;
    const double FY = a->Fy_f * cd + a->Fx_f * sd + a->Fy_r;
    a->ax = FX / v->mass;
    a->ay = FY / v->mass;

    const double front_share = v->drive == 0 ? 1.0 : (v->drive == 1 ? 0.0 : v->awd_front_share);
    const double Tdf = front_share * v->drive_torque, Tdr = (1.0 - front_share) * v->drive_torque;
    const double Tbf = v->brake_front_share * v->brake_torque;
    const double Tbr = (1.0 - v->brake_front_share) * v->brake_torque;

    dx[X_VX] = vy * r + a->ax;                                            /* (1a) */
    dx[X_VY] = -vx * r + a->ay - g * sin(v->bank);                         /* (1b) */
    dx[X_R] = (v->lf * (a->Fy_f * cd + a->Fx_f * sd) - v->lr * a->Fy_r) / v->yaw_inertia; /* (1c) */
    dx[X_WF] = (Tdf - Tbf * tanh(x[X_WF] / WHEEL_OMEGA_EPS) - Rw * a->Fx_f) / v->wheel_inertia_f;
    dx[X_WR] = (Tdr - Tbr * tanh(x[X_WR] / WHEEL_OMEGA_EPS) - Rw * a->Fx_r) / v->wheel_inertia_r;
    dx[X_PX] = vx * cos(x[X_PSI]) - vy * sin(x[X_PSI]);
    dx[X_PY] = vx * sin(x[X_PSI]) + vy * cos(x[X_PSI]);
    dx[X_PSI] = r;
    dx[X_ALT] = (a->ax - x[X_ALT]) / v->load_transfer_time_constant;
}

static void rk4_step(const VehicleModel *m, double x[VM_NX], double h) {
    double k1[VM_NX], k2[VM_NX], k3[VM_NX], k4[VM_NX], xt[VM_NX];
    VmAux aux;
    vm_derivatives(m, x, k1, &aux);
    for (int i = 0; i < VM_NX; i++) xt[i] = x[i] + 0.5 * h * k1[i];
    vm_derivatives(m, xt, k2, &aux);
    for (int i = 0; i < VM_NX; i++) xt[i] = x[i] + 0.5 * h * k2[i];
    vm_derivatives(m, xt, k3, &aux);
    for (int i = 0; i < VM_NX; i++) xt[i] = x[i] + h * k3[i];
    vm_derivatives(m, xt, k4, &aux);
    for (int i = 0; i < VM_NX; i++) x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
}

/* ---- sampling ------------------------------------------------------------------------ */

/* Draw the random quantities of a new sample: bias increment (k >= 1), stiffness
 * deviations, sensor noise; always the same number of normals. */
static void draw_sample(VehicleModel *m, int first) {
    const VehicleVars *v = &m->v;
    if (!first) {
        /* random walk of intensity q (variance per second): increment std sqrt(q Ts) */
        const double Ts = v->sample_period;
        m->bias[0] += sqrt(v->bias_q_ax * Ts) * vm_rng_normal(&m->rng);
        m->bias[1] += sqrt(v->bias_q_ay * Ts) * vm_rng_normal(&m->rng);
        m->bias[2] += sqrt(v->bias_q_yaw_rate * Ts) * vm_rng_normal(&m->rng);
    }
    for (int i = 0; i < VM_NDEV; i++) m->dev[i] = v->stiffness_dev_std * vm_rng_normal(&m->rng);
    for (int i = 0; i < VM_NNOISE; i++) m->noise[i] = vm_rng_normal(&m->rng);
}

int vm_at_sample(const VehicleModel *m) {
    const double Ts = m->v.sample_period;
    return fabs(m->time - (m->start_time + (double)m->sample_index * Ts)) <= 1e-9 * Ts;
}

void vm_update_outputs(VehicleModel *m) {
    VehicleVars *v = &m->v;
    double dx[VM_NX];
    VmAux a;
    vm_derivatives(m, m->x, dx, &a);
    const double r = m->x[X_R], racc = dx[X_R];

    v->vx = m->x[X_VX];
    v->vy = m->x[X_VY];
    v->yaw_rate = r;
    v->beta = atan2(v->vy, v->vx);
    v->alpha_f = a.alpha_f;
    v->alpha_r = a.alpha_r;
    v->lambda_f = a.lambda_f;
    v->lambda_r = a.lambda_r;
    v->omega_f = m->x[X_WF];
    v->omega_r = m->x[X_WR];
    v->ax = a.ax;
    v->ay = a.ay;
    v->yaw_acc = racc;
    v->x = m->x[X_PX];
    v->y = m->x[X_PY];
    v->psi = m->x[X_PSI];
    v->Fz_f = a.Fz_f;
    v->Fz_r = a.Fz_r;
    v->Fx_f = a.Fx_f;
    v->Fx_r = a.Fx_r;
    v->Fy_f = a.Fy_f;
    v->Fy_r = a.Fy_r;
    v->true_Cf_y = a.Cf_y;
    v->true_Cr_y = a.Cr_y;
    v->true_Cf_x = a.Cf_x;
    v->true_Cr_x = a.Cr_x;
    v->true_Cx = v->drive == 1 ? a.Cr_x : a.Cf_x;
    v->true_Cf_y_mean = a.Cf_y_mean;
    v->true_Cr_y_mean = a.Cr_y_mean;
    v->true_Cx_mean = v->drive == 1 ? a.Cr_x_mean : a.Cf_x_mean;
    v->true_b_ax = m->bias[0];
    v->true_b_ay = m->bias[1];
    v->true_b_yaw_rate = m->bias[2];

    /* The sensors are sampled at the sample instants t_k = start + k Ts and held between
     * them (variability "discrete"); at t_k they see the inputs set at t_k. */
    if (!vm_at_sample(m)) return;
    /* IMU at (imu_x, imu_y) from the CG: a_p = a_cg + r' x p + r x (r x p) */
    const double ax_imu = a.ax - racc * v->imu_y - r * r * v->imu_x;
    const double ay_imu = a.ay + racc * v->imu_x - r * r * v->imu_y;
    /* body roll phi = k a^Y; the lateral axis picks up gravity: a_m ~ (1 + k g) a^Y */
    v->roll = v->roll_gradient * a.ay;
    v->ax_meas = ax_imu + m->bias[0] + v->sigma_ax * m->noise[NOISE_AX];
    v->ay_meas = ay_imu * cos(v->roll) + VM_GRAVITY * cos(v->bank) * sin(v->roll) + m->bias[1] +
                 v->sigma_ay * m->noise[NOISE_AY];
    v->yaw_rate_meas = r + m->bias[2] + v->sigma_yaw_rate * m->noise[NOISE_R];
    v->omega_f_meas = m->x[X_WF] + v->sigma_omega * m->noise[NOISE_WF];
    v->omega_r_meas = m->x[X_WR] + v->sigma_omega * m->noise[NOISE_WR];
    v->delta_meas = v->delta + v->sigma_delta * m->noise[NOISE_DELTA];
}

int vm_initialize(VehicleModel *m, double start_time, char *msg, size_t len) {
    if (vm_check(m, 0, msg, len)) return 1;
    const VehicleVars *v = &m->v;
    vm_rng_seed(&m->rng, (uint64_t)(uint32_t)v->seed);
    m->time = start_time;
    m->start_time = start_time;
    m->sample_index = 0;
    m->below_v_min = 0;
    memset(m->x, 0, sizeof(m->x));
    m->x[X_VX] = v->vx0 + v->vx0_std * vm_rng_normal(&m->rng);
    m->x[X_VY] = v->vy0 + v->vy0_std * vm_rng_normal(&m->rng);
    m->x[X_R] = v->yaw_rate0 + v->yaw_rate0_std * vm_rng_normal(&m->rng);
    m->x[X_WF] = m->x[X_VX] / v->wheel_radius; /* free rolling */
    m->x[X_WR] = m->x[X_VX] / v->wheel_radius;
    m->bias[0] = v->bias0_ax + v->bias0_std_ax * vm_rng_normal(&m->rng);
    m->bias[1] = v->bias0_ay + v->bias0_std_ay * vm_rng_normal(&m->rng);
    m->bias[2] = v->bias0_yaw_rate + v->bias0_std_yaw_rate * vm_rng_normal(&m->rng);
    draw_sample(m, 1);
    if (m->x[X_VX] < v->v_min) {
        snprintf(msg, len, "initial speed vx = %g m/s is below v_min = %g m/s", m->x[X_VX], v->v_min);
        return 1;
    }
    m->initialized = 1;
    vm_update_outputs(m);
    return 0;
}

int vm_do_step(VehicleModel *m, double t_end, char *msg, size_t len) {
    const VehicleVars *v = &m->v;
    const double Ts = v->sample_period, tol = 1e-9 * Ts;
    if (!isfinite(t_end) || t_end < m->time - tol) {
        snprintf(msg, len, "cannot step from t = %.9g s to t = %.9g s: the end time must be finite and not "
                 "before the current time", m->time, t_end);
        return 1;
    }
    m->below_v_min = 0;
    if (vm_check(m, 1, msg, len)) return 1;
    while (t_end - m->time > tol) {
        const double t_sample = m->start_time + (double)(m->sample_index + 1) * Ts;
        const int hits = t_sample <= t_end + tol;
        const double t_target = hits ? t_sample : t_end;
        const double span = t_target - m->time;
        int n = (int)ceil(span / v->max_step - 1e-9);
        if (n < 1) n = 1;
        const double h = span / n;
        for (int i = 0; i < n; i++) {
            rk4_step(m, m->x, h);
            m->time = (i == n - 1) ? t_target : m->time + h;
            int finite = 1;
            for (int j = 0; j < VM_NX; j++) finite &= isfinite(m->x[j]);
            if (!finite) {
                snprintf(msg, len, "state became non-finite at t = %.6f s", m->time);
                return 1;
            }
            if (m->x[X_VX] < v->v_min) {
                m->below_v_min = 1;
                snprintf(msg, len,
                         "speed vx = %.4g m/s fell below v_min = %g m/s at t = %.6f s: the "
                         "single-track model is not valid at standstill",
                         m->x[X_VX], v->v_min, m->time);
                return 1;
            }
        }
        if (hits) {
            m->sample_index++;
            draw_sample(m, 0);
            vm_update_outputs(m); /* the sample of the sensors at t_k */
        }
    }
    m->time = t_end;
    vm_update_outputs(m);
    return 0;
}
