"""Compiled (numba, nopython, cached) kernels of the stiffness MPF's per-particle work, one
per stage of `StiffnessMPF.step` so that a change of the model maps onto one kernel:

  model       the accelerations a + B w of eq. (1)-(4) (`StiffnessMPF._model`)
  slip        the wheel slip averaged over the step interval, the first stage (`_slip_over_step`)
  propagate   eq. (9), Euler or Heun with w and the wheel slip held, sub-steps (`_propagate`)
  weights     h, d of eq. (12) and the Student-t log-likelihood of eq. (36) (step 2)
  normalise   log-sum-exp and the ESS (`normalize_log_weights`, `effective_sample_size`)
  sample      the conditional Student-t of eq. (39)-(41) and its draw (`t_conditional`, `t_sample`)
  bias        the per-particle Kalman update of eq. (30) (`_bias_update`)
  niw         NiW update (19) with the mask and the projection of Sec. V, forgetting (20)
  moments     the weighted means of the gate and of eq. (26)-(27) (`_estimate`)

The numpy methods of `StiffnessMPF` are the readable reference; each kernel computes the
same expressions in the same order, one particle at a time, and consumes random numbers
drawn by the caller with the reference's calls, so both backends follow the same path
(tests/test_kernels.py: equal to 1e-12 relative, full and lateral models, bias on and off,
resampling and restarts). Kernels compile on first use and are cached beside this file.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_JIT = dict(cache=True, nogil=True)


# ---- model and propagation -----------------------------------------------------------------
@njit(**_JIT)
def _model1(x0, x1, x2, u0, u1, u2, u3, held, sf, sr, a, B, vp, full, rear_drive, n_w):
    """One particle of `_model`: fills a (3,), B (3, n_w); returns (af, ar, lam_f, lam_r).
    vp = (m, I, lf, lr, Cf_y, Cr_y, C_nom_fx, C_nom_rx, R_w, undriven_share)."""
    m, I, lf, lr, Cfy, Cry, Cfx, Crx, Rw = vp[0], vp[1], vp[2], vp[3], vp[4], vp[5], vp[6], vp[7], vp[8]
    s = vp[9]
    if full:
        vx, vy, r = x0, x1, x2
    else:
        vx, vy, r = u3, x0, x1
    inv_vx = 1.0 / max(vx, 1.0)
    af = u0 - (vy + lf * r) * inv_vx
    ar = (lr * r - vy) * inv_vx
    cd, sd = math.cos(u0), math.sin(u0)
    Ffy, Fry = Cfy * af, Cry * ar
    for i in range(3):
        for j in range(n_w):
            B[i, j] = 0.0
    j = 0
    lam_f = lam_r = 0.0
    if full:
        if held:
            lam_f, lam_r = sf, sr
        else:
            wf, wr = Rw * u1, Rw * u2
            lam_f = (wf - vx) / max(max(abs(vx), abs(wf)), 1.0)
            lam_r = (wr - vx) / max(max(abs(vx), abs(wr)), 1.0)
        Ffx, Frx = Cfx * lam_f, Crx * lam_r
        if rear_drive:
            B[0, 0] = lam_r * (1.0 / m) + (s * lam_f) * (cd / m)
            B[1, 0] = (s * lam_f) * (sd / m)
            B[2, 0] = (s * lam_f) * (lf * sd / I)
        else:
            B[0, 0] = lam_f * (cd / m) + (s * lam_r) * (1.0 / m)
            B[1, 0] = lam_f * (sd / m)
            B[2, 0] = lam_f * (lf * sd / I)
        j = 1
        Fy_f = Ffy * cd + Ffx * sd
        aX = (Ffx * cd - Ffy * sd + Frx) * (1.0 / m)
    else:
        Fy_f = Ffy * cd
        aX = 0.0
    B[0, j] = af * (-sd / m)
    B[1, j] = af * (cd / m)
    B[2, j] = af * (lf * cd / I)
    B[1, j + 1] = ar * (1.0 / m)
    B[2, j + 1] = ar * (-lr / I)
    a[0] = aX
    a[1] = (Fy_f + Fry) * (1.0 / m)
    a[2] = (lf * Fy_f - lr * Fry) * (1.0 / I)
    return af, ar, lam_f, lam_r


@njit(**_JIT)
def model(x, u, vp, full, rear_drive, n_w):
    """`StiffnessMPF._model(x, u)` for all particles: a (N, 3), B (N, 3, n_w), af, ar (N,),
    slip (2, N) (zeros in the lateral model, where the reference returns None)."""
    n = x.shape[0]
    a = np.empty((n, 3))
    B = np.empty((n, 3, n_w))
    af = np.empty(n)
    ar = np.empty(n)
    slip = np.zeros((2, n))
    for i in range(n):
        x2 = x[i, 2] if full else 0.0
        af[i], ar[i], slip[0, i], slip[1, i] = _model1(x[i, 0], x[i, 1], x2, u[0], u[1], u[2], u[3], False, 0.0,
                                                       0.0, a[i], B[i], vp, full, rear_drive, n_w)
    return a, B, af, ar, slip


@njit(**_JIT)
def slip_over_step(x, u0, u1, w, a, B, slip, dt, vp, jw, c_floor, rear_drive, n_w):
    """`StiffnessMPF._slip_over_step` (full model): the first stage of the propagation from t_k
    to t_k + dt with the wheel slip averaged over the interval (derivations, Sec. 20).

    x (N, 3) at t_k; u0, u1 (4,) the inputs at t_k and t_k+1; w (N, n_w) held over the step;
    a (N, 3), B (N, 3, n_w), slip (2, N) of `model(x, u0)`; vp as in `_model1`; jw (2,) the
    front and rear spin inertia over R_w^2; c_floor (2,) the lowest axle stiffness in the time
    constant. Returns (a, B, af, ar, slip) (new arrays) at x with the interval slip."""
    n = x.shape[0]
    Rw, s, Cfx, Crx = vp[8], vp[9], vp[6], vp[7]
    a2 = np.empty((n, 3))
    B2 = np.empty((n, 3, n_w))
    af = np.empty(n)
    ar = np.empty(n)
    out = np.empty((2, n))
    cn = np.empty(2)
    for i in range(n):
        acc0 = 0.0
        for j in range(n_w):
            acc0 += B[i, 0, j] * w[i, j]
        acc0 = a[i, 0] + acc0
        vx = x[i, 0]
        vx1 = vx + dt * (x[i, 1] * x[i, 2] + acc0)
        wx = w[i, 0]
        if rear_drive:
            cn[0], cn[1] = Cfx + s * wx, Crx + wx
        else:
            cn[0], cn[1] = Cfx + wx, Crx + s * wx
        for k in range(2):
            wr1 = Rw * u1[1 + k]
            slip1 = (wr1 - vx1) / max(max(abs(vx1), abs(wr1)), 1.0)
            C = max(cn[k], c_floor[k])
            D = max(max(abs(vx), abs(Rw * u0[1 + k])), 1.0)
            tau = max(jw[k] * D / C, 1e-12)
            share = (tau / dt) * -math.expm1(-dt / tau)
            out[k, i] = slip1 + (slip[k, i] - slip1) * share
        af[i], ar[i], _, _ = _model1(x[i, 0], x[i, 1], x[i, 2], u0[0], u0[1], u0[2], u0[3], True, out[0, i],
                                     out[1, i], a2[i], B2[i], vp, True, rear_drive, n_w)
    return a2, B2, af, ar, out


@njit(**_JIT)
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
def propagate(x, u, w, a, B, slip, dt, max_step, heun, vp, full, rear_drive, n_w):
    """`StiffnessMPF._propagate`: x_{k+1} from x_k (N, nx) with w (N, n_w) held, the first
    stage (a, B, slip) evaluated at x_k by the measurement step; a step longer than
    max_step is split into equal sub-steps (the model re-evaluated, slip recomputed)."""
    n, nx = x.shape
    n_sub = max(1, math.ceil(dt / max_step - 1e-9))
    h = dt / n_sub
    out = np.empty((n, nx))
    xi = np.empty(nx)
    x1 = np.empty(nx)
    k1 = np.empty(nx)
    k2 = np.empty(nx)
    ai = np.empty(3)
    Bi = np.empty((3, n_w))
    for i in range(n):
        for c in range(nx):
            xi[c] = x[i, c]
        sf, sr = slip[0, i], slip[1, i]
        for s in range(n_sub):
            if s == 0:
                for c in range(3):
                    ai[c] = a[i, c]
                    for j in range(n_w):
                        Bi[c, j] = B[i, c, j]
            else:
                x2 = xi[2] if full else 0.0
                _, _, sf, sr = _model1(xi[0], xi[1], x2, u[0], u[1], u[2], u[3], False, 0.0, 0.0, ai, Bi, vp, full,
                                       rear_drive, n_w)
            _xdot1(xi, u[3], ai, Bi, w[i], k1, full, n_w)
            if not heun:
                for c in range(nx):
                    xi[c] = xi[c] + h * k1[c]
                continue
            for c in range(nx):
                x1[c] = xi[c] + h * k1[c]
            x2 = x1[2] if full else 0.0
            _model1(x1[0], x1[1], x2, u[0], u[1], u[2], u[3], full, sf, sr, ai, Bi, vp, full, rear_drive, n_w)
            _xdot1(x1, u[3], ai, Bi, w[i], k2, full, n_w)
            for c in range(nx):
                xi[c] = xi[c] + (0.5 * h) * (k1[c] + k2[c])
        for c in range(nx):
            out[i, c] = xi[c]
    return out


# ---- small dense helpers ---------------------------------------------------------------------
@njit(**_JIT)
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


# ---- weights (eq. (12), (36)) ------------------------------------------------------------------
@njit(**_JIT)
def weights(a, B, x, gamma, mu, Lam, nu, b, P, R, y, avail, bias_on, roll_gain, full, n_w):
    """Step 2 of `StiffnessMPF.step` for the available channels `avail` (indices into the
    model's channels): h, D of `_measurement`, the predictive L11 of the NiW (eq. (21)),
    L12 = (D_a L11)^T, S = D_a L11 D_a^T + (nu~ - 2) / nu~ (R + P)_aa, its factor Lc, the
    residual e = y_a - h_a - b_a - D_a mu and v = Lc^-1 e, and the Student-t log-likelihood
    (`t_logpdf_whitened`; when all particles share one nu~ its log-Gamma terms are computed
    once, as the reference does). Last: that common nu~, or 0 when the particles differ."""
    n = x.shape[0]
    mch = 3 if full else 2
    na = avail.shape[0]
    h = np.empty((n, mch))
    D = np.zeros((n, mch, n_w))
    L11 = np.empty((n, n_w, n_w))
    nu_w = np.empty(n)
    L12 = np.empty((n, n_w, na))
    Lc = np.zeros((n, na, na))
    e = np.empty((n, na))
    v = np.empty((n, na))
    ll = np.zeros(n)
    S = np.empty((na, na))
    DL = np.empty((na, n_w))
    p = float(na)
    cst = 0.0
    const_nu = nu[0] - n_w + 1.0 if n else 0.0
    for i in range(n):
        if nu[i] != nu[0]:
            const_nu = 0.0
            break
    if const_nu > 0:
        cst = math.lgamma(0.5 * (const_nu + p)) - math.lgamma(0.5 * const_nu) - 0.5 * p * math.log(const_nu * math.pi)
    for i in range(n):
        r = x[i, x.shape[1] - 1]
        if full:
            h[i, 0] = a[i, 0]
            h[i, 1] = roll_gain * a[i, 1]
            h[i, 2] = r
            for j in range(n_w):
                D[i, 0, j] = B[i, 0, j]
                D[i, 1, j] = B[i, 1, j] * roll_gain
        else:
            h[i, 0] = roll_gain * a[i, 1]
            h[i, 1] = r
            for j in range(n_w):
                D[i, 0, j] = roll_gain * B[i, 1, j]
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
        for q in range(na):
            for q2 in range(na):
                s = 0.0
                for k in range(n_w):
                    s += DL[q, k] * D[i, avail[q2], k]
                noise = R[avail[q], avail[q2]]
                if bias_on:
                    noise = noise + P[i, avail[q], avail[q2]]
                S[q, q2] = s + c * noise
        _chol(S, Lc[i], na)
        logdet = 0.0
        vv = 0.0
        for q in range(na):
            ch = avail[q]
            s = 0.0
            for j in range(n_w):
                s += D[i, ch, j] * mu[i, j]
            e[i, q] = y[ch] - (h[i, ch] + b[i, ch]) - s
            acc = e[i, q]
            for k in range(q):
                acc = acc - Lc[i, q, k] * v[i, k]
            v[i, q] = acc / Lc[i, q, q]
            vv += v[i, q] * v[i, q]
            logdet += math.log(Lc[i, q, q])
        logdet *= 2.0
        if const_nu > 0:
            cn, nn = cst, const_nu
        else:
            nn = dof
            cn = math.lgamma(0.5 * (nn + p)) - math.lgamma(0.5 * nn) - 0.5 * p * math.log(nn * math.pi)
        ll[i] = cn - 0.5 * logdet - 0.5 * (nn + p) * math.log1p(vv / nn)
    return h, D, L11, nu_w, L12, Lc, e, v, ll, const_nu


@njit(**_JIT)
def weighted_nis(logw, v, nu):
    """sum_i q_i |v_i|^2 (nu_i - 2) / (nu_i nc) for v (N, nc): the predictive-weighted normalised
    innovation of `StiffnessMPF._adapt_forgetting`."""
    n, nc = v.shape
    s = 0.0
    for i in range(n):
        vv = 0.0
        for q in range(nc):
            vv += v[i, q] * v[i, q]
        s += math.exp(logw[i]) * (vv * (nu[i] - 2.0) / (nu[i] * nc))
    return s


@njit(**_JIT)
def normalise(logw):
    """(normalised log-weights, ESS): `normalize_log_weights` then `effective_sample_size`."""
    n = logw.shape[0]
    out = np.empty(n)
    m = -np.inf
    for i in range(n):
        li = logw[i]
        if math.isnan(li):
            li = -np.inf
        out[i] = li
        if li > m:
            m = li
    if not math.isfinite(m):
        out[:] = -math.log(n)
        return out, float(n)
    s = 0.0
    for i in range(n):
        out[i] = out[i] - m
        s += math.exp(out[i])
    lse = math.log(s)
    s2 = 0.0
    for i in range(n):
        out[i] = out[i] - lse
        s2 += math.exp(2.0 * out[i])
    return out, 1.0 / s2


# ---- conditional sampling (eq. (39)-(41)) ---------------------------------------------------------
@njit(**_JIT)
def sample(mu, L11, L12, Lc, v, nu_w, nc, z, chi, nu_draw):
    """w ~ St(mu_c, Lam_c, nu~ + nc), the conditional of w given the first nc (accelerometer)
    residuals: M = Lc^-1 L21, mu_c = mu + M^T v, Lam_c = (nu~ + v^T v) / (nu~ + nc) (L11 - M^T M)
    (`t_conditional` with `L22_chol`, `x2_white`), then `t_sample`'s draw with the caller's
    standard normals z (N, n_w) and chi-square draws chi (N,) of nu_draw (N,) degrees."""
    n, n_w = mu.shape
    w = np.empty((n, n_w))
    M = np.empty((nc, n_w))
    Lam = np.empty((n_w, n_w))
    L = np.zeros((n_w, n_w))
    mc = np.empty(n_w)
    for i in range(n):
        for k in range(n_w):  # M = solve_lower(Lc, L21): column k of L21 is row k of L12
            for q in range(nc):
                acc = L12[i, k, q]
                for j in range(q):
                    acc = acc - Lc[i, q, j] * M[j, k]
                M[q, k] = acc / Lc[i, q, q]
        vv = 0.0
        for q in range(nc):
            vv += v[i, q] * v[i, q]
        for k in range(n_w):
            s = 0.0
            for q in range(nc):
                s += M[q, k] * v[i, q]
            mc[k] = mu[i, k] + s
        sc = (nu_w[i] + vv) / (nu_w[i] + nc)
        for j in range(n_w):
            for k in range(n_w):
                g = 0.0
                for q in range(nc):
                    g += M[q, j] * M[q, k]
                Lam[j, k] = sc * (L11[i, j, k] - g)
        _chol(Lam, L, n_w)
        f = math.sqrt(nu_draw[i] / chi[i])
        for j in range(n_w):
            s = 0.0
            for k in range(j + 1):
                s += L[j, k] * z[i, k]
            w[i, j] = mc[j] + s * f
    return w


# ---- bias (eq. (30)) ----------------------------------------------------------------------------
@njit(**_JIT)
def bias_update(b, P, R, D, avail, mu, Lam, nu, y, h):
    """In place, `_bias_update`: S = P_aa + R_aa + D_a E[Sigma] D_a^T, K^T = S^-1 P_{a,:},
    b += K (y_a - h_a - D_a mu - b_a), P -= P_{:,a} K^T, symmetrised."""
    n, mch = b.shape
    n_w = mu.shape[1]
    na = avail.shape[0]
    S = np.empty((na, na))
    Lc = np.zeros((na, na))
    Kt = np.empty((na, mch))
    DE = np.empty((na, n_w))
    innov = np.empty(na)
    Pn = np.empty((mch, mch))
    for i in range(n):
        den = nu[i] - n_w - 1.0
        for q in range(na):
            for k in range(n_w):
                s = 0.0
                for j in range(n_w):
                    s += D[i, avail[q], j] * (Lam[i, j, k] / den)
                DE[q, k] = s
        for q in range(na):
            for q2 in range(na):
                s = 0.0
                for k in range(n_w):
                    s += DE[q, k] * D[i, avail[q2], k]
                S[q, q2] = P[i, avail[q], avail[q2]] + R[avail[q], avail[q2]] + s
        _chol(S, Lc, na)
        for c in range(mch):  # Kt[:, c] = S^-1 P[a, c]
            for q in range(na):
                acc = P[i, avail[q], c]
                for j in range(q):
                    acc = acc - Lc[q, j] * Kt[j, c]
                Kt[q, c] = acc / Lc[q, q]
            for q in range(na - 1, -1, -1):
                acc = Kt[q, c]
                for j in range(q + 1, na):
                    acc = acc - Lc[j, q] * Kt[j, c]
                Kt[q, c] = acc / Lc[q, q]
        for q in range(na):
            ch = avail[q]
            s = 0.0
            for j in range(n_w):
                s += D[i, ch, j] * mu[i, j]
            innov[q] = y[ch] - h[i, ch] - s - b[i, ch]
        for c in range(mch):
            s = 0.0
            for q in range(na):
                s += Kt[q, c] * innov[q]
            b[i, c] = b[i, c] + s
        for c in range(mch):  # Pn = P - P_{:,a} K^T (from the old P), then 0.5 (Pn + Pn^T)
            for c2 in range(mch):
                s = 0.0
                for q in range(na):
                    s += P[i, avail[q], c] * Kt[q, c2]
                Pn[c, c2] = P[i, c, c2] - s
        for c in range(mch):
            for c2 in range(mch):
                P[i, c, c2] = 0.5 * (Pn[c, c2] + Pn[c2, c])


# ---- NiW (eq. (19), (20)) and the projection of Sec. V ----------------------------------------
@njit(**_JIT)
def niw_update(gamma, mu, Lam, nu, w, learn, use_mask, lo, hi):
    """In place, `NiW.update(w, mask)` then the clip of mu to [lo, hi]."""
    n, n_w = mu.shape
    for i in range(n):
        if use_mask and not learn[i]:
            for j in range(n_w):
                mu[i, j] = min(max(mu[i, j], lo[j]), hi[j])
            continue
        g = gamma[i]
        g_new = g / (1.0 + g)
        inv = 1.0 + g
        for j in range(n_w):
            zj = w[i, j] - mu[i, j]
            for k in range(n_w):
                Lam[i, j, k] = Lam[i, j, k] + zj * (w[i, k] - mu[i, k]) / inv
        for j in range(n_w):
            m = mu[i, j] + g_new * (w[i, j] - mu[i, j])
            mu[i, j] = min(max(m, lo[j]), hi[j])
        gamma[i] = g_new
        nu[i] = nu[i] + 1.0


@njit(**_JIT)
def niw_forget(gamma, Lam, nu, lam, nu_min):
    """In place, `NiW.forget(lam, nu_min)`."""
    n, n_w, _ = Lam.shape
    for i in range(n):
        f = max(lam, min(1.0, nu_min / nu[i])) if nu_min > 0 else lam
        gamma[i] = gamma[i] / f
        nu[i] = nu[i] * f
        for j in range(n_w):
            for k in range(n_w):
                Lam[i, j, k] = Lam[i, j, k] * f


# ---- weighted moments ---------------------------------------------------------------------------
@njit(**_JIT)
def gate_moments(logw, x, af, ar, full):
    """(E[vx] (full model), std of vy, max(|E[af]|, |E[ar]|)) under the weights exp(logw)."""
    n = x.shape[0]
    iv = 1 if full else 0
    mvx = mvy = maf = mar = 0.0
    for i in range(n):
        q = math.exp(logw[i])
        mvx += q * x[i, 0]
        mvy += q * x[i, iv]
        maf += q * af[i]
        mar += q * ar[i]
    s = 0.0
    for i in range(n):
        d = x[i, iv] - mvy
        s += math.exp(logw[i]) * (d * d)
    return mvx, math.sqrt(max(s, 0.0)), max(abs(maf), abs(mar))


@njit(**_JIT)
def estimate_moments(logw, x, gamma, mu, Lam, nu, b):
    """`_estimate`'s sums: x mean and std, the mean of mu, the posterior variance of the mean
    (gamma E[Sigma] plus the spread of the particle means), eq. (27b) sigma^2, bias mean."""
    n, nx = x.shape
    n_w = mu.shape[1]
    mch = b.shape[1]
    xm = np.zeros(nx)
    xs = np.zeros(nx)
    mbar = np.zeros(n_w)
    spread = np.zeros(n_w)
    vm = np.zeros(n_w)
    s2 = np.zeros(n_w)
    bm = np.zeros(mch)
    q = np.empty(n)
    for i in range(n):
        q[i] = math.exp(logw[i])
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
    return xm, xs, mbar, vm, s2, bm


@njit(**_JIT)
def plausible(x, vx_lateral, full, beta, yaw_max, gate_speed):
    """`StiffnessMPF._plausible`'s test per particle: (ok (N,) bool, how many are ok)."""
    n = x.shape[0]
    ok = np.empty(n, np.bool_)
    count = 0
    for i in range(n):
        vx = x[i, 0] if full else vx_lateral
        vy, r = x[i, x.shape[1] - 2], x[i, x.shape[1] - 1]
        ok[i] = abs(vy) <= beta * max(abs(vx), gate_speed) and abs(r) <= yaw_max
        count += ok[i]
    return ok, count
