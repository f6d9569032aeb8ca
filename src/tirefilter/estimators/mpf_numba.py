"""Compiled (numba, nopython, cached) kernels of the stiffness MPF's per-particle work, one
per stage of `StiffnessMPF.step` so that a change of the model maps onto one kernel:

  model       the accelerations a + B w of eq. (1)-(4) (`StiffnessMPF._model`)
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
    vp = (m, I, lf, lr, Cf_y, Cr_y, C_nom_fx, C_nom_rx, R_w)."""
    m, I, lf, lr, Cfy, Cry, Cfx, Crx, Rw = vp[0], vp[1], vp[2], vp[3], vp[4], vp[5], vp[6], vp[7], vp[8]
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
            B[0, 0] = lam_r * (1.0 / m)
        else:
            B[0, 0] = lam_f * (cd / m)
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
def _propagate1(xi, u, wi, ai, Bi, sf, sr, n_sub, h, heun, vp, full, rear_drive, n_w, x1, k1, k2):
    """One particle of `propagate`, xi (nx,) in place; ai (3,), Bi (3, n_w) hold the first
    stage at x_k (and are overwritten)."""
    nx = xi.shape[0]
    for s in range(n_sub):
        if s > 0:
            x2 = xi[2] if full else 0.0
            _, _, sf, sr = _model1(xi[0], xi[1], x2, u[0], u[1], u[2], u[3], False, 0.0, 0.0, ai, Bi, vp, full,
                                   rear_drive, n_w)
        _xdot1(xi, u[3], ai, Bi, wi, k1, full, n_w)
        if not heun:
            for c in range(nx):
                xi[c] = xi[c] + h * k1[c]
            continue
        for c in range(nx):
            x1[c] = xi[c] + h * k1[c]
        x2 = x1[2] if full else 0.0
        _model1(x1[0], x1[1], x2, u[0], u[1], u[2], u[3], full, sf, sr, ai, Bi, vp, full, rear_drive, n_w)
        _xdot1(x1, u[3], ai, Bi, wi, k2, full, n_w)
        for c in range(nx):
            xi[c] = xi[c] + (0.5 * h) * (k1[c] + k2[c])


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
        for c in range(3):
            ai[c] = a[i, c]
            for j in range(n_w):
                Bi[c, j] = B[i, c, j]
        _propagate1(xi, u, w[i], ai, Bi, slip[0, i], slip[1, i], n_sub, h, heun, vp, full, rear_drive, n_w, x1, k1,
                    k2)
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
def _weigh1(ai, Bi, xi, gamma_i, mu_i, Lam_i, nu_i, b_i, P_i, R, y, avail, bias_on, roll_gain, full, n_w, h, D, L11,
            L12, Lc, e, v, S, DL):
    """One particle of `weights`: fills its rows h (m,), D (m, n_w), L11 (n_w, n_w) and, for
    the na available channels, L12[:, :na], Lc[:na, :na], e[:na], v[:na]; returns
    (nu~, log det S, v^T v)."""
    na = avail.shape[0]
    r = xi[xi.shape[0] - 1]
    if full:
        h[0] = ai[0]
        h[1] = roll_gain * ai[1]
        h[2] = r
        for j in range(n_w):
            D[0, j] = Bi[0, j]
            D[1, j] = Bi[1, j] * roll_gain
            D[2, j] = 0.0
    else:
        h[0] = roll_gain * ai[1]
        h[1] = r
        for j in range(n_w):
            D[0, j] = roll_gain * Bi[1, j]
            D[1, j] = 0.0
    dof = nu_i - n_w + 1.0
    f = (1.0 + gamma_i) / dof
    for j in range(n_w):
        for k in range(n_w):
            L11[j, k] = f * Lam_i[j, k]
    if na == 0:
        return dof, 0.0, 0.0
    for q in range(na):
        ch = avail[q]
        for k in range(n_w):
            s = 0.0
            for j in range(n_w):
                s += D[ch, j] * L11[j, k]
            DL[q, k] = s
            L12[k, q] = s
    c = (dof - 2.0) / dof
    for q in range(na):
        for q2 in range(na):
            s = 0.0
            for k in range(n_w):
                s += DL[q, k] * D[avail[q2], k]
            noise = R[avail[q], avail[q2]]
            if bias_on:
                noise = noise + P_i[avail[q], avail[q2]]
            S[q, q2] = s + c * noise
    _chol(S, Lc, na)
    logdet = 0.0
    vv = 0.0
    for q in range(na):
        ch = avail[q]
        s = 0.0
        for j in range(n_w):
            s += D[ch, j] * mu_i[j]
        e[q] = y[ch] - (h[ch] + b_i[ch]) - s
        acc = e[q]
        for k in range(q):
            acc = acc - Lc[q, k] * v[k]
        v[q] = acc / Lc[q, q]
        vv += v[q] * v[q]
        logdet += math.log(Lc[q, q])
    return dof, 2.0 * logdet, vv


