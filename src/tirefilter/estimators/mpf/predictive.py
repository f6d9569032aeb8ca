"""The stiffness MPF's one-step predictive of the measured a^Y and yaw rate, for the model check
(`tirefilter.model_check`; docs/derivations.md, "The model check").

Before sample k is weighed, particle i predicts channel j with the Student-t of eq. (35)-(36):
location y_j - e_ij (e the residual of the weighting), scale S_i,jj and nu~_i degrees of
freedom, i.e. variance S_i,jj nu~_i / (nu~_i - 2). The filter's predictive is their mixture with
the predictive weights w_{k-1}: its mean is y_j - sum_i w_i e_ij and its variance, by the law of
total variance, sum_i w_i S_i,jj nu~_i / (nu~_i - 2) + sum_i w_i (e_ij - e_bar_j)^2.

`mixture_moments` is the numpy reference (from S's diagonal); `mixture_moments_chol` the
compiled step's (from the Cholesky factor of S that the weighting leaves, S_jj = sum_k L_jk^2),
the same expressions in one pass over the particles.
"""

from __future__ import annotations

import math

import numpy as np


def mixture_moments(logw: np.ndarray, e: np.ndarray, s_diag: np.ndarray, nu: np.ndarray, cols) -> np.ndarray:
    """(2, len(cols)): the mixture's mean residual sum_i w_i e_ij and its predictive variance, for
    the columns `cols` of e (N, na) and s_diag (N, na) (the scale's diagonal), nu (N,), logw (N,)
    the predictive log-weights."""
    q = np.exp(logw)
    out = np.empty((2, len(cols)))
    for k, j in enumerate(cols):
        ej = e[:, j]
        em = float(q @ ej)
        out[0, k] = em
        out[1, k] = float(q @ (s_diag[:, j] * nu / (nu - 2.0))) + float(q @ (ej - em) ** 2)
    return out


def _mixture_moments_chol(q, e, Lc, nu, cols, out):
    """`mixture_moments` from the predictive weights q (N,) (not their logarithms) and the Cholesky
    factors Lc (N, m, m) of the scale, into out (2, len(cols))."""
    n = q.shape[0]
    for k in range(cols.shape[0]):
        j = cols[k]
        em = 0.0
        for i in range(n):
            em += q[i] * e[i, j]
        v = 0.0
        d = 0.0
        for i in range(n):
            s = 0.0
            for c in range(j + 1):
                s += Lc[i, j, c] * Lc[i, j, c]
            v += q[i] * (s * nu[i] / (nu[i] - 2.0))
            r = e[i, j] - em
            d += q[i] * r * r
        out[0, k] = em
        out[1, k] = v + d


_COMPILED = []  # the compiled `_mixture_moments_chol`, once (numba imported on first use only)


def mixture_moments_chol(q, e, Lc, nu, cols, out) -> None:
    """`_mixture_moments_chol` compiled (numba, cached)."""
    if not _COMPILED:
        from numba import njit

        _COMPILED.append(njit(cache=True, nogil=True)(_mixture_moments_chol))
    _COMPILED[0](q, e, Lc, nu, cols, out)


def predictive_columns(channels, a) -> tuple[int, int]:
    """The columns of a^Y and of the yaw rate among the available channels `a` (indices into
    `channels`, whose entries 0, 1, 2 are a^X, a^Y, yaw rate); -1 where missing."""
    ay = yaw = -1
    for j, c in enumerate(a):
        if channels[c] == 1:
            ay = j
        elif channels[c] == 2:
            yaw = j
    return ay, yaw


def keep(mpf, t: float, yk: np.ndarray, a: np.ndarray, e, scale, nu, logw, q=None) -> None:
    """`mpf._pred` (`one_step_predictive`): (t, the predicted means, variances and the measured
    values of a^Y and the yaw rate), NaN for a missing channel; nothing without an a^Y sample.
    The numpy step gives the scale matrices S (N, na, na) and the log-weights, the compiled one
    their Cholesky factors and the weights `q` (a buffer for them)."""
    cols = predictive_columns(mpf.channels, a)
    if cols[0] < 0:
        return
    present = [j for j in cols if j >= 0]
    if q is None:
        moments = mixture_moments(logw, e, np.diagonal(scale, axis1=1, axis2=2), nu, present)
    else:
        moments = np.empty((2, len(present)))
        mixture_moments_chol(np.exp(logw, out=q), e, scale, nu, np.array(present, np.int64), moments)
    mean, var, meas = np.full(2, math.nan), np.full(2, math.nan), np.full(2, math.nan)
    k = 0
    for c, j in enumerate(cols):
        if j >= 0:
            y = float(yk[a[j]])
            meas[c], mean[c], var[c] = y, y - moments[0, k], moments[1, k]
            k += 1
    mpf._pred = (t, mean, var, meas)
