"""The IMU model an estimator assumes, and where each figure came from.

White noise per channel (ax, ay, yaw rate): the vehicle TOML's `sigma_*` where given,
else estimated from the data (`stats.noise.white_noise_std`); a given figure more than
DISAGREE times off the data's is reported as a warning. IMU bias: the vehicle TOML's
`bias0_std_*` / `bias_rw_*` where given, else the automotive MEMS defaults below; bias
estimation is on unless both are set to 0. The run summary records the result
(`SensorModel.to_dict`, `run.json` key `sensors`) and prints `describe()`.

Defaults (README, "Sensor defaults"), for an IMU of the automotive MEMS class (for
example ST ASM330LHH, Bosch SMI230) mounted in a car:
- bias prior std 0.3 m/s^2 per accelerometer: the data sheets' zero-g offset (tens of mg)
  plus a mounting tilt of 1 deg (g sin 1 deg = 0.17 m/s^2) and road grade or crown;
- 0.01 rad/s (0.57 deg/s) for the gyro: the order of a data sheet's zero-rate offset over
  temperature;
- bias random walk 0.001 m/s^2 / sqrt(s) and 1e-4 rad/s / sqrt(s): slow drift (temperature),
  a few hundredths of the prior over a 10-minute drive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from tirefilter.stats.noise import held_share, white_noise_std

CHANNELS = ("ax", "ay", "yaw_rate")
UNITS = ("m/s^2", "m/s^2", "rad/s")
MEMS_BIAS0_STD = (0.3, 0.3, 0.01)  # m/s^2, m/s^2, rad/s
MEMS_BIAS_RW = (0.001, 0.001, 0.0001)  # per sqrt(s)
DISTURBANCE_RW = (0.0, 0.05, 0.0)  # per sqrt(s): road bank and roll seen on a^Y (derivations, "Bias defaults and wandering offsets")
FALLBACK_SIGMA = (0.3, 0.3, 0.005)  # no figure given and too few samples to estimate one
DISAGREE = 3.0  # a given noise figure this many times off the data's is reported


@dataclass(frozen=True)
class SensorModel:
    """White noise and bias model per IMU channel (ax, ay, yaw rate), with their sources."""

    sigma: tuple[float, float, float]  # white-noise std used by the estimator
    sigma_source: tuple[str, str, str]  # per channel: "vehicle file", "scenario", "data", "default", "--config"
    sigma_data: tuple[float, float, float] = (math.nan,) * 3  # estimated from the data (NaN: no estimate)
    data_span: str = ""  # which data the estimate comes from
    bias0_std: tuple[float, float, float] = MEMS_BIAS0_STD
    bias_rw: tuple[float, float, float] = MEMS_BIAS_RW
    bias_source: str = "defaults (automotive MEMS)"
    held: tuple[float, float, float] = (math.nan,) * 3  # share of held (repeated) samples per channel
    disturbance_rw: tuple[float, float, float] = (0.0, 0.0, 0.0)  # wandering offsets (road bank, roll), per sqrt(s)
    warnings: tuple[str, ...] = field(default=())
    # wheel-speed white noise (rad/s; 0: none, or none known), where it came from ("data", "scenario"); the
    # MPF filters the wheel speeds with it (`[mpf] sigma_omega`, derivations, "Wheel-speed pre-filter")
    sigma_omega: float = 0.0
    sigma_omega_source: str = ""

    @property
    def bias_on(self) -> bool:
        return any(v > 0 for v in self.bias0_std + self.bias_rw)

    def to_dict(self) -> dict:
        def num(v):
            return None if not math.isfinite(v) else float(v)

        return {
            "sigma": dict(zip(CHANNELS, map(num, self.sigma))),
            "sigma_source": dict(zip(CHANNELS, self.sigma_source)),
            "sigma_from_data": dict(zip(CHANNELS, map(num, self.sigma_data))),
            "sigma_data_span": self.data_span,
            "noise_estimated": any(s == "data" for s in self.sigma_source),
            "bias_estimated": self.bias_on,
            "bias0_std": dict(zip(CHANNELS, self.bias0_std)),
            "bias_rw": dict(zip(CHANNELS, self.bias_rw)),
            "bias_source": self.bias_source,
            "held_share": dict(zip(CHANNELS, map(num, self.held))),
            "disturbance_rw": dict(zip(CHANNELS, self.disturbance_rw)),
            "sigma_omega": float(self.sigma_omega),
            "sigma_omega_source": self.sigma_omega_source,
            "warnings": list(self.warnings),
        }

    def describe(self) -> list[str]:
        """Lines for a run summary: the noise used and its source, the bias model, warnings."""
        noise = ", ".join(f"{c} {_fmt(s)} {u}" + (f" ({src})" if src != "data" else "")
                          for c, s, u, src in zip(CHANNELS, self.sigma, UNITS, self.sigma_source))
        head = "sensor noise (std)" + (f", estimated from {self.data_span}" if "data" in self.sigma_source else "")
        lines = [f"{head}: {noise}"]
        if self.bias_on:
            prior = ", ".join(f"{c} {_fmt(b)} {u}" for c, b, u in zip(CHANNELS, self.bias0_std, UNITS))
            walk = ", ".join(f"{c} {_fmt(q)} {u}/sqrt(s)" for c, q, u in zip(CHANNELS, self.bias_rw, UNITS))
            lines.append(f"IMU bias: estimated; prior std {prior}; random walk {walk} ({self.bias_source})")
        else:
            lines.append(f"IMU bias: not estimated ({self.bias_source})")
        if any(q > 0 for q in self.disturbance_rw):
            lines.append("wandering offsets (road bank and crown, body roll): random walk " + ", ".join(
                f"{c} {_fmt(q)} {u}/sqrt(s)" for c, q, u in zip(CHANNELS, self.disturbance_rw, UNITS) if q > 0)
                + ", in the linear tire region")
        if self.sigma_omega > 0:
            src = f"estimated from {self.data_span}" if self.sigma_omega_source == "data" else self.sigma_omega_source
            lines.append(f"wheel-speed noise (std): {_fmt(self.sigma_omega)} rad/s ({src}); the MPF filters the wheel "
                         "speeds with it ([mpf] sigma_omega = 0: taken as exact)")
        return lines + [f"warning: {w}" for w in self.warnings]

    def with_config(self, sigma, bias0_std, bias_rw, channels=CHANNELS) -> "SensorModel":
        """The model after an estimator's own configuration (`[mpf] sigma = ...`) changed
        figures: those channels' sources become "--config"."""
        def merged(old, new, idx):
            out = list(old)
            for j, v in zip(idx, new):
                out[j] = float(v)
            return tuple(out)

        idx = [CHANNELS.index(c) for c in channels]
        sig = merged(self.sigma, sigma, idx) if sigma is not None else self.sigma
        src = tuple("--config" if not math.isclose(a, b, rel_tol=1e-12) else s
                    for a, b, s in zip(self.sigma, sig, self.sigma_source))
        b0 = tuple(bias0_std) if bias0_std is not None else self.bias0_std
        rw = tuple(bias_rw) if bias_rw is not None else self.bias_rw
        bias_source = self.bias_source if (b0, rw) == (self.bias0_std, self.bias_rw) else "--config"
        return replace(self, sigma=sig, sigma_source=src, bias0_std=b0, bias_rw=rw, bias_source=bias_source)