@njit(**_JIT)
def _t_const(nn, p):
    """The log-Gamma terms of `t_logpdf_whitened` for nn dof in p dimensions."""
    return math.lgamma(0.5 * (nn + p)) - math.lgamma(0.5 * nn) - 0.5 * p * math.log(nn * math.pi)


@njit(**_JIT)
def weights(a, B, x, gamma, mu, Lam, nu, b, P, R, y, avail, bias_on, roll_gain, full, n_w):
    """Step 2 of `StiffnessMPF.step` for the available channels `avail` (indices into the
    model's channels): h, D of `_measurement`, the predictive L11 of the NiW (eq. (21)),
    L12 = (D_a L11)^T, S = D_a L11 D_a^T + (nu~ - 2) / nu~ (R + P)_aa, its factor Lc, the
    residual e = y_a - h_a - b_a - D_a mu and v = Lc^-1 e, and the Student-t log-likelihood
    (`t_logpdf_whitened`; the log-Gamma terms are computed once per distinct nu~, which gives
    the same numbers as the reference's once-for-all when all particles share it). Last:
    that common nu~, or 0 when the particles differ."""
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
    last, cn = -1.0, 0.0
    for i in range(n):
        dof, logdet, vv = _weigh1(a[i], B[i], x[i], gamma[i], mu[i], Lam[i], nu[i], b[i], P[i], R, y, avail, bias_on,
                                  roll_gain, full, n_w, h[i], D[i], L11[i], L12[i], Lc[i], e[i], v[i], S, DL)
        nu_w[i] = dof
        if na == 0:
            continue
        if dof != last:
            last, cn = dof, _t_const(dof, p)
        ll[i] = cn - 0.5 * logdet - 0.5 * (dof + p) * math.log1p(vv / dof)
    return h, D, L11, nu_w, L12, Lc, e, v, ll, _common_dof(nu_w)


@njit(**_JIT)
def _common_dof(nu_w):
    """nu~ when every particle has it, else 0 (the reference's `_common`)."""
    n = nu_w.shape[0]
    if n == 0:
        return 0.0
    for i in range(n):
        if nu_w[i] != nu_w[0]:
            return 0.0
    return nu_w[0] if nu_w[0] > 0 else 0.0


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
def _sample1(mu_i, L11_i, L12_i, Lc_i, v_i, nu_w_i, nc, z_i, chi_i, nu_draw_i, w_i, M, Lam, L, mc, n_w):
    """One particle of `sample`, into w_i (n_w,)."""
    for k in range(n_w):  # M = solve_lower(Lc, L21): column k of L21 is row k of L12
        for q in range(nc):
            acc = L12_i[k, q]
            for j in range(q):
                acc = acc - Lc_i[q, j] * M[j, k]
            M[q, k] = acc / Lc_i[q, q]
    vv = 0.0
    for q in range(nc):
        vv += v_i[q] * v_i[q]
    for k in range(n_w):
        s = 0.0
        for q in range(nc):
            s += M[q, k] * v_i[q]
        mc[k] = mu_i[k] + s
    sc = (nu_w_i + vv) / (nu_w_i + nc)
    for j in range(n_w):
        for k in range(n_w):
            g = 0.0
            for q in range(nc):
                g += M[q, j] * M[q, k]
            Lam[j, k] = sc * (L11_i[j, k] - g)
    _chol(Lam, L, n_w)
    f = math.sqrt(nu_draw_i / chi_i)
    for j in range(n_w):
        s = 0.0
        for k in range(j + 1):
            s += L[j, k] * z_i[k]
        w_i[j] = mc[j] + s * f


