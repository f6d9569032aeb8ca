"""The peer drives' sensors: a cheap automotive MEMS IMU and wheel-speed sensors.

Accelerometers and gyro: white noise plus a bias that is constant with a slow random
walk, b(t) = b0 + sum of N(0, q^2 dt) increments (bias = measured - true, DESIGN.md),
b0 uniform in [-b_max, b_max] per channel. The defaults sit in the range of automotive
MEMS data sheets (accelerometer noise 0.1-0.3 m/s^2 and zero-g offset up to a few
0.1 m/s^2 over temperature; gyro noise 0.003-0.01 rad/s and zero-rate offset up to about
0.01 rad/s at 100 Hz). Wheel rates: white noise only. The IMU reads the specific force and
rate of the body that carries it (`model.PeerModel.sample`): on the rolling body of the MB
model that includes g sin(roll).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

IMU_CHANNELS = ("ax", "ay", "yaw_rate")


@dataclass(frozen=True)
class SensorSpec:
    """Noise and bias of the peer drives' sensors (per channel: ax, ay, yaw rate)."""

    sigma: tuple[float, float, float] = (0.2, 0.2, 0.005)  # m/s^2, m/s^2, rad/s white-noise std
    bias_max: tuple[float, float, float] = (0.25, 0.25, 0.008)  # |b0| bound: m/s^2, m/s^2, rad/s
    bias_rw: tuple[float, float, float] = (0.002, 0.002, 5e-5)  # random-walk std per sqrt(s)
    sigma_omega: float = 0.03  # rad/s, wheel-rate white noise

    def scaled(self, noise: float = 1.0, bias: float = 1.0) -> "SensorSpec":
        """This spec with the white noise and the bias (b_max and random walk) scaled."""
        return SensorSpec(tuple(noise * s for s in self.sigma), tuple(bias * b for b in self.bias_max),
                          tuple(bias * q for q in self.bias_rw), noise * self.sigma_omega)


def imu_biases(t: np.ndarray, spec: SensorSpec, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) biases of ax, ay, yaw rate at the sample times t (n,)."""
    b0 = rng.uniform(-1.0, 1.0, 3) * np.asarray(spec.bias_max)
    dt = np.diff(t, prepend=t[0])
    steps = rng.standard_normal((t.size, 3)) * np.sqrt(dt)[:, None] * np.asarray(spec.bias_rw)
    return b0 + np.cumsum(steps, axis=0)


def measure(t: np.ndarray, true: dict, spec: SensorSpec, rng: np.random.Generator) -> tuple[dict, np.ndarray]:
    """Sensor readings from the true IMU readings `true["ax_imu"]`, `["ay_imu"]`,
    `["yaw_rate_imu"]` and wheel rates `["omega_f"]`, `["omega_r"]` (each (n,)); returns
    the readings (log names) and the (n, 3) biases."""
    bias = imu_biases(t, spec, rng)
    noise = rng.standard_normal((t.size, 3)) * np.asarray(spec.sigma)
    out = {name: true[f"{name}_imu"] + bias[:, i] + noise[:, i] for i, name in enumerate(IMU_CHANNELS)}
    for w in ("omega_f", "omega_r"):
        out[w] = true[w] + spec.sigma_omega * rng.standard_normal(t.size)
    return out, bias
