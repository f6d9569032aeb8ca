"""The compiled (numba, nopython, cached) twin of the estimators' single-track model of
`single_track` (`accelerations`, `propagate`, `slip_over_step`; the same expressions in the same
order, one particle at a time), and the per-particle scalar helpers that the stiffness MPF's
kernels (`estimators.mpf.kernels_weigh`) inline: `_model_t`, `_xdot_t` on scalars (the values
returned, not stored in scratch arrays and read back, so that LLVM keeps them in registers),
`_model1`, `_xdot1` into arrays, `_interval_slip1`, `_steer_consts`. The GP-SSM's kernels take
`slip_angles1`; the measurement map's `_measure_h`, `_measure_d` (`measurement` for all particles).
The packed parameters vp are `single_track.model_params`': (m, I, lf, lr, Cf_y, Cr_y, C_nom_fx,
C_nom_rx, R_w, undriven_share, imu_x, imu_y). Compiled on first use and cached beside this file.
Numba keys a kernel's cache by its own file only: after editing a helper here, delete the cache of
the kernels that inline it (`estimators/mpf/__pycache__/kernels_*`, `estimators/gpssm/__pycache__/kernels_particles.*`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True)  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls either (each wrapper, which unboxes every
# argument, was compiled and never called: docs/development.md, "How long `make test` takes");
# called from Python such a helper crashes the interpreter instead of raising (tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)


@njit(inline="always", **_JIT)
def slip_angles1(vx, vy, r, delta, lf, lr):
    """`single_track.slip_angles` on scalars: alpha_f = delta - atan((vy + lf r) / vx),
    alpha_r = -atan((vy - lr r) / vx)."""
    return delta - math.atan((vy + lf * r) / vx), -math.atan((vy - lr * r) / vx)


@njit(inline="always", **_JIT)
def _steer_consts(u0, vp):
    """The factors of `_model1` that depend only on the steering angle u0 and the vehicle:
    (cos, sin, 1 / m, 1 / I, cos / m, sin / m, lf sin / I, -sin / m, lf cos / I, -lr / I),
    each the reference's parenthesised expression, computed once per sample instead of once
    per particle and model evaluation (a division costs as much as the rest of a term)."""
    m, I, lf, lr = vp[0], vp[1], vp[2], vp[3]
    cd, sd = math.cos(u0), math.sin(u0)
    return (cd, sd, 1.0 / m, 1.0 / I, cd / m, sd / m, lf * sd / I, -sd / m, lf * cd / I, -lr / I)


@njit(inline="always", **_JIT)
def _model1(xs, us, k, held, sf, sr, out, vp, full, rear_drive, n_w, per):
    """One particle of `accelerations`: `_model_t` stored, out = (a (3,), B (3, n_w)) filled; returns (af,
    ar, lam_f, lam_r). xs, us, k, per as in `_model_t`; vp = (m, I, lf, lr, Cf_y, Cr_y, C_nom_fx,
    C_nom_rx, R_w, undriven_share, imu_x, imu_y, relaxation_length)."""
    a, B = out
    m = _model_t(xs, us, k, held, sf, sr, vp, full, rear_drive, per)
    a[0], a[1], a[2] = m[0], m[1], m[2]
    for i in range(3):
        for j in range(n_w):
            B[i, j] = m[3 + 3 * i + j]
    return m[12], m[13], m[14], m[15]


@njit(**_JIT_IN)
def _model_t(xs, us, k, held, sf, sr, vp, full, rear_drive, per):
    """One particle's model (`single_track.accelerations`) on scalars, returned, not stored: the
    propagation of the MPF's `predict_weigh` keeps the values in registers this way (stored in
    scratch arrays and read back, they cannot stay there: docs/performance.md, "Backends");
    `_model1` stores them for the other kernels. xs = (x0, x1, x2) the state ([vx, vy, r], or
    [vy, r, 0] in the lateral model), us = (u0, u1, u2, u3) the inputs [delta, omega_f, omega_r,
    vx], k = `_steer_consts(u0, vp)`; `held`: the wheel slip (sf, sr) held, not computed;
    vp = (m, I, lf, lr, Cf_y, Cr_y, C_nom_fx, C_nom_rx, R_w, undriven_share); per = (lg, pf, pr, hr) the
    particle's: lg its load-transfer gain on the lateral axle forces (`single_track.accelerations`'
    load_gain; 1.0: none), pf, pr its relaxed slip angles hr seconds earlier, which the slip angles relax
    from with the relaxation length vp[12] > 0 (`single_track.accelerations`' relax; hr < 0: none).
    Returns (a0, a1, a2, b00, b01, b02, b10, b11, b12, b20, b21, b22, af, ar, lam_f, lam_r), b_rc the
    entries of B (3, 3) in the full model; in the lateral model B is (3, 2): b_r0, b_r1, and b_r2 = 0."""
    lf, lr, Cfy, Cry, Cfx, Crx, Rw = vp[2], vp[3], vp[4], vp[5], vp[6], vp[7], vp[8]
    lg, pf, pr, hr = per
    s = vp[9]
    x0, x1, x2 = xs
    u0, u1, u2, u3 = us
    cd, sd, inv_m, inv_I, cd_m, sd_m, lf_sd_I, msd_m, lf_cd_I, mlr_I = k
    if full:
        vx, vy, r = x0, x1, x2
    else:
        vx, vy, r = u3, x0, x1
    inv_vx = 1.0 / max(vx, 1.0)
    af = u0 - (vy + lf * r) * inv_vx
    ar = (lr * r - vy) * inv_vx
    if hr >= 0.0 and vp[12] > 0.0:
        share = -math.expm1(-(max(vx, 1.0) * (hr / vp[12])))
        af = pf + share * (af - pf)
        ar = pr + share * (ar - pr)
    gf, gr = af * lg, ar * lg  # (the reference's sf, sr)
    Ffy, Fry = Cfy * gf, Cry * gr
    lam_f = lam_r = 0.0
    g0 = g1 = g2 = 0.0
    if full:
        if held:
            lam_f, lam_r = sf, sr
        else:
            wf, wr = Rw * u1, Rw * u2
            lam_f = (wf - vx) / max(max(abs(vx), abs(wf)), 1.0)
            lam_r = (wr - vx) / max(max(abs(vx), abs(wr)), 1.0)
        Ffx, Frx = Cfx * lam_f, Crx * lam_r
        if rear_drive:
            g0 = lam_r * inv_m + (s * lam_f) * cd_m
            g1 = (s * lam_f) * sd_m
            g2 = (s * lam_f) * lf_sd_I
        else:
            g0 = lam_f * cd_m + (s * lam_r) * inv_m
            g1 = lam_f * sd_m
            g2 = lam_f * lf_sd_I
        Fy_f = Ffy * cd + Ffx * sd
        aX = (Ffx * cd - Ffy * sd + Frx) * inv_m
    else:
        Fy_f = Ffy * cd
        aX = 0.0
    f0, f1, f2 = gf * msd_m, gf * cd_m, gf * lf_cd_I
    r1, r2 = gr * inv_m, gr * mlr_I
    a1 = (Fy_f + Fry) * inv_m
    a2 = (lf * Fy_f - lr * Fry) * inv_I
    if full:
        return aX, a1, a2, g0, f0, 0.0, g1, f1, r1, g2, f2, r2, af, ar, lam_f, lam_r
    return aX, a1, a2, f0, 0.0, 0.0, f1, r1, 0.0, f2, r2, 0.0, af, ar, lam_f, lam_r


@njit(**_JIT_IN)
def _xdot_t(x0, x1, x2, u3, m, w0, w1, w2, full):
    """`_xdot1` on scalars: m = (a0, a1, a2, the rows of B, ...) as `_model_t` returns it, w = (w0, w1,
    w2) (w2 unused in the lateral model, n_w = 2). Returns dx/dt (dx2 = 0 in the lateral model)."""
    s0 = 0.0 + m[3] * w0
    s1 = 0.0 + m[6] * w0
    s2 = 0.0 + m[9] * w0
    s0 = s0 + m[4] * w1
    s1 = s1 + m[7] * w1
    s2 = s2 + m[10] * w1
    if full:
        s0 = s0 + m[5] * w2
        s1 = s1 + m[8] * w2
        s2 = s2 + m[11] * w2
    acc0, acc1, acc2 = m[0] + s0, m[1] + s1, m[2] + s2
    if full:
        return x1 * x2 + acc0, acc1 - x0 * x2, acc2
    return acc1 - u3 * x1, acc2, 0.0


@njit(inline="always", **_JIT)
def _interval_slip1(xs, acc0, wx, slips, u0, u1, dt, vp, jw, c_floor, rear_drive):
    """One particle of `slip_over_step`: the front and rear wheel slip averaged over the step
    from the slips = (slip_f, slip_r) at t_k, xs = (vx, vy, r), acc0 = a^X + B_0 w at t_k, the
    driven axle's deviation wx, the inputs u0, u1 (4,) at t_k and t_k+1."""
    vx, vy, r = xs
    slip_f, slip_r = slips
    Rw, s, Cfx, Crx = vp[8], vp[9], vp[6], vp[7]
    vx1 = vx + dt * (vy * r + acc0)
    if rear_drive:
        c_f, c_r = Cfx + s * wx, Crx + wx
    else:
        c_f, c_r = Cfx + wx, Crx + s * wx
    out_f = out_r = 0.0
    for k in range(2):
        wr1 = Rw * u1[1 + k]
        slip1 = (wr1 - vx1) / max(max(abs(vx1), abs(wr1)), 1.0)
        C = max(c_f if k == 0 else c_r, c_floor[k])
        D = max(max(abs(vx), abs(Rw * u0[1 + k])), 1.0)
        tau = max(jw[k] * D / C, 1e-12)
        share = (tau / dt) * -math.expm1(-dt / tau)
        if k == 0:
            out_f = slip1 + (slip_f - slip1) * share
        else:
            out_r = slip1 + (slip_r - slip1) * share
    return out_f, out_r


@njit(**_JIT)
def slip_over_step(x, u0, u1, w, first, dt, vp, jw, c_floor, rear_drive, n_w, particle):
    """`single_track.slip_over_step` (full model): the first stage of the propagation from t_k
    to t_k + dt with the wheel slip averaged over the interval (derivations, "Wheel slip").

    x (N, 3) at t_k; u0, u1 (4,) the inputs at t_k and t_k+1; w (N, n_w) held over the step;
    first = (a (N, 3), B (N, 3, n_w), slip (2, N)) of `accelerations(x, u0)`; vp as in `_model1`; jw (2,) the
    front and rear spin inertia over R_w^2; c_floor (2,) the lowest axle stiffness in the time
    constant; particle = (lg (N,) the load-transfer gain per particle (`_model_t`), rel (2, N) the relaxed
    slip angles at x (shape (2, 0): none)). Returns (a, B, af, ar, slip) (new
    arrays) at x with the interval slip. The same
    per-particle arithmetic as the first stage in the MPF's `predict_weigh`; for the reference path and
    tests/test_kernels.py."""
    a, B, slip = first
    n = x.shape[0]
    k0 = _steer_consts(u0[0], vp)
    us = (u0[0], u0[1], u0[2], u0[3])
    a2 = np.empty((n, 3))
    B2 = np.empty((n, 3, n_w))
    af = np.empty(n)
    ar = np.empty(n)
    out = np.empty((2, n))
    lg, rel = particle
    relaxing = rel.shape[1] == n
    for i in range(n):
        pf, pr, hr = (rel[0, i], rel[1, i], 0.0) if relaxing else (0.0, 0.0, -1.0)
        acc0 = 0.0
        for j in range(n_w):
            acc0 += B[i, 0, j] * w[i, j]
        acc0 = a[i, 0] + acc0
        xs = (x[i, 0], x[i, 1], x[i, 2])
        out[0, i], out[1, i] = _interval_slip1(xs, acc0, w[i, 0], (slip[0, i], slip[1, i]), u0, u1, dt, vp, jw,
                                               c_floor, rear_drive)
        af[i], ar[i], _, _ = _model1(xs, us, k0, True, out[0, i], out[1, i], (a2[i], B2[i]), vp, True, rear_drive,
                                     n_w, (lg[i], pf, pr, hr))
    return a2, B2, af, ar, out


@njit(inline="always", **_JIT)
def _measure_h(a0, a1, a2, r, gain, ix, iy, lever):
    """One particle's h of `single_track.measurement` on scalars: (h^X, h^Y) from the accelerations
    (a0, a1, a2) = (a^X, a^Y, r') and the yaw rate r, the roll gain `gain`, the IMU at (ix, iy)
    (vp[10], vp[11]); `lever` False (the IMU at the centre of gravity): no lever-arm terms."""
    hx, hy = a0, gain * a1
    if lever:
        r2 = r * r
        hx = (a0 - iy * a2) - ix * r2
        hy = (hy + ix * a2) - iy * r2
    return hx, hy


@njit(inline="always", **_JIT)
def _measure_d(b0, b1, b2, gain, ix, iy, lever):
    """One column of d of `single_track.measurement` on scalars, from the column (b0, b1, b2) of B:
    (d^X, d^Y) = (b0 - iy b2, gain b1 + ix b2) (without the lever arm (b0, b1 gain))."""
    if lever:
        return b0 - iy * b2, b1 * gain + ix * b2
    return b0, b1 * gain


@njit(**_JIT)
def measurement(a, B, x, gain, vp, full, n_w):
    """`single_track.measurement(a, B, x, gain, full, vp)` for all particles, gain (N,) the roll
    gain per particle: h (N, m), d (N, m, n_w) by `_measure_h`, `_measure_d` (the per-particle
    arithmetic of the MPF's weighting, `kernels_weigh._weigh`)."""
    n, nx = x.shape
    m = 3 if full else 2
    ix, iy = vp[10], vp[11]
    lever = ix != 0.0 or iy != 0.0
    h = np.zeros((n, m))
    D = np.zeros((n, m, n_w))
    for i in range(n):
        r = x[i, nx - 1]
        hx, hy = _measure_h(a[i, 0], a[i, 1], a[i, 2], r, gain[i], ix, iy, lever)
        jy = 1 if full else 0
        if full:
            h[i, 0] = hx
        h[i, jy] = hy
        h[i, m - 1] = r
        for j in range(n_w):
            dx, dy = _measure_d(B[i, 0, j], B[i, 1, j], B[i, 2, j], gain[i], ix, iy, lever)
            if full:
                D[i, 0, j] = dx
            D[i, jy, j] = dy
    return h, D


@njit(inline="always", **_JIT)
def _xdot1(x, u3, a, B, w, out, full, n_w):
    s0 = s1 = s2 = 0.0
    for j in range(n_w):
        s0 += B[0, j] * w[j]
        s1 += B[1, j] * w[j]
        s2 += B[2, j] * w[j]
    acc0, acc1, acc2 = a[0] + s0, a[1] + s1, a[2] + s2
    if full:
        out[0] = x[1] * x[2] + acc0
        out[1] = acc1 - x[0] * x[2]
        out[2] = acc2
    else:
        out[0] = acc1 - u3 * x[1]
        out[1] = acc2


@njit(**_JIT)
def accelerations(x, u, vp, full, rear_drive, n_w, lg, rel, h):
    """`single_track.accelerations(x, u, load_gain=lg)` for all particles (lg (N,) the load-transfer gain
    per particle, ones: none; `relax=(rel, h)`, rel (2, N) the relaxed slip angles h seconds earlier, shape
    (2, 0): none): a (N, 3), B (N, 3, n_w), af, ar (N,),
    slip (2, N) (zeros in the lateral model, where the reference returns None). For the
    reference path's compiled model (the first sample, restarts, gaps) and the AUGPF."""
    n = x.shape[0]
    ku = _steer_consts(u[0], vp)
    us = (u[0], u[1], u[2], u[3])
    a = np.empty((n, 3))
    B = np.empty((n, 3, n_w))
    af = np.empty(n)
    ar = np.empty(n)
    slip = np.zeros((2, n))
    relaxing = rel.shape[1] == n
    for i in range(n):
        x2 = x[i, 2] if full else 0.0
        pf, pr, hr = (rel[0, i], rel[1, i], h) if relaxing else (0.0, 0.0, -1.0)
        af[i], ar[i], slip[0, i], slip[1, i] = _model1((x[i, 0], x[i, 1], x2), us, ku, False, 0.0, 0.0, (a[i], B[i]),
                                                       vp, full, rear_drive, n_w, (lg[i], pf, pr, hr))
    return a, B, af, ar, slip


@njit(**_JIT)
def propagate(x, u, w, first, dt, max_step, heun, vp, full, rear_drive, n_w, particle):
    """`single_track.propagate`: x_{k+1} from x_k (N, nx) with w (N, n_w) and particle = (lg (N,) the
    load-transfer gain, held; rel (2, N) the relaxed slip angles at x_k, shape (2, 0): none), the first
    stage first = (a, B, slip) evaluated at x_k; a step longer than max_step is split into equal
    sub-steps (the model re-evaluated, slip recomputed). The same loop as the propagation
    in the MPF's `predict_weigh`; for the reference path and the AUGPF."""
    a, B, slip = first
    n, nx = x.shape
    ku = _steer_consts(u[0], vp)
    us = (u[0], u[1], u[2], u[3])
    n_sub = max(1, math.ceil(dt / max_step - 1e-9))
    hs = dt / n_sub
    out = np.empty((n, nx))
    xi = np.empty(nx)
    x1 = np.empty(nx)
    k1 = np.empty(nx)
    k2 = np.empty(nx)
    ai = np.empty(3)
    Bi = np.empty((3, n_w))
    lg, rel = particle
    relaxing = rel.shape[1] == n
    for i in range(n):
        for c in range(nx):
            xi[c] = x[i, c]
        sf, sr = slip[0, i], slip[1, i]
        pf, pr = (rel[0, i], rel[1, i]) if relaxing else (0.0, 0.0)
        for s in range(n_sub):
            if s == 0:
                for c in range(3):
                    ai[c] = a[i, c]
                    for j in range(n_w):
                        Bi[c, j] = B[i, c, j]
            else:
                xs2 = xi[2] if full else 0.0
                _, _, sf, sr = _model1((xi[0], xi[1], xs2), us, ku, False, 0.0, 0.0, (ai, Bi), vp, full, rear_drive,
                                       n_w, (lg[i], pf, pr, s * hs if relaxing else -1.0))
            _xdot1(xi, u[3], ai, Bi, w[i], k1, full, n_w)
            if not heun:
                for c in range(nx):
                    xi[c] = xi[c] + hs * k1[c]
                continue
            for c in range(nx):
                x1[c] = xi[c] + hs * k1[c]
            xs2 = x1[2] if full else 0.0
            _model1((x1[0], x1[1], xs2), us, ku, full, sf, sr, (ai, Bi), vp, full, rear_drive, n_w,
                    (lg[i], pf, pr, (s + 1) * hs if relaxing else -1.0))
            _xdot1(x1, u[3], ai, Bi, w[i], k2, full, n_w)
            for c in range(nx):
                xi[c] = xi[c] + (0.5 * hs) * (k1[c] + k2[c])
        for c in range(nx):
            out[i, c] = xi[c]
    return out
