/* The first of the MPF's three passes, `predict_weigh` (estimators/mpf/kernels_weigh.py, whose
 * docstrings tell the maths): steps 1 and 2 of the step, the propagation, bias prediction, forgetting,
 * the model at x_k, plausibility, the Student-t weights, log-sum-exp and the ESS. The loops are those of
 * the numba kernel in the same order; the bodies take n_w and na as arguments and are inlined with them as
 * constants in the usual cases (full model, lateral model, every channel), so that the compiler unrolls
 * the small loops, as numba does with its `sizes`. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include "mpf_core.h"
#include "single_track.h"

#define INLINE static inline __attribute__((always_inline))
#define PI 3.141592653589793 /* math.pi */

/* `_t_const`: the log-Gamma terms of the Student-t density for nn dof in p dimensions */
static double t_const(double nn, double p)
{
    return lgamma(0.5 * (nn + p)) - lgamma(0.5 * nn) - 0.5 * p * log(nn * PI);
}

/* `_common_dof`: nu~ when every particle has it, else 0 */
static double common_dof(const double *nu_w, int64_t n)
{
    if (n == 0)
        return 0.0;
    for (int64_t i = 0; i < n; i++)
        if (nu_w[i] != nu_w[0])
            return 0.0;
    return nu_w[0] > 0 ? nu_w[0] : 0.0;
}

/* `_normalise_into`: logw := normalised (logw + add) (add NULL: zeros), NaN as -inf, uniform when all are
 * -inf; returns the ESS */
static double normalise_into(double *logw, const double *add, int64_t n)
{
    double m = -INFINITY;
    for (int64_t i = 0; i < n; i++) {
        double li = logw[i] + (add ? add[i] : 0.0);
        if (isnan(li))
            li = -INFINITY;
        logw[i] = li;
        if (li > m)
            m = li;
    }
    if (!isfinite(m)) {
        double u = -log((double)n);
        for (int64_t i = 0; i < n; i++)
            logw[i] = u;
        return (double)n;
    }
    double s = 0.0;
    for (int64_t i = 0; i < n; i++) {
        logw[i] = logw[i] - m;
        s += exp(logw[i]);
    }
    double lse = log(s);
    double s2 = 0.0;
    for (int64_t i = 0; i < n; i++) {
        logw[i] = logw[i] - lse;
        s2 += exp(2.0 * logw[i]);
    }
    return 1.0 / s2;
}

