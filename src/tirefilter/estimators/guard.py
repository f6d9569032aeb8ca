"""The measurement guard: per-channel outlier, stuck- and held-value detection in front of
every estimator (docs/derivations.md, "Measurement guard").

The estimators' likelihoods (the MPF's Student-t, the Gaussian ones of the baselines)
down-weight a large residual but still let it move the conditionally linear parts: the
MPF's stiffness statistics are updated with a w drawn given the residual, a Kalman update
is linear in it. A +20 m/s^2 spike in a^Y therefore shifts the stiffness and the bias and
can empty the plausible region (a restart). The guard removes such samples *before* the
update by marking the component missing (NaN), which every estimator already handles as a
missing sample (docs/design.md, `Measurement`). It needs nothing from the estimator, so one
implementation serves them all; the run loop (`runs.Run.step`) applies the guard an
estimator carries as `estimator.guard` (set by `estimators.build_estimator` /
`build_log_estimator` from the `[guard]` table of `--config`).

Per IMU channel c (ax, ay, yaw_rate), at the sample y_k:
- **held / stuck**: y_k exactly equal to the channel's previous sample is no new
  measurement (a sample-and-hold of a slower sensor, or a frozen sensor): missing.
- **outlier**: with m_k the median of the last `window` non-repeated samples (accepted or
  not, so that a real level change passes after window / 2 samples) and s_c a robust
  estimate of the sample-to-sample noise (1.4826 MAD of first differences / sqrt 2, over
  the last `scale_window` differences, never below `min_scale`), y_k is missing when
  |y_k - m_k| > threshold s_c + jump_c. jump_c is the largest change the vehicle itself
  can produce between two samples (a steer step moves a^Y at once; the yaw rate is an
  integral and cannot jump): a spike smaller than that is left to the likelihood.
- after a time step longer than `stale_after` (a gap) the median's history is dropped (it
  no longer predicts the channel), and the run loop restarts the estimator's learning
  warm-up: over the gap the estimator held its inputs, so its state is off for a moment
  and must settle before the stiffness learns from the residuals again
  (`baseline_common.gate_open` counts `gate_warmup` from the estimator's `t_start`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Measurement

CHANNELS = ("ax", "ay", "yaw_rate")


@dataclass(frozen=True)
class GuardConfig:
    """The `[guard]` table of `--config`."""

    enabled: bool = True
    held: bool = True  # an exactly repeated sample is missing
    window: int = 9  # samples in the running median
    threshold: float = 8.0  # robust noise scales beyond the median ...
    jump: tuple[float, float, float] = (8.0, 8.0, 0.3)  # ... plus this (ax, ay [m/s^2], yaw_rate [rad/s])
    min_scale: tuple[float, float, float] = (0.01, 0.01, 0.0005)  # floor of the noise scale, same units
    scale_window: int = 200  # first differences the noise scale is estimated from
    stale_after: float = 0.5  # s: a longer time step clears the median's history

    def validated(self) -> GuardConfig:
        def bad(key, problem):
            raise ConfigError("--config [guard]", key, problem)

        if not isinstance(self.enabled, bool) or not isinstance(self.held, bool):
            bad("enabled" if not isinstance(self.enabled, bool) else "held", "expected true or false")
        for key in ("window", "scale_window"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < 3:
                bad(key, f"expected an integer >= 3, got {v!r}")
        for key in ("threshold", "stale_after"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                bad(key, f"expected a positive number, got {v!r}")
        for key in ("jump", "min_scale"):
            v = getattr(self, key)
            if (not isinstance(v, tuple) or len(v) != 3
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x >= 0
                               for x in v)):
                bad(key, f"expected 3 numbers >= 0 (ax, ay, yaw_rate), got {v!r}")
        return self


def _median(x) -> float:
    """The median of a few floats (sorting in Python beats numpy's overhead at this size)."""
    s = sorted(x)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


class _Channel:
    """The state of one channel's tests."""

    def __init__(self, cfg: GuardConfig, jump: float, min_scale: float):
        self.cfg, self.jump, self.min_scale = cfg, jump, min_scale
        # plain lists, not deques: an estimator FMU's state pickle admits builtins and tirefilter classes only
        self.recent: list[float] = []  # the last `window` samples
        self.diffs: list[float] = []  # the last `scale_window` |first differences|
        self.prev = math.nan  # the previous sample (for held values and differences)
        self.scale = min_scale
        self._since_scale = 0
        self.held = self.outliers = 0

    def clear(self) -> None:
        self.recent.clear()
        self.prev = math.nan

    def __call__(self, y: float) -> float:
        if not math.isfinite(y):
            return y
        cfg, prev = self.cfg, self.prev  # locals: this runs three times a sample
        if cfg.held and y == prev:
            self.held += 1
            return math.nan
        if math.isfinite(prev):
            diffs = self.diffs
            diffs.append(abs(y - prev))
            if len(diffs) > cfg.scale_window:
                del diffs[0]
            self._since_scale += 1
            if self._since_scale >= 25 and len(diffs) >= 10:  # re-estimated every 25 samples
                self._since_scale = 0
                self.scale = max(self.min_scale, 1.4826 * _median(diffs) / math.sqrt(2.0))
        self.prev = y
        verdict = y
        recent = self.recent
        n = len(recent)
        if n >= 3:
            s = sorted(recent)  # _median, inlined
            m = s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])
            if abs(y - m) > cfg.threshold * self.scale + self.jump:
                self.outliers += 1
                verdict = math.nan
        recent.append(y)
        if n >= cfg.window:  # len(recent) > window after the append
            del recent[0]
        return verdict


