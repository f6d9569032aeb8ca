/* The second and third of the MPF's three passes (estimators/mpf/kernels_update.py, whose docstrings tell
 * the maths): `resample_gate` (systematic resampling and the gate's moments) and `sample_update` (the
 * conditional draw of w, the bias update, the drift of the adaptive forgetting, the NiW update with the
 * projection, the moments of the estimate); and the per-particle parts of the replay's options,
 * `match_state_noise` and `walk_roll`. The same loops as the numba kernels, in the same order. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "mpf_core.h"
#include "single_track.h"

#define INLINE static inline __attribute__((always_inline))

/* `systematic_into`: ancestors by the points (u0 + k) / N in cdf = cumsum(exp(logw)), cdf[-1] = 1 */
static void systematic_into(const double *logw, double u0, int64_t *idx, double *cdf, int64_t n)
{
    double acc = 0.0;
    for (int64_t i = 0; i < n; i++) {
        acc += exp(logw[i]);
        cdf[i] = acc;
    }
    cdf[n - 1] = 1.0;
    int64_t j = 0;
    for (int64_t k = 0; k < n; k++) {
        double u = (u0 + (double)k) / (double)n;
        while (j < n - 1 && cdf[j] <= u)
            j++;
        idx[k] = j;
    }
}

/* `_take_rows`: dst[i] = src[idx[i]] for (N, k) rows */
static void take_rows(const double *src, double *dst, const int64_t *idx, int64_t n, int64_t k)
{
    for (int64_t i = 0; i < n; i++)
        memcpy(dst + i * k, src + idx[i] * k, (size_t)k * sizeof(double));
}

void mpf_resample_gate(const mpf_dims *dm, double *logw, double u0, int32_t resample, int64_t *idx,
                       const mpf_own *own, const mpf_own *spares, const double *af, const double *ar, int32_t full,
                       const double *pin_lo, const double *pin_hi, double *qw, double *out)
{
    const int64_t n = dm->n, nx = dm->nx, n_w = dm->n_w, m = dm->m;
    const double *xs, *ms;
    if (resample) {
        double *cdf = malloc((size_t)n * sizeof(double));
        systematic_into(logw, u0, idx, cdf, n);
        free(cdf);
        take_rows(own->x, spares->x, idx, n, nx);
        take_rows(own->b, spares->b, idx, n, m);
        take_rows(own->P, spares->P, idx, n, m * m);
        take_rows(own->gamma, spares->gamma, idx, n, 1);
        take_rows(own->mu, spares->mu, idx, n, n_w);
        take_rows(own->Lam, spares->Lam, idx, n, n_w * n_w);
        take_rows(own->nu, spares->nu, idx, n, 1);
        take_rows(own->a, spares->a, idx, n, 3);
        take_rows(own->B, spares->B, idx, n, 3 * n_w);
        for (int64_t k = 0; k < n; k++) {
            spares->slip[k] = own->slip[idx[k]];
            spares->slip[n + k] = own->slip[n + idx[k]];
        }
        const double u = -log((double)n);
        for (int64_t i = 0; i < n; i++)
            logw[i] = u;
        xs = spares->x;
        ms = spares->mu;
    } else {
        for (int64_t k = 0; k < n; k++)
            idx[k] = k;
        xs = own->x;
        ms = own->mu;
    }
    const int64_t iv = full ? 1 : 0;
    double mvx = 0.0, mvy = 0.0, maf = 0.0, mar = 0.0;
    for (int64_t i = 0; i < n; i++) {
        const double q = exp(logw[i]);
        qw[i] = q;
        mvx += q * xs[i * nx];
        mvy += q * xs[i * nx + iv];
        maf += q * af[idx[i]];
        mar += q * ar[idx[i]];
    }
    double mbar[MPF_MAX_DIM] = {0.0};
    double s = 0.0;
    for (int64_t i = 0; i < n; i++) {
        const double q = qw[i];
        const double d = xs[i * nx + iv] - mvy;
        s += q * (d * d);
        for (int64_t j = 0; j < n_w; j++)
            mbar[j] += q * ms[i * n_w + j];
    }
    int pinned = 0;
    for (int64_t j = 0; j < n_w; j++)
        if (mbar[j] <= pin_lo[j] || mbar[j] >= pin_hi[j])
            pinned = 1;
    out[0] = mvx;
    out[1] = sqrt(py_max(s, 0.0));
    out[2] = py_max(fabs(maf), fabs(mar));
    out[3] = pinned;
}

