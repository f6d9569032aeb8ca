"""The friction GP-SSM's step compiled (numba, nopython, `cache=True`): the `backend = "numba"`
path of `FrictionGPSSM.step`, the same arithmetic as the numpy reference in
`friction_gpssm.py` (tested equal to 1e-12 relative in tests/test_kernels.py with the same
random numbers, resampling included).

One step is four kernel calls (five on a resampling step); the random numbers are drawn outside
them with the reference's generator calls, in the reference's order (yaw-rate start or state
noise, the resampling uniform, the Student-t draws `student_t.t_draws`), so both backends follow
one path:
  1. `front`: propagation (eq. (1), Euler sub-steps), slip angles (eq. (4)) clipped to
     [-L, L], the basis (eq. (10b)) by the angle-addition recurrence
     sin((k+1) a) = sin(k a) cos a + cos(k a) sin a (one sin and one cos per slip angle
     instead of one sin per function), the Pacejka prior (Sec. 4); the libm calls in one loop
     over the particles, the recurrence in a second one over all particles at once (a vector
     operation per function: per particle it is a chain of dependent multiply-adds);
  2. one pass over the statistics: for the exact statistics the previous step's update
     (eq. (27), kept pending until now), the forgetting (eq. (29)) and the predictive
     (eq. (31)-(32)), `exact_forget_predictive` (`_rows` from `LANES_BELOW` functions);
     for the rank-one ones the forgetting and the predictive, `rank1_forget_predictive`;
  3. `weigh`: the Student-t a^Y and Gaussian yaw-rate likelihoods (eq. (22)), the one-step
     prediction, log-sum-exp normalisation and the ESS, and `common_dof` (whether every
     particle draws with the same dof: the step then makes `t_draws`' two generator calls
     itself, `t_draws` otherwise);
  4. `resample` (when the ESS is low): systematic resampling (`systematic_ancestors`, the
     uniform drawn as `stats.systematic_resample` draws it) and its copies, in place
     (`gather_rows`, `gather_lanes`; sorted ancestors: only the rows that change are copied),
     the log-weights reset, `common_dof` again; from `LANES_BELOW` functions (the tensor bases)
     K's copy is left to the next pass, whose sweep copies each row of an element's ancestor's
     K into the element's and updates it there (`exact_forget_predictive_rows`, `copy_order`;
     sorted ancestors only, else `resample` copies K itself; `flush` makes the copy with
     `gather_lower` when the statistics are read in between): one pass over K instead of two;
  5. `sample`: the conditional Student-t draw of zeta (the locally optimal proposal), mu = mu~
     + zeta, the weighted moments for the estimate and, while the exact statistics learn, the
     features of the pending update;
  6. `rank1_update` (rank-one statistics, eq. (27)/(28) as recursive least squares); the exact
     statistics' update waits for the next step's pass (`CompiledStep.flush` applies it with
     `exact_update` when the statistics are read in between).

The step keeps only the lower triangle of the exact statistics' K = Sigma + V up to date
(`flush` mirrors it); below `LANES_BELOW` functions it keeps K in lanes (`CompiledStep.Kl`,
below) and writes it back into the statistics only at `flush`. The exact predictive factorises K
(m x m) per batch element, and only forward substitution is needed: with Z = C^-1 [Psi^T, phi]
(C C^T = K), Psi K^-1 Psi^T = Z_Psi^T Z_Psi, phi^T K^-1 phi = |z_phi|^2 and M phi = Z_Psi^T
z_phi. Below `LANES_BELOW` basis functions (the per-axle basis) the factorisation runs on
`LANES` batch elements at once, one SIMD lane each (the matrices interleaved as (m, m, LANES),
so every inner loop is a vector operation over lanes; fewer lanes when the batch is smaller), in
three stages per block of lanes: the pending update and the forgetting, a vector operation over
the lanes per entry of K, since the step keeps K itself in lanes between `flush`es (`Kl`
(blocks, m, m, LANES), loaded from the statistics by `lanes_load` at the first step after a
flush, written back by `lanes_store`; the sweep over each element's K apart,
written into its lane strided by the lane count, took half of the pass), each entry written into
the factorisation's matrix in the same sweep (`_lane_heads` does each element's scalar part),
the factorisation with the forward substitution (`_chol_lanes`), and the predictive's sums over
the basis accumulated over all lanes at once before each lane's scalar tail
(`_write_predictive_lanes`; reading each lane's sums apart, strided by the lane count, cost
10-20% of the pass at m = 10). From `LANES_BELOW` up (the tensor bases) each matrix is
factorised alone by a register-blocked row Cholesky (`_chol_rows`: four rows against two
columns, the sums over the columns vectorised), about 0.6 of LAPACK's dpotrf called per matrix
at m = 100 and 0.9 of the lanes at m = 50 (docs/performance.md, "Backends"). No exact low-rank update of the factor exists under the paper's forgetting
(docs/derivations.md, "The GP-SSM's exact statistics in the compiled step"): each step refactorises.

Per-particle quantities of the step live in one (N, columns) array `work` (columns below),
so resampling copies them with the statistics in one call. The Python around the kernels is
kept short (at N = 8 the per-axle step is mostly this fixed cost): the flat views
of the statistics and the configuration's scalars are made once (`CompiledStep._arrays`,
rebuilt when the statistics or the particles' arrays are replaced, not pickled), and the
Estimate is a copy of a template's fields (`CompiledStep._estimate`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate
from tirefilter.stats.mniw_numba import _factor, _phi1, _rank1_forget1, _rank1_update1, exact_update
from tirefilter.stats.particles_numba import systematic_into
from tirefilter.stats.student_t import t_draws
from tirefilter.vehicle.single_track_numba import slip_angles1

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True)  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls (called from Python it crashes the
# interpreter instead of raising: tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)
NAN = math.nan
_new = object.__new__
LANES = 32  # batch elements factorised together (eight AVX2 vectors of float64; measured best of 8-32)
LANES_BELOW = 32  # basis size from which `_chol_rows` factorises each matrix alone instead

# columns of `work`
AF, AR, PF, PR, LOC, S, DOF, SC, SY, E, PHI = 0, 1, 2, 3, 4, 6, 10, 11, 13, 14, 15


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
def front(x, mu, work, propagate, n_sub, h, cd, vx_prev, Fz0, Fz1, mass, lf, lr, Iz, delta, vx, L, m, keep,
          keep_r, tensor, pB0, pB1, pC, pD0, pD1, pE):
    """In place: x propagated (`propagate`: n_sub Euler steps of h, eq. (1a)-(1b), friction mu
    held), then work[:, AF:PR + 1] = alpha_f, alpha_r (eq. (4), clipped to [-L, L]),
    mu~_f, mu~_r and work[:, PHI:] the features (tensor: phi_keep; axle: front then rear
    row; tensor: keep = the front function's index j1, keep_r = the rear one's j2). Returns
    the number of particles with a slip angle outside [-L, L].
    Two loops over the particles: the libm calls (atan, sin, cos) per particle, then the
    basis's angle-addition recurrence (`_phi1`, the same operations in the same order) for
    all particles at once, one vector operation per function: per particle the recurrence is
    a chain of dependent multiply-adds, which in one loop body per particle nothing overlaps."""
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


# ---- 2. forgetting and predictive ---------------------------------------------------------------
@njit(**_JIT_IN)
def _scale_psi_phi(Psi, Phi, b, f):
    """Phi and Psi of batch element b times the forgetting factor f (eq. (29))."""
    d, m = Psi.shape[1], Psi.shape[2]
    for i in range(d):
        for k in range(d):
            Phi[b, i, k] = Phi[b, i, k] * f
        Pi = Psi[b, i]
        for j in range(m):
            Pi[j] = Pi[j] * f


@njit(inline="always", **_JIT)
def _pending_head(Psi, Phi, nu, b, per, zeta, phi_p, forget, lam, nu_min):
    """The start of batch element b's pending update (eq. (27a)-(27b), (28f)) with the
    forgetting factor f (eq. (29)): nu += 1, Phi and Psi updated and scaled by f. Returns
    (f, 1 - f, phi) for the update of K, which each caller sweeps its own way."""
    d, m = Psi.shape[1], Psi.shape[2]
    n, a = b // per, b % per
    nu[b] += 1.0
    f = _factor(lam, nu_min, nu[b]) if forget else 1.0
    ph = phi_p[n, a * m:(a + 1) * m]
    for i in range(d):
        zi = zeta[n, a + i]
        for k in range(d):
            Phi[b, i, k] = (Phi[b, i, k] + zi * zeta[n, a + k]) * f
        Pi = Psi[b, i]
        for j in range(m):
            Pi[j] = (Pi[j] + zi * ph[j]) * f
    return f, 1.0 - f, ph


@njit(inline="always", **_JIT)
def _write_scale(work, n, a, d, f, lam, df):
    """Particle n's predictive scale f Lambda* (symmetrised, d = 2: the tensor basis) or axle a's
    diagonal entry (d = 1: the per-axle basis, the off-diagonal zero), and its dof df."""
    if d == 2:
        work[n, S + 0] = f * lam[0, 0]
        work[n, S + 1] = f * (0.5 * (lam[0, 1] + lam[1, 0]))
        work[n, S + 2] = f * (0.5 * (lam[1, 0] + lam[0, 1]))
        work[n, S + 3] = f * lam[1, 1]
        work[n, DOF] = df
    else:
        work[n, S + 3 * a] = f * lam[0, 0]
        if a == 0:
            work[n, S + 1] = 0.0
            work[n, S + 2] = 0.0
            work[n, DOF] = df


@njit(**_JIT)
def _write_predictive_lanes(work, b0, nw, per, d, m, Z, Lam0, Phi, nu, acc, lam):
    """`_write_predictive_rows` for the lanes w < nw of a block (batch elements b0 + w) at once: the
    sums over j (c, M phi, Psi K^-1 Psi^T) accumulated over the lanes first (one vector
    operation per j), then each lane's loc, scale, dof. Per lane the same operations in the same
    order as `_write_predictive_rows` (acc: (1 + d + d d, >= lanes) scratch; lam: (2, 2))."""
    W = Z.shape[2]
    nq = 1 + d + d * d
    for w in range(W):
        acc[0, w] = 1.0
    for q in range(1, nq):
        for w in range(W):
            acc[q, w] = 0.0
    for j in range(m):
        zp = Z[m + d, j]
        a0 = acc[0]
        for w in range(W):
            a0[w] += zp[w] * zp[w]
        for i in range(d):
            zi = Z[m + i, j]
            ai = acc[1 + i]
            for w in range(W):
                ai[w] += zi[w] * zp[w]
            for k in range(d):
                zk = Z[m + k, j]
                aq = acc[1 + d + i * d + k]
                for w in range(W):
                    aq[w] += zi[w] * zk[w]
    for w in range(nw):
        b = b0 + w
        n, a = b // per, b % per
        df = nu[b] - d + 1.0
        f = acc[0, w] / df
        for i in range(d):
            work[n, LOC + a + i] = acc[1 + i, w]
            for k in range(d):
                lam[i, k] = Lam0[i, k] + Phi[b, i, k] - acc[1 + d + i * d + k, w]
        _write_scale(work, n, a, d, f, lam, df)


@njit(**_JIT_IN)
def _chol_row(A, r, j0, m, W, inv):
    """Row r of `_chol_lanes` from column j0 on (the columns before j0 are done)."""
    row = A[r]
    for j in range(j0, min(r + 1, m)):
        Arj = row[j]
        Aj = A[j]
        for k in range(j):
            Ark = row[k]
            Ajk = Aj[k]
            for w in range(W):
                Arj[w] -= Ark[w] * Ajk[w]
        ij = inv[j]
        if r == j:
            for w in range(W):
                v = Arj[w]
                c = math.sqrt(v) if v > 0.0 else math.nan
                Arj[w] = c
                ij[w] = 1.0 / c
        else:
            for w in range(W):
                Arj[w] *= ij[w]


@njit(**_JIT)
def _chol_lanes(A, m, W, inv):
    """In place over W interleaved lanes, A (n, m, >= W), rows 0..m-1 a symmetric positive
    definite matrix (lower triangle read), rows m..n-1 right-hand sides b^T: afterwards the
    lower Cholesky factor C and the rows (C^-1 b)^T (forward substitution is the Cholesky
    recurrence continued below the matrix). Row-oriented, A[i, j] = (A[i, j] -
    sum_{k<j} A[i, k] A[j, k]) / A[j, j], two rows at a time where both need column j (each
    A[j, k] loaded once for both); every inner loop runs over lanes (contiguous, SIMD; W is a
    run-time count so that LLVM's loop vectoriser, not the SLP one numba disables, takes it)."""
    n = A.shape[0]
    i = 0
    while i + 2 <= n:
        R0 = A[i]
        R1 = A[i + 1]
        jmax = min(i, m)
        for j in range(jmax):
            a0 = R0[j]
            a1 = R1[j]
            Aj = A[j]
            for k in range(j):
                b0 = R0[k]
                b1 = R1[k]
                c = Aj[k]
                for w in range(W):
                    x = c[w]
                    a0[w] -= b0[w] * x
                    a1[w] -= b1[w] * x
            ij = inv[j]
            for w in range(W):
                a0[w] *= ij[w]
                a1[w] *= ij[w]
        _chol_row(A, i, jmax, m, W, inv)
        _chol_row(A, i + 1, jmax, m, W, inv)
        i += 2
    if i < n:
        _chol_row(A, i, 0, m, W, inv)


@njit(**_JIT)
def _lane_heads(Psi, Phi, nu, b0, nw, per, pending, zeta, phi_p, forget, lam, nu_min, fv, gv, phl):
    """The per-element start of a block's pass, lanes w < nw (batch elements b0 + w): with
    `pending` the previous step's update of Phi, Psi and nu (eq. (27a)-(27b), (28f)) scaled by
    the forgetting factor f (`_pending_head`) and its features phl[:, w]; without, the
    forgetting of Phi and Psi (`_scale_psi_phi`); then nu *= f (as the reference, after
    nu += 1). fv[w] = f and gv[w] = 1 - f for the sweep over K; the padding lanes f = 1, 1 - f =
    0, zero features (their identity matrix stays the identity)."""
    m = Psi.shape[2]
    W = fv.shape[0]
    for w in range(W):
        if w >= nw:
            fv[w], gv[w] = 1.0, 0.0
            for j in range(m):
                phl[j, w] = 0.0
            continue
        b = b0 + w
        if pending:
            f, g, ph = _pending_head(Psi, Phi, nu, b, per, zeta, phi_p, forget, lam, nu_min)
            for j in range(m):
                phl[j, w] = ph[j]
        else:
            f = _factor(lam, nu_min, nu[b])
            _scale_psi_phi(Psi, Phi, b, f)
            g = 1.0 - f
        nu[b] = nu[b] * f
        fv[w], gv[w] = f, g


@njit(**_JIT)
def exact_forget_predictive(Kl, Psi, Phi, nu, V, Lam0, work, per, forget, lam, nu_min, pending, zeta, phi_p):
    """The exact statistics' pass below `LANES_BELOW` functions, with K = Sigma + V kept by the
    compiled step in lanes (`Kl` (blocks, m, m, LANES): Kl[b // LANES, i, j, b % LANES] = K[b, i,
    j], lower triangle; the padding lanes of the last block the identity; `lanes_load`,
    `lanes_store`). Psi (B, d, m), Phi (B, d, d), nu (B,): the flat batch, per batch elements
    per particle (axle 2). In one pass over each block of lanes: with `pending` the previous
    step's update (eq. (27), zeta (N, 2) at features phi_p), with `forget` eq. (29), written
    into Kl and into the factorisation's matrix A in one sweep, every operation a vector one
    over the lanes; then the factorisation with the forward substitution (`_chol_lanes`) and the
    predictive St(M phi, c Lambda / (nu - d + 1), nu - d + 1) (eq. (31)-(32)) into work. Per
    element the reference's operations in the reference's order ((K + phi phi^T) * f, then
    + (1 - f) V on the diagonal; without a pending update K * f, then + (1 - f) V): the lanes
    layout only changes which element an instruction works on, not what it computes."""
    nb, d, m = Psi.shape
    W = Kl.shape[3]
    A = np.empty((m + d + 1, m, W))
    inv = np.empty((m, W))
    acc = np.empty((1 + d + d * d, W))
    lam2 = np.empty((2, 2))
    fv = np.empty(W)
    gv = np.empty(W)
    phl = np.empty((m, W))
    for blk in range(Kl.shape[0]):
        b0 = blk * W
        nw = min(W, nb - b0)
        Kb = Kl[blk]
        if pending or forget:
            _lane_heads(Psi, Phi, nu, b0, nw, per, pending, zeta, phi_p, forget, lam, nu_min, fv, gv, phl)
        for i in range(m):
            Ki = Kb[i]
            Ai = A[i]
            if pending:
                pi = phl[i]
                for j in range(i + 1):
                    kij = Ki[j]
                    aij = Ai[j]
                    pj = phl[j]
                    for w in range(W):
                        kij[w] = (kij[w] + pi[w] * pj[w]) * fv[w]
                kii = Ki[i]
                for w in range(W):
                    kii[w] += gv[w] * V[i]
            elif forget:
                for j in range(i + 1):
                    kij = Ki[j]
                    for w in range(W):
                        kij[w] *= fv[w]
                kii = Ki[i]
                for w in range(W):
                    kii[w] += gv[w] * V[i]
            for j in range(i + 1):
                kij = Ki[j]
                aij = Ai[j]
                for w in range(W):
                    aij[w] = kij[w]
        for w in range(W):
            if w < nw:
                b = b0 + w
                n, a = b // per, b % per
                for i in range(d):
                    Pi = Psi[b, i]
                    Ai = A[m + i]
                    for j in range(m):
                        Ai[j, w] = Pi[j]
                ph = work[n, PHI + a * m:PHI + (a + 1) * m]
                Ai = A[m + d]
                for j in range(m):
                    Ai[j, w] = ph[j]
            else:  # padding lanes: zero right-hand sides
                for i in range(m, m + d + 1):
                    for j in range(m):
                        A[i, j, w] = 0.0
        _chol_lanes(A, m, W, inv)
        _write_predictive_lanes(work, b0, nw, per, d, m, A, Lam0, Phi, nu, acc, lam2)


@njit(**_JIT)
def lanes_load(K, Kl):
    """Kl[b // W, i, j, b % W] = K[b, i, j] (lower triangle), the padding lanes the identity."""
    nblk, m, W = Kl.shape[0], Kl.shape[1], Kl.shape[3]
    nb = K.shape[0]
    for blk in range(nblk):
        for w in range(W):
            b = blk * W + w
            for i in range(m):
                for j in range(i + 1):
                    Kl[blk, i, j, w] = K[b, i, j] if b < nb else (1.0 if i == j else 0.0)


@njit(**_JIT)
def lanes_store(Kl, K):
    """K[b, i, j] = Kl[b // W, i, j, b % W], lower triangle."""
    W = Kl.shape[3]
    nb, m = K.shape[0], K.shape[1]
    for b in range(nb):
        blk, w = b // W, b % W
        for i in range(m):
            for j in range(i + 1):
                K[b, i, j] = Kl[blk, i, j, w]


@njit(**_JIT_IN)
def _update_forget_rows(K, Psi, Phi, nu, V, b, src, per, pending, zeta, phi_p, forget, lam, nu_min, A):
    """Batch element b: the pending update (eq. (27a)-(27c), (28f)) then the forgetting
    (eq. (29)), in one sweep over K with the reference's operations in the reference's order
    ((K + phi phi^T) * f, then + (1 - f) V on the diagonal; without a pending update K * f, then
    + (1 - f) V), each entry of K's lower triangle written to K and to A (>= m, m), A[i, j] =
    K[b, i, j], as it is computed. With src != b (after a resampling, whose copy of K the pass
    makes: `exact_forget_predictive_rows`) each row of element src's K is first copied into
    element b's, then updated there while in cache (the same numbers as copying K first; the
    update reading one view and writing another of the same K would fail LLVM's run-time
    overlap test at src == b and run scalar). K's lower triangle only: the upper one is
    restored by `mirror` before anything else reads K (the reference's K is exactly symmetric:
    p_i p_j = p_j p_i and the forgetting is elementwise)."""
    m = Psi.shape[2]
    Kb = K[b]
    Ks = K[src]
    copy = src != b
    if pending:
        f, g, ph = _pending_head(Psi, Phi, nu, b, per, zeta, phi_p, forget, lam, nu_min)
        for i in range(m):
            Ki = Kb[i]
            if copy:
                _copy_row(Ki, Ks[i], i + 1)
            p = ph[i]
            Ai = A[i]
            for j in range(i):
                v = (Ki[j] + p * ph[j]) * f
                Ki[j] = v
                Ai[j] = v
            v = (Ki[i] + p * ph[i]) * f
            v += g * V[i]
            Ki[i] = v
            Ai[i] = v
        nu[b] = nu[b] * f
        return
    if forget:
        f = _factor(lam, nu_min, nu[b])
        _scale_psi_phi(Psi, Phi, b, f)
        for i in range(m):
            Ki = Kb[i]
            if copy:
                _copy_row(Ki, Ks[i], i + 1)
            for j in range(i + 1):
                Ki[j] *= f
            Ki[i] += (1.0 - f) * V[i]
        nu[b] = nu[b] * f
    elif copy:
        for i in range(m):
            _copy_row(Kb[i], Ks[i], i + 1)
    for i in range(m):
        Ki = Kb[i]
        Ai = A[i]
        for j in range(i + 1):
            Ai[j] = Ki[j]


@njit(**_JIT_IN)
def _copy_row(a, b, n):
    for j in range(n):
        a[j] = b[j]


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _chol_rows(A, m, inv, spare):
    """In place, one matrix: A (n, m), rows 0..m-1 a symmetric positive definite matrix (lower
    triangle read), rows m..n-1 right-hand sides b^T; afterwards the lower Cholesky factor C and
    the rows (C^-1 b)^T (the recurrence continued below the matrix, as `_chol_lanes`).
    Row-oriented, A[i, j] = (A[i, j] - sum_{k<j} A[i, k] A[j, k]) / A[j, j], register-blocked:
    four rows against two columns, the eight sums over k < j accumulated together (each A[j, k]
    loaded once for four rows, each A[i, k] once for two columns; `reassoc` lets LLVM vectorise
    the sums over k), then both columns finished in order (the term k = j of the second); the
    columns left of the block's diagonal and the diagonal block itself row by row. The sums'
    order differs from dpotrf's and the reference's LU solve by rounding only (measured against
    2 x 4 blocking: 10% faster at m = 100, the same at m = 50). `spare`: (m,) scratch standing in
    for the missing rows of the last block."""
    n = A.shape[0]
    i = 0
    while i < n:
        R0 = A[i]
        R1 = A[i + 1] if i + 1 < n else spare
        R2 = A[i + 2] if i + 2 < n else spare
        R3 = A[i + 3] if i + 3 < n else spare
        jmax = min(i, m)
        j = 0
        while j + 2 <= jmax:
            Q0, Q1 = A[j], A[j + 1]
            s00 = s01 = s10 = s11 = s20 = s21 = s30 = s31 = 0.0
            for k in range(j):
                q0 = Q0[k]
                q1 = Q1[k]
                a = R0[k]
                s00 += a * q0
                s01 += a * q1
                a = R1[k]
                s10 += a * q0
                s11 += a * q1
                a = R2[k]
                s20 += a * q0
                s21 += a * q1
                a = R3[k]
                s30 += a * q0
                s31 += a * q1
            iv = inv[j]
            x0 = (R0[j] - s00) * iv
            x1 = (R1[j] - s10) * iv
            x2 = (R2[j] - s20) * iv
            x3 = (R3[j] - s30) * iv
            R0[j], R1[j], R2[j], R3[j] = x0, x1, x2, x3
            q = Q1[j]
            iv = inv[j + 1]
            R0[j + 1] = (R0[j + 1] - s01 - x0 * q) * iv
            R1[j + 1] = (R1[j + 1] - s11 - x1 * q) * iv
            R2[j + 1] = (R2[j + 1] - s21 - x2 * q) * iv
            R3[j + 1] = (R3[j + 1] - s31 - x3 * q) * iv
            j += 2
        for r in range(min(4, n - i)):
            ii = i + r
            R = A[ii]
            for jj in range(j, min(ii + 1, m)):
                Q = A[jj]
                s = 0.0
                for k in range(jj):
                    s += R[k] * Q[k]
                if jj == ii:
                    v = R[ii] - s
                    c = math.sqrt(v) if v > 0.0 else math.nan
                    R[ii] = c
                    inv[ii] = 1.0 / c
                else:
                    R[jj] = (R[jj] - s) * inv[jj]
        i += 4


@njit(**_JIT_IN)
def _write_predictive_rows(work, b, per, d, m, Z, Lam0, Phi, nu, lam):
    """loc, scale, dof of batch element b into work from Z[m + q, j] = (C^-1 [Psi^T, phi])[j, q]
    (lam: (2, 2) scratch)."""
    n, a = b // per, b % per
    c = 1.0
    zp = Z[m + d]
    for j in range(m):
        c += zp[j] * zp[j]
    df = nu[b] - d + 1.0
    f = c / df
    for i in range(d):
        zi = Z[m + i]
        s = 0.0
        for j in range(m):
            s += zi[j] * zp[j]
        work[n, LOC + a + i] = s
        for k in range(d):
            zk = Z[m + k]
            q = 0.0
            for j in range(m):
                q += zi[j] * zk[j]
            lam[i, k] = Lam0[i, k] + Phi[b, i, k] - q
    _write_scale(work, n, a, d, f, lam, df)


@njit(**_JIT)
def copy_order(idx):
    """The particles in the order in which an in-place copy a[:] = a[idx] reads every row before
    it is written, for sorted ancestors (`gather_lower`'s order): ascending where idx[i] > i,
    then descending where idx[i] < i, then the rows that keep their own (idx[i] == i)."""
    n = idx.shape[0]
    order = np.empty(n, np.int64)
    c = 0
    for i in range(n):
        if idx[i] > i:
            order[c] = i
            c += 1
    for i in range(n - 1, -1, -1):
        if idx[i] < i:
            order[c] = i
            c += 1
    for i in range(n):
        if idx[i] == i:
            order[c] = i
            c += 1
    return order


@njit(**_JIT)
def exact_forget_predictive_rows(K, Psi, Phi, nu, V, Lam0, work, per, forget, lam, nu_min, pending, zeta, phi_p,
                                 anc, gather):
    """`exact_forget_predictive` one matrix at a time (large bases): the pending update and
    the forgetting written into K and A in one sweep, the factorisation with the forward
    substitution by `_chol_rows`, then the predictive. With `gather`, the last resampling's
    copy of K's lower triangles (K[b] = K[anc-element of b], left to this pass by `resample`,
    which makes it itself unless the ancestors are sorted) is made by the sweep itself, which
    reads the ancestor's K and writes the element's: the elements in `copy_order` (sorted
    ancestors: no K is read after it was written)."""
    nb, d, m = Psi.shape
    A = np.zeros((m + d + 1, m))
    inv = np.empty(m)
    spare = np.zeros(m)
    lam2 = np.empty((2, 2))
    N = nb // per
    order = copy_order(anc) if gather else np.arange(N)
    for q in range(N):
        n = order[q]
        for a in range(per):
            b = n * per + a
            src = anc[n] * per + a if gather else b
            _update_forget_rows(K, Psi, Phi, nu, V, b, src, per, pending, zeta, phi_p, forget, lam, nu_min, A)
            for i in range(d):
                Pi = Psi[b, i]
                Ai = A[m + i]
                for j in range(m):
                    Ai[j] = Pi[j]
            ph = work[n, PHI + a * m:PHI + (a + 1) * m]
            Ai = A[m + d]
            for j in range(m):
                Ai[j] = ph[j]
            _chol_rows(A, m, inv, spare)
            _write_predictive_rows(work, b, per, d, m, A, Lam0, Phi, nu, lam2)


@njit(**_JIT)
def rank1_forget_predictive(M, P, Lam, nu, work, per, forget, lam, nu_min, bounded, trace0):
    """`MNIWRank1.forget` (with `forget`) then `.predictive` over a flat batch, into work."""
    nb, d, m = M.shape
    for b in range(nb):
        if forget:
            _rank1_forget1(P, Lam, nu, b, lam, nu_min, bounded, trace0)
        n, a = b // per, b % per
        c = 0.0
        for i in range(m):
            s = 0.0
            for j in range(m):
                s += P[b, i, j] * work[n, PHI + a * m + j]
            c += work[n, PHI + a * m + i] * s
        c = 1.0 + c
        df = nu[b] - d + 1.0
        f = c / df
        for i in range(d):
            s = 0.0
            for j in range(m):
                s += M[b, i, j] * work[n, PHI + a * m + j]
            work[n, LOC + a + i] = s
        if d == 2:
            for i in range(2):
                for k in range(2):
                    work[n, S + 2 * i + k] = f * Lam[b, i, k]
            work[n, DOF] = df
        else:
            work[n, S + 3 * a] = f * Lam[b, 0, 0]
            if a == 0:
                work[n, S + 1] = 0.0
                work[n, S + 2] = 0.0
                work[n, DOF] = df


# ---- 3. weights ---------------------------------------------------------------------------------
@njit(**_JIT)
def weigh(x, work, logw, c0, c1, ay, yr, R0, R1, have_ay, have_r, learned, add):
    """Eq. (22) with zeta integrated out; returns (ESS, predicted a^Y, predicted yaw rate) and
    writes the normalised log-weights (as `normalize_log_weights`) and, for the learned
    measurement, work[:, SC:E + 1] = S c, the a^Y marginal's scale and the residual."""
    n = x.shape[0]
    lw = np.empty(n)
    pred_ay = 0.0
    pred_r = 0.0
    nu_last = math.nan
    const = 0.0
    for i in range(n):
        h0 = c0 * work[i, PF] + c1 * work[i, PR]
        lc = work[i, LOC] * c0 + work[i, LOC + 1] * c1
        l = 0.0
        if have_ay:
            if learned:
                sc0 = work[i, S] * c0 + work[i, S + 1] * c1
                sc1 = work[i, S + 2] * c0 + work[i, S + 3] * c1
                nu = work[i, DOF]
                s_y = (sc0 * c0 + sc1 * c1) + R0 * (nu - 2.0) / nu
                e = ay - h0 - lc
                work[i, SC], work[i, SC + 1], work[i, SY], work[i, E] = sc0, sc1, s_y, e
                if nu != nu_last:
                    const = math.lgamma(0.5 * (nu + 1.0)) - math.lgamma(0.5 * nu)
                    nu_last = nu
                l += const - 0.5 * math.log(nu * math.pi * s_y) - 0.5 * (nu + 1.0) * math.log1p(e * e / (nu * s_y))
            else:
                e = ay - h0
                l += -0.5 * (e * e / R0 + math.log(2 * math.pi * R0))
        if have_r:
            er = yr - x[i, 1]
            l += -0.5 * (er * er / R1 + math.log(2 * math.pi * R1))
        q = math.exp(logw[i])
        pred_ay += q * (h0 + lc if learned else h0)
        pred_r += q * x[i, 1]
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
    return 1.0 / s2, pred_ay, pred_r, common_dof(work, add)


# ---- 4. resampling copies -----------------------------------------------------------------------
@njit(**_JIT_IN)
def _sorted(idx):
    for i in range(1, idx.shape[0]):
        if idx[i] < idx[i - 1]:
            return False
    return True


@njit(**_JIT)
def gather_rows(arrays, idx):
    """a[:] = a[idx] for each (N, k) array, in place. Sorted ancestors (systematic
    resampling): row i only ever reads a row j with idx[j] == j or one not yet written
    (ascending pass for idx[i] > i, descending for idx[i] < i), so no copy is needed;
    otherwise through a copy."""
    n = idx.shape[0]
    if _sorted(idx):
        for a in arrays:
            for i in range(n):
                j = idx[i]
                if j > i:
                    a[i, :] = a[j, :]
            for i in range(n - 1, -1, -1):
                j = idx[i]
                if j < i:
                    a[i, :] = a[j, :]
    else:
        for a in arrays:
            b = a.copy()
            for i in range(n):
                a[i, :] = b[idx[i], :]


@njit(**_JIT_IN)
def _copy_lower(K, i, j):
    for a in range(K.shape[1]):
        for r in range(K.shape[2]):
            for c in range(r + 1):
                K[i, a, r, c] = K[j, a, r, c]


@njit(**_JIT)
def systematic_ancestors(logw, u0):
    """`stats.systematic_resample` after its uniform draw u0 (`systematic_into`), into a new
    array."""
    idx = np.empty(logw.shape[0], np.int64)
    systematic_into(logw, u0, idx)
    return idx


@njit(**_JIT)
def gather_lower(K, idx):
    """K[:] = K[idx] (K (N, per, m, m)) for the lower triangles, in place as `gather_rows`."""
    n = idx.shape[0]
    if _sorted(idx):
        for i in range(n):
            if idx[i] > i:
                _copy_lower(K, i, idx[i])
        for i in range(n - 1, -1, -1):
            if idx[i] < i:
                _copy_lower(K, i, idx[i])
    else:
        B = K.copy()
        for i in range(n):
            K[i] = B[idx[i]]


@njit(**_JIT_IN)
def _copy_lanes(Kl, per, i, j):
    """Particle j's batch elements' K (lower triangles) into particle i's, in the lanes layout."""
    W, m = Kl.shape[3], Kl.shape[1]
    for a in range(per):
        s, t = j * per + a, i * per + a
        bs, ws, bt, wt = s // W, s % W, t // W, t % W
        for r in range(m):
            for c in range(r + 1):
                Kl[bt, r, c, wt] = Kl[bs, r, c, ws]


@njit(**_JIT)
def gather_lanes(Kl, idx, per):
    """`gather_lower` for K in lanes (`exact_forget_predictive`), in place, the same order."""
    n = idx.shape[0]
    if _sorted(idx):
        for i in range(n):
            if idx[i] > i:
                _copy_lanes(Kl, per, i, idx[i])
        for i in range(n - 1, -1, -1):
            if idx[i] < i:
                _copy_lanes(Kl, per, i, idx[i])
    else:
        B = Kl.copy()
        W, m = Kl.shape[3], Kl.shape[1]
        for i in range(n):
            for a in range(per):
                s, t = idx[i] * per + a, i * per + a
                for r in range(m):
                    for c in range(r + 1):
                        Kl[t // W, r, c, t % W] = B[s // W, r, c, s % W]


@njit(**_JIT)
def resample(logw, u0, arrays, K, per, lanes, add, work, anc, defer):
    """Systematic resampling after its uniform u0 (`systematic_ancestors`), its copies in place
    (`gather_rows` for every (N, k) array; K's lower triangles by `gather_lanes` when `lanes`,
    else `gather_lower` (K (N, per, m, m)); none when K is empty: the rank-one statistics), the
    log-weights set to -log N; returns `common_dof(work, add)` after the copies. The ancestors
    into anc; with `defer` (the rows pass) K's copy is left to the next pass
    (`exact_forget_predictive_rows` with anc) when the ancestors are sorted (systematic
    resampling's always are), else made here and anc set to the identity."""
    n = logw.shape[0]
    idx = systematic_ancestors(logw, u0)
    anc[:] = idx
    gather_rows(arrays, idx)
    if K.shape[0] > 0:
        if lanes:
            gather_lanes(K, idx, per)
        elif not (defer and _sorted(idx)):
            gather_lower(K, idx)
            for i in range(n):
                anc[i] = i
    v = -math.log(n)
    for i in range(n):
        logw[i] = v
    return common_dof(work, add)


@njit(**_JIT)
def mirror(K):
    """K[b] upper triangle = lower triangle transposed, for every b."""
    nb, m = K.shape[0], K.shape[1]
    for b in range(nb):
        for i in range(m):
            for j in range(i):
                K[b, j, i] = K[b, i, j]


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
def sample(x, work, logw, z, u, zeta, mu, conditional, keep_phi, phi_p):
    """zeta ~ St (the t conditional given the a^Y residual when `conditional`, else the
    predictive) from z ~ N(0, I), u ~ chi2(dof'), as `student_t.t_sample`; mu = mu~ + zeta.
    Returns the weighted means and std of x and the mean slip angles."""
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
    m0 = m1 = mf = mr = 0.0
    qs = np.empty(n)  # the weights, exponentiated once for both sums
    for i in range(n):
        q = qs[i] = math.exp(logw[i])
        m0 += q * x[i, 0]
        m1 += q * x[i, 1]
        mf += q * work[i, AF]
        mr += q * work[i, AR]
    v0 = v1 = 0.0
    for i in range(n):
        q = qs[i]
        v0 += q * (x[i, 0] - m0) ** 2
        v1 += q * (x[i, 1] - m1) ** 2
    if keep_phi:  # the features of the pending update (exact statistics while learning)
        k = phi_p.shape[1]
        for i in range(n):
            for j in range(k):
                phi_p[i, j] = work[i, PHI + j]
    return m0, m1, math.sqrt(max(v0, 0.0)), math.sqrt(max(v1, 0.0)), mf, mr


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


# ---- 6. learning ----------------------------------------------------------------------------------
@njit(**_JIT)
def rank1_update(M, P, Lam, nu, work, zeta, per):
    """`MNIWRank1.update` in place (recursive least squares) with the features in work."""
    nb, d, m = M.shape
    g = np.empty(m)
    gs = np.empty(m)
    e = np.empty(d)
    for b in range(nb):
        n, a = b // per, b % per
        _rank1_update1(M, P, Lam, nu, b, zeta[n, a:a + d], work[n, PHI + a * m:PHI + (a + 1) * m], g, gs, e)


# ---- the step ------------------------------------------------------------------------------------
def _flat(a, tail: int):
    return a.reshape((-1,) + a.shape[a.ndim - tail:])


class CompiledStep:
    """The compiled step of one `FrictionGPSSM` (built at its `reset`): the work array and
    flat views of the statistics' arrays (the statistics are updated in place); below
    `LANES_BELOW` functions with the exact statistics also K in lanes (`Kl`, the statistics'
    K written back by `flush`)."""

    def __init__(self, est):
        from tirefilter.stats.mniw_numba import NumbaMNIW, NumbaMNIWRank1

        cfg, N = est.cfg, est.cfg.particles
        self.est = est
        self.N = N
        self.tensor = est.d == 2
        self.per = 1 if self.tensor else 2
        size = est.basis.size
        self.work = np.zeros((N, PHI + size * self.per))
        self.zeta = np.zeros((N, 2))
        self.phi_p = np.zeros((N, size * self.per))  # features of the pending update
        self.pending = False  # exact statistics: this step's update waits for the next pass
        self.stale_upper = False  # the kernels keep K's lower triangle; `flush` mirrors it
        # the rows pass (from LANES_BELOW functions): the last resampling's ancestors, whose copy
        # of K's lower triangles the next pass makes (`gather`: still to be made)
        self.anc = np.arange(N, dtype=np.int64)
        self.gather = False
        keep = np.ascontiguousarray(est.basis.keep, np.int64)
        m1 = int(est.b1.m)
        self.keep, self.keep_r = (keep // m1, keep % m1) if est.d == 2 else (keep, keep)
        self.m1 = m1
        self.L = float(cfg.L)
        self.exact = cfg.stats == "exact"
        st = est._stats
        if not isinstance(st, (NumbaMNIW, NumbaMNIWRank1)):
            raise TypeError("the compiled step needs the compiled statistics (backend numba)")
        self.lanes = size < LANES_BELOW
        # exact statistics in lanes: K lives in Kl between `flush`es (kl_loaded: Kl holds K, the
        # statistics' K is stale; loaded from the statistics at the next step after a flush)
        nb = N * self.per
        W = min(LANES, -(-nb // 4) * 4)  # fewer lanes for a small batch (each lane's numbers are its own)
        self.Kl = (np.zeros((-(-nb // W), size, size, W)) if self.exact and self.lanes
                   else np.zeros((0, 0, 0, 0)))
        self.kl_loaded = False
        v = est.vehicle
        self.veh = (float(est.Fz[0]), float(est.Fz[1]), float(v.mass), float(v.lf), float(v.lr),
                    float(v.yaw_inertia))
        # the configuration's scalars, read once (the configuration is frozen)
        self.max_step = float(cfg.max_step)
        self.sn = np.asarray(cfg.state_noise, float)
        self.noise = bool(cfg.state_noise[0] > 0 or cfg.state_noise[1] > 0)
        self.gate_speed = float(cfg.gate_speed)
        self.lam = float(cfg.forgetting)
        self.nu0 = float(est.nu0)
        self.learned = cfg.measurement_friction == "learned"
        self.threshold = cfg.resample_threshold * N
        self.R0, self.R1 = float(est.R[0]), float(est.R[1])
        self.sqrt_R1 = math.sqrt(est.R[1])
        self._cache = None  # views of the statistics and the particles (`_arrays`); not pickled
        self._prior = self._template = self._slope = self._front_prior = self._pargs = None

    def __getstate__(self):  # views would come back as copies: rebuilt after unpickling
        state = dict(self.__dict__)
        state["_cache"] = None
        return state

    def _arrays(self):
        """(statistics, particles, flat statistics' views, the resampling's (N, k) views, K for the
        resampling copies, the statistics' arrays), rebuilt when the statistics, their arrays or
        the particles' array were replaced (K then loaded into the lanes again)."""
        est = self.est
        st = est._stats
        a0, a1, a2 = (st.K, st.Psi, st.Phi) if self.exact else (st.M, st.P, st.Lam)
        c = self._cache
        if c is not None:  # (`is` one by one: a generator over the four costs about a microsecond)
            a = c[5]
            if c[0] is st and c[1] is est.x and a[0] is a0 and a[1] is a1 and a[2] is a2 and a[3] is st.nu:
                return c
        arrays = (a0, a1, a2, st.nu)
        N = self.N
        views = (_flat(arrays[0], 2), _flat(arrays[1], 2), _flat(arrays[2], 2), arrays[3].reshape(-1))
        rows = (st.Psi, st.Phi) if self.exact else (st.M, st.P, st.Lam)
        rows = tuple(a.reshape(N, -1) for a in rows) + (st.nu.reshape(N, -1), est.x, self.work)
        if self.exact and not self.lanes:  # (the rows pass makes the copy: `resample`'s `defer`)
            kcopy = st.K.reshape((N, self.per) + st.K.shape[-2:])
        else:
            kcopy = self.Kl  # lanes, or empty (rank-one statistics: nothing beyond the rows)
        if c is not None and not (c[0] is st and c[5][0] is a0):
            self.kl_loaded = False  # other statistics or another K: K from them (a new particles'
            # array alone leaves the lanes holding the statistics' current K)
            self.gather = False  # (and no resampling copy made into them)
        self._cache = c = (st, est.x, views, rows, kcopy, arrays)
        return c

    def flush(self) -> None:
        """Apply a pending update of the exact statistics now (before anything reads them)."""
        # (each flag cleared once its work is done: a reader never sees it cleared over statistics
        # that are still stale)
        if self.kl_loaded:  # K's lower triangle back from the lanes
            lanes_store(self.Kl, self._views()[0])
            self.stale_upper = True
            self.kl_loaded = False  # the step loads it again (a reader may change the statistics)
        if self.gather:  # the last resampling's copy of K, left to the next pass
            K = self._views()[0]
            gather_lower(K.reshape((self.N, self.per) + K.shape[1:]), self.anc)
            self.stale_upper = True
            self.gather = False
        if self.pending:
            K, Psi, Phi, nu = self._views()
            d, m = Psi.shape[1:]  # per particle and step: `per` batch rows of d outputs and m features
            exact_update(Phi, Psi, K, nu, self.zeta.reshape(-1, d), self.phi_p.reshape(-1, m))
            self.stale_upper = True  # the reference's update writes both triangles; the lower one is kept
            self.pending = False
        if self.stale_upper:
            mirror(self._views()[0])
            self.stale_upper = False

    def _views(self):
        return self._arrays()[2]

    def _rows(self):
        """Every per-particle array as (N, k) views, for the resampling copies."""
        return self._arrays()[3]

    def _estimate(self, ess, vx, moments):
        """`FrictionGPSSM._estimate` with the exact statistics and no MPF, the same fields: the
        stiffness fields (`_curve_slope` without M: the last snapshot's or the prior's) and the
        Estimate's defaults built by `Estimate` again only when the snapshot's slope or the prior
        changed; per step a copy of that template's fields with this step's (a frozen dataclass's
        `__init__` sets its 18 fields one by one: 3-5 us a step)."""
        est = self.est
        if est._slope is not self._slope or est.prior is not self._prior:
            self._slope, self._prior = est._slope, est.prior
            stiff = {k: float(v) for k, v in est._curve_slope(None, None).items()}
            self._template = Estimate(active=False, vx=NAN, vy=NAN, yaw_rate=NAN, ess=NAN, **stiff).__dict__
        m0, m1, s0, s1 = moments
        e = _new(Estimate)
        fields = e.__dict__
        fields.update(self._template)
        fields.update(active=est.active, vx=vx, vy=float(m0), yaw_rate=float(m1), ess=ess,
                      state_std=(0.0, float(s0), float(s1)))
        return e

    def step(self, t, uk, delta: float, vx: float, y):
        est = self.est
        N, rng = self.N, est.rng
        work, Fz0, Fz1, mass, lf, lr, Iz = self.work, *self.veh
        _, _, (a1, a2, a3, nu), rows, kcopy, _ = self._arrays()
        # 1. propagate with the friction drawn at k-1 (eq. (1)), forget (eq. (29), fused into 2.)
        forget = False
        propagate, n_sub, h, cd, vx_prev = False, 0, 0.0, 1.0, 0.0
        if est.t_prev is None:
            if math.isfinite(y.yaw_rate):
                est.x[:, 1] = y.yaw_rate + self.sqrt_R1 * rng.standard_normal(N)
        else:
            dt = t - est.t_prev
            if dt <= 0:
                raise ConfigError("inputs", "t", f"time must increase: {t} after {est.t_prev}")
            n_sub = max(1, math.ceil(dt / self.max_step - 1e-9))
            h = dt / n_sub
            u_prev = est.u_prev
            cd, vx_prev, propagate = math.cos(u_prev[0]), float(u_prev[1]), True
            if self.noise:
                front(est.x, est.mu, work, True, n_sub, h, cd, vx_prev, Fz0, Fz1, mass, lf, lr, Iz, delta, vx,
                      self.L, self.m1, self.keep, self.keep_r, self.tensor, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0)
                est.x[:] = est.x + math.sqrt(dt) * self.sn * rng.standard_normal(est.x.shape)
                propagate = False
            forget = est.active
        est.active = active = bool(vx > self.gate_speed and est.learning_started)
        # 2. slip angles (clipped, counted), features, prior
        p = est.prior
        if p is not self._front_prior:  # the prior's parameters as floats, again when the prior changes
            self._front_prior = p
            self._pargs = (float(p.B[0]), float(p.B[1]), float(p.C), float(p.D[0]), float(p.D[1]), float(p.E))
        n_out = front(est.x, est.mu, work, propagate, n_sub, h, cd, vx_prev, Fz0, Fz1, mass, lf, lr, Iz, delta, vx,
                      self.L, self.m1, self.keep, self.keep_r, self.tensor, *self._pargs)
        est.slip_evaluations += N
        if n_out:
            est.clipped += n_out
            est.clipped_steps += 1
        # 3. forgetting and predictive
        if self.exact:
            V, Lam0 = est._stats.V, est._stats.Lam0
            if self.lanes:
                if not self.kl_loaded:
                    lanes_load(a1, self.Kl)
                    self.kl_loaded = True
                exact_forget_predictive(self.Kl, a2, a3, nu, V, Lam0, work, self.per, forget, self.lam, self.nu0,
                                        self.pending, self.zeta, self.phi_p)
            else:
                exact_forget_predictive_rows(a1, a2, a3, nu, V, Lam0, work, self.per, forget, self.lam, self.nu0,
                                             self.pending, self.zeta, self.phi_p, self.anc, self.gather)
                self.stale_upper = True
                self.gather = False
            self.pending = False
        else:
            rank1_forget_predictive(a1, a2, a3, nu, work, self.per, forget, self.lam, self.nu0,
                                    bool(est._stats.bounded), float(est._stats.trace0))
        # 4. weights (eq. (22)), resampling
        yay, yr = float(y.ay), float(y.yaw_rate)
        have_ay = math.isfinite(yay)
        learned = self.learned
        conditional = have_ay and learned
        add = 1.0 if conditional else 0.0
        ess, pa, pr_, c = weigh(est.x, work, est.logw, Fz0 * math.cos(delta) / mass, Fz1 / mass, yay, yr, self.R0,
                                self.R1, have_ay, math.isfinite(yr), learned, add)
        est.prediction = (pa, pr_)
        if ess < self.threshold:  # as stats.systematic_resample, its uniform first
            defer = self.exact and not self.lanes
            c = resample(est.logw, float(rng.random((1,))[0]), rows, kcopy, self.per, self.lanes, add, work,
                         self.anc, defer)
            est.resamples += 1
            self.gather = defer  # K's copy: in the next pass (or `flush`)
        # 5. zeta (t conditional given the a^Y residual), mu, learning
        if math.isnan(c):  # dof differing between particles (or NaN): as the reference
            z, u = t_draws(work[:, DOF] + 1.0 if conditional else work[:, DOF], (N, 2), rng)
            u = np.ascontiguousarray(u, float)
        else:  # t_draws' generator calls for a common dof, without its checks
            z, u = rng.standard_normal((N, 2)), rng.chisquare(c, (N,))
        exact_active = active and self.exact
        m0, m1, s0, s1, mf, mr = sample(est.x, work, est.logw, z, u, self.zeta, est.mu, conditional, exact_active,
                                        self.phi_p)
        if active:
            if self.exact:  # applied in the next step's pass over the statistics (or by `flush`)
                self.pending = True
            else:
                rank1_update(a1, a2, a3, nu, work, self.zeta, self.per)
            v = est.visited
            est.visited = [min(v[0], mf), max(v[1], mf), min(v[2], mr), max(v[3], mr)]
            if self.tensor:  # the reference's `_path[0, jf] += (1.0, mr)`, element by element
                jf, jr = est._bin(mf), est._bin(mr)
                path = est._path
                path[0, jf, 0] += 1.0
                path[0, jf, 1] += mr
                path[1, jr, 0] += 1.0
                path[1, jr, 1] += mf
        est.t_prev, est.u_prev, est.last_t = t, uk, t
        if self.exact and est.mpf_estimate is None:
            return self._estimate(ess, vx, (m0, m1, s0, s1))
        return est._estimate(ess, vx, (m0, m1, s0, s1))
