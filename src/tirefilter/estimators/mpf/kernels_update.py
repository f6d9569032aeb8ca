"""The second and third of the stiffness MPF's three compiled passes (`kernels` tells the whole
story): `resample_gate` (systematic resampling and the gate's moments) and `sample_update`
(the conditional draw of w, the bias update, the drift of the adaptive forgetting, the NiW
update with the projection, the moments of the estimate), with their helpers; and the per-particle
parts of the options: `match_state_noise` (the state noise from the data) and `walk_roll`
(the roll gradient's walk)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tirefilter.stats.particles_numba import systematic_into

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True, error_model="numpy")  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls either (each wrapper, which unboxes every
# argument, was compiled and never called: docs/development.md, "How long `make test` takes");
# called from Python such a helper crashes the interpreter instead of raising (tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)


@njit(inline="always", **_JIT)
def _mean_std(q, k):
    """The mean and std of k (N,) under the weights q (N,) (`_roll_moments`)."""
    m = 0.0
    for i in range(k.shape[0]):
        m += q[i] * k[i]
    s = 0.0
    for i in range(k.shape[0]):
        d = k[i] - m
        s += q[i] * (d * d)
    return m, math.sqrt(max(s, 0.0))


# ---- small dense helpers ---------------------------------------------------------------------
@njit(inline="always", **_JIT)
def _chol(S, L, n):
    """`stats.linalg.chol` of the leading n x n block of S into L (same pivot floor)."""
    for j in range(n):
        Sjj = S[j, j]
        d = Sjj
        for k in range(j):
            d = d - L[j, k] * L[j, k]
        Ljj = math.sqrt(max(d, abs(Sjj) * 1e-14 + 1e-300))
        L[j, j] = Ljj
        for i in range(j + 1, n):
            acc = S[i, j]
            for k in range(j):
                acc = acc - L[i, k] * L[j, k]
            L[i, j] = acc * (1.0 / Ljj)
        for i in range(j):
            L[i, j] = 0.0


# ---- the second and third passes ------------------------------------------------------------
@njit(**_JIT_IN)
def _take_rows(src, dst, idx):
    """dst[i] = src[idx[i]] for C-contiguous (N, k) arrays (`resample_gate` passes the others as
    such views)."""
    n, k = src.shape
    for i in range(n):
        r = idx[i]
        for c in range(k):
            dst[i, c] = src[r, c]


@njit(**_JIT)
def resample_gate(logw, u0, resample, idx, own, spares, af, ar, full, pin_lo, pin_hi, qw):
    """Resampling and the gate's moments. `resample`: systematic resampling
    (`systematic_resample` with the caller's uniform u0) into idx, the particles' arrays
    own = (x, b, P, gamma, mu, Lam, nu, a, B, slip) (the statistics, the model's first stage a,
    B, slip) copied by idx into their spares (the same tuple; the caller swaps), logw uniform;
    else idx = 0..N-1. The arrays of the weighting (h, D, L11, ...) are not copied:
    `sample_update` reads them through idx.
    Returns the gate's moments over the (resampled) particles, E[vx] (full model), the std
    of vy and max(|E[af]|, |E[ar]|), and whether the posterior mean of mu lies at or beyond
    pin_lo or pin_hi (n_w,) in some component (the bound restart, `_pinned`). The weights
    exp(logw) after resampling go into qw (N,), for `sample_update`."""
    x, b, P, gamma, mu, Lam, nu, a, B, slip = own
    x2, b2, P2, gamma2, mu2, Lam2, nu2, a2, B2, slip2 = spares
    n = logw.shape[0]
    if resample:
        systematic_into(logw, u0, idx)
        # (each array as (N, k) rows: `_take_rows` compiles once, not once per number of dimensions)
        _take_rows(x, x2, idx)
        _take_rows(b, b2, idx)
        _take_rows(P.reshape((n, P.size // n)), P2.reshape((n, P2.size // n)), idx)
        _take_rows(gamma.reshape((n, 1)), gamma2.reshape((n, 1)), idx)
        _take_rows(mu, mu2, idx)
        _take_rows(Lam.reshape((n, Lam.size // n)), Lam2.reshape((n, Lam2.size // n)), idx)
        _take_rows(nu.reshape((n, 1)), nu2.reshape((n, 1)), idx)
        _take_rows(a, a2, idx)
        _take_rows(B.reshape((n, B.size // n)), B2.reshape((n, B2.size // n)), idx)
        for k in range(n):
            slip2[0, k] = slip[0, idx[k]]
            slip2[1, k] = slip[1, idx[k]]
        logw[:] = -math.log(n)
        xs = x2
    else:
        for k in range(n):
            idx[k] = k
        xs = x
    iv = 1 if full else 0
    mvx = mvy = maf = mar = 0.0
    for i in range(n):
        q = math.exp(logw[i])
        qw[i] = q
        mvx += q * xs[i, 0]
        mvy += q * xs[i, iv]
        maf += q * af[idx[i]]
        mar += q * ar[idx[i]]
    n_w = mu.shape[1]
    ms = mu2 if resample else mu
    mbar = np.zeros(n_w)
    s = 0.0
    for i in range(n):
        q = qw[i]
        d = xs[i, iv] - mvy
        s += q * (d * d)
        for j in range(n_w):
            mbar[j] += q * ms[i, j]
    pinned = False
    for j in range(n_w):
        if mbar[j] <= pin_lo[j] or mbar[j] >= pin_hi[j]:
            pinned = True
    return mvx, math.sqrt(max(s, 0.0)), max(abs(maf), abs(mar)), pinned


@njit(inline="always", **_JIT)
def _sample(idx, own, scratch, draws, w, learning, flags, qw, ub, n_w, nc):
    """Steps 3 and 5 of `sample_update` (its arguments, n_w and nc the sizes; ub (n_w,) the weighted
    lean of the drift, accumulated; infl (2,) of `draws` the std factors of the draw about mu_c,
    sqrt(c) of the surprise inflation (1 when off), of the draw that drives the state (into w) and
    of the one the drift and the statistics learn from (the same draw when they are equal))."""
    x, b, P, gamma, mu, Lam, nu, a, B, slip = own
    af, ar, h, D, L11, nu_w, L12, Lc, e, v, ll, ok = scratch
    z, chi, nu_draw, infl = draws
    bound, drift_a, lo, hi = learning
    use_mask, do_bias, active, drift = flags
    n = mu.shape[0]
    M = np.empty((max(nc, 1), n_w))
    ui = np.empty(n_w)
    Lw = np.empty((n, n_w, n_w))  # the conditional scale Lam_c, factorised in place
    learn = np.ones(n, np.bool_)
    for i in range(n):
        s = idx[i]
        # 3. the conditional Student-t and its draw: Lam_c and mu_c (into w), then each of
        # chol(Lam_c) and the draw in a short loop of its own over the particles (the CPU
        # overlaps the square roots and divisions of successive particles)
        for k in range(n_w):  # M = solve_lower(Lc, L21): column k of L21 is row k of L12
            for q in range(nc):
                acc = L12[s, k, q]
                for j in range(q):
                    acc = acc - Lc[s, q, j] * M[j, k]
                M[q, k] = acc / Lc[s, q, q]
        vv = 0.0
        for q in range(nc):
            vv += v[s, q] * v[s, q]
        for k in range(n_w):
            t = 0.0
            for q in range(nc):
                t += M[q, k] * v[s, q]
            w[i, k] = mu[i, k] + t
        sc = (nu_w[s] + vv) / (nu_w[s] + nc)
        for j in range(n_w):
            for k in range(j + 1):
                g = 0.0
                for q in range(nc):
                    g += M[q, j] * M[q, k]
                Lw[i, j, k] = sc * (L11[s, j, k] - g)
        if use_mask:  # the outlier mask: learn while |v_acc|^2 < bound
            learn[i] = vv < bound
    for i in range(n):  # chol(Lam_c) in place (`_chol`)
        for j in range(n_w):
            Sjj = Lw[i, j, j]
            d = Sjj
            for k in range(j):
                d = d - Lw[i, j, k] * Lw[i, j, k]
            Ljj = math.sqrt(max(d, abs(Sjj) * 1e-14 + 1e-300))
            Lw[i, j, j] = Ljj
            for r in range(j + 1, n_w):
                acc = Lw[i, r, j]
                for k in range(j):
                    acc = acc - Lw[i, r, k] * Lw[i, j, k]
                Lw[i, r, j] = acc * (1.0 / Ljj)
    same = infl[0] == infl[1]
    wl = w if same else np.empty_like(w)  # the draw the statistics learn from (surprise inflation)
    for i in range(n):  # the draw mu_c + chol(Lam_c) z sqrt(nu_draw / chi), times infl (surprise inflation)
        f0 = math.sqrt(nu_draw[i] / chi[i])
        f, fl = f0 * infl[0], f0 * infl[1]
        for j in range(n_w):
            t = 0.0
            for k in range(j + 1):
                t += Lw[i, j, k] * z[i, k]
            if not same:
                wl[i, j] = w[i, j] + t * fl
            w[i, j] = w[i, j] + t * f
    # 5. the drift of the adaptive forgetting (u = chol(L11)^-1 (w - mu), before the update: chol(L11) in
    # place of Lam_c's factor, then the solve), then the NiW update and the projection, each in a loop of its own
    for i in range(n if active and drift else 0):
        s = idx[i]
        for j in range(n_w):
            Sjj = L11[s, j, j]
            d = Sjj
            for k in range(j):
                d = d - Lw[i, j, k] * Lw[i, j, k]
            Ljj = math.sqrt(max(d, abs(Sjj) * 1e-14 + 1e-300))
            Lw[i, j, j] = Ljj
            for r in range(j + 1, n_w):
                acc = L11[s, r, j]
                for k in range(j):
                    acc = acc - Lw[i, r, k] * Lw[i, j, k]
                Lw[i, r, j] = acc * (1.0 / Ljj)
    for i in range(n if active and drift else 0):
        for j in range(n_w):
            acc = wl[i, j] - mu[i, j]
            for k in range(j):
                acc = acc - Lw[i, j, k] * ui[k]
            ui[j] = acc / Lw[i, j, j]
        q_i = qw[i]
        for j in range(n_w):
            ub[j] += q_i * ui[j]
    for i in range(n if active else 0):
        if not learn[i]:
            for j in range(n_w):
                mu[i, j] = min(max(mu[i, j], lo[j]), hi[j])
            continue
        g0 = gamma[i]
        g_new = g0 / (1.0 + g0)
        inv = 1.0 + g0
        for j in range(n_w):
            zj = wl[i, j] - mu[i, j]
            for k in range(n_w):
                Lam[i, j, k] = Lam[i, j, k] + zj * (wl[i, k] - mu[i, k]) / inv
        for j in range(n_w):
            m = mu[i, j] + g_new * (wl[i, j] - mu[i, j])
            mu[i, j] = min(max(m, lo[j]), hi[j])
        gamma[i] = g_new
        nu[i] = nu[i] + 1.0


@njit(**_JIT_IN)
def _bias(idx, own, scratch, R, avail, y, n_w, na, mch, every):
    """Step 4 of `sample_update` (its arguments; n_w, na, mch the sizes, `every`: avail = 0..m-1, every
    channel there): the bias Kalman update of eq. (30) per particle, in three short loops over the
    particles (the CPU overlaps the chains of square roots and divisions of successive particles):
    the innovation and its scale S, the factorisation of S in place, the gain and the update of b and P."""
    x, b, P, gamma, mu, Lam, nu, a, B, slip = own
    af, ar, h, D, L11, nu_w, L12, Lc, e, v, ll, ok = scratch
    n = mu.shape[0]
    nb = max(na, 1)
    Sb = np.empty((n, nb, nb))  # S, then its factor in place
    inn = np.empty((n, nb))
    DE = np.empty((nb, n_w))
    Kt = np.empty((nb, mch))
    Pn = np.empty((mch, mch))
    for i in range(n):
        s = idx[i]
        # 4. bias, eq. (30), with the predicted statistics: S = P_aa + R_aa + D_a E[Sigma] D_a^T and the innovation
        den = nu[i] - n_w - 1.0
        for q in range(na):
            cq = q if every else avail[q]
            for k in range(n_w):
                t = 0.0
                for j in range(n_w):
                    t += D[s, cq, j] * (Lam[i, j, k] / den)
                DE[q, k] = t
        for q in range(na):
            cq = q if every else avail[q]
            for q2 in range(q + 1):  # (the lower triangle: all the factorisation reads)
                c2 = q2 if every else avail[q2]
                t = 0.0
                for k in range(n_w):
                    t += DE[q, k] * D[s, c2, k]
                Sb[i, q, q2] = P[i, cq, c2] + R[cq, c2] + t
        for q in range(na):
            ch = q if every else avail[q]
            t = 0.0
            for j in range(n_w):
                t += D[s, ch, j] * mu[i, j]
            inn[i, q] = y[ch] - h[s, ch] - t - b[i, ch]
    for i in range(n):  # chol(S) in place (`_chol`)
        for j in range(na):
            Sjj = Sb[i, j, j]
            d = Sjj
            for k in range(j):
                d = d - Sb[i, j, k] * Sb[i, j, k]
            Ljj = math.sqrt(max(d, abs(Sjj) * 1e-14 + 1e-300))
            Sb[i, j, j] = Ljj
            for r in range(j + 1, na):
                acc = Sb[i, r, j]
                for k in range(j):
                    acc = acc - Sb[i, r, k] * Sb[i, j, k]
                Sb[i, r, j] = acc * (1.0 / Ljj)
    for i in range(n):
        for c in range(mch):  # Kt[:, c] = S^-1 P[a, c]
            for q in range(na):
                acc = P[i, q if every else avail[q], c]
                for j in range(q):
                    acc = acc - Sb[i, q, j] * Kt[j, c]
                Kt[q, c] = acc / Sb[i, q, q]
            for q in range(na - 1, -1, -1):
                acc = Kt[q, c]
                for j in range(q + 1, na):
                    acc = acc - Sb[i, j, q] * Kt[j, c]
                Kt[q, c] = acc / Sb[i, q, q]
        for c in range(mch):
            t = 0.0
            for q in range(na):
                t += Kt[q, c] * inn[i, q]
            b[i, c] = b[i, c] + t
        for c in range(mch):  # Pn = P - P_{:,a} K^T (from the old P), then 0.5 (Pn + Pn^T)
            for c2 in range(mch):
                t = 0.0
                for q in range(na):
                    t += P[i, q if every else avail[q], c] * Kt[q, c2]
                Pn[c, c2] = P[i, c, c2] - t
        for c in range(mch):
            for c2 in range(mch):
                P[i, c, c2] = 0.5 * (Pn[c, c2] + Pn[c2, c])


LANES = 32  # particles of a block of `_bias_lanes` (eight AVX2 vectors of float64)


@njit(**_JIT_IN)
def _bias_lanes(idx, own, scratch, R, y, n_w, m):
    """`_bias` with every channel there (avail = 0..m-1) in blocks of LANES particles, particles in the
    inner, contiguous dimension of the block's arrays: each step of the update below is a loop over the
    lanes that the compiler runs in SIMD registers (the same operations in the same order per particle as
    `_bias`, bit for bit; the gathers from and scatters to the particles' rows stay scalar)."""
    x, b, P, gamma, mu, Lam, nu, a, B, slip = own
    af, ar, h, D, L11, nu_w, L12, Lc, e, v, ll, ok = scratch
    n = mu.shape[0]
    L = LANES
    den = np.empty(L)
    Dl = np.empty((m, n_w, L))
    Laml = np.empty((n_w, n_w, L))
    DE = np.empty((m, n_w, L))
    S = np.empty((m, m, L))
    inn = np.empty((m, L))
    Kt = np.empty((m, m, L))
    Pl = np.empty((m, m, L))
    Pn = np.empty((m, m, L))
    mul = np.empty((n_w, L))
    inv = np.empty(L)
    for b0 in range(0, n, L):
        W = min(L, n - b0)
        for w in range(W):  # gather
            i = b0 + w
            s = idx[i]
            den[w] = nu[i] - n_w - 1.0
            for q in range(m):
                for j in range(n_w):
                    Dl[q, j, w] = D[s, q, j]
                for c in range(m):
                    Pl[q, c, w] = P[i, q, c]
            for j in range(n_w):
                mul[j, w] = mu[i, j]
                for k in range(n_w):
                    Laml[j, k, w] = Lam[i, j, k]
        # DE = D E[Sigma] (E[Sigma] = Lam / den), S = P + R + DE D^T (lower triangle), the innovation
        for q in range(m):
            for k in range(n_w):
                for w in range(W):
                    DE[q, k, w] = 0.0
                for j in range(n_w):
                    for w in range(W):
                        DE[q, k, w] += Dl[q, j, w] * (Laml[j, k, w] / den[w])
        for q in range(m):
            for q2 in range(q + 1):
                for w in range(W):
                    inv[w] = 0.0
                for k in range(n_w):
                    for w in range(W):
                        inv[w] += DE[q, k, w] * Dl[q2, k, w]
                r = R[q, q2]
                for w in range(W):
                    S[q, q2, w] = Pl[q, q2, w] + r + inv[w]
        for q in range(m):
            for w in range(W):
                inv[w] = 0.0
            for j in range(n_w):
                for w in range(W):
                    inv[w] += Dl[q, j, w] * mul[j, w]
            for w in range(W):
                inn[q, w] = y[q] - h[idx[b0 + w], q] - inv[w] - b[b0 + w, q]
        # chol(S) in place (`_chol`)
        for j in range(m):
            for w in range(W):
                Sjj = S[j, j, w]
                d = Sjj
                for k in range(j):
                    d = d - S[j, k, w] * S[j, k, w]
                Ljj = math.sqrt(max(d, abs(Sjj) * 1e-14 + 1e-300))
                S[j, j, w] = Ljj
                inv[w] = 1.0 / Ljj
            for r in range(j + 1, m):
                for w in range(W):
                    acc = S[r, j, w]
                    for k in range(j):
                        acc = acc - S[r, k, w] * S[j, k, w]
                    S[r, j, w] = acc * inv[w]
        # Kt[:, c] = S^-1 P[:, c]
        for c in range(m):
            for q in range(m):
                for w in range(W):
                    acc = Pl[q, c, w]
                    for j in range(q):
                        acc = acc - S[q, j, w] * Kt[j, c, w]
                    Kt[q, c, w] = acc / S[q, q, w]
            for q in range(m - 1, -1, -1):
                for w in range(W):
                    acc = Kt[q, c, w]
                    for j in range(q + 1, m):
                        acc = acc - S[j, q, w] * Kt[j, c, w]
                    Kt[q, c, w] = acc / S[q, q, w]
        # b += K innovation, P := sym(P - P_{:,a} K^T)
        for c in range(m):
            for w in range(W):
                inv[w] = 0.0
            for q in range(m):
                for w in range(W):
                    inv[w] += Kt[q, c, w] * inn[q, w]
            for w in range(W):
                b[b0 + w, c] = b[b0 + w, c] + inv[w]
            for c2 in range(m):
                for w in range(W):
                    inv[w] = 0.0
                for q in range(m):
                    for w in range(W):
                        inv[w] += Pl[q, c, w] * Kt[q, c2, w]
                for w in range(W):
                    Pn[c, c2, w] = Pl[c, c2, w] - inv[w]
        for w in range(W):
            i = b0 + w
            for c in range(m):
                for c2 in range(m):
                    P[i, c, c2] = 0.5 * (Pn[c, c2, w] + Pn[c2, c, w])


@njit(**_JIT)
def sample_update(idx, own, scratch, draws, w, obs, learning, flags, nc_, out, sizes):
    """Steps 3-5 of `StiffnessMPF.step`, in place, on the workspace of `compiled._MPFWork`:
      own = (x, b, P, gamma, mu, Lam, nu, a, B, slip) as `resample_gate` left them (read and written);
      scratch = (af, ar, h, D, L11, nu_w, L12, Lc, e, v, ll, ok) of `predict_weigh` (read, by idx);
      draws = (z, chi, nu_draw, infl), the caller's random numbers and the draw's std factors;
      w (N, n_w) written; obs = (R, avail, y); learning = (bound, drift_a, lo, hi);
      flags = (use_mask, do_bias, active, drift); nc_ the accelerometer channels;
      out = (drift_state, mom, qw, k): the drift statistic (updated), the moments (written), the weights (read),
      the roll gradient k (N,) of each particle (read; shape (0,) where it is not estimated).
    Per particle i (its weighting arrays h, D, L11, nu_w, L12, Lc, v at row idx[i], the ancestor
    when resampled):
    - w_i (into w) from the conditional of w given the first nc (accelerometer) residuals,
      eq. (39)-(41) (`t_conditional` with `L22_chol`, `x2_white`): M = Lc^-1 L21,
      mu_c = mu + M^T v, Lam_c = (nu~ + v^T v) / (nu~ + nc) (L11 - M^T M), and `t_sample`'s
      draw mu_c + chol(Lam_c) z sqrt(nu_draw / chi) with the caller's z (N, n_w), chi (N,), its
      spread about mu_c times infl[0] (sqrt(c) of the surprise inflation, derivations, "Surprise inflation"; 1: off),
      and the statistics' update and the drift from the same draw with infl[1] in its place;
    - the outlier mask (`use_mask`): learn while |v_acc|^2 < bound;
    - the bias update (`_bias_update`, eq. (30), `do_bias`): S = P_aa + R_aa + D_a E[Sigma] D_a^T,
      K^T = S^-1 P_{a,:}, b += K (y_a - h_a - D_a mu - b_a), P -= P_{:,a} K^T, symmetrised;
    - gate open (`active`): the whitened lean chol(L11)^-1 (w_i - mu_i) of `_track_drift`
      (`drift`), then `NiW.update` (eq. (19)) and the projection of mu onto [lo, hi] (Sec. V).
    Then `_track_drift`'s smoothing of the weighted mean lean into drift_state (n_w,) with
    the factor drift_a, and `_estimate`'s moments after the update into the rows of mom
    (7, >= max(nx, n_w, m)): x mean, x std, mean of mu, posterior variance of the mean,
    sigma^2 of eq. (27b), bias mean, and E[v^Y r] in mom[6, 0]. Returns the drift statistic z' of
    `_track_drift`, NaN
    when not computed (or when the lean is not finite: the reference then keeps its state).
    The weights exp(logw) are read from qw (N,), as `resample_gate` left them. Returns besides the mean and
    the std of k under them (`_roll_moments`; NaN, NaN without k)
    `sizes` as in `predict_weigh`: 3 dimensions the full model with both accelerometers (n_w = 3,
    nc = 2), 2 the lateral one (n_w = 2, nc = 1), 1 any (n_w = mu.shape[1], the given nc)."""
    x, b, P, gamma, mu, Lam, nu, a, B, slip = own
    af, ar, h, D, L11, nu_w, L12, Lc, e, v, ll, ok = scratch
    R, avail, y = obs
    use_mask, do_bias, active, drift = flags
    bound, drift_a, lo, hi = learning
    drift_state, mom, qw, k_roll = out
    if sizes.ndim == 3:
        if mu.shape[1] != 3 or nc_ != 2 or avail.shape[0] != 3 or b.shape[1] != 3:
            raise ValueError("sample_update with SIZES_FULL: n_w = na = m = 3, nc = 2 only")
        n_w, nc, na, mch = 3, 2, 3, 3
    elif sizes.ndim == 2:
        if mu.shape[1] != 2 or nc_ != 1 or avail.shape[0] != 2 or b.shape[1] != 2:
            raise ValueError("sample_update with SIZES_LATERAL: n_w = na = m = 2, nc = 1 only")
        n_w, nc, na, mch = 2, 1, 2, 2
    else:
        n_w, nc, na, mch = mu.shape[1], nc_, avail.shape[0], b.shape[1]
    n = mu.shape[0]
    ub = np.zeros(n_w)
    if do_bias:  # (first: it reads the statistics before their update and writes only b, P)
        if sizes.ndim > 1:  # every channel: in lanes
            _bias_lanes(idx, own, scratch, R, y, n_w, mch)
        else:
            _bias(idx, own, scratch, R, avail, y, n_w, na, mch, False)
    # 3. and 5.
    _sample(idx, own, scratch, draws, w, learning, flags, qw, ub, n_w, nc)
    zd = math.nan
    if active and drift:
        finite = True
        for j in range(n_w):
            if not math.isfinite(ub[j]):
                finite = False
        if finite:
            dd = 0.0
            for j in range(n_w):
                drift_state[j] = drift_state[j] + drift_a * (ub[j] - drift_state[j])
                dd += drift_state[j] * drift_state[j]
            zd = dd * (2.0 - drift_a) / (drift_a * n_w)
    _moments(qw, x, gamma, mu, Lam, nu, b, mom)
    if k_roll.shape[0] == 0:
        return zd, math.nan, math.nan
    km, ks = _mean_std(qw, k_roll)
    return zd, km, ks


@njit(**_JIT)
def estimate_moments(logw, x, gamma, mu, Lam, nu, b, mom):
    """`_estimate`'s sums into the rows of mom (7, >= max(nx, n_w, m)): x mean and std, the
    mean of mu, the posterior variance of the mean (gamma E[Sigma] plus the spread of the
    particle means), eq. (27b) sigma^2, bias mean; mom[6, 0] E[v^Y r] (the last two state components' product)."""
    q = np.empty(logw.shape[0])
    for i in range(logw.shape[0]):
        q[i] = math.exp(logw[i])
    _moments(q, x, gamma, mu, Lam, nu, b, mom)


@njit(**_JIT_IN)
def _moments(q, x, gamma, mu, Lam, nu, b, mom):
    """`estimate_moments` with the weights q = exp(logw) (N,) given."""
    n, nx = x.shape
    n_w = mu.shape[1]
    mch = b.shape[1]
    mom[:] = 0.0
    xm, xs, mbar, vm, s2, bm = mom[0], mom[1], mom[2], mom[3], mom[4], mom[5]
    vyr = 0.0  # E[v^Y r] (the wheel-speed filter's drive at the next sample, `_filter_wheels`)
    spread = np.zeros(n_w)
    for i in range(n):
        for c in range(nx):
            xm[c] += q[i] * x[i, c]
        for j in range(n_w):
            mbar[j] += q[i] * mu[i, j]
        for c in range(mch):
            bm[c] += q[i] * b[i, c]
        vyr += q[i] * (x[i, nx - 2] * x[i, nx - 1])
    mom[6, 0] = vyr
    for i in range(n):
        for c in range(nx):
            d = x[i, c] - xm[c]
            xs[c] += q[i] * d * d
        den = nu[i] - n_w - 1.0
        for j in range(n_w):
            d = mu[i, j] - mbar[j]
            spread[j] += q[i] * d * d
            es = Lam[i, j, j] / den
            vm[j] += q[i] * (gamma[i] * es)
            s2[j] += q[i] * es
    for c in range(nx):
        xs[c] = math.sqrt(max(xs[c], 0.0))
    for j in range(n_w):
        vm[j] += spread[j]
        s2[j] += spread[j]


# ---- the per-particle parts of the adaptive options (one call each, in place of numpy's dozen) ------
@njit(**_JIT)
def match_state_noise(logw_pred, logw, x, scale, dt, a, q_state):
    """`_match_state_noise` (derivations, "State noise from the data"): the means m-, m+ and spreads P-, P+
    (nx,) of x (N, nx) under the predictive weights exp(logw_pred) and the weights exp(logw), each
    normalised by its sum; g = ((m+ - m-)^2 - (P- - P+)) / dt + scale^2 / dt with `scale` (nx,) the
    state noise's std over the step; when g is finite, q_state (nx,) := max(q_state + a (g - q_state), 0)."""
    n, nx = x.shape
    q0 = np.empty(n)
    q1 = np.empty(n)
    s0 = s1 = 0.0
    for i in range(n):
        q0[i] = math.exp(logw_pred[i])
        q1[i] = math.exp(logw[i])
        s0 += q0[i]
        s1 += q1[i]
    m0 = np.zeros(nx)
    m1 = np.zeros(nx)
    for i in range(n):
        q0[i] = q0[i] / s0
        q1[i] = q1[i] / s1
        for c in range(nx):
            m0[c] += q0[i] * x[i, c]
            m1[c] += q1[i] * x[i, c]
    p0 = np.zeros(nx)
    p1 = np.zeros(nx)
    for i in range(n):
        for c in range(nx):
            d0 = x[i, c] - m0[c]
            d1 = x[i, c] - m1[c]
            p0[c] += q0[i] * (d0 * d0)
            p1[c] += q1[i] * (d1 * d1)
    g = np.empty(nx)
    for c in range(nx):
        dm = m1[c] - m0[c]
        g[c] = (dm * dm - (p0[c] - p1[c])) / dt + scale[c] * scale[c] / dt
        if not math.isfinite(g[c]):
            return
    for c in range(nx):
        q_state[c] = max(q_state[c] + a * (g[c] - q_state[c]), 0.0)


@njit(**_JIT)
def walk_roll(k, z, c, lo, hi, g, gain):
    """`_walk_roll` in place: k (N,) := k + c z (the caller's normals z (N,), c = roll_gradient_rw sqrt(dt)),
    reflected at lo and hi and clipped to [lo, hi]; and the roll gain 1 + k g per particle into gain (N,)."""
    for i in range(k.shape[0]):
        ki = k[i] + c * z[i]
        if ki < lo:
            ki = 2.0 * lo - ki
        if ki > hi:
            ki = 2.0 * hi - ki
        ki = min(max(ki, lo), hi)
        k[i] = ki
        gain[i] = ki * g + 1.0