/* `_bias`: step 4, the bias Kalman update of eq. (30) per particle, in three short loops */
INLINE void bias_update(const mpf_dims *dm, const int64_t *idx, const mpf_own *own, const mpf_scratch *sc,
                        const double *R, const int64_t *avail, const int na, const double *y, const int n_w,
                        const int mch)
{
    const int64_t n = dm->n, m = mch;
    double *b = own->b, *P = own->P;
    const double *Lam = own->Lam, *nu = own->nu, *mu = own->mu, *D = sc->D, *h = sc->h;
    const int nb = na > 1 ? na : 1;
    double *Sb = malloc((size_t)(n * nb * nb) * sizeof(double));
    double *inn = malloc((size_t)(n * nb) * sizeof(double));
    double DE[MPF_MAX_DIM][MPF_MAX_DIM], Kt[MPF_MAX_DIM][MPF_MAX_DIM], Pn[MPF_MAX_DIM][MPF_MAX_DIM];
#define Dx(i, c, j) D[((i) * m + (c)) * n_w + (j)]
#define Px(i, c, c2) P[((i) * mch + (c)) * mch + (c2)]
#define Sx(i, q, q2) Sb[((i) * nb + (q)) * nb + (q2)]
    for (int64_t i = 0; i < n; i++) {
        const int64_t s = idx[i];
        const double den = nu[i] - n_w - 1.0;
        for (int q = 0; q < na; q++) {
            const int64_t cq = avail[q];
            for (int k = 0; k < n_w; k++) {
                double t = 0.0;
                for (int j = 0; j < n_w; j++)
                    t += Dx(s, cq, j) * (Lam[(i * n_w + j) * n_w + k] / den);
                DE[q][k] = t;
            }
        }
        for (int q = 0; q < na; q++) {
            const int64_t cq = avail[q];
            for (int q2 = 0; q2 <= q; q2++) {
                const int64_t c2 = avail[q2];
                double t = 0.0;
                for (int k = 0; k < n_w; k++)
                    t += DE[q][k] * Dx(s, c2, k);
                Sx(i, q, q2) = Px(i, cq, c2) + R[cq * m + c2] + t;
            }
        }
        for (int q = 0; q < na; q++) {
            const int64_t ch = avail[q];
            double t = 0.0;
            for (int j = 0; j < n_w; j++)
                t += Dx(s, ch, j) * mu[i * n_w + j];
            inn[i * nb + q] = y[ch] - h[s * m + ch] - t - b[i * mch + ch];
        }
    }
    for (int64_t i = 0; i < n; i++) /* chol(S) in place */
        chol_lower(&Sx(i, 0, 0), nb, &Sx(i, 0, 0), nb, na);
    for (int64_t i = 0; i < n; i++) {
        for (int c = 0; c < mch; c++) { /* Kt[:, c] = S^-1 P[a, c] */
            for (int q = 0; q < na; q++) {
                double acc = Px(i, avail[q], c);
                for (int j = 0; j < q; j++)
                    acc = acc - Sx(i, q, j) * Kt[j][c];
                Kt[q][c] = acc / Sx(i, q, q);
            }
            for (int q = na - 1; q >= 0; q--) {
                double acc = Kt[q][c];
                for (int j = q + 1; j < na; j++)
                    acc = acc - Sx(i, j, q) * Kt[j][c];
                Kt[q][c] = acc / Sx(i, q, q);
            }
        }
        for (int c = 0; c < mch; c++) {
            double t = 0.0;
            for (int q = 0; q < na; q++)
                t += Kt[q][c] * inn[i * nb + q];
            b[i * mch + c] = b[i * mch + c] + t;
        }
        for (int c = 0; c < mch; c++) { /* Pn = P - P_{:,a} K^T, then 0.5 (Pn + Pn^T) */
            for (int c2 = 0; c2 < mch; c2++) {
                double t = 0.0;
                for (int q = 0; q < na; q++)
                    t += Px(i, avail[q], c) * Kt[q][c2];
                Pn[c][c2] = Px(i, c, c2) - t;
            }
        }
        for (int c = 0; c < mch; c++)
            for (int c2 = 0; c2 < mch; c2++)
                Px(i, c, c2) = 0.5 * (Pn[c][c2] + Pn[c2][c]);
    }
#undef Dx
#undef Px
#undef Sx
    free(Sb);
    free(inn);
}

