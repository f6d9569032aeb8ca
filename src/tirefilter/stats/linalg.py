"""Batched linear algebra for the small matrices of a particle filter (n <= 4 per
particle, thousands of particles): Cholesky and triangular solves written out entry by
entry, each entry a vector operation over the batch. For such sizes this is several
times faster than numpy.linalg's batched routines, which pay a per-matrix overhead."""

from __future__ import annotations

import numpy as np


def chol(S: np.ndarray, jitter: float = 0.0) -> np.ndarray:
    """Lower Cholesky factor of (...,n,n) symmetric positive-definite matrices (the
    lower triangle is read). Non-positive pivots are floored at a tiny fraction of the
    diagonal scale instead of producing NaN (round-off on near-singular matrices)."""
    n = S.shape[-1]
    L = np.zeros_like(S)
    for j in range(n):
        Sjj = S[..., j, j]
        d = Sjj + jitter if jitter else Sjj
        for k in range(j):
            d = d - L[..., j, k] * L[..., j, k]
        Ljj = np.sqrt(np.maximum(d, np.abs(Sjj) * 1e-14 + 1e-300))
        L[..., j, j] = Ljj
        if j + 1 < n:
            inv = 1.0 / Ljj
            for i in range(j + 1, n):
                acc = S[..., i, j]
                for k in range(j):
                    acc = acc - L[..., i, k] * L[..., j, k]
                L[..., i, j] = acc * inv
    return L


def solve_lower(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with L x = b; b is (..., n) or (..., n, k)."""
    n = L.shape[-1]
    vec = b.ndim == L.ndim - 1
    B = b[..., None] if vec else b
    x = np.empty(np.broadcast_shapes(L.shape[:-2], B.shape[:-2]) + B.shape[-2:])
    for i in range(n):
        acc = B[..., i, :]
        for k in range(i):
            acc = acc - L[..., i, k, None] * x[..., k, :]
        x[..., i, :] = acc / L[..., i, i, None]
    return x[..., 0] if vec else x


def solve_upper_t(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with L^T x = b; b is (..., n) or (..., n, k)."""
    n = L.shape[-1]
    vec = b.ndim == L.ndim - 1
    B = b[..., None] if vec else b
    x = np.empty(np.broadcast_shapes(L.shape[:-2], B.shape[:-2]) + B.shape[-2:])
    for i in reversed(range(n)):
        acc = B[..., i, :]
        for k in range(i + 1, n):
            acc = acc - L[..., k, i, None] * x[..., k, :]
        x[..., i, :] = acc / L[..., i, i, None]
    return x[..., 0] if vec else x


def chol_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with (L L^T) x = b."""
    return solve_upper_t(L, solve_lower(L, b))


def gram(M: np.ndarray) -> np.ndarray:
    """M^T M for (..., k, n) matrices, as a sum of k outer products (exactly symmetric)."""
    G = M[..., 0, :, None] * M[..., 0, None, :]
    for k in range(1, M.shape[-2]):
        G = G + M[..., k, :, None] * M[..., k, None, :]
    return G


def logdet_chol(L: np.ndarray) -> np.ndarray:
    return 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
