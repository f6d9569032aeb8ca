"""Particle weights in log space and systematic resampling."""

from __future__ import annotations

import numpy as np


def normalize_log_weights(log_w: np.ndarray) -> np.ndarray:
    """Normalised log-weights along the last axis (log-sum-exp, no underflow).

    Particles with log-weight -inf keep weight 0; if every particle has -inf (or NaN),
    the weights are reset to uniform rather than becoming NaN.
    """
    log_w = np.where(np.isnan(log_w), -np.inf, log_w)
    m = np.max(log_w, axis=-1, keepdims=True)
    bad = ~np.isfinite(m)
    shifted = np.where(bad, 0.0, log_w - np.where(bad, 0.0, m))
    lse = np.log(np.sum(np.exp(shifted), axis=-1, keepdims=True))
    return np.where(bad, -np.log(log_w.shape[-1]), shifted - lse)


def effective_sample_size(log_w_normalized: np.ndarray) -> np.ndarray:
    """1 / sum(q^2) for normalised log-weights (Algorithm 1, line 7)."""
    return 1.0 / np.sum(np.exp(2.0 * log_w_normalized), axis=-1)


def systematic_resample(log_w_normalized: np.ndarray, rng: np.random.Generator, count: int | None = None) -> np.ndarray:
    """Ancestor indices by systematic resampling: one uniform u, points (u + j) / count
    (count defaults to the number of particles).

    Works on the last axis; leading axes (Monte-Carlo trials) get independent uniforms.
    The caller applies the indices to every per-particle array.
    """
    w = np.exp(log_w_normalized)
    n = w.shape[-1]
    m = n if count is None else int(count)
    cdf = np.cumsum(w, axis=-1)
    cdf[..., -1] = 1.0  # guard against round-off
    u = (rng.random(w.shape[:-1] + (1,)) + np.arange(m)) / m
    if w.ndim == 1:
        return np.searchsorted(cdf, u[0] if u.ndim > 1 else u, side="right").clip(0, n - 1)
    idx = np.empty(w.shape[:-1] + (m,), dtype=np.intp)
    for pos in np.ndindex(w.shape[:-1]):
        idx[pos] = np.searchsorted(cdf[pos], u[pos], side="right")
    return idx.clip(0, n - 1)
