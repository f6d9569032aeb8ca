"""Compiled (numba, nopython, cached) systematic resampling, shared by the compiled steps of
the MPF (`estimators.mpf.kernels`) and the GP-SSM (`estimators.gpssm.kernels_resample`); the reference is
`tirefilter.stats.particles.systematic_resample`, tested equal in tests/test_kernels.py."""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(inline="always", cache=True, nogil=True)
def systematic_into(logw, u0, idx):
    """`systematic_resample` after its uniform draw u0, into idx (N,): cdf = cumsum(exp(logw))
    with cdf[-1] = 1, points (u0 + k) / N, ancestors by searchsorted(cdf, points, 'right')
    clipped to N - 1 (the points increase, so one merge pass)."""
    n = logw.shape[0]
    cdf = np.empty(n)
    acc = 0.0
    for i in range(n):
        acc += math.exp(logw[i])
        cdf[i] = acc
    cdf[n - 1] = 1.0
    j = 0
    for k in range(n):
        u = (u0 + k) / n
        while j < n - 1 and cdf[j] <= u:
            j += 1
        idx[k] = j