@njit(**_JIT)
def sample(mu, L11, L12, Lc, v, nu_w, nc, z, chi, nu_draw):
    """w ~ St(mu_c, Lam_c, nu~ + nc), the conditional of w given the first nc (accelerometer)
    residuals: M = Lc^-1 L21, mu_c = mu + M^T v, Lam_c = (nu~ + v^T v) / (nu~ + nc) (L11 - M^T M)
    (`t_conditional` with `L22_chol`, `x2_white`), then `t_sample`'s draw with the caller's
    standard normals z (N, n_w) and chi-square draws chi (N,) of nu_draw (N,) degrees."""
    n, n_w = mu.shape
    w = np.empty((n, n_w))
    M = np.empty((max(nc, 1), n_w))
    Lam = np.empty((n_w, n_w))
    L = np.zeros((n_w, n_w))
    mc = np.empty(n_w)
    for i in range(n):
        _sample1(mu[i], L11[i], L12[i], Lc[i], v[i], nu_w[i], nc, z[i], chi[i], nu_draw[i], w[i], M, Lam, L, mc, n_w)
    return w


# ---- bias (eq. (30)) ----------------------------------------------------------------------------
@njit(**_JIT)
def _bias1(b_i, P_i, R, D_i, avail, mu_i, Lam_i, nu_i, y, h_i, S, Lc, Kt, DE, innov, Pn, n_w):
    """One particle of `bias_update`, b_i (m,) and P_i (m, m) in place."""
    mch = b_i.shape[0]
    na = avail.shape[0]
    den = nu_i - n_w - 1.0
    for q in range(na):
        for k in range(n_w):
            s = 0.0
            for j in range(n_w):
                s += D_i[avail[q], j] * (Lam_i[j, k] / den)
            DE[q, k] = s
    for q in range(na):
        for q2 in range(na):
            s = 0.0
            for k in range(n_w):
                s += DE[q, k] * D_i[avail[q2], k]
            S[q, q2] = P_i[avail[q], avail[q2]] + R[avail[q], avail[q2]] + s
    _chol(S, Lc, na)
    for c in range(mch):  # Kt[:, c] = S^-1 P[a, c]
        for q in range(na):
            acc = P_i[avail[q], c]
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
            s += D_i[ch, j] * mu_i[j]
        innov[q] = y[ch] - h_i[ch] - s - b_i[ch]
    for c in range(mch):
        s = 0.0
        for q in range(na):
            s += Kt[q, c] * innov[q]
        b_i[c] = b_i[c] + s
    for c in range(mch):  # Pn = P - P_{:,a} K^T (from the old P), then 0.5 (Pn + Pn^T)
        for c2 in range(mch):
            s = 0.0
            for q in range(na):
                s += P_i[avail[q], c] * Kt[q, c2]
            Pn[c, c2] = P_i[c, c2] - s
    for c in range(mch):
        for c2 in range(mch):
            P_i[c, c2] = 0.5 * (Pn[c, c2] + Pn[c2, c])


@njit(**_JIT)
def bias_update(b, P, R, D, avail, mu, Lam, nu, y, h):
    """In place, `_bias_update`: S = P_aa + R_aa + D_a E[Sigma] D_a^T, K^T = S^-1 P_{a,:},
    b += K (y_a - h_a - D_a mu - b_a), P -= P_{:,a} K^T, symmetrised."""
    n, mch = b.shape
    n_w = mu.shape[1]
    na = max(avail.shape[0], 1)
    S = np.empty((na, na))
    Lc = np.zeros((na, na))
    Kt = np.empty((na, mch))
    DE = np.empty((na, n_w))
    innov = np.empty(na)
    Pn = np.empty((mch, mch))
    for i in range(n):
        _bias1(b[i], P[i], R, D[i], avail, mu[i], Lam[i], nu[i], y, h[i], S, Lc, Kt, DE, innov, Pn, n_w)