/* `_sample`: steps 3 and 5, the conditional Student-t and its draw (into w), the outlier mask, the
 * drift's whitened lean (accumulated into ub), the NiW update and the projection */
INLINE void sample(const mpf_dims *dm, const int64_t *idx, const mpf_own *own, const mpf_scratch *sc,
                   const double *z, const double *chi, const double *nu_draw, const double *infl, double *w,
                   double bound, const double *lo, const double *hi, const int32_t *flags, const double *qw,
                   double *ub, double *Lw, uint8_t *learn, double *wl_buf, const int n_w, const int nc)
{
    const int64_t n = dm->n, m = dm->m;
    double *gamma = own->gamma, *mu = own->mu, *Lam = own->Lam, *nu = own->nu;
    const double *L11 = sc->L11, *nu_w = sc->nu_w, *L12 = sc->L12, *Lc = sc->Lc, *v = sc->v;
    const int use_mask = flags[0], active = flags[2], drift = flags[3];
    double M[MPF_MAX_DIM][MPF_MAX_DIM], ui[MPF_MAX_DIM];
#define LWx(i, j, k) Lw[((i) * n_w + (j)) * n_w + (k)]
#define LCx(s, q, j) Lc[((s) * m + (q)) * m + (j)]
#define L11x(s, j, k) L11[((s) * n_w + (j)) * n_w + (k)]
    for (int64_t i = 0; i < n; i++) {
        const int64_t s = idx[i];
        for (int k = 0; k < n_w; k++) { /* M = solve_lower(Lc, L21) */
            for (int q = 0; q < nc; q++) {
                double acc = L12[(s * n_w + k) * m + q];
                for (int j = 0; j < q; j++)
                    acc = acc - LCx(s, q, j) * M[j][k];
                M[q][k] = acc / LCx(s, q, q);
            }
        }
        double vv = 0.0;
        for (int q = 0; q < nc; q++)
            vv += v[s * m + q] * v[s * m + q];
        for (int k = 0; k < n_w; k++) {
            double t = 0.0;
            for (int q = 0; q < nc; q++)
                t += M[q][k] * v[s * m + q];
            w[i * n_w + k] = mu[i * n_w + k] + t;
        }
        const double scl = (nu_w[s] + vv) / (nu_w[s] + (double)nc);
        for (int j = 0; j < n_w; j++) {
            for (int k = 0; k <= j; k++) {
                double g = 0.0;
                for (int q = 0; q < nc; q++)
                    g += M[q][j] * M[q][k];
                LWx(i, j, k) = scl * (L11x(s, j, k) - g);
            }
        }
        learn[i] = use_mask ? vv < bound : 1;
    }
    for (int64_t i = 0; i < n; i++) /* chol(Lam_c) in place */
        chol_lower(&LWx(i, 0, 0), n_w, &LWx(i, 0, 0), n_w, n_w);
    const int same = infl[0] == infl[1];
    double *wl = same ? w : wl_buf;
    for (int64_t i = 0; i < n; i++) { /* mu_c + chol(Lam_c) z sqrt(nu_draw / chi), times infl */
        const double f0 = sqrt(nu_draw[i] / chi[i]);
        const double f = f0 * infl[0], fl = f0 * infl[1];
        for (int j = 0; j < n_w; j++) {
            double t = 0.0;
            for (int k = 0; k <= j; k++)
                t += LWx(i, j, k) * z[i * n_w + k];
            if (!same)
                wl[i * n_w + j] = w[i * n_w + j] + t * fl;
            w[i * n_w + j] = w[i * n_w + j] + t * f;
        }
    }
    /* 5. the drift (chol(L11) in place of Lam_c's factor, then the solve), the NiW update, the projection */
    for (int64_t i = 0; i < (active && drift ? n : 0); i++)
        chol_lower(&L11x(idx[i], 0, 0), n_w, &LWx(i, 0, 0), n_w, n_w);
    for (int64_t i = 0; i < (active && drift ? n : 0); i++) {
        for (int j = 0; j < n_w; j++) {
            double acc = wl[i * n_w + j] - mu[i * n_w + j];
            for (int k = 0; k < j; k++)
                acc = acc - LWx(i, j, k) * ui[k];
            ui[j] = acc / LWx(i, j, j);
        }
        const double q_i = qw[i];
        for (int j = 0; j < n_w; j++)
            ub[j] += q_i * ui[j];
    }
    for (int64_t i = 0; i < (active ? n : 0); i++) {
        double *mui = mu + i * n_w;
        const double *wli = wl + i * n_w;
        if (!learn[i]) {
            for (int j = 0; j < n_w; j++)
                mui[j] = py_min(py_max(mui[j], lo[j]), hi[j]);
            continue;
        }
        const double g0 = gamma[i];
        const double g_new = g0 / (1.0 + g0);
        const double inv = 1.0 + g0;
        double *Lami = Lam + i * n_w * n_w;
        for (int j = 0; j < n_w; j++) {
            const double zj = wli[j] - mui[j];
            for (int k = 0; k < n_w; k++)
                Lami[j * n_w + k] = Lami[j * n_w + k] + zj * (wli[k] - mui[k]) / inv;
        }
        for (int j = 0; j < n_w; j++) {
            const double mj = mui[j] + g_new * (wli[j] - mui[j]);
            mui[j] = py_min(py_max(mj, lo[j]), hi[j]);
        }
        gamma[i] = g_new;
        nu[i] = nu[i] + 1.0;
    }
#undef LWx
#undef LCx
#undef L11x
}

