"""v^X for the friction GP-SSM where the log has no `vx` column: the rolling speed R_w omega of
the undriven axle (the axle that hardly slips; the stiffness MPF's `single_track.vx_from_wheels`),
pre-filtered with a^X when the wheel speeds are noisy (`wheel_filter.WheelSpeedFilter`;
docs/derivations.md, "F8. v^X from the wheel speeds")."""

from __future__ import annotations

import math

import numpy as np

from tirefilter.estimators.wheel_filter import WheelSpeedFilter


def undriven_wheel(vehicle) -> str:
    """The wheel-speed signal v^X is taken from: the rear axle's unless the car is rear-driven
    (as `single_track.vx_from_wheels`)."""
    return "omega_f" if vehicle.drive == "rear" else "omega_r"


class WheelSpeedVx:
    """v^X [m/s] at each sample from the undriven axle's wheel speed: R_w omega as measured
    (`sigma_omega` 0), or its `WheelSpeedFilter` estimate driven by the last sample's a^X plus
    v^Y r (`sigma_omega` > 0 rad/s; `sigma_ax` m/s^2 the accelerometer's white noise,
    `slip_rw` m/s per sqrt(s) the random walk of the axle's slip speed). NaN while the wheel
    has given no sample."""

    def __init__(self, vehicle, sigma_omega: float, sigma_ax: float, slip_rw: float):
        self.front = vehicle.drive == "rear"
        self.radius = float(vehicle.wheel_radius)
        self.filter = WheelSpeedFilter(sigma_omega, self.radius, sigma_ax, slip_rw) if sigma_omega > 0 else None
        self.reset()

    def reset(self) -> None:
        self.t_prev = None
        self.drive = math.nan  # a^X + v^Y r of the last sample (m/s^2)
        self.last = math.nan
        if self.filter is not None:
            self.filter.reset()

    def step(self, t: float, omega_f: float, omega_r: float) -> float:
        """v^X at t from the wheel speeds of this sample (NaN: missing; the filter's prediction,
        or the last value without a filter)."""
        omega = omega_f if self.front else omega_r
        if self.filter is None:
            v = self.radius * omega
        else:
            dt = t - self.t_prev if self.t_prev is not None else 0.0
            pair = np.array([omega, math.nan]) if self.front else np.array([math.nan, omega])
            v = self.radius * float(self.filter.step(dt, pair, self.drive)[0 if self.front else 1])
            if not math.isfinite(v) and math.isfinite(self.filter.s[0 if self.front else 1]):
                v = float(self.filter.s[0 if self.front else 1])  # a missing sample: the prediction
        self.t_prev = t
        if math.isfinite(v):
            self.last = v
        return self.last

    def set_drive(self, ax: float, vy_r: float) -> None:
        """The bracket of the filter's next prediction: this sample's measured a^X and the
        posterior mean of v^Y r (NaN a^X: the prediction holds the speed)."""
        self.drive = ax + vy_r if math.isfinite(ax) else math.nan
