"""Plausibility of a log's values (`check-log`, and the start of `replay`): values a car
cannot produce are almost always a unit or a column mix-up. Accumulated chunk by chunk, so
a streamed replay checks the whole file in its first pass.

Each warning names the column, the extreme value, where it occurs first, and the likely
cause (ISO 8855 magnitudes of a road car: v^X < 90 m/s, road-wheel steer < 45 deg,
|a| < 15 m/s^2, |yaw rate| < 2.5 rad/s).
"""

from __future__ import annotations

import math

import numpy as np

REPEAT_SHARE = 0.05  # repeated IMU samples beyond this share are held samples
IMU = ("ax", "ay", "yaw_rate")

# (signal, limit, unit, how the limit is shown, likely cause)
LIMITS = (
    ("vx", 90.0, "m/s", "90 m/s", "vx in km/h? (the Log CSV wants m/s: divide by 3.6)"),
    ("delta", math.radians(45.0), "rad", "45 deg of road-wheel steer",
     None),  # cause depends on the size: see _delta_cause
    ("ax", 15.0, "m/s^2", "15 m/s^2", "spikes from a faulty sensor, or another unit (g, ft/s^2)?"),
    ("ay", 15.0, "m/s^2", "15 m/s^2", "spikes from a faulty sensor, or another unit (g, ft/s^2)?"),
    ("yaw_rate", 2.5, "rad/s", "2.5 rad/s", "yaw rate in deg/s? (the Log CSV wants rad/s: multiply by pi/180)"),
)


def _delta_cause(value: float) -> str:
    if abs(value) > 2 * math.pi:
        return ("steering in degrees? (the Log CSV wants rad)" if abs(value) <= 720 else
                "the steering-wheel angle in degrees?") + " A steering-wheel angle belongs in steering_wheel_angle " \
            "with steering_ratio in the vehicle TOML"
    return ("the steering-wheel angle instead of the road-wheel angle? Give it as steering_wheel_angle with "
            "steering_ratio in the vehicle TOML (or delta in degrees?)")


class Plausibility:
    """`add(chunk)` for each chunk of a log (io.log.Log), then `warnings()`."""

    def __init__(self):
        self.extreme: dict[str, tuple[float, float, int]] = {}  # signal -> (value, t, data row) of the first beyond
        self.beyond: dict[str, int] = {}
        self.prev: dict[str, float] = {}
        self.repeats = {s: 0 for s in IMU}
        self.finite = {s: 0 for s in IMU}

    def add(self, log) -> None:
        for name, limit, *_ in LIMITS:
            x = log.signals.get(name)
            if x is None:
                continue
            over = np.flatnonzero(np.abs(x) > limit)  # NaN compares False
            if over.size:
                self.beyond[name] = self.beyond.get(name, 0) + int(over.size)
                k = int(over[np.argmax(np.abs(x[over]))])
                if name not in self.extreme or abs(x[k]) > abs(self.extreme[name][0]):
                    self.extreme[name] = (float(x[k]), float(log.t[k]), log.row0 + k + 1)
        for name in IMU:
            x = log.signals.get(name)
            if x is None:
                continue
            f = x[np.isfinite(x)]
            if not f.size:
                continue
            self.finite[name] += int(f.size)
            self.repeats[name] += int(np.count_nonzero(f[1:] == f[:-1])) + int(f[0] == self.prev.get(name))
            self.prev[name] = float(f[-1])

    def repeated_share(self, name: str) -> float:
        return self.repeats[name] / self.finite[name] if self.finite[name] else 0.0

    def warnings(self) -> list[str]:
        out = []
        for name, limit, unit, shown, cause in LIMITS:
            if name in self.extreme:
                v, t, row = self.extreme[name]
                out.append(f"{name} beyond {shown} in {self.beyond[name]} samples (largest {v:.4g} {unit} at t = "
                           f"{t:g} s, data row {row}): {cause or _delta_cause(v)}")
        for name in IMU:
            share = self.repeated_share(name)
            if share > REPEAT_SHARE:
                out.append(f"{name} repeats its previous sample in {100 * share:.1f}% of its samples: held samples "
                           f"(the IMU sampled slower than the log, a sample-and-hold) or a frozen sensor; the "
                           f"measurement guard treats a repeat as a missing sample")
        return out
