"""The friction GP-SSM's IMU bias: the a^Y and yaw-rate offsets b = (b_ay, b_r), each a random
walk observed additively, marginalised per particle by a Kalman filter (the sensor model of
the stiffness MPF, its eq. (29)-(30); docs/derivations.md, "F7. IMU bias").

Given a particle's trajectory (its state x_k and its sampled friction deviation zeta_k) both
channels are linear-Gaussian in b:

    y^Y_k = c_k . (mu~(alpha_k) + zeta_k) + b_ay + e^Y_k,   e^Y ~ N(0, R_ay)
    y^r_k = r_k + b_r + e^r_k,                             e^r ~ N(0, R_r)
    b_{k+1} = b_k + v_k,                                    v_k ~ N(0, diag(q) dt)

with independent noises, so the posterior of b given the trajectory is Gaussian with a
diagonal covariance (a diagonal prior stays diagonal): two scalar Kalman filters per particle.
Their state lives in one (N, 4) array, columns `AY, R` (means) and `AY_VAR, R_VAR`
(variances), so that resampling copies it in one row gather with the other per-particle
arrays.
"""

from __future__ import annotations

import numpy as np

AY, R, AY_VAR, R_VAR = 0, 1, 2, 3  # columns of the bias array


def bias_prior(n: int, bias0_std) -> np.ndarray:
    """(n, 4): zero means, the prior variances bias0_std^2 (a^Y [m/s^2], yaw rate [rad/s])."""
    out = np.zeros((n, 4))
    out[:, AY_VAR], out[:, R_VAR] = float(bias0_std[0]) ** 2, float(bias0_std[1]) ** 2
    return out


def bias_predict(bias: np.ndarray, q, dt: float) -> None:
    """The random walk over dt, in place: P += q dt (q = bias_rw^2 per s, per channel)."""
    bias[:, AY_VAR] += q[0] * dt
    bias[:, R_VAR] += q[1] * dt


def bias_update(bias: np.ndarray, channel: int, residual: np.ndarray, noise_var: float) -> None:
    """The Kalman update of one channel (AY or R) in place, per particle: with the innovation
    v = residual - b (residual: the measurement minus what the particle's trajectory
    predicts without bias) and S = P + noise_var, K = P / S, b += K v, P -= K P
    (as P noise_var / S, which stays positive)."""
    var = R_VAR if channel == R else AY_VAR
    P = bias[:, var]
    S = P + noise_var
    bias[:, channel] += P / S * (residual - bias[:, channel])
    bias[:, var] = P * (noise_var / S)


def bias_moments(q: np.ndarray, bias: np.ndarray) -> tuple[float, float, float, float]:
    """The mixture's mean and variance of b_ay and b_r over the particles (weights q):
    (mean_ay, mean_r, var_ay, var_r)."""
    m = q @ bias[:, :2]
    v = q @ (bias[:, 2:] + (bias[:, :2] - m) ** 2)
    return float(m[0]), float(m[1]), float(v[0]), float(v[1])
