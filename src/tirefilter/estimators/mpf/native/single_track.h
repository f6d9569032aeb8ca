/* The estimators' single-track model on scalars, one particle at a time: the C twin of
 * vehicle/single_track_numba.py (`_steer_consts`, `_model_t`, `_xdot_t`, `_interval_slip1`,
 * `_measure_h`, `_measure_d`), the same expressions in the same order, so that the results equal
 * the numba kernels' bit for bit (compiled without FMA contraction: native.py).
 *
 * vp, the packed parameters of `single_track.model_params`: (m, I, lf, lr, Cf_y, Cr_y, C_nom_fx,
 * C_nom_rx, R_w, undriven_share, imu_x, imu_y, relaxation_length). */
#ifndef TIREFILTER_SINGLE_TRACK_H
#define TIREFILTER_SINGLE_TRACK_H

#include <math.h>
#include <stdint.h>

/* Python's max(a, b) and min(a, b) on floats (and numba's): a unless b is strictly greater (smaller) */
static inline double py_max(double a, double b) { return b > a ? b : a; }
static inline double py_min(double a, double b) { return b < a ? b : a; }

/* The lower Cholesky factor of the n x n matrix a (row stride lda, lower triangle read) into l (row
   stride ldl; l == a with ldl == lda factors in place), the numba kernels' operation order: a pivot
   below |a_jj| 1e-14 (a rounding-level loss of definiteness) is floored there. The upper triangle of l
   is left as it was. */
static inline void chol_lower(const double *a, int lda, double *l, int ldl, int n)
{
    for (int j = 0; j < n; j++) {
        const double ajj = a[j * lda + j];
        double d = ajj;
        for (int k = 0; k < j; k++)
            d = d - l[j * ldl + k] * l[j * ldl + k];
        const double ljj = sqrt(py_max(d, fabs(ajj) * 1e-14 + 1e-300));
        l[j * ldl + j] = ljj;
        const double inv = 1.0 / ljj;
        for (int r = j + 1; r < n; r++) {
            double acc = a[r * lda + j];
            for (int k = 0; k < j; k++)
                acc = acc - l[r * ldl + k] * l[j * ldl + k];
            l[r * ldl + j] = acc * inv;
        }
    }
}

/* `_steer_consts`: the factors that depend only on the steering angle u0 and the vehicle,
 * (cos, sin, 1 / m, 1 / I, cos / m, sin / m, lf sin / I, -sin / m, lf cos / I, -lr / I) */
static inline void st_steer_consts(double u0, const double *vp, double k[10])
{
    double m = vp[0], I = vp[1], lf = vp[2], lr = vp[3];
    double cd = cos(u0), sd = sin(u0);
    k[0] = cd; k[1] = sd; k[2] = 1.0 / m; k[3] = 1.0 / I; k[4] = cd / m; k[5] = sd / m;
    k[6] = lf * sd / I; k[7] = -sd / m; k[8] = lf * cd / I; k[9] = -lr / I;
}

/* `_model_t`: one particle's model (`single_track.accelerations`) into out (16,) = (a0, a1, a2, b00, b01,
 * b02, b10, b11, b12, b20, b21, b22, af, ar, lam_f, lam_r). xs (x0, x1, x2): [vx, vy, r], or [vy, r, 0] in
 * the lateral model; us (4,) = [delta, omega_f, omega_r, vx]; k the `st_steer_consts` of us[0]; `held`:
 * the wheel slip (sf, sr) held, not computed; lg the load-transfer gain; pf, pr the relaxed slip angles
 * hr seconds earlier (hr < 0: no relaxation). */
static inline void st_model_t(double x0, double x1, double x2, const double *us, const double *k, int held,
                              double sf, double sr, const double *vp, int full, int rear_drive, double lg,
                              double pf, double pr, double hr, double *out)
{
    double lf = vp[2], lr = vp[3], Cfy = vp[4], Cry = vp[5], Cfx = vp[6], Crx = vp[7], Rw = vp[8];
    double s = vp[9];
    double u0 = us[0], u1 = us[1], u2 = us[2], u3 = us[3];
    double cd = k[0], sd = k[1], inv_m = k[2], inv_I = k[3], cd_m = k[4], sd_m = k[5], lf_sd_I = k[6];
    double msd_m = k[7], lf_cd_I = k[8], mlr_I = k[9];
    double vx, vy, r;
    if (full) { vx = x0; vy = x1; r = x2; } else { vx = u3; vy = x0; r = x1; }
    double inv_vx = 1.0 / py_max(vx, 1.0);
    double af = u0 - (vy + lf * r) * inv_vx;
    double ar = (lr * r - vy) * inv_vx;
    if (hr >= 0.0 && vp[12] > 0.0) {
        double share = -expm1(-(py_max(vx, 1.0) * (hr / vp[12])));
        af = pf + share * (af - pf);
        ar = pr + share * (ar - pr);
    }
    double gf = af * lg, gr = ar * lg;
    double Ffy = Cfy * gf, Fry = Cry * gr;
    double lam_f = 0.0, lam_r = 0.0, g0 = 0.0, g1 = 0.0, g2 = 0.0, Fy_f, aX;
    if (full) {
        if (held) {
            lam_f = sf; lam_r = sr;
        } else {
            double wf = Rw * u1, wr = Rw * u2;
            lam_f = (wf - vx) / py_max(py_max(fabs(vx), fabs(wf)), 1.0);
            lam_r = (wr - vx) / py_max(py_max(fabs(vx), fabs(wr)), 1.0);
        }
        double Ffx = Cfx * lam_f, Frx = Crx * lam_r;
        if (rear_drive) {
            g0 = lam_r * inv_m + (s * lam_f) * cd_m;
            g1 = (s * lam_f) * sd_m;
            g2 = (s * lam_f) * lf_sd_I;
        } else {
            g0 = lam_f * cd_m + (s * lam_r) * inv_m;
            g1 = lam_f * sd_m;
            g2 = lam_f * lf_sd_I;
        }
        Fy_f = Ffy * cd + Ffx * sd;
        aX = (Ffx * cd - Ffy * sd + Frx) * inv_m;
    } else {
        Fy_f = Ffy * cd;
        aX = 0.0;
    }
    double f0 = gf * msd_m, f1 = gf * cd_m, f2 = gf * lf_cd_I;
    double r1 = gr * inv_m, r2 = gr * mlr_I;
    double a1 = (Fy_f + Fry) * inv_m;
    double a2 = (lf * Fy_f - lr * Fry) * inv_I;
    out[0] = aX; out[1] = a1; out[2] = a2;
    if (full) {
        out[3] = g0; out[4] = f0; out[5] = 0.0;
        out[6] = g1; out[7] = f1; out[8] = r1;
        out[9] = g2; out[10] = f2; out[11] = r2;
    } else {
        out[3] = f0; out[4] = 0.0; out[5] = 0.0;
        out[6] = f1; out[7] = r1; out[8] = 0.0;
        out[9] = f2; out[10] = r2; out[11] = 0.0;
    }
    out[12] = af; out[13] = ar; out[14] = lam_f; out[15] = lam_r;
}