class MeasurementGuard:
    """Marks held, stuck and outlying IMU samples missing (see the module docstring).

    `guard(t, y)` returns the Measurement the estimator is given; `counts()` what it removed.
    """

    def __init__(self, cfg: GuardConfig | None = None):
        self.cfg = (cfg or GuardConfig()).validated()
        self.reset()

    def reset(self) -> None:
        c = self.cfg
        self.channels = {name: _Channel(c, c.jump[j], c.min_scale[j]) for j, name in enumerate(CHANNELS)}
        self.t_prev = math.nan
        self.after_gap = False  # this sample follows a gap (a time step longer than stale_after)
        self.gaps = 0

    def __call__(self, t: float, y: Measurement) -> Measurement:
        if not self.cfg.enabled:
            return y
        self.after_gap = math.isfinite(self.t_prev) and t - self.t_prev > self.cfg.stale_after
        if self.after_gap:
            self.gaps += 1
            for ch in self.channels.values():
                ch.clear()
        self.t_prev = t
        ch = self.channels  # the three of CHANNELS, spelled out: this runs at every sample of every run
        ax, ay, r = y.ax, y.ay, y.yaw_rate
        gx, gy, gr = ch["ax"](ax), ch["ay"](ay), ch["yaw_rate"](r)
        if ((gx == ax or (gx != gx and ax != ax)) and (gy == ay or (gy != gy and ay != ay))
                and (gr == r or (gr != gr and r != r))):
            return y
        return replace(y, ax=gx, ay=gy, yaw_rate=gr)

    def counts(self) -> dict:
        """The configuration and the samples marked missing so far, per channel:
        {"config": {...}, "held": {...}, "outliers": {...}}."""
        return {"config": asdict(self.cfg), "gaps": self.gaps, "held": {n: c.held for n, c in self.channels.items()},
                "outliers": {n: c.outliers for n, c in self.channels.items()}}


def guard_from_config(config: dict) -> MeasurementGuard:
    """The guard of a `--config` file's `[guard]` table (defaults without one)."""
    from tirefilter.estimators import apply_overrides

    table = config.get("guard", {})
    if not isinstance(table, dict):
        raise ConfigError("--config", "guard", "expected a table [guard]")
    return MeasurementGuard(apply_overrides(GuardConfig(), table, "--config [guard]"))
