"""The first of the stiffness MPF's three compiled passes (`kernels` tells the whole story):
`predict_weigh`, steps 1 and 2 of the step (propagation, bias prediction, forgetting, the
model at x_k, plausibility, the Student-t weights, log-sum-exp and the ESS), with its helpers."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tirefilter.vehicle.single_track_numba import (_interval_slip1, _measure_d, _measure_h, _model_t, _steer_consts,
                                                   _xdot_t)

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True)  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls either (each wrapper, which unboxes every
# argument, was compiled and never called: docs/development.md, "How long `make test` takes");
# called from Python such a helper crashes the interpreter instead of raising (tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)
# the last argument of `predict_weigh` and `sample_update`: its number of dimensions picks the sizes
SIZES_FULL = np.empty((0, 0, 0))  # the full model with every channel: n_w = 3, na = 3, nc = 2
SIZES_LATERAL = np.empty((0, 0))  # the lateral model with every channel: n_w = 2, na = 2, nc = 1
SIZES_ANY = np.empty(0)  # the sizes from the arrays (a missing sample)


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
def _weigh(own, scratch, y, avail, R, gain, vp, full, bias_on, n_w, na):
    """Step 2 of `predict_weigh` (its arguments, n_w and na the sizes; gain (N,) the roll gain per
    particle, vp the model's parameters with the IMU's lever arm): per particle h, D, nu~ (nu_w),
    L11, L12, Lc = chol(S), e, v and the Student-t log-density ll, into `scratch`."""
    x, b, P, gamma, mu, Lam, nu, a, B, slip = own
    af, ar, h, D, L11, nu_w, L12, Lc, e, v, ll, ok = scratch
    n, nx = x.shape
    DL = np.empty((max(na, 1), n_w))
    p = float(na)
    last, cn = -1.0, 0.0
    ix, iy = vp[10], vp[11]  # the IMU's lever arm (`single_track.measurement`)
    lever = ix != 0.0 or iy != 0.0
    for i in range(n):
        # 2. h, D (`_measurement`: the model twin's `_measure_h`, `_measure_d`), the predictive (eq. (21))
        # and the weight (eq. (36))
        r = x[i, nx - 1]
        g = gain[i]
        hx, hy = _measure_h(a[i, 0], a[i, 1], a[i, 2], r, g, ix, iy, lever)
        if full:
            h[i, 0] = hx
            h[i, 1] = hy
            h[i, 2] = r
            for j in range(n_w):
                D[i, 0, j], D[i, 1, j] = _measure_d(B[i, 0, j], B[i, 1, j], B[i, 2, j], g, ix, iy, lever)
                D[i, 2, j] = 0.0
        else:
            h[i, 0] = hy
            h[i, 1] = r
            for j in range(n_w):
                D[i, 0, j] = _measure_d(B[i, 0, j], B[i, 1, j], B[i, 2, j], g, ix, iy, lever)[1]
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


# ---- the first pass ----------------------------------------------------------------------------
@njit(**_JIT)
def predict_weigh(own, scratch, inputs, model, scalars, flags, nc, sizes):
    """Steps 1 and 2 of `StiffnessMPF.step`, in place, on the workspace of `compiled._MPFWork`:
      own = (x, b, P, gamma, mu, Lam, nu, a, B, slip), the particles' own arrays (read and written);
      scratch = (af, ar, h, D, L11, nu_w, L12, Lc, e, v, ll, ok), the weighting's arrays (written);
      inputs = (u_prev, uk, y, avail, w_prev, logw, noise, noise_scale, redraw), this sample's
      (logw written); model = (vp, jw, c_floor, R, q, gain, load_gain), gain (N,) the roll gain per particle,
      load_gain (N,) the load-transfer gain on the lateral axle forces per particle (`_model_t`'s lg), relaxed
      (2, N) the relaxed slip angles at the last sample, overwritten by this sample's (shape (2, 0): no
      relaxation; `_model_t`'s pf, pr);
      scalars = (dt, max_step, lam, nu_min, beta, yaw_max, gate_speed); flags = (heun, interval, bias_on, forget,
      full, rear_drive, want_nis, propagate, weigh); nc the accelerometer channels among `avail`; `sizes` below.
    `propagate` False (the first sample) skips step 1 (propagation, bias prediction, forgetting);
    `weigh` False (the informed start) normalises the start's weights that the caller put in logw
    instead of adding the likelihood. Per particle: the first stage of the
    propagation, a (N, 3), B (N, 3, n_w), slip (2, N) kept from the last sample, or with
    `interval` (full model, slip_hold = "interval") the model at x with the wheel slip averaged
    over the step (`_slip_over_step`, jw, c_floor as there, towards the slip of uk); propagate
    x (N, nx) (`_propagate`: eq. (9), w_prev held, `max_step` sub-steps), add the state noise
    noise_scale * noise (the caller's normals; noise of shape (0, nx) when off; after a gap v^X
    first set to redraw (N,), the caller's draw around the wheel speeds, `_redraw_after_gap`; redraw
    of shape (0,) otherwise), predict the
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
    x, b, P, gamma, mu, Lam, nu, a, B, slip = own
    af, ar, h, D, L11, nu_w, L12, Lc, e, v, ll, ok = scratch
    u_prev, uk, y, avail, w_prev, logw, noise, noise_scale, redraw = inputs
    vp, jw, c_floor, R, q, gain, load_gain, relaxed = model
    dt, max_step, lam, nu_min, beta, yaw_max, gate_speed = scalars
    heun, interval, bias_on, forget, full, rear_drive, want_nis, propagate, weigh = flags
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
    up = (u_prev[0], u_prev[1], u_prev[2], u_prev[3])
    uu = (uk[0], uk[1], uk[2], uk[3])
    n_sub = max(1, math.ceil(dt / max_step - 1e-9))
    hs = dt / n_sub
    with_noise = noise.shape[0] > 0
    with_redraw = redraw.shape[0] > 0
    count = 0
    if interval and propagate:  # the slip over the step (`_slip_over_step`) into slip, in a short loop of its own
        for i in range(n):
            acc0 = 0.0
            for j in range(n_wp):
                acc0 += B[i, 0, j] * w_prev[i, j]
            acc0 = a[i, 0] + acc0
            slip[0, i], slip[1, i] = _interval_slip1((x[i, 0], x[i, 1], x[i, 2]), acc0, w_prev[i, 0],
                                                     (slip[0, i], slip[1, i]), u_prev, uk, dt, vp, jw, c_floor,
                                                     rear_drive)
    relaxing = relaxed.shape[1] == n
    h0 = 0.0 if relaxing else -1.0
    for i in range(n):
        lg = load_gain[i]
        pf, pr = (relaxed[0, i], relaxed[1, i]) if relaxing else (0.0, 0.0)
        x0 = x[i, 0]
        x1 = x[i, 1]
        x2 = x[i, 2] if full else 0.0
        if propagate:
            # 1. propagation (`_propagate`), the first stage from the last sample; the state, w and the
            # model's values as scalars (`_model_t`, `_xdot_t`: in registers, not through scratch arrays)
            w0 = w_prev[i, 0]
            w1 = w_prev[i, 1]
            w2 = w_prev[i, 2] if full else 0.0
            sf, sr = slip[0, i], slip[1, i]
            if interval:
                m = _model_t((x0, x1, x2), up, kp, True, sf, sr, vp, True, rear_drive, (lg, pf, pr, h0))
            elif full:
                m = (a[i, 0], a[i, 1], a[i, 2], B[i, 0, 0], B[i, 0, 1], B[i, 0, 2], B[i, 1, 0], B[i, 1, 1],
                     B[i, 1, 2], B[i, 2, 0], B[i, 2, 1], B[i, 2, 2], 0.0, 0.0, 0.0, 0.0)
            else:
                m = (a[i, 0], a[i, 1], a[i, 2], B[i, 0, 0], B[i, 0, 1], 0.0, B[i, 1, 0], B[i, 1, 1], 0.0, B[i, 2, 0],
                     B[i, 2, 1], 0.0, 0.0, 0.0, 0.0, 0.0)
            for s in range(n_sub):
                if s > 0:
                    m = _model_t((x0, x1, x2), up, kp, False, 0.0, 0.0, vp, full, rear_drive,
                                 (lg, pf, pr, s * hs if relaxing else -1.0))
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
                m = _model_t((y0, y1, y2), up, kp, full, sf, sr, vp, full, rear_drive,
                             (lg, pf, pr, (s + 1) * hs if relaxing else -1.0))
                k20, k21, k22 = _xdot_t(y0, y1, y2, u_prev[3], m, w0, w1, w2, full)
                x0 = x0 + (0.5 * hs) * (k10 + k20)
                x1 = x1 + (0.5 * hs) * (k11 + k21)
                if full:
                    x2 = x2 + (0.5 * hs) * (k12 + k22)
            if with_redraw:  # after a gap: v^X drawn again from the wheel speeds (`_redraw_after_gap`)
                x0 = redraw[i]
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
        m = _model_t((x0, x1, x2), uu, kk, False, 0.0, 0.0, vp, full, rear_drive,
                     (lg, pf, pr, dt if relaxing and propagate else -1.0))
        if relaxing:  # the relaxed slip angles at x_k, which the next propagation relaxes from
            relaxed[0, i], relaxed[1, i] = m[12], m[13]
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
    _weigh(own, scratch, y, avail, R, gain, vp, full, bias_on, n_w, na)
    innovation = math.nan
    if want_nis and nc:
        innovation = 0.0
        for i in range(n):
            vv = 0.0
            for q in range(nc):
                vv += v[i, q] * v[i, q]
            innovation += math.exp(logw[i]) * (vv * (nu_w[i] - 2.0) / (nu_w[i] * nc))
    if weigh:
        ess = _normalise_into(logw, ll) if na else -1.0
    else:  # the start's weights (`_informed_start`) in logw take the place of the likelihood's
        ess = _normalise_into(logw, np.zeros(n))
    return innovation, ess, count, _common_dof(nu_w)