def _fmt(v: float) -> str:
    return f"{v:.3g}" if math.isfinite(v) else "n/a"


def noise_from_data(signals: dict, span: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """White-noise std and held-sample share of each IMU channel in `signals` (name -> (n,)
    array; an absent channel gives NaN)."""
    sig, held = [], []
    for c in CHANNELS:
        x = signals.get(c)
        sig.append(white_noise_std(x) if x is not None else math.nan)
        held.append(held_share(x) if x is not None else math.nan)
    return tuple(sig), tuple(held)


def wheel_noise_from_data(signals: dict) -> float:
    """White-noise std (rad/s) of the wheel speeds `omega_f`, `omega_r` in `signals`: the root
    mean square of the two channels' `white_noise_std` (one where the other is absent or has
    too few samples); 0 without any estimate."""
    found = [white_noise_std(signals[c]) for c in ("omega_f", "omega_r") if signals.get(c) is not None]
    found = [v for v in found if math.isfinite(v)]
    return math.sqrt(sum(v * v for v in found) / len(found)) if found else 0.0


def _compare(sigma, sigma_data, sources, span: str) -> list[str]:
    out = []
    for c, u, s, d, src in zip(CHANNELS, UNITS, sigma, sigma_data, sources):
        if src != "data" and math.isfinite(d) and d > 0 and not 1 / DISAGREE <= s / d <= DISAGREE:
            out.append(f"the {src}'s sigma_{c} = {s:.3g} {u} is {s / d:.2g} times the white noise of {span} "
                       f"({d:.3g} {u}); the filter trusts the sensor {'more' if s < d else 'less'} than the data "
                       "supports (remove the figure to use the data's)")
    return out


def sensors_for_log(vehicle, signals: dict, span: str = "the log") -> SensorModel:
    """The IMU model for a replay: the vehicle's figures where given, else the data's
    (`vehicle` None: no figures given)."""
    sigma_data, held = noise_from_data(signals, span)
    given = (None,) * 3 if vehicle is None else (vehicle.sigma_ax, vehicle.sigma_ay, vehicle.sigma_yaw_rate)
    sigma, sources = [], []
    for g, d in zip(given, sigma_data):
        if g is not None:
            sigma.append(float(g)), sources.append("vehicle file")
        elif math.isfinite(d) and d > 0:
            sigma.append(d), sources.append("data")
        else:
            sigma.append(FALLBACK_SIGMA[len(sigma)]), sources.append("default")
    b0 = (None,) * 3 if vehicle is None else (vehicle.bias0_std_ax, vehicle.bias0_std_ay, vehicle.bias0_std_yaw_rate)
    rw = (None,) * 3 if vehicle is None else (vehicle.bias_rw_ax, vehicle.bias_rw_ay, vehicle.bias_rw_yaw_rate)
    given_bias = any(v is not None for v in b0 + rw)
    b0 = tuple(d if v is None else float(v) for v, d in zip(b0, MEMS_BIAS0_STD))
    rw = tuple(d if v is None else float(v) for v, d in zip(rw, MEMS_BIAS_RW))
    warnings = _compare(sigma, sigma_data, sources, span)
    if "default" in sources:
        missing = [c for c, s in zip(CHANNELS, sources) if s == "default" and c in signals]
        if missing:
            warnings.append(f"too few samples to estimate the noise of {', '.join(missing)}: "
                            f"assumed {', '.join(_fmt(FALLBACK_SIGMA[CHANNELS.index(c)]) for c in missing)}")
    return SensorModel(sigma=tuple(sigma), sigma_source=tuple(sources), sigma_data=sigma_data, data_span=span,
                       bias0_std=b0, bias_rw=rw,
                       bias_source="vehicle file" if given_bias else "defaults (automotive MEMS)",
                       held=held, warnings=tuple(warnings), sigma_omega=wheel_noise_from_data(signals),
                       sigma_omega_source="data")


def sensors_for_scenario(spec) -> SensorModel:
    """The IMU model for a co-simulation: the scenario's sensor spec (what the vehicle FMU
    simulates). `checked_against` adds the figures of the data once the run has some."""
    bias0 = (spec.bias0_std_ax, spec.bias0_std_ay, spec.bias0_std_yaw_rate)
    rw = (spec.bias_rw_ax, spec.bias_rw_ay, spec.bias_rw_yaw_rate)
    has_bias = any(v > 0 for v in bias0 + rw) or any(
        v != 0 for v in (spec.bias0_ax, spec.bias0_ay, spec.bias0_yaw_rate))
    return SensorModel(sigma=(spec.sigma_ax, spec.sigma_ay, spec.sigma_yaw_rate), sigma_source=("scenario",) * 3,
                       bias0_std=bias0, bias_rw=rw,
                       bias_source="scenario sensor spec" + ("" if has_bias else ": the sensors have no bias"),
                       sigma_omega=float(spec.sigma_omega), sigma_omega_source="scenario")


def checked_against(model: SensorModel, signals: dict, span: str) -> SensorModel:
    """`model` with the noise estimated from `signals` (e.g. a co-simulation's first
    seconds) and a warning for every given figure more than DISAGREE times off."""
    sigma_data, held = noise_from_data(signals, span)
    warnings = list(model.warnings) + _compare(model.sigma, sigma_data, model.sigma_source, span)
    return replace(model, sigma_data=sigma_data, data_span=span, held=held, warnings=tuple(warnings))


def first_seconds(t: np.ndarray, signals: dict, seconds: float) -> dict:
    """The samples of `signals` in the first `seconds` of `t`."""
    t = np.asarray(t, float)
    keep = t <= t[0] + seconds if t.size else np.zeros(0, bool)
    return {k: np.asarray(v, float)[keep] for k, v in signals.items()}
