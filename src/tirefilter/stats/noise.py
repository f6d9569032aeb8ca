"""White-noise level of a sampled signal, from the signal alone (docs/derivations.md,
"White noise from the data").

A vehicle signal sampled at 100 Hz is smooth on the scale of a few samples, while the
sensor's white noise is not. The second difference

    d_k = y_{k+1} - 2 y_k + y_{k-1} = (s_{k+1} - 2 s_k + s_{k-1}) + (e_{k+1} - 2 e_k + e_{k-1})

removes a signal s that is locally linear and leaves noise with variance 6 sigma^2 (the
weights 1, -2, 1 squared and summed). The curvature of s contributes s'' dt^2: 0.012 m/s^2
for a 3 m/s^2 a^Y swinging at 1 Hz, far below any accelerometer's noise. Steps in s (a
square-wave steer, a pothole) give a few large d_k; the median absolute deviation ignores
them, so the scale is sigma = 1.4826 MAD(d) / sqrt(6) (1.4826 makes the MAD of a Gaussian
its std).

Held samples (a logger repeating the last value when no new one arrived; 12% of the IMU
samples of the shared real recording) would add exact zeros to the differences and pull
the figure down; a sample equal to the one before is dropped first, and the differences are
taken over the samples that remain.
"""

from __future__ import annotations

import math

import numpy as np

MAD_TO_STD = 1.482602218505602  # 1 / Phi^-1(3/4)
MIN_SAMPLES = 20  # fewer usable samples: no estimate (NaN)


def white_noise_std(y: np.ndarray) -> float:
    """The white-noise std of the samples `y` (n,), NaN = missing; NaN when fewer than
    MIN_SAMPLES usable samples remain. Missing samples are skipped (the differences span
    them), held samples (equal to the previous finite sample) are dropped."""
    y = np.asarray(y, float)
    y = y[np.isfinite(y)]
    if y.size:
        fresh = np.concatenate(([True], np.diff(y) != 0.0))
        y = y[fresh]
    if y.size < MIN_SAMPLES:
        return math.nan
    d = y[2:] - 2.0 * y[1:-1] + y[:-2]
    mad = float(np.median(np.abs(d - np.median(d))))
    return MAD_TO_STD * mad / math.sqrt(6.0)


def held_share(y: np.ndarray) -> float:
    """Share of the finite samples of `y` that repeat the finite sample before them exactly
    (held values); NaN when there are fewer than two."""
    y = np.asarray(y, float)
    y = y[np.isfinite(y)]
    if y.size < 2:
        return math.nan
    return float(np.mean(np.diff(y) == 0.0))
