/* The single-track model for all particles (vehicle/single_track_numba.py's `accelerations`, `propagate`,
 * `slip_over_step`): the MPF's reference path with the C backend (the first sample, restarts, gaps) calls
 * them; the per-particle code is single_track.h's, which `predict_weigh` inlines. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include "mpf_core.h"
#include "single_track.h"

/* `_model1`: `st_model_t` stored into a (3,) and B (3, n_w); returns the 16 values in mm */
static void model1(double x0, double x1, double x2, const double *us, const double *k, int held, double sf,
                   double sr, double *a, double *B, const double *vp, int full, int rear_drive, int64_t n_w,
                   double lg, double pf, double pr, double hr, double *mm)
{
    st_model_t(x0, x1, x2, us, k, held, sf, sr, vp, full, rear_drive, lg, pf, pr, hr, mm);
    a[0] = mm[0];
    a[1] = mm[1];
    a[2] = mm[2];
    for (int r = 0; r < 3; r++)
        for (int64_t j = 0; j < n_w; j++)
            B[r * n_w + j] = mm[3 + 3 * r + j];
}

void st_accelerations(int64_t n, int64_t nx, int64_t n_w, const double *x, const double *u, const double *vp,
                      int32_t full, int32_t rear_drive, const double *lg, const double *rel, double h, double *a,
                      double *B, double *af, double *ar, double *slip)
{
    double ku[10], mm[16];
    st_steer_consts(u[0], vp, ku);
    for (int64_t i = 0; i < n; i++) {
        const double x2 = full ? x[i * nx + 2] : 0.0;
        const double pf = rel ? rel[i] : 0.0, pr = rel ? rel[n + i] : 0.0, hr = rel ? h : -1.0;
        model1(x[i * nx], x[i * nx + 1], x2, u, ku, 0, 0.0, 0.0, a + i * 3, B + i * 3 * n_w, vp, full, rear_drive,
               n_w, lg[i], pf, pr, hr, mm);
        af[i] = mm[12];
        ar[i] = mm[13];
        slip[i] = mm[14];
        slip[n + i] = mm[15];
    }
}

/* `_xdot1`: dx/dt from a (3,), B (3, n_w), w (n_w,) into out (nx,) */
static void xdot1(const double *x, double u3, const double *a, const double *B, const double *w, double *out,
                  int full, int64_t n_w)
{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0;
    for (int64_t j = 0; j < n_w; j++) {
        s0 += B[j] * w[j];
        s1 += B[n_w + j] * w[j];
        s2 += B[2 * n_w + j] * w[j];
    }
    const double acc0 = a[0] + s0, acc1 = a[1] + s1, acc2 = a[2] + s2;
    if (full) {
        out[0] = x[1] * x[2] + acc0;
        out[1] = acc1 - x[0] * x[2];
        out[2] = acc2;
    } else {
        out[0] = acc1 - u3 * x[1];
        out[1] = acc2;
    }
}

void st_propagate(int64_t n, int64_t nx, int64_t n_w, const double *x, const double *u, const double *w,
                  const double *a, const double *B, const double *slip, double dt, double max_step, int32_t heun,
                  const double *vp, int32_t full, int32_t rear_drive, const double *lg, const double *rel,
                  double *out)
{
    double ku[10], mm[16], xi[3], x1[3], k1[3], k2[3], ai[3], Bi[3 * MPF_MAX_DIM];
    st_steer_consts(u[0], vp, ku);
    const double nsub_f = ceil(dt / max_step - 1e-9);
    const int64_t n_sub = nsub_f > 1.0 ? (int64_t)nsub_f : 1;
    const double hs = dt / (double)n_sub;
    for (int64_t i = 0; i < n; i++) {
        for (int64_t c = 0; c < nx; c++)
            xi[c] = x[i * nx + c];
        double sf = slip[i], sr = slip[n + i];
        const double pf = rel ? rel[i] : 0.0, pr = rel ? rel[n + i] : 0.0;
        const double *wi = w + i * n_w;
        for (int64_t s = 0; s < n_sub; s++) {
            if (s == 0) {
                for (int c = 0; c < 3; c++) {
                    ai[c] = a[i * 3 + c];
                    for (int64_t j = 0; j < n_w; j++)
                        Bi[c * n_w + j] = B[(i * 3 + c) * n_w + j];
                }
            } else {
                model1(xi[0], xi[1], full ? xi[2] : 0.0, u, ku, 0, 0.0, 0.0, ai, Bi, vp, full, rear_drive, n_w,
                       lg[i], pf, pr, rel ? s * hs : -1.0, mm);
                sf = mm[14];
                sr = mm[15];
            }
            xdot1(xi, u[3], ai, Bi, wi, k1, full, n_w);
            if (!heun) {
                for (int64_t c = 0; c < nx; c++)
                    xi[c] = xi[c] + hs * k1[c];
                continue;
            }
            for (int64_t c = 0; c < nx; c++)
                x1[c] = xi[c] + hs * k1[c];
            model1(x1[0], x1[1], full ? x1[2] : 0.0, u, ku, full, sf, sr, ai, Bi, vp, full, rear_drive, n_w, lg[i],
                   pf, pr, rel ? (s + 1) * hs : -1.0, mm);
            xdot1(x1, u[3], ai, Bi, wi, k2, full, n_w);
            for (int64_t c = 0; c < nx; c++)
                xi[c] = xi[c] + (0.5 * hs) * (k1[c] + k2[c]);
        }
        for (int64_t c = 0; c < nx; c++)
            out[i * nx + c] = xi[c];
    }
}

void st_slip_over_step(int64_t n, int64_t n_w, const double *x, const double *u0, const double *u1,
                       const double *w, const double *a, const double *B, const double *slip, double dt,
                       const double *vp, const double *jw, const double *c_floor, int32_t rear_drive,
                       const double *lg, const double *rel, double *a2, double *B2, double *af, double *ar,
                       double *out)
{
    double k0[10], mm[16];
    st_steer_consts(u0[0], vp, k0);
    for (int64_t i = 0; i < n; i++) {
        const double pf = rel ? rel[i] : 0.0, pr = rel ? rel[n + i] : 0.0, hr = rel ? 0.0 : -1.0;
        double acc0 = 0.0;
        for (int64_t j = 0; j < n_w; j++)
            acc0 += B[(i * 3) * n_w + j] * w[i * n_w + j];
        acc0 = a[i * 3] + acc0;
        st_interval_slip1(x[i * 3], x[i * 3 + 1], x[i * 3 + 2], acc0, w[i * n_w], slip[i], slip[n + i], u0, u1, dt,
                          vp, jw, c_floor, rear_drive, &out[i], &out[n + i]);
        model1(x[i * 3], x[i * 3 + 1], x[i * 3 + 2], u0, k0, 1, out[i], out[n + i], a2 + i * 3, B2 + i * 3 * n_w,
               vp, 1, rear_drive, n_w, lg[i], pf, pr, hr, mm);
        af[i] = mm[12];
        ar[i] = mm[13];
    }
}