# ---- NiW (eq. (19), (20)) and the projection of Sec. V ----------------------------------------
@njit(**_JIT)
def _niw1(gamma, mu_i, Lam_i, nu, i, w_i, learn_i, lo, hi):
    """One particle of `niw_update` (gamma, nu: the (N,) arrays, particle i)."""
    n_w = mu_i.shape[0]
    if not learn_i:
        for j in range(n_w):
            mu_i[j] = min(max(mu_i[j], lo[j]), hi[j])
        return
    g = gamma[i]
    g_new = g / (1.0 + g)
    inv = 1.0 + g
    for j in range(n_w):
        zj = w_i[j] - mu_i[j]
        for k in range(n_w):
            Lam_i[j, k] = Lam_i[j, k] + zj * (w_i[k] - mu_i[k]) / inv
    for j in range(n_w):
        m = mu_i[j] + g_new * (w_i[j] - mu_i[j])
        mu_i[j] = min(max(m, lo[j]), hi[j])
    gamma[i] = g_new
    nu[i] = nu[i] + 1.0


@njit(**_JIT)
def niw_update(gamma, mu, Lam, nu, w, learn, use_mask, lo, hi):
    """In place, `NiW.update(w, mask)` then the clip of mu to [lo, hi]."""
    n = mu.shape[0]
    for i in range(n):
        _niw1(gamma, mu[i], Lam[i], nu, i, w[i], learn[i] if use_mask else True, lo, hi)


@njit(**_JIT)
def _forget1(gamma, Lam_i, nu, i, lam, nu_min):
    """One particle of `niw_forget`."""
    n_w = Lam_i.shape[0]
    f = max(lam, min(1.0, nu_min / nu[i])) if nu_min > 0 else lam
    gamma[i] = gamma[i] / f
    nu[i] = nu[i] * f
    for j in range(n_w):
        for k in range(n_w):
            Lam_i[j, k] = Lam_i[j, k] * f


@njit(**_JIT)
def niw_forget(gamma, Lam, nu, lam, nu_min):
    """In place, `NiW.forget(lam, nu_min)`."""
    for i in range(Lam.shape[0]):
        _forget1(gamma, Lam[i], nu, i, lam, nu_min)


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


# ---- the fused step (`StiffnessMPF._step_compiled`) ---------------------------------------------
# Three kernels per sample instead of a dozen: each makes one pass over the particles and
# calls the per-particle functions above, so the fused step and the stage kernels compute
# the same expressions. The caller owns every array (allocated once, reused from step to
# step) and draws the random numbers with the reference's generator calls in between.
@njit(**_JIT)
def _normalise_into(logw, add, out):
    """out = normalised (logw + add) (`add` may be None), NaN as -inf, uniform when all are
    -inf (`normalize_log_weights`); returns the ESS."""
    n = logw.shape[0]
    m = -np.inf
    for i in range(n):
        li = logw[i] + add[i] if add is not None else logw[i]
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


