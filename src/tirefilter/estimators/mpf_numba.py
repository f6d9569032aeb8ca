"""Compiled (numba, nopython, cached) kernels of the stiffness MPF: `StiffnessMPF.step` for
every sample after the first (`StiffnessMPF._step_compiled`) in three passes over the
particles, each a loop of straight per-particle arithmetic on arrays the caller allocated
once and reuses from sample to sample:

  predict_weigh   step 1 and 2: the wheel slip over the step (derivations, "Wheel slip"),
                  propagation (eq. (9), Euler or Heun with w and the wheel slip held,
                  sub-steps), state noise, bias prediction (eq. (29)), forgetting
                  (eq. (20)), the model at x_k (eq. (1)-(4): a + B w, also the first stage of
                  the next propagation), plausibility, h, d of eq. (12), the predictive of the
                  NiW (eq. (21)) and the Student-t likelihood of eq. (36), the adaptive
                  forgetting's innovation, log-sum-exp and the ESS
  resample_gate   systematic resampling (ancestor indices and the copies of the particles'
                  arrays) and the weighted moments of the gate (Sec. V)
  sample_update   step 3-5: the conditional Student-t of eq. (39)-(41) and its draw, the
                  outlier mask, the bias Kalman update (eq. (30)), the drift of the adaptive
                  forgetting, the NiW update (eq. (19)) with the projection of Sec. V, and the
                  moments of eq. (26)-(27)

Why three passes and not one kernel per stage: at N = 500 a stage does a few hundred
nanoseconds of arithmetic per particle, and a dozen numba calls per sample with their
argument checks, fresh output arrays and re-reads of the model's outputs cost as much
(docs/performance.md, "Backends"). The per-particle code is written inline in the
loops: views of per-particle rows (x[i]) passed to helper functions cost a reference count
each and measured slower.

Inside a pass, the stages whose arithmetic is a chain of dependent square roots, divisions
and logarithms (the 3 x 3 Cholesky factorisations, the triangular solves, the Student-t
density, the wheel slip over the step) each run in a short loop of their own over the
particles, reading and writing the per-particle arrays: in one long loop body the CPU
cannot overlap one particle's chain with the next particle's, in a short one it does
(docs/performance.md, "Backends"). The weights (`_weigh`) and the
conditional draw with the learning (`_sample`) are inlined functions that the passes call
with the sizes (n_w, the available channels, the accelerometer channels) as constants in the
usual cases, the full model with every channel and the lateral model, so that the compiler
unrolls their small loops; other sizes (a missing sample) take the same code with the sizes
as variables. Each case is a signature of its own of the one entry point (`predict_weigh`, the
same for `sample_update`), picked by the number of dimensions of the empty array `sizes` that
the caller passes last (`SIZES_FULL`, `SIZES_LATERAL`, `SIZES_ANY`: the sizes are then constants
of the argument's type), so that a run compiles only the ones it calls, each once (one entry point per case calling the
pass's body with the sizes as literals compiled each case twice, its body and the entry point
that linked it in; inlining the body into the entry point instead took a third more compile:
docs/development.md, "How long `make test` takes").

In `predict_weigh` the propagation evaluates the model on scalars (`_model_t`, `_xdot_t` of the
model's compiled twin, `vehicle.single_track_numba`: the model's a, B and dx/dt returned, not
stored in scratch arrays and read back, so that LLVM keeps them in registers; 1.6-2x faster on
that stage, bit for bit the same numbers); the twin's other kernels keep `_model1`, which
computes the same expressions into arrays. The loops stay scalar
(one particle at a time): LLVM vectorises a loop across particles only over one array per
component and with numba's internal `noalias` flag, and the transposes into such arrays cost
more than the vector lanes save (docs/performance.md, "Backends").

The numpy methods of `StiffnessMPF` are the readable reference; the kernels compute the
same expressions in the same order, one particle at a time, and consume random numbers
drawn by the caller with the reference's generator calls, so both backends follow the same
path (tests/test_kernels.py: equal to 1e-12 relative, full and lateral models, bias on and
off, resampling, missing samples, sub-steps and restarts). The kernels compile on first use
and are cached beside this file.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tirefilter.stats.particles_numba import systematic_into
from tirefilter.vehicle.single_track_numba import _interval_slip1, _model_t, _steer_consts, _xdot_t

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True)  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls either (each wrapper, which unboxes every
# argument, was compiled and never called: docs/development.md, "How long `make test` takes");
# called from Python such a helper crashes the interpreter instead of raising (tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)
# the last argument of `predict_weigh` and `sample_update`: its number of dimensions picks the sizes
SIZES_FULL = np.empty((0, 0, 0))  # the full model with every channel: n_w = 3, na = 3, nc = 2
SIZES_LATERAL = np.empty((0, 0))  # the lateral model with every channel: n_w = 2, na = 2, nc = 1
SIZES_ANY = np.empty(0)  # the sizes from the arrays (a missing sample)


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




@njit(inline="always", **_JIT)
def _t_const(nn, p):
    """The log-Gamma terms of `t_logpdf_whitened` for nn dof in p dimensions."""
    return math.lgamma(0.5 * (nn + p)) - math.lgamma(0.5 * nn) - 0.5 * p * math.log(nn * math.pi)



@njit(**_JIT_IN)
def _common_dof(nu_w):
    """nu~ when every particle has it, else 0 (the reference's `_common`)."""
    n = nu_w.shape[0]
    if n == 0:
        return 0.0
    for i in range(n):
        if nu_w[i] != nu_w[0]:
            return 0.0
    return nu_w[0] if nu_w[0] > 0 else 0.0



@njit(**_JIT_IN)
def _normalise_into(logw, add):
    """logw := normalised (logw + add), NaN as -inf, uniform when all are -inf
    (`normalize_log_weights`); returns the ESS (`effective_sample_size`)."""
    n = logw.shape[0]
    out = logw
    m = -np.inf
    for i in range(n):
        li = logw[i] + add[i]
        if math.isnan(li):
            li = -np.inf
        out[i] = li
        if li > m:
            m = li
    if not math.isfinite(m):
        out[:] = -math.log(n)
        return float(n)
    s = 0.0
    for i in range(n):
        out[i] = out[i] - m
        s += math.exp(out[i])
    lse = math.log(s)
    s2 = 0.0
    for i in range(n):
        out[i] = out[i] - lse
        s2 += math.exp(2.0 * out[i])
    return 1.0 / s2



@njit(inline="always", **_JIT)
def _weigh(x, a, B, full, roll_gain, h, D, nu, nu_w, gamma, Lam, L11, avail, L12, R, bias_on, P, Lc, mu, y, b, e, v, ll,
           n_w, na):
    """Step 2 of `predict_weigh` (its arguments, n_w and na the sizes): per particle h, D, nu~ (nu_w),
    L11, L12, Lc = chol(S), e, v and the Student-t log-density ll."""
    n, nx = x.shape
    DL = np.empty((max(na, 1), n_w))
    p = float(na)
    last, cn = -1.0, 0.0
    for i in range(n):
        # 2. h, D (`_measurement`), the predictive (eq. (21)) and the weight (eq. (36))
        r = x[i, nx - 1]
        if full:
            h[i, 0] = a[i, 0]
            h[i, 1] = roll_gain * a[i, 1]
            h[i, 2] = r
            for j in range(n_w):
                D[i, 0, j] = B[i, 0, j]
                D[i, 1, j] = B[i, 1, j] * roll_gain
                D[i, 2, j] = 0.0
        else:
            h[i, 0] = roll_gain * a[i, 1]
            h[i, 1] = r
            for j in range(n_w):
                D[i, 0, j] = roll_gain * B[i, 1, j]
                D[i, 1, j] = 0.0
        dof = nu[i] - n_w + 1.0
        nu_w[i] = dof
        f = (1.0 + gamma[i]) / dof
        for j in range(n_w):
            for k in range(n_w):
                L11[i, j, k] = f * Lam[i, j, k]
        if na == 0:
            continue
        for q in range(na):
            ch = avail[q]
            for k in range(n_w):
                s = 0.0
                for j in range(n_w):
                    s += D[i, ch, j] * L11[i, j, k]
                DL[q, k] = s
                L12[i, k, q] = s
        c = (dof - 2.0) / dof
        for q in range(na):  # S (its lower triangle) into Lc[i], factorised there in place below
            for q2 in range(q + 1):
                s = 0.0
                for k in range(n_w):
                    s += DL[q, k] * D[i, avail[q2], k]
                noise_qq = R[avail[q], avail[q2]]
                if bias_on:
                    noise_qq = noise_qq + P[i, avail[q], avail[q2]]
                Lc[i, q, q2] = s + c * noise_qq
        for q in range(na):
            ch = avail[q]
            s = 0.0
            for j in range(n_w):
                s += D[i, ch, j] * mu[i, j]
            e[i, q] = y[ch] - (h[i, ch] + b[i, ch]) - s
    # Lc = chol(S) in place (`_chol`), then v = Lc^-1 e and the weight: each in its own short loop
    # over the particles, whose latency chains (square roots, divisions, logarithms) the CPU then
    # overlaps across particles (in one long loop body it cannot: docs/performance.md)
    for i in range(n if na else 0):
        for j in range(na):
            Sjj = Lc[i, j, j]
            d = Sjj
            for k in range(j):
                d = d - Lc[i, j, k] * Lc[i, j, k]
            Ljj = math.sqrt(max(d, abs(Sjj) * 1e-14 + 1e-300))
            Lc[i, j, j] = Ljj
            inv = 1.0 / Ljj
            for r in range(j + 1, na):
                acc = Lc[i, r, j]
                for k in range(j):
                    acc = acc - Lc[i, r, k] * Lc[i, j, k]
                Lc[i, r, j] = acc * inv
            for r in range(j):
                Lc[i, r, j] = 0.0
    for i in range(n if na else 0):
        dof = nu_w[i]
        logdet = 0.0
        vv = 0.0
        for q in range(na):
            acc = e[i, q]
            for k in range(q):
                acc = acc - Lc[i, q, k] * v[i, k]
            v[i, q] = acc / Lc[i, q, q]  # (a division, as `solve_lower`: the test's equality is to rounding)
            vv += v[i, q] * v[i, q]
            logdet += math.log(Lc[i, q, q])
        logdet *= 2.0
        if dof != last:
            last, cn = dof, _t_const(dof, p)
        ll[i] = cn - 0.5 * logdet - 0.5 * (dof + p) * math.log1p(vv / dof)


# ---- the three passes --------------------------------------------------------------------------
@njit(**_JIT)
def predict_weigh(x, u_prev, w_prev, a, B, af, ar, slip, dt, max_step, heun, interval, jw, c_floor, noise, noise_scale,
                  b, P, q, bias_on, forget, lam, nu_min, gamma, mu, Lam, nu, uk, y, avail, R, roll_gain, vp, full,
                  rear_drive, h, D, L11, nu_w, L12, Lc, e, v, ll, ok, logw, nc, want_nis, beta, yaw_max, gate_speed,
                  sizes):
    """Steps 1 and 2 of `StiffnessMPF.step`, in place. Per particle: the first stage of the
    propagation, a (N, 3), B (N, 3, n_w), slip (2, N) kept from the last sample, or with
    `interval` (full model, slip_hold = "interval") the model at x with the wheel slip averaged
    over the step (`_slip_over_step`, jw, c_floor as there, towards the slip of uk); propagate
    x (N, nx) (`_propagate`: eq. (9), w_prev held, `max_step` sub-steps), add the state noise
    noise_scale * noise (the caller's normals; noise of shape (0, nx) when off), predict the
    bias covariance P += diag(q dt) (eq. (29)), forget (`NiW.forget`, eq. (20), when
    `forget`), evaluate the model at x_k with uk (`_model`: a, B, af, ar, slip, the first
    stage of the next propagation), mark the plausible particles (`_plausible`: ok), and for
    the channels `avail` (indices into the model's m channels; y (m,)) weigh as `step` does:
    h, D of `_measurement`, L11 = (1 + gamma) / nu~ Lam, L12 = (D_a L11)^T,
    S = D_a L11 D_a^T + (nu~ - 2) / nu~ (R + P)_aa (P only with `bias_on`), Lc = chol(S),
    e = y_a - h_a - b_a - D_a mu, v = Lc^-1 e and ll, the Student-t log-density
    (`t_logpdf_whitened`; its log-Gamma terms once per distinct nu~).
    Then: the adaptive forgetting's innovation (`_adapt_forgetting`: the predictive-weighted
    normalised |v_acc|^2 over the first nc channels; NaN unless `want_nis` and nc) and
    logw := normalised logw + ll (when any channel is available).
    Returns (innovation, ESS (-1: no channel, logw unchanged), number of plausible
    particles, nu~ common to all particles or 0). The caller zeroes the weights of the
    implausible particles when some (not all) are, as `_plausible` does.
    `sizes` (an empty array) picks the sizes by its number of dimensions, a constant of its type:
    3 the full model with every channel (n_w = na = 3), 2 the lateral one with every channel
    (n_w = na = 2), 1 any (n_w = mu.shape[1], na = avail.shape[0]; a missing sample). Each is a
    signature of its own, compiled on its first call only, the first two with the sizes as
    constants, so that the compiler unrolls the small loops (`SIZES_FULL`, `SIZES_LATERAL`,
    `SIZES_ANY`)."""
    if sizes.ndim == 3:
        if mu.shape[1] != 3 or avail.shape[0] != 3:
            raise ValueError("predict_weigh with SIZES_FULL: n_w = na = 3 only")
        n_w, na = 3, 3
    elif sizes.ndim == 2:
        if mu.shape[1] != 2 or avail.shape[0] != 2:
            raise ValueError("predict_weigh with SIZES_LATERAL: n_w = na = 2 only")
        n_w, na = 2, 2
    else:
        n_w, na = mu.shape[1], avail.shape[0]
    n, nx = x.shape
    # the sizes as constants in the propagation too (taken from mu.shape[1] there, the step ran
    # slower: docs/development.md, "How long `make test` takes")
    n_wp = n_w
    mch = q.shape[0]
    kp = _steer_consts(u_prev[0], vp)  # (once per sample, not per particle)
    kk = _steer_consts(uk[0], vp)
    n_sub = max(1, math.ceil(dt / max_step - 1e-9))
    hs = dt / n_sub
    with_noise = noise.shape[0] > 0
    count = 0
    if interval:  # the slip over the step (`_slip_over_step`) into slip, in a short loop of its own
        for i in range(n):
            acc0 = 0.0
            for j in range(n_wp):
                acc0 += B[i, 0, j] * w_prev[i, j]
            acc0 = a[i, 0] + acc0
            slip[0, i], slip[1, i] = _interval_slip1(x[i, 0], x[i, 1], x[i, 2], acc0, w_prev[i, 0], slip[0, i],
                                                     slip[1, i], u_prev, uk, dt, vp, jw, c_floor, rear_drive)
    for i in range(n):
        # 1. propagation (`_propagate`), the first stage from the last sample; the state, w and the
        # model's values as scalars (`_model_t`, `_xdot_t`: in registers, not through scratch arrays)
        x0 = x[i, 0]
        x1 = x[i, 1]
        x2 = x[i, 2] if full else 0.0
        w0 = w_prev[i, 0]
        w1 = w_prev[i, 1]
        w2 = w_prev[i, 2] if full else 0.0
        sf, sr = slip[0, i], slip[1, i]
        if interval:
            m = _model_t(x0, x1, x2, u_prev[0], u_prev[1], u_prev[2], u_prev[3], kp, True, sf, sr, vp, True,
                         rear_drive)
        elif full:
            m = (a[i, 0], a[i, 1], a[i, 2], B[i, 0, 0], B[i, 0, 1], B[i, 0, 2], B[i, 1, 0], B[i, 1, 1], B[i, 1, 2],
                 B[i, 2, 0], B[i, 2, 1], B[i, 2, 2], 0.0, 0.0, 0.0, 0.0)
        else:
            m = (a[i, 0], a[i, 1], a[i, 2], B[i, 0, 0], B[i, 0, 1], 0.0, B[i, 1, 0], B[i, 1, 1], 0.0, B[i, 2, 0],
                 B[i, 2, 1], 0.0, 0.0, 0.0, 0.0, 0.0)
        for s in range(n_sub):
            if s > 0:
                m = _model_t(x0, x1, x2, u_prev[0], u_prev[1], u_prev[2], u_prev[3], kp, False, 0.0, 0.0, vp, full,
                             rear_drive)
                sf, sr = m[14], m[15]
            k10, k11, k12 = _xdot_t(x0, x1, x2, u_prev[3], m, w0, w1, w2, full)
            if not heun:
                x0 = x0 + hs * k10
                x1 = x1 + hs * k11
                if full:
                    x2 = x2 + hs * k12
                continue
            y0 = x0 + hs * k10
            y1 = x1 + hs * k11
            y2 = x2 + hs * k12 if full else 0.0
            m = _model_t(y0, y1, y2, u_prev[0], u_prev[1], u_prev[2], u_prev[3], kp, full, sf, sr, vp, full,
                         rear_drive)
            k20, k21, k22 = _xdot_t(y0, y1, y2, u_prev[3], m, w0, w1, w2, full)
            x0 = x0 + (0.5 * hs) * (k10 + k20)
            x1 = x1 + (0.5 * hs) * (k11 + k21)
            if full:
                x2 = x2 + (0.5 * hs) * (k12 + k22)
        if with_noise:
            x0 = x0 + noise_scale[0] * noise[i, 0]
            x1 = x1 + noise_scale[1] * noise[i, 1]
            if full:
                x2 = x2 + noise_scale[2] * noise[i, 2]
        x[i, 0] = x0
        x[i, 1] = x1
        if full:
            x[i, 2] = x2
        if bias_on:  # eq. (29)
            for c in range(mch):
                P[i, c, c] = P[i, c, c] + q[c] * dt
        if forget:  # eq. (20), `NiW.forget`
            f = max(lam, min(1.0, nu_min / nu[i])) if nu_min > 0 else lam
            gamma[i] = gamma[i] / f
            nu[i] = nu[i] * f
            for j in range(n_wp):
                for k in range(n_wp):
                    Lam[i, j, k] = Lam[i, j, k] * f
        # the model at x_k, u_k (`_model`) and the plausible region (`_plausible`)
        m = _model_t(x0, x1, x2, uk[0], uk[1], uk[2], uk[3], kk, False, 0.0, 0.0, vp, full, rear_drive)
        a[i, 0], a[i, 1], a[i, 2] = m[0], m[1], m[2]
        B[i, 0, 0], B[i, 0, 1] = m[3], m[4]
        B[i, 1, 0], B[i, 1, 1] = m[6], m[7]
        B[i, 2, 0], B[i, 2, 1] = m[9], m[10]
        if full:
            B[i, 0, 2], B[i, 1, 2], B[i, 2, 2] = m[5], m[8], m[11]
        af[i], ar[i], slip[0, i], slip[1, i] = m[12], m[13], m[14], m[15]
        vxp = x[i, 0] if full else uk[3]
        ok[i] = abs(x[i, nx - 2]) <= beta * max(abs(vxp), gate_speed) and abs(x[i, nx - 1]) <= yaw_max
        count += ok[i]
    # 2. the weights
    _weigh(x, a, B, full, roll_gain, h, D, nu, nu_w, gamma, Lam, L11, avail, L12, R, bias_on, P, Lc, mu, y, b, e, v,
           ll, n_w, na)
    innovation = math.nan
    if want_nis and nc:
        innovation = 0.0
        for i in range(n):
            vv = 0.0
            for q in range(nc):
                vv += v[i, q] * v[i, q]
            innovation += math.exp(logw[i]) * (vv * (nu_w[i] - 2.0) / (nu_w[i] * nc))
    ess = _normalise_into(logw, ll) if na else -1.0
    return innovation, ess, count, _common_dof(nu_w)


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
def resample_gate(logw, u0, resample, idx, x, b, P, gamma, mu, Lam, nu, a, B, slip, x2, b2, P2, gamma2, mu2, Lam2,
                  nu2, a2, B2, slip2, af, ar, full, pin_lo, pin_hi, qw):
    """Resampling and the gate's moments. `resample`: systematic resampling
    (`systematic_resample` with the caller's uniform u0) into idx, the particles' arrays
    (x, b, P, the statistics, the model's first stage a, B, slip) copied by idx into their
    spares (x2, ...; the caller swaps), logw uniform; else idx = 0..N-1. The arrays of the
    weighting (h, D, L11, ...) are not copied: `sample_update` reads them through idx.
    Returns the gate's moments over the (resampled) particles, E[vx] (full model), the std
    of vy and max(|E[af]|, |E[ar]|), and whether the posterior mean of mu lies at or beyond
    pin_lo or pin_hi (n_w,) in some component (the bound restart, `_pinned`). The weights
    exp(logw) after resampling go into qw (N,), for `sample_update`."""
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
def _sample(idx, gamma, mu, Lam, nu, L11, nu_w, L12, Lc, v, z, chi, nu_draw, w, use_mask, bound, active, drift,
            lo, hi, qw, ub, infl, n_w, nc):
    """Steps 3 and 5 of `sample_update` (its arguments, n_w and nc the sizes; ub (n_w,) the weighted
    lean of the drift, accumulated; infl (2,) the std factors of the draw about mu_c, sqrt(c) of the
    surprise inflation (1 when off), of the draw that drives the state (into w) and of the one the
    drift and the statistics learn from (the same draw when they are equal))."""
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


@njit(**_JIT)
def sample_update(idx, x, logw, gamma, mu, Lam, nu, b, P, h, D, L11, nu_w, L12, Lc, v, nc_, z, chi, nu_draw, w,
                  use_mask, bound, do_bias, R, avail, y, active, drift, drift_state, drift_a, lo, hi, mom, qw,
                  infl, sizes):
    """Steps 3-5 of `StiffnessMPF.step`, in place. Per particle i (its weighting arrays h, D,
    L11, nu_w, L12, Lc, v at row idx[i], the ancestor when resampled):
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
    (6, >= max(nx, n_w, m)): x mean, x std, mean of mu, posterior variance of the mean,
    sigma^2 of eq. (27b), bias mean. Returns the drift statistic z' of `_track_drift`, NaN
    when not computed (or when the lean is not finite: the reference then keeps its state).
    The weights exp(logw) are read from qw (N,), as `resample_gate` left them.
    `sizes` as in `predict_weigh`: 3 dimensions the full model with both accelerometers (n_w = 3,
    nc = 2), 2 the lateral one (n_w = 2, nc = 1), 1 any (n_w = mu.shape[1], the given nc)."""
    if sizes.ndim == 3:
        if mu.shape[1] != 3 or nc_ != 2:
            raise ValueError("sample_update with SIZES_FULL: n_w = 3, nc = 2 only")
        n_w, nc = 3, 2
    elif sizes.ndim == 2:
        if mu.shape[1] != 2 or nc_ != 1:
            raise ValueError("sample_update with SIZES_LATERAL: n_w = 2, nc = 1 only")
        n_w, nc = 2, 1
    else:
        n_w, nc = mu.shape[1], nc_
    n = mu.shape[0]
    na = avail.shape[0]
    mch = b.shape[1]
    nb = max(na, 1)
    S = np.empty((nb, nb))
    Lb = np.zeros((nb, nb))
    Kt = np.empty((nb, mch))
    DE = np.empty((nb, n_w))
    innov = np.empty(nb)
    Pn = np.empty((mch, mch))
    ub = np.zeros(n_w)
    for i in range(n if do_bias else 0):  # (first: it reads the statistics before their update and writes only b, P)
        s = idx[i]
        # 4. bias, eq. (30), with the predicted statistics
        den = nu[i] - n_w - 1.0
        for q in range(na):
            for k in range(n_w):
                t = 0.0
                for j in range(n_w):
                    t += D[s, avail[q], j] * (Lam[i, j, k] / den)
                DE[q, k] = t
        for q in range(na):
            for q2 in range(na):
                t = 0.0
                for k in range(n_w):
                    t += DE[q, k] * D[s, avail[q2], k]
                S[q, q2] = P[i, avail[q], avail[q2]] + R[avail[q], avail[q2]] + t
        _chol(S, Lb, na)
        for c in range(mch):  # Kt[:, c] = S^-1 P[a, c]
            for q in range(na):
                acc = P[i, avail[q], c]
                for j in range(q):
                    acc = acc - Lb[q, j] * Kt[j, c]
                Kt[q, c] = acc / Lb[q, q]
            for q in range(na - 1, -1, -1):
                acc = Kt[q, c]
                for j in range(q + 1, na):
                    acc = acc - Lb[j, q] * Kt[j, c]
                Kt[q, c] = acc / Lb[q, q]
        for q in range(na):
            ch = avail[q]
            t = 0.0
            for j in range(n_w):
                t += D[s, ch, j] * mu[i, j]
            innov[q] = y[ch] - h[s, ch] - t - b[i, ch]
        for c in range(mch):
            t = 0.0
            for q in range(na):
                t += Kt[q, c] * innov[q]
            b[i, c] = b[i, c] + t
        for c in range(mch):  # Pn = P - P_{:,a} K^T (from the old P), then 0.5 (Pn + Pn^T)
            for c2 in range(mch):
                t = 0.0
                for q in range(na):
                    t += P[i, avail[q], c] * Kt[q, c2]
                Pn[c, c2] = P[i, c, c2] - t
        for c in range(mch):
            for c2 in range(mch):
                P[i, c, c2] = 0.5 * (Pn[c, c2] + Pn[c2, c])
    # 3. and 5.
    _sample(idx, gamma, mu, Lam, nu, L11, nu_w, L12, Lc, v, z, chi, nu_draw, w, use_mask, bound, active, drift, lo,
            hi, qw, ub, infl, n_w, nc)
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
    return zd


@njit(**_JIT)
def estimate_moments(logw, x, gamma, mu, Lam, nu, b, mom):
    """`_estimate`'s sums into the rows of mom (6, >= max(nx, n_w, m)): x mean and std, the
    mean of mu, the posterior variance of the mean (gamma E[Sigma] plus the spread of the
    particle means), eq. (27b) sigma^2, bias mean."""
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
    spread = np.zeros(n_w)
    for i in range(n):
        for c in range(nx):
            xm[c] += q[i] * x[i, c]
        for j in range(n_w):
            mbar[j] += q[i] * mu[i, j]
        for c in range(mch):
            bm[c] += q[i] * b[i, c]
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
