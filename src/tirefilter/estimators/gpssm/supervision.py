"""Divergence of the friction GP-SSM: its three symptoms watched at every sample, a divergence
confirmed when one of them lasts, and what the filter keeps of its learning when it starts
again (docs/derivations.md, "F9. Divergence: detection and recovery").

Symptoms (`DivergenceMonitor.observe`):
  - "clip": the share of particles with a slip angle outside the basis domain [-L, L] above
    `diverge_clip_share` (the model has no curve there: those particles are clipped);
  - "beta": the posterior-mean sideslip |atan(v^Y / v^X)| above `diverge_beta`;
  - "residual": the normalised squared one-step prediction errors of a^Y and the yaw rate,
    averaged over the channels and smoothed with time constant `diverge_window`, above
    `diverge_nis` (1 while the data fit the predictive).
A symptom that holds for `diverge_after` seconds is a divergence; its onset is the time it
began. `Checkpoints` keeps the statistics of the last healthy moments so that a restart can take
the learned curve from before the onset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

CAUSES = {
    "clip": "slip angles of {value:.0%} of the particles outside the basis domain +-{L:.0f} deg",
    "beta": "the sideslip estimate at {value:.1f} deg, implausible at {vx:.1f} m/s",
    "residual": "one-step prediction errors {value:.1f} times their predicted variance (a^Y and yaw rate)",
}


@dataclass
class Divergence:
    """One divergence: when its symptom began and was confirmed (s), which symptom, its size
    there, and what the filter did."""

    t_onset: float
    t_detected: float
    cause: str  # "clip" | "beta" | "residual"
    detail: str
    action: str = ""

    def message(self) -> str:
        return (f"friction GP-SSM diverged at t = {self.t_onset:.2f} s (confirmed at {self.t_detected:.2f} s): "
                f"{self.detail}; {self.action}")

    def to_dict(self) -> dict:
        return {"t_onset": self.t_onset, "t_detected": self.t_detected, "cause": self.cause, "detail": self.detail,
                "action": self.action}


class DivergenceMonitor:
    """The symptoms of the module docstring, sample by sample (`observe`)."""

    def __init__(self, clip_share: float, beta: float, nis: float, window: float, after: float):
        self.limits = {"clip": clip_share, "beta": beta, "residual": nis}
        self.window, self.after = window, after
        self.reset()

    def reset(self) -> None:
        self.since = {k: None for k in self.limits}  # the time each symptom began (None: absent)
        self.nis = 1.0  # the smoothed normalised squared prediction error
        self.t_prev = None
        self.values = {k: math.nan for k in self.limits}
        self.worst = {k: 0.0 for k in self.limits}  # the largest value of each symptom seen

    @property
    def healthy(self) -> bool:
        return all(s is None for s in self.since.values())

    def observe(self, t: float, clip_share: float, beta: float, z2: float) -> tuple[str, float] | None:
        """One sample: the share of clipped particles, |beta| (rad) and the mean over the
        available channels of the squared prediction errors over their predicted variances
        (NaN: no channel). Returns (symptom, onset) once a symptom has lasted `after`
        seconds, else None."""
        dt = 0.0 if self.t_prev is None else t - self.t_prev
        self.t_prev = t
        if math.isfinite(z2):
            a = 1.0 - math.exp(-dt / self.window) if dt > 0 else 0.0
            self.nis += a * (z2 - self.nis)
        v = self.values
        v["clip"], v["beta"], v["residual"] = clip_share, beta, self.nis
        found = None
        for k, limit in self.limits.items():
            x = v[k]
            if math.isfinite(x):
                self.worst[k] = max(self.worst[k], x)
            if x > limit or (k == "beta" and not math.isfinite(x)):
                if self.since[k] is None:
                    self.since[k] = t
                if found is None and t - self.since[k] >= self.after:
                    found = (k, self.since[k])
            else:
                self.since[k] = None
        return found


class Checkpoints:
    """Copies of the statistics (and whatever else the caller passes) taken every `every`
    seconds while the filter is healthy, the last `keep` of them."""

    def __init__(self, every: float, keep: int = 3):
        self.every, self.keep = every, keep
        self.items: list[tuple[float, object]] = []

    def due(self, t: float) -> bool:
        return not self.items or t - self.items[-1][0] >= self.every

    def add(self, t: float, item) -> None:
        self.items.append((t, item))
        del self.items[:-self.keep]

    def before(self, t: float):
        """(time, item) of the newest checkpoint taken before t, None without one."""
        for tc, item in reversed(self.items):
            if tc < t:
                return tc, item
        return None

    def clear(self) -> None:
        self.items.clear()