@njit(**_JIT)
def predict_weigh(x, u_prev, w_prev, a, B, af, ar, slip, dt, max_step, heun, noise, noise_scale, b, P, qdt, bias_on,
                  forget, lam, nu_min, gamma, mu, Lam, nu, uk, y, avail, R, roll_gain, vp, full, rear_drive, h, D, L11,
                  nu_w, L12, Lc, e, v, ll, ok, logw, nc, want_nis, beta, yaw_max, gate_speed):
    """Steps 1 and 2 of `StiffnessMPF.step` in one pass, in place: per particle, propagate
    x (eq. (9), from the first stage a, B, slip kept from the last sample, with w_prev held),
    add the optional state noise (noise_scale * noise: sqrt(dt) q times the caller's normals,
    noise of shape (0, nx) when off), predict the bias covariance (P += diag(qdt), eq. (29)),
    forget (eq. (20), `forget`), evaluate the model at x_k (a, B, af, ar, slip: also the first
    stage of the next propagation), test plausibility (`ok`) and weigh (`_weigh1`: h, D, L11,
    nu_w, L12, Lc, e, v, ll). Then over all particles: the adaptive forgetting's innovation
    with the predictive weights (`weighted_nis`; NaN when not wanted) and logw + ll
    normalised. Returns (innovation, ESS (-1 without channels: logw unchanged), number of
    plausible particles, common nu~ or 0); the caller zeroes the implausible particles'
    weights when some (not all) are, as the reference does."""
    n, nx = x.shape
    n_w = mu.shape[1]
    na = avail.shape[0]
    n_sub = max(1, math.ceil(dt / max_step - 1e-9))
    hstep = dt / n_sub
    x1 = np.empty(nx)
    k1 = np.empty(nx)
    k2 = np.empty(nx)
    ai = np.empty(3)
    Bi = np.empty((3, n_w))
    S = np.empty((max(na, 1), max(na, 1)))
    DL = np.empty((max(na, 1), n_w))
    with_noise = noise.shape[0] > 0
    vx_lat = uk[3]
    p = float(na)
    last, cn = -1.0, 0.0
    count = 0
    for i in range(n):
        xi = x[i]
        for c in range(3):
            ai[c] = a[i, c]
            for j in range(n_w):
                Bi[c, j] = B[i, c, j]
        _propagate1(xi, u_prev, w_prev[i], ai, Bi, slip[0, i], slip[1, i], n_sub, hstep, heun, vp, full, rear_drive,
                    n_w, x1, k1, k2)
        if with_noise:
            for c in range(nx):
                xi[c] = xi[c] + noise_scale[c] * noise[i, c]
        if bias_on:
            for c in range(qdt.shape[0]):
                P[i, c, c] = P[i, c, c] + qdt[c]
        if forget:
            _forget1(gamma, Lam[i], nu, i, lam, nu_min)
        x2 = xi[2] if full else 0.0
        af[i], ar[i], slip[0, i], slip[1, i] = _model1(xi[0], xi[1], x2, uk[0], uk[1], uk[2], uk[3], False, 0.0, 0.0,
                                                       a[i], B[i], vp, full, rear_drive, n_w)
        vxp = xi[0] if full else vx_lat
        ok[i] = abs(xi[nx - 2]) <= beta * max(abs(vxp), gate_speed) and abs(xi[nx - 1]) <= yaw_max
        count += ok[i]
        dof, logdet, vv = _weigh1(a[i], B[i], xi, gamma[i], mu[i], Lam[i], nu[i], b[i], P[i], R, y, avail, bias_on,
                                  roll_gain, full, n_w, h[i], D[i], L11[i], L12[i], Lc[i], e[i], v[i], S, DL)
        nu_w[i] = dof
        if na:
            if dof != last:
                last, cn = dof, _t_const(dof, p)
            ll[i] = cn - 0.5 * logdet - 0.5 * (dof + p) * math.log1p(vv / dof)
    innovation = math.nan
    if want_nis and nc:
        innovation = 0.0
        for i in range(n):
            vv = 0.0
            for q in range(nc):
                vv += v[i, q] * v[i, q]
            innovation += math.exp(logw[i]) * (vv * (nu_w[i] - 2.0) / (nu_w[i] * nc))
    ess = _normalise_into(logw, ll, logw) if na else -1.0
    return innovation, ess, count, _common_dof(nu_w)


@njit(**_JIT)
def _take_rows(src, dst, idx):
    for i in range(idx.shape[0]):
        dst[i] = src[idx[i]]