/* `_weigh`: step 2, per particle h, D, nu~, L11, L12, Lc = chol(S), e, v and the log-density ll */
INLINE void weigh(const mpf_dims *dm, const mpf_own *own, const mpf_scratch *sc, const double *y,
                  const int64_t *avail, const double *R, const double *gain, const double *vp, int full,
                  int bias_on, const int n_w, const int na)
{
    const int64_t n = dm->n, nx = dm->nx, m = dm->m;
    const double *x = own->x, *b = own->b, *P = own->P, *gamma = own->gamma, *mu = own->mu, *Lam = own->Lam;
    const double *nu = own->nu, *a = own->a, *B = own->B;
    double *h = sc->h, *D = sc->D, *L11 = sc->L11, *nu_w = sc->nu_w, *L12 = sc->L12, *Lc = sc->Lc, *e = sc->e;
    double *v = sc->v, *ll = sc->ll;
    double DL[MPF_MAX_DIM][MPF_MAX_DIM];
    const double p = (double)na;
    double last = -1.0, cn = 0.0;
    const double ix = vp[10], iy = vp[11];
    const int lever = ix != 0.0 || iy != 0.0;
#define Dx(i, c, j) D[((i) * m + (c)) * n_w + (j)]
#define LCx(i, q, k) Lc[((i) * m + (q)) * m + (k)]
    for (int64_t i = 0; i < n; i++) {
        const double r = x[i * nx + nx - 1];
        const double g = gain[i];
        const double *ai = a + i * 3, *Bi = B + i * 3 * n_w;
        double hx, hy, dx, dy;
        st_measure_h(ai[0], ai[1], ai[2], r, g, ix, iy, lever, &hx, &hy);
        if (full) {
            h[i * m + 0] = hx;
            h[i * m + 1] = hy;
            h[i * m + 2] = r;
            for (int j = 0; j < n_w; j++) {
                st_measure_d(Bi[j], Bi[n_w + j], Bi[2 * n_w + j], g, ix, iy, lever, &dx, &dy);
                Dx(i, 0, j) = dx;
                Dx(i, 1, j) = dy;
                Dx(i, 2, j) = 0.0;
            }
        } else {
            h[i * m + 0] = hy;
            h[i * m + 1] = r;
            for (int j = 0; j < n_w; j++) {
                st_measure_d(Bi[j], Bi[n_w + j], Bi[2 * n_w + j], g, ix, iy, lever, &dx, &dy);
                Dx(i, 0, j) = dy;
                Dx(i, 1, j) = 0.0;
            }
        }
        const double dof = nu[i] - n_w + 1.0;
        nu_w[i] = dof;
        const double f = (1.0 + gamma[i]) / dof;
        double *L11i = L11 + i * n_w * n_w;
        const double *Lami = Lam + i * n_w * n_w;
        for (int j = 0; j < n_w; j++)
            for (int k = 0; k < n_w; k++)
                L11i[j * n_w + k] = f * Lami[j * n_w + k];
        if (na == 0)
            continue;
        for (int q = 0; q < na; q++) {
            const int64_t ch = avail[q];
            for (int k = 0; k < n_w; k++) {
                double s = 0.0;
                for (int j = 0; j < n_w; j++)
                    s += Dx(i, ch, j) * L11i[j * n_w + k];
                DL[q][k] = s;
                L12[(i * n_w + k) * m + q] = s;
            }
        }
        const double c = (dof - 2.0) / dof;
        for (int q = 0; q < na; q++) {
            for (int q2 = 0; q2 <= q; q2++) {
                double s = 0.0;
                for (int k = 0; k < n_w; k++)
                    s += DL[q][k] * Dx(i, avail[q2], k);
                double noise_qq = R[avail[q] * m + avail[q2]];
                if (bias_on)
                    noise_qq = noise_qq + P[(i * m + avail[q]) * m + avail[q2]];
                LCx(i, q, q2) = s + c * noise_qq;
            }
        }
        for (int q = 0; q < na; q++) {
            const int64_t ch = avail[q];
            double s = 0.0;
            for (int j = 0; j < n_w; j++)
                s += Dx(i, ch, j) * mu[i * n_w + j];
            e[i * m + q] = y[ch] - (h[i * m + ch] + b[i * m + ch]) - s;
        }
    }
    /* Lc = chol(S) in place, then v = Lc^-1 e and the weight, each in a short loop of its own */
    for (int64_t i = 0; i < (na ? n : 0); i++) {
        chol_lower(&LCx(i, 0, 0), m, &LCx(i, 0, 0), m, na);
        for (int j = 1; j < na; j++) /* the upper triangle zero */
            for (int r = 0; r < j; r++)
                LCx(i, r, j) = 0.0;
    }
    for (int64_t i = 0; i < (na ? n : 0); i++) {
        const double dof = nu_w[i];
        double logdet = 0.0, vv = 0.0;
        for (int q = 0; q < na; q++) {
            double acc = e[i * m + q];
            for (int k = 0; k < q; k++)
                acc = acc - LCx(i, q, k) * v[i * m + k];
            v[i * m + q] = acc / LCx(i, q, q);
            vv += v[i * m + q] * v[i * m + q];
            logdet += log(LCx(i, q, q));
        }
        logdet *= 2.0;
        if (dof != last) {
            last = dof;
            cn = t_const(dof, p);
        }
        ll[i] = cn - 0.5 * logdet - 0.5 * (dof + p) * log1p(vv / dof);
    }
#undef Dx
#undef LCx
}

/* step 1 of `predict_weigh` (propagation, noise, bias prediction, forgetting) and the model at x_k,
 * plausibility; returns the number of plausible particles */