/* `_moments`: `estimate_moments` with the weights q = exp(logw) given */
static void moments(const mpf_dims *dm, const double *q, const double *x, const double *gamma, const double *mu,
                    const double *Lam, const double *nu, const double *b, double *mom, int64_t K)
{
    const int64_t n = dm->n, nx = dm->nx, n_w = dm->n_w, mch = dm->m;
    memset(mom, 0, (size_t)(7 * K) * sizeof(double));
    double *xm = mom, *xs = mom + K, *mbar = mom + 2 * K, *vm = mom + 3 * K, *s2 = mom + 4 * K, *bm = mom + 5 * K;
    double vyr = 0.0, spread[MPF_MAX_DIM] = {0.0};
    for (int64_t i = 0; i < n; i++) {
        for (int64_t c = 0; c < nx; c++)
            xm[c] += q[i] * x[i * nx + c];
        for (int64_t j = 0; j < n_w; j++)
            mbar[j] += q[i] * mu[i * n_w + j];
        for (int64_t c = 0; c < mch; c++)
            bm[c] += q[i] * b[i * mch + c];
        vyr += q[i] * (x[i * nx + nx - 2] * x[i * nx + nx - 1]);
    }
    mom[6 * K] = vyr;
    for (int64_t i = 0; i < n; i++) {
        for (int64_t c = 0; c < nx; c++) {
            const double d = x[i * nx + c] - xm[c];
            xs[c] += q[i] * d * d;
        }
        const double den = nu[i] - n_w - 1.0;
        for (int64_t j = 0; j < n_w; j++) {
            const double d = mu[i * n_w + j] - mbar[j];
            spread[j] += q[i] * d * d;
            const double es = Lam[(i * n_w + j) * n_w + j] / den;
            vm[j] += q[i] * (gamma[i] * es);
            s2[j] += q[i] * es;
        }
    }
    for (int64_t c = 0; c < nx; c++)
        xs[c] = sqrt(py_max(xs[c], 0.0));
    for (int64_t j = 0; j < n_w; j++) {
        vm[j] += spread[j];
        s2[j] += spread[j];
    }
}

