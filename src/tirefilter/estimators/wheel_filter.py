"""Wheel-speed pre-filter of the stiffness MPF: a Kalman filter per axle for the rolling
speed s = R_w omega, driven by the IMU's longitudinal acceleration (docs/derivations.md,
"Wheel-speed pre-filter").

Why: the MPF takes the wheel speeds as exact inputs (the paper's model). Their white noise
then enters the predicted a^X through the wheel slip, C (R_w omega - v^X) / (m D), as a noise
proportional to the stiffness C that the measured a^X does not contain; the weights and the
conditional of the stiffness deviations prefer a smaller C that injects less of it (an
errors-in-variables bias): on the peer drives' 0.03 rad/s wheel-speed noise the MPF's Cx ended
48 % low. The filter gives the MPF an estimate of the noise-free rolling speed instead.

Model per axle i (f, r), at the samples k:

    s_k = s_{k-1} + dt_k (a^X_{k-1} - b_ax + v^Y r) + e_k,    e_k ~ N(0, (sigma_ax dt_k)^2 + q_s^2 dt_k)
    z_k = R_w omega_k,meas = s_k + n_k,                       n_k ~ N(0, (R_w sigma_omega)^2)

The vehicle's own acceleration d v^X / dt = a^X + v^Y r carries the wheels along; what it
leaves out is the accelerometer's white noise over the step (sigma_ax dt) and the change of
the axle's slip speed s - v^X, a random walk with `slip_rw` q_s (m/s per sqrt(s)). A common
error of both axles' s (an accelerometer bias left over, a pitch or grade) shifts the MPF's
v^X with it and leaves the stiffness alone ("Wheel-speed pre-filter"). `drive` is the bracket, given by the
caller (the MPF: the last sample's measured a^X minus its posterior-mean bias plus the
posterior-mean v^Y r).
"""

from __future__ import annotations

import math

import numpy as np


class WheelSpeedFilter:
    """Scalar Kalman filters of the two axles' rolling speeds R_w omega (m/s), sharing the
    drive input. `sigma_omega` rad/s (> 0), `wheel_radius` m, `sigma_ax` m/s^2 (>= 0),
    `slip_rw` m/s per sqrt(s) (>= 0)."""

    def __init__(self, sigma_omega: float, wheel_radius: float, sigma_ax: float, slip_rw: float):
        if not (sigma_omega > 0 and math.isfinite(sigma_omega)):
            raise ValueError(f"sigma_omega must be finite and > 0, got {sigma_omega!r}")
        if not (wheel_radius > 0 and sigma_ax >= 0 and slip_rw >= 0):
            raise ValueError("wheel_radius must be > 0, sigma_ax and slip_rw >= 0")
        self.r = (wheel_radius * sigma_omega) ** 2  # measurement variance of R_w omega, (m/s)^2
        self.radius = wheel_radius
        self.sigma_ax, self.slip_rw = float(sigma_ax), float(slip_rw)
        # (Python floats: two scalar filters cost less on floats than on numpy's scalars, bit for bit the same)
        self.s = [math.nan, math.nan]  # rolling speeds of the front and rear axle, m/s
        self.P = [math.nan, math.nan]  # their variances

    def process_variance(self, dt: float) -> float:
        """Variance added to each s over a step dt: (sigma_ax dt)^2 + q_s^2 dt."""
        return (self.sigma_ax * dt) ** 2 + self.slip_rw**2 * dt

    def reset(self) -> None:
        """Forget the estimates: the next measurement of each axle starts it again."""
        self.s = [math.nan, math.nan]
        self.P = [math.nan, math.nan]

    def step(self, dt: float, omega, drive: float) -> np.ndarray:
        """The filtered wheel speeds omega (2,) rad/s at this sample, from the measured ones
        `omega` (2,) (NaN: missing, the prediction stands and NaN is returned for it), after a
        step dt (s) from the last sample with the bracket `drive` (m/s^2; NaN: no input, the
        prediction holds s and adds nothing for the acceleration). An axle without an
        estimate yet starts at its measurement with variance r."""
        out = [math.nan, math.nan]
        q = self.process_variance(dt)
        s, P, r = self.s, self.P, self.r
        step = dt * drive if math.isfinite(drive) else None
        for i in range(2):
            z = self.radius * float(omega[i])
            si, pi = s[i], P[i]
            if math.isfinite(si):
                if step is not None:
                    si += step
                pi += q
            if math.isfinite(z):
                if not math.isfinite(si):
                    si, pi = z, r
                else:
                    k = pi / (pi + r)
                    si += k * (z - si)
                    pi *= 1.0 - k
                out[i] = si / self.radius
            s[i], P[i] = si, pi
        return np.array(out)


def steady_state_gain(r: float, q: float) -> float:
    """The gain the filter settles to for a constant step: with the predicted variance M
    solving M = M r / (M + r) + q, M = (q + sqrt(q^2 + 4 q r)) / 2, the gain K = M / (M + r)."""
    m = 0.5 * (q + math.sqrt(q * q + 4.0 * q * r))
    return m / (m + r)