/* `_xdot_t`: dx/dt from m (`st_model_t`'s out) and w = (w0, w1, w2) (w2 unused in the lateral model,
 * where dx2 = 0) into k (3,) */
static inline void st_xdot_t(double x0, double x1, double x2, double u3, const double *m, double w0, double w1,
                             double w2, int full, double *k)
{
    double s0 = 0.0 + m[3] * w0;
    double s1 = 0.0 + m[6] * w0;
    double s2 = 0.0 + m[9] * w0;
    s0 = s0 + m[4] * w1;
    s1 = s1 + m[7] * w1;
    s2 = s2 + m[10] * w1;
    if (full) {
        s0 = s0 + m[5] * w2;
        s1 = s1 + m[8] * w2;
        s2 = s2 + m[11] * w2;
    }
    double acc0 = m[0] + s0, acc1 = m[1] + s1, acc2 = m[2] + s2;
    if (full) {
        k[0] = x1 * x2 + acc0; k[1] = acc1 - x0 * x2; k[2] = acc2;
    } else {
        k[0] = acc1 - u3 * x1; k[1] = acc2; k[2] = 0.0;
    }
}

/* `_interval_slip1`: one particle's front and rear wheel slip averaged over the step (derivations,
 * "Wheel slip") from the slips at t_k; xs = (vx, vy, r), acc0 = a^X + B_0 w at t_k, wx the driven axle's
 * deviation, u0, u1 (4,) the inputs at t_k and t_k+1; jw (2,) spin inertia over R_w^2, c_floor (2,) */
static inline void st_interval_slip1(double vx, double vy, double r, double acc0, double wx, double slip_f,
                                     double slip_r, const double *u0, const double *u1, double dt,
                                     const double *vp, const double *jw, const double *c_floor, int rear_drive,
                                     double *out_f, double *out_r)
{
    double Rw = vp[8], s = vp[9], Cfx = vp[6], Crx = vp[7];
    double vx1 = vx + dt * (vy * r + acc0);
    double c_f, c_r;
    if (rear_drive) { c_f = Cfx + s * wx; c_r = Crx + wx; } else { c_f = Cfx + wx; c_r = Crx + s * wx; }
    for (int k = 0; k < 2; k++) {
        double wr1 = Rw * u1[1 + k];
        double slip1 = (wr1 - vx1) / py_max(py_max(fabs(vx1), fabs(wr1)), 1.0);
        double C = py_max(k == 0 ? c_f : c_r, c_floor[k]);
        double D = py_max(py_max(fabs(vx), fabs(Rw * u0[1 + k])), 1.0);
        double tau = py_max(jw[k] * D / C, 1e-12);
        double share = (tau / dt) * -expm1(-dt / tau);
        if (k == 0)
            *out_f = slip1 + (slip_f - slip1) * share;
        else
            *out_r = slip1 + (slip_r - slip1) * share;
    }
}

/* `_measure_h`: (h^X, h^Y) of `single_track.measurement` from (a0, a1, a2), the yaw rate r, the roll gain,
 * the IMU at (ix, iy) (`lever` 0: at the centre of gravity) */
static inline void st_measure_h(double a0, double a1, double a2, double r, double gain, double ix, double iy,
                                int lever, double *hx, double *hy)
{
    *hx = a0;
    *hy = gain * a1;
    if (lever) {
        double r2 = r * r;
        *hx = (a0 - iy * a2) - ix * r2;
        *hy = (*hy + ix * a2) - iy * r2;
    }
}

/* `_measure_d`: one column (d^X, d^Y) of d from the column (b0, b1, b2) of B */
static inline void st_measure_d(double b0, double b1, double b2, double gain, double ix, double iy, int lever,
                                double *dx, double *dy)
{
    if (lever) {
        *dx = b0 - iy * b2;
        *dy = b1 * gain + ix * b2;
    } else {
        *dx = b0;
        *dy = b1 * gain;
    }
}

#endif