INLINE int64_t predict(const mpf_dims *dm, const mpf_own *own, const mpf_scratch *sc, const double *u_prev,
                       const double *uk, const double *w_prev, const double *noise, const double *noise_scale,
                       const double *redraw, const mpf_model *md, const double *scalars, const int32_t *flags,
                       const int n_wp)
{
    const int64_t n = dm->n, nx = dm->nx, mch = dm->m;
    double *x = own->x, *P = own->P, *gamma = own->gamma, *Lam = own->Lam, *nu = own->nu, *a = own->a;
    double *B = own->B, *slip = own->slip;
    double *af = sc->af, *ar = sc->ar;
    uint8_t *ok = sc->ok;
    const double *vp = md->vp, *q = md->q, *load_gain = md->load_gain;
    double *relaxed = md->relaxed;
    const double dt = scalars[0], max_step = scalars[1], lam = scalars[2], nu_min = scalars[3];
    const double beta = scalars[4], yaw_max = scalars[5], gate_speed = scalars[6];
    const int heun = flags[0], interval = flags[1], bias_on = flags[2], forget = flags[3], full = flags[4];
    const int rear_drive = flags[5], propagate = flags[7];
    double kp[10], kk[10];
    st_steer_consts(u_prev[0], vp, kp);
    st_steer_consts(uk[0], vp, kk);
    double nsub_f = ceil(dt / max_step - 1e-9);
    const int64_t n_sub = nsub_f > 1.0 ? (int64_t)nsub_f : 1;
    const double hs = dt / (double)n_sub;
    int64_t count = 0;
#define Bx(i, r, j) B[((i) * 3 + (r)) * n_wp + (j)]
    if (interval && propagate) { /* the slip over the step into slip, in a short loop of its own */
        for (int64_t i = 0; i < n; i++) {
            double acc0 = 0.0;
            for (int j = 0; j < n_wp; j++)
                acc0 += Bx(i, 0, j) * w_prev[i * n_wp + j];
            acc0 = a[i * 3] + acc0;
            st_interval_slip1(x[i * nx], x[i * nx + 1], x[i * nx + 2], acc0, w_prev[i * n_wp], slip[i],
                              slip[n + i], u_prev, uk, dt, vp, md->jw, md->c_floor, rear_drive, &slip[i],
                              &slip[n + i]);
        }
    }
    const int relaxing = relaxed != NULL;
    const double h0 = relaxing ? 0.0 : -1.0;
    double mm[16], k1[3], k2[3];
    for (int64_t i = 0; i < n; i++) {
        const double lg = load_gain[i];
        const double pf = relaxing ? relaxed[i] : 0.0, pr = relaxing ? relaxed[n + i] : 0.0;
        double x0 = x[i * nx], x1 = x[i * nx + 1], x2 = full ? x[i * nx + 2] : 0.0;
        if (propagate) {
            const double w0 = w_prev[i * n_wp], w1 = w_prev[i * n_wp + 1], w2 = full ? w_prev[i * n_wp + 2] : 0.0;
            double sf = slip[i], sr = slip[n + i];
            if (interval) {
                st_model_t(x0, x1, x2, u_prev, kp, 1, sf, sr, vp, 1, rear_drive, lg, pf, pr, h0, mm);
            } else {
                mm[0] = a[i * 3]; mm[1] = a[i * 3 + 1]; mm[2] = a[i * 3 + 2];
                for (int r = 0; r < 3; r++)
                    for (int j = 0; j < 3; j++)
                        mm[3 + 3 * r + j] = j < n_wp ? Bx(i, r, j) : 0.0;
                if (!full)
                    mm[5] = mm[8] = mm[11] = 0.0;
                mm[12] = mm[13] = mm[14] = mm[15] = 0.0;
            }
            for (int64_t s = 0; s < n_sub; s++) {
                if (s > 0) {
                    st_model_t(x0, x1, x2, u_prev, kp, 0, 0.0, 0.0, vp, full, rear_drive, lg, pf, pr,
                               relaxing ? s * hs : -1.0, mm);
                    sf = mm[14];
                    sr = mm[15];
                }
                st_xdot_t(x0, x1, x2, u_prev[3], mm, w0, w1, w2, full, k1);
                if (!heun) {
                    x0 = x0 + hs * k1[0];
                    x1 = x1 + hs * k1[1];
                    if (full)
                        x2 = x2 + hs * k1[2];
                    continue;
                }
                const double y0 = x0 + hs * k1[0], y1 = x1 + hs * k1[1], y2 = full ? x2 + hs * k1[2] : 0.0;
                st_model_t(y0, y1, y2, u_prev, kp, full, sf, sr, vp, full, rear_drive, lg, pf, pr,
                           relaxing ? (s + 1) * hs : -1.0, mm);
                st_xdot_t(y0, y1, y2, u_prev[3], mm, w0, w1, w2, full, k2);
                x0 = x0 + (0.5 * hs) * (k1[0] + k2[0]);
                x1 = x1 + (0.5 * hs) * (k1[1] + k2[1]);
                if (full)
                    x2 = x2 + (0.5 * hs) * (k1[2] + k2[2]);
            }
            if (redraw) /* after a gap: v^X drawn again from the wheel speeds */
                x0 = redraw[i];
            if (noise) {
                x0 = x0 + noise_scale[0] * noise[i * nx];
                x1 = x1 + noise_scale[1] * noise[i * nx + 1];
                if (full)
                    x2 = x2 + noise_scale[2] * noise[i * nx + 2];
            }
            x[i * nx] = x0;
            x[i * nx + 1] = x1;
            if (full)
                x[i * nx + 2] = x2;
            if (bias_on) /* eq. (29) */
                for (int64_t c = 0; c < mch; c++)
                    P[(i * mch + c) * mch + c] = P[(i * mch + c) * mch + c] + q[c] * dt;
            if (forget) { /* eq. (20) */
                const double f = nu_min > 0 ? py_max(lam, py_min(1.0, nu_min / nu[i])) : lam;
                gamma[i] = gamma[i] / f;
                nu[i] = nu[i] * f;
                for (int j = 0; j < n_wp; j++)
                    for (int k = 0; k < n_wp; k++)
                        Lam[(i * n_wp + j) * n_wp + k] = Lam[(i * n_wp + j) * n_wp + k] * f;
            }
        }
        /* the model at x_k, u_k and the plausible region */
        st_model_t(x0, x1, x2, uk, kk, 0, 0.0, 0.0, vp, full, rear_drive, lg, pf, pr,
                   relaxing && propagate ? dt : -1.0, mm);
        if (relaxing) {
            relaxed[i] = mm[12];
            relaxed[n + i] = mm[13];
        }
        a[i * 3] = mm[0]; a[i * 3 + 1] = mm[1]; a[i * 3 + 2] = mm[2];
        Bx(i, 0, 0) = mm[3]; Bx(i, 0, 1) = mm[4];
        Bx(i, 1, 0) = mm[6]; Bx(i, 1, 1) = mm[7];
        Bx(i, 2, 0) = mm[9]; Bx(i, 2, 1) = mm[10];
        if (full) {
            Bx(i, 0, 2) = mm[5]; Bx(i, 1, 2) = mm[8]; Bx(i, 2, 2) = mm[11];
        }
        af[i] = mm[12]; ar[i] = mm[13]; slip[i] = mm[14]; slip[n + i] = mm[15];
        const double vxp = full ? x[i * nx] : uk[3];
        ok[i] = fabs(x[i * nx + nx - 2]) <= beta * py_max(fabs(vxp), gate_speed)
                && fabs(x[i * nx + nx - 1]) <= yaw_max;
        count += ok[i];
    }
#undef Bx
    return count;
}

