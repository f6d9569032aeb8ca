"""The peer drives' sensors: a cheap automotive MEMS IMU and wheel-speed sensors.

Accelerometers and gyro: white noise plus a bias that is constant with a slow random
walk, b(t) = b0 + sum of N(0, q^2 dt) increments (bias = measured - true, docs/design.md),
b0 uniform in [-b_max, b_max] per channel. The defaults sit in the range of automotive
MEMS data sheets (accelerometer noise 0.1-0.3 m/s^2 and zero-g offset up to a few
0.1 m/s^2 over temperature; gyro noise 0.003-0.01 rad/s and zero-rate offset up to about
0.01 rad/s at 100 Hz). Wheel rates: white noise only. The IMU reads the specific force and
rate of the body that carries it (`model.PeerModel.sample`): on the rolling body of the MB
model that includes g sin(roll). A data logger's dropouts (`dropouts`): single empty cells,
single missing rows and one gap of 0.5-1 s.
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


def imu_biases(t: np.ndarray, spec: SensorSpec, seed: np.random.SeedSequence) -> np.ndarray:
    """(n, 3) biases of ax, ay, yaw rate at the sample times t (n,): one generator per
    channel, so a longer drive of the same seed starts with the same biases."""
    dt = np.diff(t, prepend=t[0])
    out = np.empty((t.size, 3))
    for i, child in enumerate(seed.spawn(3)):
        rng = np.random.default_rng(child)
        b0 = rng.uniform(-1.0, 1.0) * spec.bias_max[i]
        out[:, i] = b0 + np.cumsum(rng.standard_normal(t.size) * np.sqrt(dt) * spec.bias_rw[i])
    return out


def measure(t: np.ndarray, true: dict, spec: SensorSpec, seed: np.random.SeedSequence) -> tuple[dict, np.ndarray]:
    """Sensor readings from the true IMU readings `true["ax_imu"]`, `["ay_imu"]`,
    `["yaw_rate_imu"]` and wheel rates `["omega_f"]`, `["omega_r"]` (each (n,)); returns
    the readings (log names) and the (n, 3) biases. Every channel draws from its own
    generator (spawned from `seed`): the readings of a drive are a prefix of those of a
    longer drive with the same seed."""
    bias_seed, *noise_seeds = seed.spawn(1 + len(IMU_CHANNELS) + 2)
    bias = imu_biases(t, spec, bias_seed)
    out = {}
    for i, (name, child) in enumerate(zip(IMU_CHANNELS, noise_seeds)):
        noise = spec.sigma[i] * np.random.default_rng(child).standard_normal(t.size)
        out[name] = true[f"{name}_imu"] + bias[:, i] + noise
    for w, child in zip(("omega_f", "omega_r"), noise_seeds[len(IMU_CHANNELS):]):
        out[w] = true[w] + spec.sigma_omega * np.random.default_rng(child).standard_normal(t.size)
    return out, bias


LOGGED_SIGNALS = ("delta", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r")


@dataclass(frozen=True)
class DropoutSpec:
    """A data logger's dropouts: empty cells, missing rows and one longer gap."""

    blank_rate: float = 0.002  # probability that a signal's cell is empty (each signal on its own)
    row_rate: float = 0.002  # probability that a row is missing
    gap: tuple[float, float] = (0.5, 1.0)  # s, one gap of missing rows, its length uniform in this range


def dropouts(t: np.ndarray, spec: DropoutSpec, seed: np.random.SeedSequence, *, after: float = 0.0,
             signals: tuple[str, ...] = LOGGED_SIGNALS) -> tuple[np.ndarray, dict]:
    """Which rows of the sample times t (n,) the logger keeps ((n,) bool: the first and the
    last always) and which cells it leaves empty (signal -> (n,) bool): single rows and
    cells missing at random, and one gap of `spec.gap` seconds starting at a uniform time
    in [after, t[-1] - 3 s - its length]."""
    rng = np.random.default_rng(seed)
    n = t.size
    keep = rng.random(n) >= spec.row_rate
    length = rng.uniform(*spec.gap)
    start = rng.uniform(after, max(after, t[-1] - 3.0 - length))
    keep &= ~((t >= start) & (t < start + length))
    keep[0] = keep[-1] = True
    blank = {name: rng.random(n) < spec.blank_rate for name in signals}
    return keep, blank
