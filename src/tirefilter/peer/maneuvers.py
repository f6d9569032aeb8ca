"""Steering and speed profiles of the peer drives, on a fine time grid.

Every maneuver starts with `straight` seconds of straight driving at the set speed, then
excites the lateral dynamics mostly in the linear tire region: the steer amplitude is
chosen for a peak lateral acceleration `ay` (m/s^2) in steady state, from the linear
single-track gain at the set speed with the peer's static axle stiffness,
delta = a_y (L + K_us v^2) / v^2, K_us = m (lr/Cf - lf/Cr) / L. Transients come from
the steering itself; every steer change is smooth (raised-cosine envelopes and ramps), so
the steering rate stays within the peer's 0.4 rad/s limit.

- `sine`: a 0.5 Hz sine to the end (1 s straight at the end).
- `sweep`: a sine whose frequency rises linearly from 0.2 to 1.2 Hz.
- `steps`: steer steps of alternating sign, 0.4 s ramps, held 2.5 s, 1.5 s apart.
- `slalom`: bursts of three 0.7 Hz periods with 2 s of straight driving between them.
- `mixed`: a longer drive of random segments (straight, sine, sweep, steps, slalom) with
  random frequency and amplitude (0.3-1 x `ay`) and a new set speed in [v - 5, v + 5] m/s
  at each segment (ramps of at most 1 m/s^2; the
  amplitude is scaled for the faster end of the ramp): what a test drive on a quiet road looks like.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tirefilter.errors import TirefilterError

MANEUVERS = ("sine", "sweep", "steps", "slalom", "mixed")
RAMP = 0.5  # s, raised-cosine envelope at the start and end of an oscillating segment


@dataclass(frozen=True)
class Profile:
    """Reference steer (road-wheel, rad) and set speed (m/s) with their time derivatives
    on the grid `t` (uniform, spacing dt)."""

    t: np.ndarray
    delta: np.ndarray
    delta_rate: np.ndarray
    speed: np.ndarray
    speed_rate: np.ndarray

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


def _window(t, t0, t1, ramp=RAMP):
    """1 inside [t0 + ramp, t1 - ramp], raised-cosine ramps to 0 at t0 and t1."""
    w = np.zeros_like(t)
    inside = (t >= t0) & (t <= t1)
    up = np.clip((t - t0) / ramp, 0.0, 1.0)
    down = np.clip((t1 - t) / ramp, 0.0, 1.0)
    w[inside] = np.minimum(0.5 - 0.5 * np.cos(np.pi * up[inside]), 0.5 - 0.5 * np.cos(np.pi * down[inside]))
    return w


def _sine(t, t0, t1, amp, freq):
    return amp * _window(t, t0, t1) * np.sin(2 * np.pi * freq * (t - t0))


def _sweep(t, t0, t1, amp, f0=0.2, f1=1.2):
    tau = np.clip(t - t0, 0.0, None)
    phase = 2 * np.pi * (f0 * tau + 0.5 * (f1 - f0) / max(t1 - t0, 1e-9) * tau**2)
    return amp * _window(t, t0, t1) * np.sin(phase)


def _steps(t, t0, t1, amp, hold=2.5, gap=1.5, ramp=0.4, sign=1.0):
    out = np.zeros_like(t)
    start = t0
    while start + 2 * ramp + hold <= t1:
        out += sign * amp * _window(t, start, start + 2 * ramp + hold, ramp)
        sign = -sign
        start += 2 * ramp + hold + gap
    return out


def _slalom(t, t0, t1, amp, freq=0.7, periods=3, gap=2.0):
    out = np.zeros_like(t)
    start, length = t0, periods / freq + 2 * RAMP
    while start + length <= t1:
        out += _sine(t, start, start + length, amp, freq)
        start += length + gap
    return out


def _speed_ramps(t, times, speeds, accel=1.0):
    """Set speed: speeds[i] from times[i], reached by raised-cosine ramps of peak |dv/dt| <= accel."""
    v = np.full_like(t, speeds[0])
    for tc, v_old, v_new in zip(times[1:], speeds[:-1], speeds[1:]):
        dur = max(np.pi / 2 * abs(v_new - v_old) / accel, 1e-9)
        s = np.clip((t - tc) / dur, 0.0, 1.0)
        v += (v_new - v_old) * (0.5 - 0.5 * np.cos(np.pi * s))
    return v


def make_profile(name: str, duration: float, *, speed: float, ay: float, steer_gain, straight: float = 4.0,
                 dt: float = 5e-4, rng: np.random.Generator | None = None) -> Profile:
    """The maneuver `name` over [0, duration] s on a grid of `dt`.

    `steer_gain(v)` is the steady-state road-wheel steer per m/s^2 of lateral acceleration
    at speed v [rad s^2/m]; `rng` draws the segments of `mixed` (required there)."""
    if name not in MANEUVERS:
        raise TirefilterError(f"maneuver must be one of {', '.join(MANEUVERS)}, got {name!r}")
    if duration < straight + 4.0:
        raise TirefilterError(f"maneuver {name}: duration must be at least {straight + 4.0:g} s "
                              f"({straight:g} s straight, then the excitation), got {duration:g}")
    if not 0 < ay <= 8.0:
        raise TirefilterError(f"maneuver {name}: lateral acceleration target must be in (0, 8] m/s^2, got {ay:g}")
    if not 5.0 <= speed <= 40.0:
        raise TirefilterError(f"maneuver {name}: speed must be in [5, 40] m/s, got {speed:g}")
    t = np.arange(int(round(duration / dt)) + 1) * dt
    t0, t1 = straight, duration - 1.0
    v = np.full_like(t, float(speed))
    amp = ay * steer_gain(speed)
    if name == "sine":
        delta = _sine(t, t0, t1, amp, 0.5)
    elif name == "sweep":
        delta = _sweep(t, t0, t1, amp)
    elif name == "steps":
        delta = _steps(t, t0, t1, amp)
    elif name == "slalom":
        delta = _slalom(t, t0, t1, amp)
    else:
        if rng is None:
            raise TirefilterError("maneuver mixed needs a random generator (its segments are drawn)")
        delta, v = _mixed(t, t0, t1, speed, ay, steer_gain, rng)
    return Profile(t, delta, np.gradient(delta, dt), v, np.gradient(v, dt))


def _mixed(t, t0, t1, speed, ay, steer_gain, rng):
    delta = np.zeros_like(t)
    times, speeds = [0.0], [float(speed)]
    start = t0
    while start < t1 - 4.0:
        kind = rng.choice(["straight", "sine", "sweep", "steps", "slalom"], p=[0.2, 0.25, 0.2, 0.2, 0.15])
        length = float(min(rng.uniform(6.0, 14.0) if kind != "straight" else rng.uniform(2.0, 6.0), t1 - start))
        v_set = float(np.clip(speed + rng.uniform(-5.0, 5.0), 8.0, 35.0))
        v_fast = max(v_set, speeds[-1])  # the speed ramps during the segment: scale for the faster end
        times.append(start)
        speeds.append(v_set)
        amp = rng.uniform(0.3, 1.0) * ay * steer_gain(v_fast)
        end = start + length
        if kind == "sine":
            delta += _sine(t, start, end, amp, rng.uniform(0.2, 1.0))
        elif kind == "sweep":
            delta += _sweep(t, start, end, amp, 0.2, rng.uniform(0.8, 1.4))
        elif kind == "steps":
            delta += _steps(t, start, end, amp, hold=rng.uniform(1.5, 3.0), gap=rng.uniform(0.5, 2.0),
                            sign=rng.choice([-1.0, 1.0]))
        elif kind == "slalom":
            delta += _slalom(t, start, end, amp, freq=rng.uniform(0.5, 0.9))
        start = end
    return delta, _speed_ramps(t, times, speeds)