void mpf_sample_update(const mpf_dims *dm, const int64_t *idx, const mpf_own *own, const mpf_scratch *sc,
                       const double *z, const double *chi, const double *nu_draw, const double *infl, double *w,
                       const double *R, const int64_t *avail, int64_t na, const double *y, double bound,
                       double drift_a, const double *lo, const double *hi, const int32_t *flags, int64_t nc,
                       double *drift_state, double *mom, int64_t mom_cols, const double *qw, const double *k_roll,
                       double *out)
{
    const int64_t n = dm->n, n_w = dm->n_w;
    const int do_bias = flags[1], active = flags[2], drift = flags[3];
    double ub[MPF_MAX_DIM] = {0.0};
    if (do_bias) { /* first: it reads the statistics before their update and writes only b, P */
        if (n_w == 3 && na == 3 && dm->m == 3)
            bias_update(dm, idx, own, sc, R, avail, 3, y, 3, 3);
        else if (n_w == 2 && na == 2 && dm->m == 2)
            bias_update(dm, idx, own, sc, R, avail, 2, y, 2, 2);
        else
            bias_update(dm, idx, own, sc, R, avail, (int)na, y, (int)n_w, (int)dm->m);
    }
    double *Lw = malloc((size_t)(n * n_w * n_w) * sizeof(double));
    uint8_t *learn = malloc((size_t)n);
    double *wl = infl[0] == infl[1] ? NULL : malloc((size_t)(n * n_w) * sizeof(double));
    if (n_w == 3 && nc == 2)
        sample(dm, idx, own, sc, z, chi, nu_draw, infl, w, bound, lo, hi, flags, qw, ub, Lw, learn, wl, 3, 2);
    else if (n_w == 2 && nc == 1)
        sample(dm, idx, own, sc, z, chi, nu_draw, infl, w, bound, lo, hi, flags, qw, ub, Lw, learn, wl, 2, 1);
    else
        sample(dm, idx, own, sc, z, chi, nu_draw, infl, w, bound, lo, hi, flags, qw, ub, Lw, learn, wl, (int)n_w,
               (int)nc);
    free(Lw);
    free(learn);
    free(wl);
    double zd = NAN;
    if (active && drift) {
        int finite = 1;
        for (int64_t j = 0; j < n_w; j++)
            if (!isfinite(ub[j]))
                finite = 0;
        if (finite) {
            double dd = 0.0;
            for (int64_t j = 0; j < n_w; j++) {
                drift_state[j] = drift_state[j] + drift_a * (ub[j] - drift_state[j]);
                dd += drift_state[j] * drift_state[j];
            }
            zd = dd * (2.0 - drift_a) / (drift_a * (double)n_w);
        }
    }
    moments(dm, qw, own->x, own->gamma, own->mu, own->Lam, own->nu, own->b, mom, mom_cols);
    out[0] = zd;
    out[1] = out[2] = NAN;
    if (k_roll) { /* `_mean_std` */
        double km = 0.0, s = 0.0;
        for (int64_t i = 0; i < n; i++)
            km += qw[i] * k_roll[i];
        for (int64_t i = 0; i < n; i++) {
            const double d = k_roll[i] - km;
            s += qw[i] * (d * d);
        }
        out[1] = km;
        out[2] = sqrt(py_max(s, 0.0));
    }
}

