"""The GP-SSM's per-particle kernels (compiled.py describes the step): `front` (step 1:
propagation, slip angles, basis, prior), `weigh` (step 3: the likelihoods, normalisation, ESS),
`sample` (step 5: the conditional draw, the friction, the moments) and `common_dof`, and the
columns of the per-particle array `work` they share with the other kernels."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tirefilter.vehicle.single_track_numba import slip_angles1

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True)  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls (called from Python it crashes the
# interpreter instead of raising: tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)

# columns of `work` (HELD: a^Y and r' held over the step from the friction of the sample before)
AF, AR, PF, PR, LOC, S, DOF, SC, SY, E, HELD, PHI = 0, 1, 2, 3, 4, 6, 10, 11, 13, 14, 15, 17


# ---- 1. propagation, slip, basis, prior -------------------------------------------------------
@njit(**_JIT_IN)
def _magic(B, C, D, E, s):
    Bs = B * s
    return D * math.sin(C * math.atan(Bs - E * (Bs - math.atan(Bs))))


@njit(inline="always", **_JIT)
def _phi_next(sf, cf, sf1, cf1, sr, cr, sr1, cr1, n):
    """One step of `_phi1`'s recurrence for every particle, front and rear: sin((j + 1) a) =
    sin(j a) cos a + cos(j a) sin a, cos((j + 1) a) = cos(j a) cos a - sin(j a) sin a."""
    for i in range(n):
        s, c = sf[i], cf[i]
        sf[i], cf[i] = s * cf1[i] + c * sf1[i], c * cf1[i] - s * sf1[i]
        s, c = sr[i], cr[i]
        sr[i], cr[i] = s * cr1[i] + c * sr1[i], c * cr1[i] - s * sr1[i]


@njit(**_JIT)
def front(x, mu, work, prop, veh, delta, vx, basis, prior):
    """In place: x propagated (prop = (propagate, n_sub, h, cd, vx_prev): with `propagate`
    n_sub Euler steps of h, eq. (1a)-(1b), friction mu held, cos delta_{k-1} and v^X_{k-1}; veh =
    (Fz0, Fz1, mass, lf, lr, Iz); the held a^Y and r' into work[:, HELD:HELD + 2]), then work[:, AF:PR + 1] = alpha_f, alpha_r (eq. (4), clipped
    to [-L, L]), mu~_f, mu~_r (prior = (B_f, B_r, C, D_f, D_r, E)) and work[:, PHI:] the
    features (basis = (L, m, keep, keep_r, tensor); tensor: phi_keep; axle: front then rear
    row; tensor: keep = the front function's index j1, keep_r = the rear one's j2). Returns
    the number of particles with a slip angle outside [-L, L].
    Two loops over the particles: the libm calls (atan, sin, cos) per particle, then the
    basis's angle-addition recurrence (`_phi1`, the same operations in the same order) for
    all particles at once, one vector operation per function: per particle the recurrence is
    a chain of dependent multiply-adds, which in one loop body per particle nothing overlaps."""
    propagate, n_sub, h, cd, vx_prev = prop
    Fz0, Fz1, mass, lf, lr, Iz = veh
    L, m, keep, keep_r, tensor = basis
    pB0, pB1, pC, pD0, pD1, pE = prior
    n = x.shape[0]
    nk = keep.shape[0]
    vxc = max(vx, 1.0)
    out = 0
    k0 = math.pi / (2.0 * L)
    r = 1.0 / math.sqrt(L)
    sc = np.empty((8, n))  # sin and cos of the first angle, front and rear; the recurrence's state
    sf1, cf1, sr1, cr1, sf, cf, sr, cr = sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6], sc[7]
    for i in range(n):
        x0, x1 = x[i, 0], x[i, 1]
        if propagate:
            Ff = Fz0 * mu[i, 0] * cd
            Fr = Fz1 * mu[i, 1]
            ay = (Ff + Fr) / mass
            rdot = (lf * Ff - lr * Fr) / Iz
            work[i, HELD], work[i, HELD + 1] = ay, rdot
            for _ in range(n_sub):
                x0 += h * (ay - vx_prev * x1)
                x1 += h * rdot
            x[i, 0], x[i, 1] = x0, x1
        af, ar = slip_angles1(vxc, x0, x1, delta, lf, lr)
        if abs(af) > L or abs(ar) > L:
            out += 1
        af = min(max(af, -L), L)
        ar = min(max(ar, -L), L)
        work[i, AF], work[i, AR] = af, ar
        work[i, PF] = _magic(pB0, pC, pD0, pE, af)
        work[i, PR] = _magic(pB1, pC, pD1, pE, ar)
        a = k0 * (af + L)
        sf1[i], cf1[i] = math.sin(a), math.cos(a)
        a = k0 * (ar + L)
        sr1[i], cr1[i] = math.sin(a), math.cos(a)
    for i in range(n):
        sf[i], cf[i], sr[i], cr[i] = sf1[i], cf1[i], sr1[i], cr1[i]
    if tensor:
        P = np.empty((2, m, n))
        Pf, Pr = P[0], P[1]
        for j in range(m):
            pfj, prj = Pf[j], Pr[j]
            for i in range(n):
                pfj[i] = sf[i] * r
                prj[i] = sr[i] * r
            _phi_next(sf, cf, sf1, cf1, sr, cr, sr1, cr1, n)
        for i in range(n):  # keep[k] = j1 * m + j2: keep_f = j1, keep_r = j2 (no division per feature)
            for k in range(nk):
                work[i, PHI + k] = Pf[keep[k], i] * Pr[keep_r[k], i]
    else:
        col = np.full(m, -1, np.int64)  # the feature column of function j, -1 where not kept
        for k in range(nk):
            col[keep[k]] = k
        for j in range(m):
            cj = col[j]
            if cj >= 0:
                for i in range(n):
                    work[i, PHI + cj] = sf[i] * r
                    work[i, PHI + nk + cj] = sr[i] * r
            _phi_next(sf, cf, sf1, cf1, sr, cr, sr1, cr1, n)
    return out

# ---- 3. weights ---------------------------------------------------------------------------------
@njit(**_JIT)
def weigh(x, work, logw, bias, c0, c1, y, R, learned, add):
    """Eq. (22) with zeta integrated out and the bias with its Kalman filter's prediction (y =
    (a^Y, yaw rate, whether each is available), R = (R_aY, R_r) their noise variances, c0, c1
    the coefficients of mu_f, mu_r in a^Y, bias (N, 4) the bias filters (`gpssm.bias`));
    returns (ESS, predicted a^Y, predicted yaw rate, `common_dof`, the variances of those
    predictions) and writes the normalised log-weights (as `normalize_log_weights`) and, for
    the learned measurement, work[:, SC:E + 1] = S c, the a^Y marginal's scale and the
    residual."""
    ay, yr, have_ay, have_r = y
    R0, R1 = R
    n = x.shape[0]
    lw = np.empty(n)
    pred_ay = 0.0
    pred_r = 0.0
    m2_ay = 0.0  # the second moments of the predictions, for their variances
    m2_r = 0.0
    nu_last = math.nan
    const = 0.0
    for i in range(n):
        h0 = c0 * work[i, PF] + c1 * work[i, PR]
        lc = work[i, LOC] * c0 + work[i, LOC + 1] * c1
        b_ay, b_r, P_ay, P_r = bias[i, 0], bias[i, 1], bias[i, 2], bias[i, 3]
        l = 0.0
        if learned:
            sc0 = work[i, S] * c0 + work[i, S + 1] * c1
            sc1 = work[i, S + 2] * c0 + work[i, S + 3] * c1
            nu = work[i, DOF]
            s_y = (sc0 * c0 + sc1 * c1) + (R0 + P_ay) * (nu - 2.0) / nu
            v_ay = s_y * nu / (nu - 2.0)
            if have_ay:
                e = ay - h0 - lc - b_ay
                work[i, SC], work[i, SC + 1], work[i, SY], work[i, E] = sc0, sc1, s_y, e
                if nu != nu_last:
                    const = math.lgamma(0.5 * (nu + 1.0)) - math.lgamma(0.5 * nu)
                    nu_last = nu
                l += const - 0.5 * math.log(nu * math.pi * s_y) - 0.5 * (nu + 1.0) * math.log1p(e * e / (nu * s_y))
        else:
            v_ay = R0 + P_ay
            if have_ay:
                e = ay - h0 - b_ay
                l += -0.5 * (e * e / v_ay + math.log(2 * math.pi * v_ay))
        v_r = R1 + P_r
        if have_r:
            er = yr - x[i, 1] - b_r
            l += -0.5 * (er * er / v_r + math.log(2 * math.pi * v_r))
        q = math.exp(logw[i])
        p_ay = (h0 + lc if learned else h0) + b_ay
        p_r = x[i, 1] + b_r
        pred_ay += q * p_ay
        pred_r += q * p_r
        m2_ay += q * (v_ay + p_ay * p_ay)
        m2_r += q * (v_r + p_r * p_r)
        v = logw[i] + l
        lw[i] = -math.inf if math.isnan(v) else v
    mx = -math.inf
    for i in range(n):
        mx = max(mx, lw[i])
    if not math.isfinite(mx):
        for i in range(n):
            logw[i] = -math.log(n)
    else:
        s = 0.0
        for i in range(n):
            s += math.exp(lw[i] - mx)
        lse = math.log(s)
        for i in range(n):
            logw[i] = (lw[i] - mx) - lse
    s2 = 0.0
    for i in range(n):
        s2 += math.exp(2.0 * logw[i])
    return 1.0 / s2, pred_ay, pred_r, common_dof(work, add), m2_ay - pred_ay * pred_ay, m2_r - pred_r * pred_r

# ---- 5. conditional draw, friction, moments --------------------------------------------------------
@njit(**_JIT_IN)
def _chol2_apply(s00, s10, s11, z0, z1):
    """L z for the lower Cholesky factor L of [[s00, s10], [s10, s11]], floored as
    `stats.linalg.chol`."""
    l00 = math.sqrt(max(s00, abs(s00) * 1e-14 + 1e-300))
    l10 = s10 * (1.0 / l00)
    dd = s11 - l10 * l10
    l11 = math.sqrt(max(dd, abs(s11) * 1e-14 + 1e-300))
    return l00 * z0, l10 * z0 + l11 * z1


@njit(**_JIT)
def sample(x, work, logw, z, u, zeta, mu, conditional, keep_phi, phi_p, hold):
    """zeta ~ St (the t conditional given the a^Y residual when `conditional`, else the
    predictive) from z ~ N(0, I), u ~ chi2(dof'), as `student_t.t_sample`; mu = mu~ + zeta.
    hold = (linear, dt, vx_prev, cd, veh): with `linear` x gains what the forces' linear growth
    over the step dt from the held rates work[:, HELD:HELD + 2] to those of the friction's
    conditional mean mu~ + the draw's location (cos delta_k = cd, veh as `front`'s) adds
    (`gpssm.dynamics.linear_hold_remainder`). Returns the weighted means and std of x and the weighted means and variances of the
    (clipped) slip angles."""
    linear, dt, vx_prev, cd, veh = hold
    Fz0, Fz1, mass, lf, lr, Iz = veh
    n = x.shape[0]
    for i in range(n):
        l0, l1 = work[i, LOC], work[i, LOC + 1]
        s00, s01, s10, s11 = work[i, S], work[i, S + 1], work[i, S + 2], work[i, S + 3]
        nu = work[i, DOF]
        if conditional:
            sc0, sc1, s_y, e = work[i, SC], work[i, SC + 1], work[i, SY], work[i, E]
            g0, g1 = sc0 / s_y, sc1 / s_y
            l0, l1 = l0 + g0 * e, l1 + g1 * e
            f = (nu + e * e / s_y) / (nu + 1.0)
            c00 = f * (s00 - sc0 * g0)
            c01 = f * (s01 - sc0 * g1)
            c10 = f * (s10 - sc1 * g0)
            c11 = f * (s11 - sc1 * g1)
            s00, s10, s11 = 0.5 * (c00 + c00), 0.5 * (c10 + c01), 0.5 * (c11 + c11)
            nu = nu + 1.0
        a0, a1 = _chol2_apply(s00, s10, s11, z[i, 0], z[i, 1])
        r = math.sqrt(nu / u[i])
        zeta[i, 0] = l0 + a0 * r
        zeta[i, 1] = l1 + a1 * r
        mu[i, 0] = work[i, PF] + zeta[i, 0]
        mu[i, 1] = work[i, PR] + zeta[i, 1]
        if linear:
            Ff = Fz0 * (work[i, PF] + l0) * cd
            Fr = Fz1 * (work[i, PR] + l1)
            da = (Ff + Fr) / mass - work[i, HELD]
            dr = (lf * Ff - lr * Fr) / Iz - work[i, HELD + 1]
            x[i, 0] += 0.5 * dt * da - vx_prev * dt * dt / 6.0 * dr
            x[i, 1] += 0.5 * dt * dr
    m0 = m1 = mf = mr = 0.0
    qs = np.empty(n)  # the weights, exponentiated once for both sums
    for i in range(n):
        q = qs[i] = math.exp(logw[i])
        m0 += q * x[i, 0]
        m1 += q * x[i, 1]
        mf += q * work[i, AF]
        mr += q * work[i, AR]
    v0 = v1 = vf = vr = 0.0
    for i in range(n):
        q = qs[i]
        v0 += q * (x[i, 0] - m0) ** 2
        v1 += q * (x[i, 1] - m1) ** 2
        vf += q * (work[i, AF] - mf) ** 2
        vr += q * (work[i, AR] - mr) ** 2
    if keep_phi:  # the features of the pending update (exact statistics while learning)
        k = phi_p.shape[1]
        for i in range(n):
            for j in range(k):
                phi_p[i, j] = work[i, PHI + j]
    return m0, m1, math.sqrt(max(v0, 0.0)), math.sqrt(max(v1, 0.0)), mf, mr, vf, vr


@njit(**_JIT)
def common_dof(work, add):
    """The draw's degrees of freedom work[:, DOF] + add when every particle has the same (the
    usual case: `student_t.t_draws` then draws the chi-square with one scalar dof), NaN
    otherwise (also when it is NaN), so that the step draws as t_draws would without its
    numpy checks."""
    v = work[0, DOF] + add
    for i in range(1, work.shape[0]):
        if work[i, DOF] + add != v:
            return math.nan
    return v
