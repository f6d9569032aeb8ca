"""Input profiles: each FMU input is a sum of components, evaluated on the time grid.

Open-loop components are vectorised over time. `speed_hold` is the one closed-loop
component: a PI driver that sets the drive torque from the speed error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tirefilter.config import get_number
from tirefilter.errors import ConfigError

INPUTS = ("delta", "drive_torque", "brake_torque", "surface", "bank")
INPUT_DEFAULTS = {"delta": 0.0, "drive_torque": 0.0, "brake_torque": 0.0, "surface": 1.0, "bank": 0.0}


def _window(t, start, end):
    return (t >= start) & (t < end)


@dataclass(frozen=True)
class Constant:
    value: float

    def evaluate(self, t):
        return np.full_like(t, self.value)


@dataclass(frozen=True)
class Square:
    """+amplitude for the first half of each period, -amplitude for the second."""

    amplitude: float
    period: float
    phase: float = 0.0  # s
    start: float = 0.0
    end: float = np.inf

    def evaluate(self, t):
        frac = np.mod(t - self.start + self.phase, self.period) / self.period
        # guard against round-off putting a grid point just below a half-period edge
        frac = np.round(frac, 12) % 1.0
        return np.where(_window(t, self.start, self.end), np.where(frac < 0.5, self.amplitude, -self.amplitude), 0.0)


@dataclass(frozen=True)
class Sine:
    amplitude: float
    period: float
    phase: float = 0.0  # s
    start: float = 0.0
    end: float = np.inf

    def evaluate(self, t):
        value = self.amplitude * np.sin(2 * np.pi * (t - self.start + self.phase) / self.period)
        return np.where(_window(t, self.start, self.end), value, 0.0)


@dataclass(frozen=True)
class Steps:
    """Piecewise constant: values[i] from times[i] on (values[0] before times[0])."""

    times: tuple[float, ...]
    values: tuple[float, ...]

    def evaluate(self, t):
        idx = np.searchsorted(np.asarray(self.times), t + 1e-9, side="right") - 1
        return np.asarray(self.values)[np.clip(idx, 0, len(self.values) - 1)]

    def change_times(self) -> list[float]:
        return [tk for tk, a, b in zip(self.times[1:], self.values[:-1], self.values[1:]) if a != b]


@dataclass(frozen=True)
class PiecewiseLinear:
    times: tuple[float, ...]
    values: tuple[float, ...]

    def evaluate(self, t):
        return np.interp(t, self.times, self.values)


@dataclass(frozen=True)
class FilteredNoise:
    """A fixed, seeded Ornstein-Uhlenbeck path (stationary std, correlation time), sampled
    every `dt` and linearly interpolated: the same 'recorded' signal on every run."""

    std: float
    correlation_time: float
    seed: int
    start: float = 0.0
    end: float = np.inf
    dt: float = 0.01

    def evaluate(self, t):
        t_end = float(np.max(t)) if np.size(t) else 0.0
        n = int(np.ceil(max(t_end - self.start, 0.0) / self.dt)) + 2
        rng = np.random.default_rng(self.seed)
        a = np.exp(-self.dt / self.correlation_time)
        e = rng.standard_normal(n) * self.std * np.sqrt(1 - a * a)
        path = np.empty(n)
        path[0] = 0.0  # starts at zero so a start time has no jump
        for k in range(1, n):
            path[k] = a * path[k - 1] + e[k]
        grid = self.start + self.dt * np.arange(n)
        return np.where(_window(t, self.start, self.end), np.interp(t, grid, path), 0.0)


@dataclass(frozen=True)
class SpeedHold:
    """PI speed controller: torque = m R_w (kp e + ki int e), e = v_ref(t) - vx.

    v_ref is constant (`speed`) or piecewise linear (`times`, `speed` lists). Gains in
    1/s and 1/s^2 act on acceleration, so they do not depend on the vehicle.
    """

    times: tuple[float, ...]
    speeds: tuple[float, ...]
    kp: float = 1.0
    ki: float = 0.2

    def reference(self, t):
        return np.interp(t, self.times, self.speeds)


_COMPONENTS = {
    "constant": (Constant, {"value"}, set()),
    "square": (Square, {"amplitude", "period"}, {"phase", "start", "end"}),
    "sine": (Sine, {"amplitude", "period"}, {"phase", "start", "end"}),
    "steps": (Steps, {"times", "values"}, set()),
    "piecewise_linear": (PiecewiseLinear, {"times", "values"}, set()),
    "filtered_noise": (FilteredNoise, {"std", "correlation_time", "seed"}, {"start", "end", "dt"}),
    "speed_hold": (SpeedHold, {"speed"}, {"times", "kp", "ki"}),
}


def _number_list(table, key, file, name, *, ascending=False):
    values = table[key]
    if not isinstance(values, list) or not values or not all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in values
    ):
        raise ConfigError(file, f"{name}.{key}", f"expected a non-empty list of numbers, got {values!r}")
    if ascending and any(b <= a for a, b in zip(values, values[1:])):
        raise ConfigError(file, f"{name}.{key}", f"times must be strictly increasing, got {values!r}")
    return tuple(float(x) for x in values)


def parse_component(table: dict, file, name: str):
    """One component from its TOML table; `name` is e.g. 'inputs.delta[0]'."""
    kind = table.get("type")
    if kind not in _COMPONENTS:
        raise ConfigError(file, f"{name}.type", f"expected one of {', '.join(_COMPONENTS)}, got {kind!r}")
    cls, required, optional = _COMPONENTS[kind]
    unknown = sorted(set(table) - required - optional - {"type"})
    if unknown:
        raise ConfigError(file, f"{name}.{unknown[0]}", f"unknown key for type {kind!r} "
                          f"(known: {', '.join(sorted(required | optional))})")
    missing = sorted(required - set(table))
    if missing:
        raise ConfigError(file, f"{name}.{missing[0]}", f"missing (required for type {kind!r})")
    prefix = f"{name}."
    if kind in ("steps", "piecewise_linear"):
        times = _number_list(table, "times", file, name, ascending=True)
        values = _number_list(table, "values", file, name)
        if len(times) != len(values):
            raise ConfigError(file, f"{name}.values", f"needs one value per time ({len(times)}), got {len(values)}")
        return cls(times, values)
    if kind == "speed_hold":
        if isinstance(table["speed"], list):
            if "times" not in table:
                raise ConfigError(file, f"{name}.times", "missing (required when speed is a list)")
            times = _number_list(table, "times", file, name, ascending=True)
            speeds = _number_list(table, "speed", file, name)
            if len(times) != len(speeds):
                raise ConfigError(file, f"{name}.speed", f"needs one speed per time ({len(times)}), got {len(speeds)}")
        else:
            times, speeds = (0.0,), (get_number(table, "speed", file, prefix=prefix, lo=0.0, lo_open=True),)
        if min(speeds) <= 0:
            raise ConfigError(file, f"{name}.speed", "speeds must be positive")
        kp = get_number(table, "kp", file, prefix=prefix, default=1.0, lo=0.0)
        ki = get_number(table, "ki", file, prefix=prefix, default=0.2, lo=0.0)
        return SpeedHold(times, speeds, kp, ki)
    kwargs = {}
    for key in required | optional:
        if key not in table:
            continue
        lo, lo_open, integer = None, False, False
        if key in ("period", "correlation_time", "dt"):
            lo, lo_open = 0.0, True
        elif key == "std":
            lo = 0.0
        elif key == "seed":
            lo, integer = 0, True
        kwargs[key] = get_number(table, key, file, prefix=prefix, lo=lo, lo_open=lo_open, integer=integer)
    if kwargs.get("end", np.inf) <= kwargs.get("start", 0.0):
        raise ConfigError(file, f"{name}.end", "must be after start")
    return cls(**kwargs)


@dataclass(frozen=True)
class InputSchedule:
    """All inputs of a scenario: open-loop components per input, and an optional
    speed-hold driver on the drive torque."""

    components: dict  # input name -> tuple of components (open loop)
    speed_hold: SpeedHold | None = None

    def open_loop(self, t: np.ndarray) -> np.ndarray:
        """(len(t), 5) inputs in INPUTS order, without the speed-hold torque."""
        out = np.empty((len(t), len(INPUTS)))
        for j, name in enumerate(INPUTS):
            comps = self.components.get(name, ())
            out[:, j] = sum((c.evaluate(t) for c in comps), np.zeros_like(t)) if comps else INPUT_DEFAULTS[name]
        return out

    def surface_changes(self) -> list[float]:
        times = []
        for c in self.components.get("surface", ()):
            if isinstance(c, Steps):
                times += c.change_times()
            elif not isinstance(c, Constant):
                raise ValueError("surface changes are defined by 'steps' or 'constant' components only")
        return sorted(set(times))
