"""Options of the friction GP-SSM (`GPSSMConfig`, the `[gpssm]` table of --config) and the
Pacejka prior of the friction curve (`PacejkaPrior`, `slip_slope_prior`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from tirefilter.errors import ConfigError
from tirefilter.estimators.sensors import MEMS_BIAS0_STD, MEMS_BIAS_RW
from tirefilter.stats.gp import GPBasis1D
from tirefilter.vehicle.tires import magic_formula

DEG = math.pi / 180.0


@dataclass(frozen=True)
class GPSSMConfig:
    """Options of the friction GP-SSM (the `[gpssm]` table of --config). Angles in rad,
    friction as lateral force over normal load."""

    particles: int = 200
    basis: str = "tensor"  # "tensor" (the paper's 2-D basis, m^2 functions) | "axle" (m per axle)
    basis_functions: int | None = None  # m per slip dimension; None: 10 (tensor, the paper), 20 (axle)
    L: float = 30.0 * DEG  # half-width of the basis domain [-L, L] (the paper: 30 deg)
    lengthscale: float = 2.0 * DEG  # SE kernel length-scale (the paper: 2 deg)
    symmetry: str = "odd"  # "odd": only the basis functions odd in alpha (mu(-a) = -mu(a)) | "none" (the paper)
    s_f: float = 500.0  # SE kernel variance, relative to Q (A | Q ~ MN(0, Q, diag S)); the paper's 500
    stats: str = "exact"  # "exact" (eq. (27)-(29)) | "rank1" (forgetting applied to the prior too)
    backend: str = "numba"  # "numba" (compiled step, estimators/gpssm/compiled.py) | "numpy" (the reference)
    forgetting: float = 0.99  # lambda of eq. (29) per `forgetting_period` (100 samples of memory at 25 Hz: 4 s)
    forgetting_period: float = 0.04  # s: a step dt forgets lambda^(dt / period), the same memory in seconds at any
    # sample rate (the paper's 25 Hz: lambda per sample; derivations, "F2. MNIW statistics with forgetting")
    q0: float = 0.01  # prior guess of the std of w (friction units): Lambda_0 = q0^2 (nu_0 - d - 1) I
    nu0_margin: float = 2.0  # nu_0 = d + 1 + margin
    prior_peak: float = 0.05  # D of the Pacejka prior (Sec. 4)
    # "peak": the prior of prior_peak and prior_B/C/E (the paper's Sec. 4); "vehicle": its slope the vehicle
    # file's cornering stiffness over the static axle load, its peak that slope times saturation_slip (F6's
    # scaling; a replay's default: a car on an unknown road, derivations, "F6. Combined pipeline")
    prior_slope: str = "peak"
    prior_B: float | None = None  # Magic-Formula shape of the prior; None: the scenario's tire set
    prior_C: float | None = None  # (else B = 10, C = 1.3, E = 0)
    prior_E: float | None = None
    measurement_friction: str = "learned"  # "learned" (mu~ + zeta) | "prior" (mu~ alone, the paper)
    # combined pipeline: the MPF's stiffness sets the prior's slope
    saturation_slip: float = 0.07  # rad: the combined prior's peak is slope x this (brush-model scaling)
    handover_std: float = 0.05  # relative posterior std of the MPF's Cf_y, Cr_y below which ...
    handover_after: float = 2.0  # s of MPF learning, after which the prior is fixed and learning starts
    # filter
    resample_threshold: float = 0.5
    sigma: tuple[float, float] = (0.05, 0.0035)  # a^Y [m/s^2], yaw rate [rad/s] white noise
    x0_mean: tuple[float, float] = (0.0, 0.0)  # vy, r (r from the first yaw-rate sample when there is one)
    x0_std: tuple[float, float] = (0.3, 0.0175)
    state_noise: tuple[float, float] = (0.0, 0.0)  # vy, r per sqrt(s): optional regularisation
    gate_speed: float = 5.0  # m/s: below this nothing is learned (as the stiffness MPF)
    sample_period: float = 0.04  # s
    max_step: float = 0.01  # s, longest Euler sub-step
    # the tire forces between two samples: "zero": the friction drawn at the first held over the step (eq. (7));
    # "linear": from the friction drawn at the first to the conditional mean of the friction at the second
    # (derivations, "F4. The filter step": no stretch of the slips at 25 Hz, worse on the 100 Hz peer drives)
    force_hold: str = "zero"
    # IMU bias of a^Y and the yaw rate (the stiffness MPF's sensor model, derivations, "F7. IMU bias"): prior std
    # and random walk per sqrt(s), a Kalman filter per particle and channel; all zero: no bias model (the paper)
    bias0_std: tuple[float, float] = MEMS_BIAS0_STD[1:]  # a^Y [m/s^2], yaw rate [rad/s]
    bias_rw: tuple[float, float] = MEMS_BIAS_RW[1:]  # per sqrt(s)
    # v^X where the log has none: the undriven axle's wheel speed R_w omega (derivations, "F8. v^X from the wheel
    # speeds"), pre-filtered with a^X where sigma_omega > 0 (`wheel_filter.WheelSpeedFilter`)
    sigma_omega: float = 0.0  # rad/s, the wheel speeds' white noise (0: taken as exact)
    sigma_ax: float = 0.3  # m/s^2, a^X white noise (the pre-filter's process noise)
    wheel_slip_rw: float = 0.02  # m/s per sqrt(s), random walk of the axle's slip speed in the pre-filter
    # divergence (derivations, "F9. Divergence: detection and recovery"): a symptom that lasts `diverge_after` s
    supervise: bool = True  # watch for divergence, report it and start the state again
    diverge_clip_share: float = 0.2  # share of particles with a slip angle outside [-L, L]
    diverge_beta: float = 20.0 * DEG  # rad, |posterior-mean sideslip|
    diverge_nis: float = 400.0  # smoothed normalised squared prediction error (1: the data fit)
    diverge_window: float = 2.0  # s, time constant of that smoothing
    diverge_after: float = 1.0  # s
    checkpoint_every: float = 5.0  # s between copies of the statistics kept for a restart
    # the band of the learned curve (derivations, "F5. The friction estimate"): "calibrated" adds the slip's
    # posterior variance at the learning samples times the curve's squared slope and scales the GP's variance by
    # the batch-means sandwich of the a^Y residuals (as the MPF's `std_calibration`); "posterior": eq. (30) alone
    band: str = "calibrated"
    calibration_batch: float = 0.75  # s of learning per batch of the sandwich
    calibration_memory: float = 2.0  # the sandwich's memory in units of the statistics' (lambda^(1 / this))
    # output
    grid_step: float = 0.25 * DEG  # spacing of the friction() grid (0.25 deg or finer)
    slip_range: float | None = None  # half-width of the friction() grid (default L; at most L)
    snapshot_every: float = 10.0  # s between friction.csv snapshots

    def validated(self) -> "GPSSMConfig":
        def bad(key, problem):
            raise ConfigError("gpssm configuration", key, problem)

        if isinstance(self.particles, bool) or int(self.particles) != self.particles or self.particles < 1:
            bad("particles", f"N must be an integer >= 1, got {self.particles!r}")
        if self.basis not in ("tensor", "axle"):
            bad("basis", f"expected tensor or axle, got {self.basis!r}")
        if self.symmetry not in ("none", "odd"):
            bad("symmetry", f"expected none or odd, got {self.symmetry!r}")
        if self.stats not in ("exact", "rank1"):
            bad("stats", f"expected exact or rank1, got {self.stats!r}")
        if self.backend not in ("numba", "numpy"):
            bad("backend", f"expected numba or numpy, got {self.backend!r}")
        if self.prior_slope not in ("peak", "vehicle"):
            bad("prior_slope", f"expected peak or vehicle, got {self.prior_slope!r}")
        if self.force_hold not in ("linear", "zero"):
            bad("force_hold", f"expected linear or zero, got {self.force_hold!r}")
        if self.band not in ("calibrated", "posterior"):
            bad("band", f"expected calibrated or posterior, got {self.band!r}")
        for key in ("calibration_batch", "calibration_memory"):
            if not (getattr(self, key) > 0 and math.isfinite(getattr(self, key))):
                bad(key, f"must be finite and > 0, got {getattr(self, key)!r}")
        if self.measurement_friction not in ("learned", "prior"):
            bad("measurement_friction", f"expected learned or prior, got {self.measurement_friction!r}")
        GPBasis1D(self.L, self.m, self.lengthscale, self.s_f)  # L, l, m, s_f checks
        if not 0.0 < self.forgetting <= 1.0:
            bad("forgetting", f"lambda must be in (0, 1], got {self.forgetting!r}")
        for key in ("q0", "prior_peak", "saturation_slip", "sample_period", "max_step", "grid_step",
                    "snapshot_every", "handover_std", "forgetting_period"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                bad(key, f"must be a finite number > 0, got {v!r}")
        for key in ("nu0_margin", "gate_speed", "handover_after"):
            if not getattr(self, key) >= 0:
                bad(key, f"must be >= 0, got {getattr(self, key)!r}")
        for key in ("prior_B", "prior_C"):
            if getattr(self, key) is not None and not getattr(self, key) > 0:
                bad(key, f"must be > 0, got {getattr(self, key)!r}")
        if self.grid_step > 0.25 * DEG + 1e-15:
            bad("grid_step", f"the friction grid needs 0.25 deg (0.004363 rad) or finer, got {self.grid_step!r}")
        if self.slip_range is not None:
            if not self.slip_range > 0:
                bad("slip_range", f"must be > 0, got {self.slip_range!r}")
            if self.slip_range > self.L * (1 + 1e-12):
                bad("slip_range", f"{self.slip_range!r} rad is wider than the basis domain L = {self.L!r} rad "
                    "(the basis is zero at +-L: widen L)")
        if not 0.0 <= self.resample_threshold <= 1.0:
            bad("resample_threshold", f"must be in [0, 1], got {self.resample_threshold!r}")
        if len(self.sigma) != 2 or min(self.sigma) <= 0:
            bad("sigma", f"two sensor noise values > 0 (a^Y, yaw rate), got {self.sigma!r}")
        for key in ("x0_mean", "x0_std", "state_noise"):
            if len(getattr(self, key)) != 2:
                bad(key, f"needs two values (vy, r), got {getattr(self, key)!r}")
        if min(self.x0_std) < 0 or min(self.state_noise) < 0:
            bad("x0_std", "standard deviations must be >= 0")
        for key in ("bias0_std", "bias_rw"):
            v = getattr(self, key)
            if len(v) != 2 or not all(math.isfinite(x) and x >= 0 for x in v):
                bad(key, f"two finite values >= 0 (a^Y, yaw rate), got {v!r}")
        for key in ("sigma_omega", "sigma_ax", "wheel_slip_rw"):
            if not (math.isfinite(getattr(self, key)) and getattr(self, key) >= 0):
                bad(key, f"must be finite and >= 0, got {getattr(self, key)!r}")
        for key in ("diverge_clip_share", "diverge_beta", "diverge_nis", "diverge_window", "checkpoint_every"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                bad(key, f"must be a finite number > 0, got {v!r}")
        if not self.diverge_after >= 0:
            bad("diverge_after", f"must be >= 0, got {self.diverge_after!r}")
        return self

    @property
    def model(self) -> str:
        return "lateral"  # state [v^Y, r], v^X given (Sec. 2.1)

    @property
    def m(self):
        if self.basis_functions is None:
            return 10 if self.basis == "tensor" else 20
        return self.basis_functions


@dataclass(frozen=True)
class PacejkaPrior:
    """mu~(alpha) = D sin(C atan(B alpha - E (B alpha - atan(B alpha)))) per axle (Sec. 4)."""

    D: tuple[float, float]
    B: tuple[float, float]
    C: float
    E: float

    def __call__(self, alpha_f, alpha_r):
        return (magic_formula(self.B[0], self.C, self.D[0], self.E, alpha_f),
                magic_formula(self.B[1], self.C, self.D[1], self.E, alpha_r))

    def slope(self) -> tuple[float, float]:
        return self.B[0] * self.C * self.D[0], self.B[1] * self.C * self.D[1]


def slip_slope_prior(slope_f: float, slope_r: float, C: float, saturation_slip: float) -> PacejkaPrior:
    """The prior of given slopes mu~'(0) per axle (cornering stiffness over the axle load) whose
    peak is the slope times `saturation_slip` (derivations, "F6. Combined pipeline"):
    D = slope a, B = 1 / (C a), E = 0, so that B C D = slope."""
    a = saturation_slip
    return PacejkaPrior((slope_f * a, slope_r * a), (1.0 / (C * a), 1.0 / (C * a)), C, 0.0)
