"""The Estimator protocol (docs/design.md) and the records it exchanges."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

NAN = math.nan


@dataclass(frozen=True)
class Inputs:
    """Known inputs at one sample. Optional signals are NaN when absent."""

    delta: float  # rad, road-wheel steer angle
    omega_f: float = NAN  # rad/s, front wheel rotation rate
    omega_r: float = NAN  # rad/s, rear wheel rotation rate
    vx: float = NAN  # m/s, longitudinal speed from other logic


@dataclass(frozen=True)
class Measurement:
    """IMU sample; any component may be NaN (missing)."""

    ax: float = NAN  # m/s^2
    ay: float = NAN  # m/s^2
    yaw_rate: float = NAN  # rad/s


@dataclass(frozen=True)
class Estimate:
    """What an estimator reports at one step (field names as in the Result CSV).

    Stiffness values are absolute (nominal plus estimated mean deviation); `*_std` is the
    posterior std of that mean, `*_sigma` the estimated spread of the deviations.
    """

    active: bool
    vx: float
    vy: float
    yaw_rate: float
    Cf_y: float
    Cr_y: float
    Cx: float = NAN
    Cf_y_std: float = NAN
    Cr_y_std: float = NAN
    Cx_std: float = NAN
    Cf_y_sigma: float = NAN
    Cr_y_sigma: float = NAN
    Cx_sigma: float = NAN
    b_ax: float = NAN
    b_ay: float = NAN
    b_yaw_rate: float = NAN
    ess: float = NAN
    state_std: tuple[float, float, float] = (NAN, NAN, NAN)  # vx, vy, yaw_rate
    roll_gradient: float = NAN  # rad per m/s^2, the IMU's a^Y gain 1 + k g where estimated (the MPF), its posterior
    roll_gradient_std: float = NAN  # mean and std

    @property
    def beta(self) -> float:
        return math.atan2(self.vy, self.vx)


def particle_estimate(*, active: bool, ess: float, x_mean, x_std, vx_input: float, stiffness: dict,
                      bias: dict, roll: tuple[float, float] = (NAN, NAN)) -> Estimate:
    """The Estimate of a particle filter over the full state (vx, vy, r) or the lateral one
    (vy, r; v^X is the input `vx_input`): weighted state mean and std, `stiffness` maps
    each estimated parameter (Cx, Cf_y, Cr_y) to (value, *_std, *_sigma), `bias` each IMU
    channel (ax, ay, yaw_rate) to its estimate, `roll` the roll gradient's mean and std; what
    is not estimated is NaN."""
    if len(x_mean) == 3:
        (vx, vy, r), std = x_mean, tuple(x_std)
    else:
        (vy, r), vx, std = x_mean, vx_input, (0.0, x_std[0], x_std[1])
    none = (NAN, NAN, NAN)
    cx, cf, cr = (stiffness.get(p, none) for p in ("Cx", "Cf_y", "Cr_y"))
    return Estimate(
        active=bool(active), vx=float(vx), vy=float(vy), yaw_rate=float(r),
        Cf_y=float(cf[0]), Cr_y=float(cr[0]), Cx=float(cx[0]),
        Cf_y_std=float(cf[1]), Cr_y_std=float(cr[1]), Cx_std=float(cx[1]),
        Cf_y_sigma=float(cf[2]), Cr_y_sigma=float(cr[2]), Cx_sigma=float(cx[2]),
        b_ax=float(bias.get("ax", NAN)), b_ay=float(bias.get("ay", NAN)), b_yaw_rate=float(bias.get("yaw_rate", NAN)),
        ess=float(ess), state_std=tuple(float(s) for s in std), roll_gradient=float(roll[0]),
        roll_gradient_std=float(roll[1]),
    )


@dataclass
class Posterior:
    """A snapshot of a particle posterior: particles, log-weights, per-particle stats."""

    particles: np.ndarray  # (N, nx)
    log_weights: np.ndarray  # (N,)
    stats: dict = field(default_factory=dict)  # name -> (N, ...) arrays


@dataclass(frozen=True)
class FrictionCurve:
    """A friction estimate mu(alpha) per axle on a fixed slip grid, as friction
    estimators report it (`friction()`); mu is lateral force over normal load.

    Arrays are (G,); `visited` is (alpha_f min, alpha_f max, alpha_r min, alpha_r max)
    over the samples seen while learning was active, in rad (NaN before any).
    """

    t: float  # s, time of the snapshot
    alpha: np.ndarray  # (G,) rad, the fixed grid over [-L, L]
    mu_f: np.ndarray  # (G,) front axle, posterior mean
    mu_f_std: np.ndarray  # (G,) its posterior std
    mu_r: np.ndarray  # (G,) rear axle
    mu_r_std: np.ndarray  # (G,)
    visited: tuple[float, float, float, float] = (NAN, NAN, NAN, NAN)


@runtime_checkable
class Estimator(Protocol):
    name: str

    def reset(self, rng: np.random.Generator) -> None: ...

    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate: ...

    def posterior(self) -> Posterior: ...