void mpf_predict_weigh(const mpf_dims *dm, const mpf_own *own, const mpf_scratch *sc, const double *u_prev,
                       const double *uk, const double *y, const int64_t *avail, int64_t na, const double *w_prev,
                       double *logw, const double *noise, const double *noise_scale, const double *redraw,
                       const mpf_model *md, const double *scalars, const int32_t *flags, int64_t nc, double *out)
{
    const int64_t n = dm->n, n_w = dm->n_w;
    const int bias_on = flags[2], full = flags[4], want_nis = flags[6], weigh_ = flags[8];
    int64_t count;
    if (n_w == 3) {
        count = predict(dm, own, sc, u_prev, uk, w_prev, noise, noise_scale, redraw, md, scalars, flags, 3);
    } else if (n_w == 2) {
        count = predict(dm, own, sc, u_prev, uk, w_prev, noise, noise_scale, redraw, md, scalars, flags, 2);
    } else {
        count = predict(dm, own, sc, u_prev, uk, w_prev, noise, noise_scale, redraw, md, scalars, flags, (int)n_w);
    }
    /* 2. the weights */
    if (n_w == 3 && na == 3)
        weigh(dm, own, sc, y, avail, md->R, md->gain, md->vp, full, bias_on, 3, 3);
    else if (n_w == 2 && na == 2)
        weigh(dm, own, sc, y, avail, md->R, md->gain, md->vp, full, bias_on, 2, 2);
    else
        weigh(dm, own, sc, y, avail, md->R, md->gain, md->vp, full, bias_on, (int)n_w, (int)na);
    double innovation = NAN;
    const double *v = sc->v, *nu_w = sc->nu_w;
    const int64_t m = dm->m;
    if (want_nis && nc) {
        innovation = 0.0;
        for (int64_t i = 0; i < n; i++) {
            double vv = 0.0;
            for (int64_t q = 0; q < nc; q++)
                vv += v[i * m + q] * v[i * m + q];
            innovation += exp(logw[i]) * (vv * (nu_w[i] - 2.0) / (nu_w[i] * (double)nc));
        }
    }
    double ess;
    if (weigh_)
        ess = na ? normalise_into(logw, sc->ll, n) : -1.0;
    else /* the start's weights in logw take the place of the likelihood's */
        ess = normalise_into(logw, NULL, n);
    out[0] = innovation;
    out[1] = ess;
    out[2] = (double)count;
    out[3] = common_dof(sc->nu_w, n);
}
