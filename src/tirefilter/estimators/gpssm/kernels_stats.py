"""The GP-SSM's kernels over the statistics (compiled.py describes the step): step 2, the pass
that applies the pending update, forgets and computes the predictive (`exact_forget_predictive`
in lanes, `exact_forget_predictive_rows` one matrix at a time, `rank1_forget_predictive`), K's
lanes (`lanes_load`, `lanes_store`) and its upper triangle (`mirror`), and step 6, the rank-one
statistics' update (`rank1_update`)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# (the columns of `work` are compiled into these kernels as constants: numba's cache, keyed by this file,
# does not see a change of them in kernels_particles.py, so a change there goes with an edit here)
from tirefilter.estimators.gpssm.kernels_particles import DOF, LOC, PHI, S  # features from column 17
from tirefilter.stats.mniw_numba import _factor, _rank1_forget1, _rank1_update1

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True)  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls (called from Python it crashes the
# interpreter instead of raising: tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)
LANES = 32  # batch elements factorised together (eight AVX2 vectors of float64; measured best of 8-32)
LANES_BELOW = 32  # basis size from which `_chol_rows` factorises each matrix alone instead


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
def _lane_heads(stats, b0, nw, per, learn, pend, heads):
    """The per-element start of a block's pass, lanes w < nw (batch elements b0 + w), stats =
    (Psi, Phi, nu), learn = (forget, lam, nu_min), pend = (pending, zeta, phi_p), heads = (fv, gv,
    phl) (`exact_forget_predictive`): with
    `pending` the previous step's update of Phi, Psi and nu (eq. (27a)-(27b), (28f)) scaled by
    the forgetting factor f (`_pending_head`) and its features phl[:, w]; without, the
    forgetting of Phi and Psi (`_scale_psi_phi`); then nu *= f (as the reference, after
    nu += 1). fv[w] = f and gv[w] = 1 - f for the sweep over K; the padding lanes f = 1, 1 - f =
    0, zero features (their identity matrix stays the identity)."""
    Psi, Phi, nu = stats
    forget, lam, nu_min = learn
    pending, zeta, phi_p = pend
    fv, gv, phl = heads
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
def exact_forget_predictive(Kl, stats, prior, work, per, learn, pend):
    """The exact statistics' pass below `LANES_BELOW` functions, with K = Sigma + V kept by the
    compiled step in lanes (`Kl` (blocks, m, m, LANES): Kl[b // LANES, i, j, b % LANES] = K[b, i,
    j], lower triangle; the padding lanes of the last block the identity; `lanes_load`,
    `lanes_store`). stats = (Psi (B, d, m), Phi (B, d, d), nu (B,)): the flat batch, per batch
    elements per particle (axle 2); prior = (V, Lam0); learn = (forget, lam, nu_min), the
    forgetting (`_factor`); pend = (pending, zeta, phi_p). In one pass over each block of lanes:
    with `pending` the previous step's update (eq. (27), zeta (N, 2) at features phi_p), with
    `forget` eq. (29), written into Kl and into the factorisation's matrix A in one sweep, every
    operation a vector one over the lanes; then the factorisation with the forward substitution
    (`_chol_lanes`) and the predictive St(M phi, c Lambda / (nu - d + 1), nu - d + 1)
    (eq. (31)-(32)) into work. Per element the reference's operations in the reference's order
    ((K + phi phi^T) * f, then + (1 - f) V on the diagonal; without a pending update K * f, then
    + (1 - f) V): the lanes layout only changes which element an instruction works on, not what
    it computes."""
    Psi, Phi, nu = stats
    V, Lam0 = prior
    forget = learn[0]
    pending = pend[0]
    nb, d, m = Psi.shape
    W = Kl.shape[3]
    A = np.empty((m + d + 1, m, W))
    inv = np.empty((m, W))
    acc = np.empty((1 + d + d * d, W))
    lam2 = np.empty((2, 2))
    fv = np.empty(W)
    gv = np.empty(W)
    phl = np.empty((m, W))
    heads = (fv, gv, phl)
    for blk in range(Kl.shape[0]):
        b0 = blk * W
        nw = min(W, nb - b0)
        Kb = Kl[blk]
        if pending or forget:
            _lane_heads(stats, b0, nw, per, learn, pend, heads)
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
def _update_forget_rows(K, stats, V, b, src, per, learn, pend, A):
    """Batch element b (stats = (Psi, Phi, nu), learn = (forget, lam, nu_min), pend = (pending,
    zeta, phi_p) as `exact_forget_predictive`): the pending update (eq. (27a)-(27c), (28f)) then the forgetting
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
    Psi, Phi, nu = stats
    forget, lam, nu_min = learn
    pending, zeta, phi_p = pend
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
def exact_forget_predictive_rows(K, stats, prior, work, per, learn, pend, anc, gather):
    """`exact_forget_predictive` one matrix at a time (large bases): the pending update and
    the forgetting written into K and A in one sweep, the factorisation with the forward
    substitution by `_chol_rows`, then the predictive. With `gather`, the last resampling's
    copy of K's lower triangles (K[b] = K[anc-element of b], left to this pass by `resample`,
    which makes it itself unless the ancestors are sorted) is made by the sweep itself, which
    reads the ancestor's K and writes the element's: the elements in `copy_order` (sorted
    ancestors: no K is read after it was written). The arguments as `exact_forget_predictive`'s."""
    Psi, Phi, nu = stats
    V, Lam0 = prior
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
            _update_forget_rows(K, stats, V, b, src, per, learn, pend, A)
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

@njit(**_JIT)
def mirror(K):
    """K[b] upper triangle = lower triangle transposed, for every b."""
    nb, m = K.shape[0], K.shape[1]
    for b in range(nb):
        for i in range(m):
            for j in range(i):
                K[b, j, i] = K[b, i, j]


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
