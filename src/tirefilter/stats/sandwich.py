"""Batch-means sandwich: how much wider the posterior of a regression coefficient is when
its per-sample scores are correlated in time (derivations, "Batch-means sandwich").

A linear-Gaussian posterior of a coefficient vector theta from samples y_k = d_k' theta +
e_k with white e_k has the covariance A^-1 (A = sum d_k d_k' / s^2, the information). When
the residuals e_k are correlated, as the misfit of a linear tire over the visited slips is,
the variance of the estimate is the sandwich A^-1 B A^-1 with B the long-run covariance of
the scores s_k = d_k e_k (White 1982; Newey and West 1987). B is estimated by batch means:
the outer products of the score sums over batches of `batch` seconds. The ratio to the same
sandwich with B0 = sum s_k s_k' (the lag-0 part, what white residuals would give) is, per
coefficient, the integrated autocorrelation time of its scores, and is scale-free: neither
the residual variance nor the regressors' scale enter it. All three statistics forget, per
closed batch of length T (seconds of samples actually fed), with exp(-T / memory) times the
product of the per-sample factors passed to `update` (the MPF passes its statistics' lambda_k,
so that the sandwich remembers what the mean remembers).
"""

from __future__ import annotations

import math

import numpy as np


class BatchMeansSandwich:
    """Online batch-means estimate of the sandwich factor of an n-vector of coefficients.

    `update(s, d, dt, forget)` feeds one sample: its score s = d e (n,), its regressor d (n,),
    its duration dt and its forgetting factor (1: none);
    `factor` (n,) is sqrt(max(1, [A^-1 B A^-1]_jj / [A^-1 B0 A^-1]_jj)), updated when a
    batch closes (1 until the first one has)."""

    def __init__(self, n: int, batch: float, memory: float):
        if not (batch > 0 and math.isfinite(batch)):
            raise ValueError(f"batch must be finite and > 0, got {batch!r}")
        if not memory > 0:
            raise ValueError(f"memory must be > 0 (inf: no forgetting), got {memory!r}")
        self.n, self.batch, self.memory = int(n), float(batch), float(memory)
        self.reset()

    def reset(self) -> None:
        n = self.n
        self.A = np.zeros((n, n))  # sum of d d' over the closed batches, forgotten
        self.B = np.zeros((n, n))  # sum over the closed batches of (sum s)(sum s)', forgotten
        self.B0 = np.zeros((n, n))  # sum over the closed batches of sum s s', forgotten
        self._S = np.zeros(n)  # the open batch: score sum, its sum of s s' and of d d', its length
        self._S0 = np.zeros((n, n))
        self._A = np.zeros((n, n))
        self._T = 0.0
        self._log_keep = 0.0  # sum of log(forget) over the open batch
        self.batches = 0
        self.factor = np.ones(n)
        self.ratio = np.ones(n)  # the unclipped ratio of the last closed batch (1 before)

    def update(self, s: np.ndarray, d: np.ndarray, dt: float, forget: float = 1.0) -> None:
        if not (dt > 0 and 0 < forget <= 1 and math.isfinite(float(s @ s) + float(d @ d))):  # (one test for all)
            return
        self._log_keep += math.log(forget)
        self._S += s
        self._S0 += s[:, None] * s  # (np.outer, without its Python wrapper)
        self._A += d[:, None] * d
        self._T += dt
        if self._T >= self.batch * (1.0 - 1e-9):
            self._close()

    def _close(self) -> None:
        keep = math.exp(self._log_keep - self._T / self.memory)
        self.A = keep * self.A + self._A
        self.B = keep * self.B + np.outer(self._S, self._S)
        self.B0 = keep * self.B0 + self._S0
        self._S[:] = 0.0
        self._S0[:] = 0.0
        self._A[:] = 0.0
        self._T = 0.0
        self._log_keep = 0.0
        self.batches += 1
        ratio = sandwich_ratio(self.A, self.B, self.B0)
        if ratio is not None:
            self.ratio = ratio
            self.factor = np.sqrt(np.maximum(1.0, ratio))


def sandwich_ratio(A: np.ndarray, B: np.ndarray, B0: np.ndarray) -> np.ndarray | None:
    """diag(A^-1 B A^-1) / diag(A^-1 B0 A^-1) (n,), or None where A is singular or a
    diagonal of the lag-0 sandwich is not positive."""
    try:
        Ai = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(Ai)):
        return None
    v = np.einsum("ij,jk,ik->i", Ai, B, Ai)
    v0 = np.einsum("ij,jk,ik->i", Ai, B0, Ai)
    if not np.all(v0 > 0):
        return None
    return v / v0


class BatchMeansSandwichPair(BatchMeansSandwich):
    """`BatchMeansSandwich` for n = 2 with the open batch's sums held as Python floats: the same
    arithmetic, element by element, as the parent's array updates (so the same numbers, bit for
    bit: tests/test_stats.py), without the parent's per-sample numpy calls (about 10 us per
    sample against 1-2 us; the MPF feeds one sample per step). `update_pair` takes the
    score and regressor components as floats; `update` (arrays) goes through it. `factor_pair` is
    `factor` as a tuple of floats. A closed batch hands the sums to the parent's `_close`."""

    def __init__(self, batch: float, memory: float):
        super().__init__(2, batch, memory)

    def reset(self) -> None:
        super().reset()
        # the open batch: score sums s0, s1; sums of s s' (00, 01, 11) and of d d' (00, 01, 11)
        self._s0 = self._s1 = self._q00 = self._q01 = self._q11 = self._a00 = self._a01 = self._a11 = 0.0
        self.factor_pair = (1.0, 1.0)

    def update(self, s: np.ndarray, d: np.ndarray, dt: float, forget: float = 1.0) -> None:
        s0, s1 = s.tolist()
        d0, d1 = d.tolist()
        self.update_pair(s0, s1, d0, d1, dt, forget)

    def update_pair(self, s0: float, s1: float, d0: float, d1: float, dt: float, forget: float = 1.0) -> None:
        if not (dt > 0 and 0 < forget <= 1 and math.isfinite(s0 * s0 + s1 * s1 + d0 * d0 + d1 * d1)):
            return
        self._log_keep += math.log(forget)
        self._s0 += s0
        self._s1 += s1
        self._q00 += s0 * s0  # (s s' and d d' are symmetric: their off-diagonal products are equal)
        self._q01 += s0 * s1
        self._q11 += s1 * s1
        self._a00 += d0 * d0
        self._a01 += d0 * d1
        self._a11 += d1 * d1
        self._T += dt
        if self._T >= self.batch * (1.0 - 1e-9):
            self._close()

    def _close(self) -> None:
        self._S[:] = (self._s0, self._s1)
        self._S0[:] = ((self._q00, self._q01), (self._q01, self._q11))
        self._A[:] = ((self._a00, self._a01), (self._a01, self._a11))
        self._s0 = self._s1 = self._q00 = self._q01 = self._q11 = self._a00 = self._a01 = self._a11 = 0.0
        super()._close()
        self.factor_pair = tuple(self.factor.tolist())