@njit(**_JIT)
def resample_gate(logw, u0, resample, idx, x, b, P, gamma, mu, Lam, nu, a, B, slip, x2, b2, P2, gamma2, mu2, Lam2,
                  nu2, a2, B2, slip2, af, ar, full):
    """Resampling and the gate's moments. `resample`: systematic resampling
    (`systematic_resample` with the caller's uniform u0) into idx, the particles' arrays
    (x, b, P, the statistics, the model's first stage a, B, slip) copied by idx into their
    spares (x2, ...; the caller swaps), logw uniform; else idx = 0..N-1. The arrays of the
    weighting (h, D, L11, ...) are not copied: `sample_update` reads them through idx.
    Returns `gate_moments` over the (resampled) particles."""
    n = logw.shape[0]
    if resample:
        cdf = np.empty(n)
        acc = 0.0
        for i in range(n):
            acc += math.exp(logw[i])
            cdf[i] = acc
        cdf[n - 1] = 1.0
        j = 0
        for k in range(n):
            u = (u0 + k) / n
            while j < n - 1 and cdf[j] <= u:  # searchsorted(cdf, u, side="right"), clipped
                j += 1
            idx[k] = j
        _take_rows(x, x2, idx)
        _take_rows(b, b2, idx)
        _take_rows(P, P2, idx)
        _take_rows(gamma, gamma2, idx)
        _take_rows(mu, mu2, idx)
        _take_rows(Lam, Lam2, idx)
        _take_rows(nu, nu2, idx)
        _take_rows(a, a2, idx)
        _take_rows(B, B2, idx)
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
        mvx += q * xs[i, 0]
        mvy += q * xs[i, iv]
        maf += q * af[idx[i]]
        mar += q * ar[idx[i]]
    s = 0.0
    for i in range(n):
        d = xs[i, iv] - mvy
        s += math.exp(logw[i]) * (d * d)
    return mvx, math.sqrt(max(s, 0.0)), max(abs(maf), abs(mar))


@njit(**_JIT)
def sample_update(idx, x, logw, gamma, mu, Lam, nu, b, P, h, D, L11, nu_w, L12, Lc, v, nc, z, chi, nu_draw, w,
                  use_mask, bound, do_bias, R, avail, y, active, drift, lo, hi):
    """Steps 3-5 of `StiffnessMPF.step` in one pass, in place: per particle i (its weighting
    arrays at row idx[i]), draw w_i from the conditional Student-t (`_sample1`, eq. (39)-(41),
    with the caller's z, chi, nu_draw), the outlier mask (`use_mask`: |v_acc|^2 < bound), the
    bias update (`_bias1`, eq. (30), `do_bias`) and, gate open (`active`), the whitened
    lean L11^-1/2 (w_i - mu_i) of the adaptive forgetting (`drift`) and the NiW update with
    the projection (`_niw1`, eq. (19), Sec. V). Returns (weighted mean of the whitened
    lean (n_w,)) + `estimate_moments` after the update."""
    n, n_w = mu.shape
    na = avail.shape[0]
    mch = b.shape[1]
    M = np.empty((max(nc, 1), n_w))
    Lm = np.empty((n_w, n_w))
    L = np.zeros((n_w, n_w))
    mc = np.empty(n_w)
    ub = np.zeros(n_w)
    ui = np.empty(n_w)
    nb = max(na, 1)
    S = np.empty((nb, nb))
    Lb = np.zeros((nb, nb))
    Kt = np.empty((nb, mch))
    DE = np.empty((nb, n_w))
    innov = np.empty(nb)
    Pn = np.empty((mch, mch))
    for i in range(n):
        s = idx[i]
        _sample1(mu[i], L11[s], L12[s], Lc[s], v[s], nu_w[s], nc, z[i], chi[i], nu_draw[i], w[i], M, Lm, L, mc, n_w)
        learn = True
        if use_mask:
            vv = 0.0
            for q in range(nc):
                vv += v[s, q] * v[s, q]
            learn = vv < bound
        if do_bias:
            _bias1(b[i], P[i], R, D[s], avail, mu[i], Lam[i], nu[i], y, h[s], S, Lb, Kt, DE, innov, Pn, n_w)
        if active:
            if drift:  # u = chol(L11)^-1 (w - mu), before the update
                _chol(L11[s], L, n_w)
                for j in range(n_w):
                    acc = w[i, j] - mu[i, j]
                    for k in range(j):
                        acc = acc - L[j, k] * ui[k]
                    ui[j] = acc / L[j, j]
                q = math.exp(logw[i])
                for j in range(n_w):
                    ub[j] += q * ui[j]
            _niw1(gamma, mu[i], Lam[i], nu, i, w[i], learn, lo, hi)
    xm, xs, mbar, vm, s2, bm = estimate_moments(logw, x, gamma, mu, Lam, nu, b)
    return ub, xm, xs, mbar, vm, s2, bm
