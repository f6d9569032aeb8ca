/* The stiffness MPF's per-particle work in C99: the C twin of the numba kernels of
 * estimators/mpf/kernels_weigh.py, kernels_update.py and vehicle/single_track_numba.py, entry point
 * for entry point, the same expressions in the same order (the results equal the numba kernels' bit for
 * bit; tests/test_kernels.py). The Python side (estimators/mpf/native.py) builds this library on first
 * use, draws the random numbers and passes them in, as it does for the numba kernels.
 *
 * Layout: every array C-contiguous float64 (int64 for indices, uint8 for flags), particles on the
 * leading axis as in the numpy reference: x (N, nx), b (N, m), P (N, m, m), gamma (N,), mu (N, n_w),
 * Lam (N, n_w, n_w), nu (N,), a (N, 3), B (N, 3, n_w), slip (2, N); the weighting's h, e, v (N, m),
 * D (N, m, n_w), L11 (N, n_w, n_w), L12 (N, n_w, m), Lc (N, m, m). n_w, m <= MPF_MAX_DIM. */
#ifndef TIREFILTER_MPF_CORE_H
#define TIREFILTER_MPF_CORE_H

#include <stdint.h>

#define MPF_MAX_DIM 4

/* the particles' own arrays (compiled._MPFWork.OWN), resampled together */
typedef struct {
    double *x, *b, *P, *gamma, *mu, *Lam, *nu, *a, *B, *slip;
} mpf_own;

/* the weighting's per-particle arrays (compiled._MPFWork's scratch) */
typedef struct {
    double *af, *ar, *h, *D, *L11, *nu_w, *L12, *Lc, *e, *v, *ll;
    uint8_t *ok;
} mpf_scratch;

/* the model's arrays: vp (13,), jw (2,), c_floor (2,), R (m, m), q (m,) the bias's random walk, gain (N,)
 * the roll gain, load_gain (N,), relaxed (2, N) the relaxed slip angles (NULL: no relaxation) */
typedef struct {
    double *vp, *jw, *c_floor, *R, *q, *gain, *load_gain, *relaxed;
} mpf_model;

/* the sizes: particles, state, stiffness parameters, channels */
typedef struct {
    int64_t n, nx, n_w, m;
} mpf_dims;

/* kernels_weigh.predict_weigh. scalars = (dt, max_step, lam, nu_min, beta, yaw_max, gate_speed);
 * flags = (heun, interval, bias_on, forget, full, rear_drive, want_nis, propagate, weigh); avail (na,);
 * noise (N, nx) or NULL, redraw (N,) or NULL. out = (innovation, ESS, count, nu~ common). */
void mpf_predict_weigh(const mpf_dims *dm, const mpf_own *own, const mpf_scratch *sc, const double *u_prev,
                       const double *uk, const double *y, const int64_t *avail, int64_t na, const double *w_prev,
                       double *logw, const double *noise, const double *noise_scale, const double *redraw,
                       const mpf_model *md, const double *scalars, const int32_t *flags, int64_t nc, double *out);

/* kernels_update.resample_gate; out = (E[vx], std vy, max |E[alpha]|, pinned) */
void mpf_resample_gate(const mpf_dims *dm, double *logw, double u0, int32_t resample, int64_t *idx,
                       const mpf_own *own, const mpf_own *spares, const double *af, const double *ar, int32_t full,
                       const double *pin_lo, const double *pin_hi, double *qw, double *out);

/* kernels_update.sample_update. draws: z (N, n_w), chi (N,), nu_draw (N,), infl (2,); obs: R, avail (na,),
 * y; learning = (bound, drift_a) and lo, hi (n_w,); flags = (use_mask, do_bias, active, drift);
 * drift_state (n_w,), mom (7, mom_cols), qw (N,), k_roll (N,) or NULL. out = (zd, k mean, k std). */
void mpf_sample_update(const mpf_dims *dm, const int64_t *idx, const mpf_own *own, const mpf_scratch *sc,
                       const double *z, const double *chi, const double *nu_draw, const double *infl, double *w,
                       const double *R, const int64_t *avail, int64_t na, const double *y, double bound,
                       double drift_a, const double *lo, const double *hi, const int32_t *flags, int64_t nc,
                       double *drift_state, double *mom, int64_t mom_cols, const double *qw, const double *k_roll,
                       double *out);

/* kernels_update.estimate_moments */
void mpf_estimate_moments(const mpf_dims *dm, const double *logw, const double *x, const double *gamma,
                          const double *mu, const double *Lam, const double *nu, const double *b, double *mom,
                          int64_t mom_cols);

/* kernels_update.match_state_noise */
void mpf_match_state_noise(int64_t n, int64_t nx, const double *logw_pred, const double *logw, const double *x,
                           const double *scale, double dt, double a, double *q_state);

/* predictive._mixture_moments_chol (the model check's one-step predictive): e (N, m), Lc (N, m, m),
 * cols (nk,) with nk <= MPF_MAX_DIM, out (2, nk) */
void mpf_mixture_moments_chol(int64_t n, int64_t m, const double *logw, const double *e, const double *Lc,
                              const double *nu, const int64_t *cols, int64_t nk, double *out);

/* kernels_update.walk_roll */
void mpf_walk_roll(int64_t n, double *k, const double *z, double c, double lo, double hi, double g, double *gain);

/* single_track_numba.accelerations: a (N, 3), B (N, 3, n_w), af, ar (N,), slip (2, N) written;
 * rel (2, N) or NULL */
void st_accelerations(int64_t n, int64_t nx, int64_t n_w, const double *x, const double *u, const double *vp,
                      int32_t full, int32_t rear_drive, const double *lg, const double *rel, double h, double *a,
                      double *B, double *af, double *ar, double *slip);

/* single_track_numba.propagate: out (N, nx) written; first = (a, B, slip); rel (2, N) or NULL */
void st_propagate(int64_t n, int64_t nx, int64_t n_w, const double *x, const double *u, const double *w,
                  const double *a, const double *B, const double *slip, double dt, double max_step, int32_t heun,
                  const double *vp, int32_t full, int32_t rear_drive, const double *lg, const double *rel,
                  double *out);

/* single_track_numba.slip_over_step (full model): a2 (N, 3), B2 (N, 3, n_w), af, ar (N,), out (2, N)
 * written; rel (2, N) or NULL */
void st_slip_over_step(int64_t n, int64_t n_w, const double *x, const double *u0, const double *u1,
                       const double *w, const double *a, const double *B, const double *slip, double dt,
                       const double *vp, const double *jw, const double *c_floor, int32_t rear_drive,
                       const double *lg, const double *rel, double *a2, double *B2, double *af, double *ar,
                       double *out);

#endif