void mpf_estimate_moments(const mpf_dims *dm, const double *logw, const double *x, const double *gamma,
                          const double *mu, const double *Lam, const double *nu, const double *b, double *mom,
                          int64_t mom_cols)
{
    double *q = malloc((size_t)dm->n * sizeof(double));
    for (int64_t i = 0; i < dm->n; i++)
        q[i] = exp(logw[i]);
    moments(dm, q, x, gamma, mu, Lam, nu, b, mom, mom_cols);
    free(q);
}

void mpf_match_state_noise(int64_t n, int64_t nx, const double *logw_pred, const double *logw, const double *x,
                           const double *scale, double dt, double a, double *q_state)
{
    double *q0 = malloc((size_t)n * sizeof(double)), *q1 = malloc((size_t)n * sizeof(double));
    double s0 = 0.0, s1 = 0.0;
    double m0[8] = {0.0}, m1[8] = {0.0}, p0[8] = {0.0}, p1[8] = {0.0}, g[8];
    for (int64_t i = 0; i < n; i++) {
        q0[i] = exp(logw_pred[i]);
        q1[i] = exp(logw[i]);
        s0 += q0[i];
        s1 += q1[i];
    }
    for (int64_t i = 0; i < n; i++) {
        q0[i] = q0[i] / s0;
        q1[i] = q1[i] / s1;
        for (int64_t c = 0; c < nx; c++) {
            m0[c] += q0[i] * x[i * nx + c];
            m1[c] += q1[i] * x[i * nx + c];
        }
    }
    for (int64_t i = 0; i < n; i++) {
        for (int64_t c = 0; c < nx; c++) {
            const double d0 = x[i * nx + c] - m0[c], d1 = x[i * nx + c] - m1[c];
            p0[c] += q0[i] * (d0 * d0);
            p1[c] += q1[i] * (d1 * d1);
        }
    }
    free(q0);
    free(q1);
    for (int64_t c = 0; c < nx; c++) {
        const double dmc = m1[c] - m0[c];
        g[c] = (dmc * dmc - (p0[c] - p1[c])) / dt + scale[c] * scale[c] / dt;
        if (!isfinite(g[c]))
            return;
    }
    for (int64_t c = 0; c < nx; c++)
        q_state[c] = py_max(q_state[c] + a * (g[c] - q_state[c]), 0.0);
}

void mpf_walk_roll(int64_t n, double *k, const double *z, double c, double lo, double hi, double g, double *gain)
{
    for (int64_t i = 0; i < n; i++) {
        double ki = k[i] + c * z[i];
        if (ki < lo)
            ki = 2.0 * lo - ki;
        if (ki > hi)
            ki = 2.0 * hi - ki;
        ki = py_min(py_max(ki, lo), hi);
        k[i] = ki;
        gain[i] = ki * g + 1.0;
    }
}

void mpf_mixture_moments_chol(int64_t n, int64_t m, const double *logw, const double *e, const double *Lc,
                              const double *nu, const int64_t *cols, int64_t nk, double *out)
{
    double e2[MPF_MAX_DIM] = {0.0};
    for (int64_t k = 0; k < nk; k++) {
        out[k] = 0.0;
        out[nk + k] = 0.0;
    }
    for (int64_t i = 0; i < n; i++) {
        const double q = exp(logw[i]);
        const double scale = nu[i] / (nu[i] - 2.0);
        for (int64_t k = 0; k < nk; k++) {
            const int64_t j = cols[k];
            double s = 0.0;
            for (int64_t c = 0; c <= j; c++)
                s += Lc[(i * m + j) * m + c] * Lc[(i * m + j) * m + c];
            out[k] += q * e[i * m + j];
            e2[k] += q * e[i * m + j] * e[i * m + j];
            out[nk + k] += q * s * scale;
        }
    }
    for (int64_t k = 0; k < nk; k++)
        out[nk + k] += py_max(e2[k] - out[k] * out[k], 0.0);
}
