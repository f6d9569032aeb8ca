"""What the learning samples' slip angles carry into the calibrated band and curve of the
friction GP-SSM (docs/derivations.md, "F5. The friction estimate", items 1 and 4): per axle and
grid bin of the posterior-mean slip, the slip's posterior variance and the held forces' signed
slip error, forgotten with the statistics' factor and smoothed over the kernel's length-scale."""

from __future__ import annotations

import numpy as np


class SlipRecord:
    """Per axle (2) and grid bin (G): `spread` [forgotten count, forgotten sum of the slip
    variance] (2, G, 2) and `lag` the forgotten sum of the held forces' slip error (2, G)."""

    def __init__(self, grid: np.ndarray, lengthscale: float):
        self.grid, self.lengthscale = grid, float(lengthscale)
        self.spread = np.zeros((2, len(grid), 2))
        self.lag = np.zeros((2, len(grid)))
        self._smoother = None

    def add(self, lam: float, jf: int, jr: int, var_f: float, var_r: float, lag: float = 0.0) -> None:
        """A learning sample: the variances var_f, var_r of its slips (over the particles, after
        resampling) and its held-force slip error `lag` into the bins jf, jr of its mean slips, the
        older ones forgotten with the statistics' factor lam."""
        sp = self.spread
        if lam != 1.0:
            sp *= lam
            self.lag *= lam
        self.lag[0, jf] += lag
        self.lag[1, jr] += lag
        sp[0, jf, 0] += 1.0
        sp[0, jf, 1] += var_f
        sp[1, jr, 0] += 1.0
        sp[1, jr, 1] += var_r

    def _smoothed(self, sums: np.ndarray) -> np.ndarray:
        """sum_b k(a - a_b) sums_b / sum_b k(a - a_b) W_b over the grid (0 where no sample is near)."""
        if self._smoother is None:
            d = (self.grid[:, None] - self.grid[None, :]) / self.lengthscale
            self._smoother = np.exp(-0.5 * d * d)
        num = sums @ self._smoother.T
        den = self.spread[:, :, 0] @ self._smoother.T
        return np.where(den > 1e-12, num / np.maximum(den, 1e-300), 0.0)

    def variance(self) -> np.ndarray:
        """(2, G): the slip's posterior variance at the learning samples near each grid point."""
        return self._smoothed(self.spread[:, :, 1])

    def shift(self) -> np.ndarray:
        """(2, G): the mean held-force slip error of the learning samples near each grid point."""
        return self._smoothed(self.lag)
