"""The GP-SSM's lateral dynamics between two samples (friction paper eq. (1) with mu^x = 0),
pure functions of arrays with the particles on the leading axis (docs/derivations.md, "F4. The
filter step"):

    v^Y' = a^Y - v^X r,   r' = (l_f F^z_f mu_f cos delta - l_r F^z_r mu_r) / I_zz,
    a^Y = (F^z_f mu_f cos delta + F^z_r mu_r) / m.

`propagate` holds the forces of the friction drawn at the step's first sample (the paper's
discretisation (7)); `linear_hold_remainder` is what forces growing linearly over the step add
to that (`force_hold = "linear"`: from the friction drawn at the first sample to the
friction's conditional mean at the last)."""

from __future__ import annotations

import math

import numpy as np


def force_rates(mu, cos_delta: float, Fz, mass: float, lf: float, lr: float, yaw_inertia: float) -> np.ndarray:
    """(N, 2): a^Y and r' of the frictions mu (N, 2) = (mu_f, mu_r) at the steering angle whose
    cosine is cos_delta (eq. (1b)-(1c) with mu^x = 0); Fz the static axle loads (eq. (2))."""
    Ff = Fz[0] * mu[:, 0] * cos_delta
    Fr = Fz[1] * mu[:, 1]
    return np.stack([(Ff + Fr) / mass, (lf * Ff - lr * Fr) / yaw_inertia], axis=1)


def propagate(x, rates, vx: float, dt: float, max_step: float) -> np.ndarray:
    """x = [v^Y, r] (N, 2) after dt with the rates (N, 2) of `force_rates` held and v^X held:
    Euler sub-steps of at most max_step for the kinematic term v^X r (v^Y first, then r)."""
    n = max(1, math.ceil(dt / max_step - 1e-9))
    h = dt / n
    x = x.copy()
    ay, rdot = rates[:, 0], rates[:, 1]
    for _ in range(n):
        x[:, 0] += h * (ay - vx * x[:, 1])
        x[:, 1] += h * rdot
    return x


def linear_hold_remainder(rates0, rates1, vx: float, dt: float) -> np.ndarray:
    """(N, 2): what the rates growing linearly from rates0 to rates1 over dt add to x = [v^Y, r]
    beyond rates0 held: with D = rates1 - rates0, the exact integral of x' = (D_a s / dt - v^X dr,
    D_r s / dt) from dr(0) = 0, i.e. r gains D_r dt / 2 and v^Y gains D_a dt / 2 - v^X D_r dt^2 / 6."""
    D = rates1 - rates0
    return np.stack([0.5 * dt * D[:, 0] - vx * dt * dt / 6.0 * D[:, 1], 0.5 * dt * D[:, 1]], axis=1)
