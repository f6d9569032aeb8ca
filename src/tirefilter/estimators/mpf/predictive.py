"""The stiffness MPF's one-step predictive of the measured a^Y and yaw rate, for the model check
(`tirefilter.model_check`; docs/derivations.md, "The model check").

Before sample k is weighed, particle i predicts channel j with the Student-t of eq. (35)-(36):
location y_j - e_ij (e the residual of the weighting), scale S_i,jj and nu~_i degrees of
freedom, i.e. variance S_i,jj nu~_i / (nu~_i - 2). The filter's predictive is their mixture with
the predictive weights w_{k-1}: its mean is y_j - sum_i w_i e_ij and its variance, by the law of
total variance, sum_i w_i S_i,jj nu~_i / (nu~_i - 2) + sum_i w_i (e_ij - e_bar_j)^2.

`mixture_moments` is the numpy reference (from S's diagonal); `mixture_moments_chol` the
compiled step's (from the Cholesky factor of S that the weighting leaves, S_jj = sum_k L_jk^2),
in one pass over the particles (tests/test_model_check.py: equal to rounding).
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


def _mixture_moments_chol(logw, e, Lc, nu, cols, out):
    """`mixture_moments` from the log-weights, the residuals e (N, m) and the Cholesky factors Lc
    (N, m, m) of the scale, in one pass over the particles, into out (2, len(cols)); the spread
    of the residuals as sum_i w^i e_ij^2 - e_bar_j^2 (one pass: equal to the two-pass reference
    to rounding, the spread being small against the residual's square only where both are small)."""
    n, nk = logw.shape[0], cols.shape[0]
    for k in range(nk):
        out[0, k] = 0.0
        out[1, k] = 0.0
    e2 = np.zeros(nk)
    for i in range(n):
        q = math.exp(logw[i])
        scale = nu[i] / (nu[i] - 2.0)
        for k in range(nk):
            j = cols[k]
            s = 0.0
            for c in range(j + 1):
                s += Lc[i, j, c] * Lc[i, j, c]
            out[0, k] += q * e[i, j]
            e2[k] += q * e[i, j] * e[i, j]
            out[1, k] += q * s * scale
    for k in range(nk):
        out[1, k] += max(e2[k] - out[0, k] * out[0, k], 0.0)


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


def keep(mpf, t: float, yk: np.ndarray, a: np.ndarray, e, scale, nu, logw, compiled: bool = False) -> None:
    """`mpf._pred` (`one_step_predictive`): (t, the predicted means, variances and the measured
    values of a^Y and the yaw rate), NaN for a missing channel; nothing without an a^Y sample.
    The numpy step gives the scale matrices S (N, na, na), the compiled one (`compiled`) their
    Cholesky factors."""
    cols = predictive_columns(mpf.channels, a)
    if cols[0] < 0:
        return
    present = cols if cols[1] >= 0 else cols[:1]
    if compiled:
        moments = np.empty((2, len(present)))
        arr = _COL_ARRAYS.get(present)
        if arr is None:
            arr = _COL_ARRAYS[present] = np.array(present, np.int64)
        (mpf._nb.mixture_moments_chol if mpf.cfg.backend == "c" else mixture_moments_chol)(logw, e, scale, nu, arr,
                                                                                          moments)
    else:
        moments = mixture_moments(logw, e, np.diagonal(scale, axis1=1, axis2=2), nu, present)
    m = moments.tolist()
    y_ay = float(yk[a[cols[0]]])
    if cols[1] >= 0:
        y_r = float(yk[a[cols[1]]])
        mpf._pred = (t, (y_ay - m[0][0], y_r - m[0][1]), (m[1][0], m[1][1]), (y_ay, y_r))
    else:
        mpf._pred = (t, (y_ay - m[0][0], NAN), (m[1][0], NAN), (y_ay, NAN))


NAN = math.nan
_COL_ARRAYS: dict = {}  # the kernel's column arrays, one per set of columns
