"""The GP-SSM's resampling (compiled.py describes the step, 4.): the ancestors
(`systematic_ancestors`) and the in-place copies of the per-particle arrays (`gather_rows`) and
of K's lower triangles (`gather_lower`, `gather_lanes` in the lanes layout), `resample`."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tirefilter.estimators.gpssm.kernels_particles import common_dof
from tirefilter.stats.particles_numba import systematic_into

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True)  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls (called from Python it crashes the
# interpreter instead of raising: tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)


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
