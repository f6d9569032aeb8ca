"""Options of the stiffness MPF: MPFConfig, every field settable from the `[mpf]` table of
--config (`estimators.apply_overrides` matches the table's keys to the field names)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from tirefilter.errors import ConfigError
from tirefilter.estimators.sensors import DISTURBANCE_RW, MEMS_BIAS0_STD, MEMS_BIAS_RW


@dataclass(frozen=True)
class MPFConfig:
    """Options of the stiffness MPF (all settable from the `[mpf]` table of --config)."""

    particles: int = 500
    forgetting: float = 0.99  # lambda of eq. (20); with adaptive forgetting its value when the data fit
    # adaptive forgetting (derivations, "Adaptive forgetting"): lambda_k = clip(1 - (1 - forgetting) z_k, forgetting_min,
    # forgetting_max), z_k the smoothed normalised innovation of the accelerometers (1 when the data fit the
    # predictive): a surface change forgets fast, a drive that fits keeps a long memory. "fixed": the paper's
    forgetting_mode: str = "adaptive"  # "adaptive" | "fixed"
    forgetting_min: float = 0.97
    forgetting_max: float = 0.999
    surprise_time: float = 0.15  # s, time constant of the smoothing of z_k (the innovation)
    drift_time: float = 1.0  # s, time constant of the smoothing of z'_k (the lean of the sampled w)
    model: str = "full"  # "full" (wheel speeds) | "lateral" (vx given)
    integrator: str = "heun"  # "euler" (the paper) | "heun" (same w, wheel slip held)
    # wheel slip in the propagation from t_k to t_k+1 (derivations, "Wheel slip"): "interval": its mean over
    # the interval, the wheel settling (time constant J v^X / (R_w^2 C), a few ms) from the slip at t_k to
    # the one the wheel speeds at t_k+1 give; "start": the slip at t_k held (the paper)
    slip_hold: str = "interval"
    # longitudinal stiffness of the undriven axle: "nominal": its nominal value (the paper); "surface": its
    # nominal scaled as the driven axle's estimate (one surface under both axles: right where Cx is learned,
    # harmful where it is not, derivations, "Wheel slip"); "learned": scaled by the share rho of the driven axle's
    # deviation that the wheel-slip excitation has taught (0: nominal, 1: surface; derivations, "The undriven axle")
    undriven_stiffness: str = "learned"
    # "learned": a driven-axle slip level held longer than this (s) is confounded with the a^X bias and v^X
    # errors; only its changes within this time count as excitation of Cx (derivations, "The undriven axle")
    cx_excitation_time: float = 1.0
    resample_threshold: float = 0.5  # resample when ESS < threshold * N
    # initial stiffness: per-particle means drawn around `init_center` (absolute, per
    # parameter, default nominal) with a relative spread of the reference stiffness
    init_center: tuple[float, ...] | None = None
    init_distribution: str = "normal"  # "normal" (init_std) | "uniform" (init_half_width)
    init_std: float = 0.3  # relative
    init_half_width: float = 0.1  # relative
    init_reference: tuple[float, ...] | None = None  # stiffness the relative spreads refer to
    init_sigma: float = 0.1  # prior guess of the deviation spread (relative), sets Lambda_0
    within_share: float = 0.25  # share of the prior variance of the mean inside each particle
    nu0_margin: float = 4.0  # nu_0 = n_w + 1 + margin (> n_w + 1: finite inverse-Wishart mean)
    x0_mean: tuple[float, ...] | None = None  # initial state mean (full: vx, vy, r)
    x0_std: tuple[float, ...] = (1.0, 0.5, 0.0175)  # full: vx, vy, r (lateral uses vy, r)
    state_noise: tuple[float, ...] = (0.0, 0.0, 0.0)  # additive process noise per sqrt(s), full: vx, vy, r
    # process noise of the state from the data (derivations, "State noise from the data"): the intensity per component that makes
    # the corrections the weights make to the state's mean consistent with the spread they remove (covariance
    # matching of the state corrections, Myers and Tapley 1976), smoothed over state_noise_time s; the applied
    # intensity is the larger of it and state_noise's. False: state_noise alone (the paper: none)
    state_noise_from_data: bool = False
    state_noise_time: float = 10.0  # s
    # v^Y process noise while the adaptive forgetting's innovation statistic z holds lambda at its floor
    # (z > z_on = (1 - forgetting_min) / (1 - forgetting)): std per sqrt(s) vy_jitter sqrt(z - z_on), added
    # to state_noise's; 0: off
    vy_jitter: float = 0.0
    # surprise inflation of the draw of w_k (derivations, "Surprise inflation"): with adaptive forgetting, the conditional
    # scale of w_k is multiplied by c = max(1, 1 + surprise_inflation (z - 1)), z the smoothed innovation
    # statistic ("Adaptive forgetting"): 1 matches the deviations' covariance to the residuals the accelerometers show; 0: off,
    # the paper's draw (the default: with it on, an unmodelled IMU gain on a peer drive ends past 10%, "Surprise inflation")
    surprise_inflation: float = 0.0
    # the draw the statistics learn from (eq. (19)) and the drift statistic sees: the same draw at c = 1,
    # mu_c + (w_k - mu_c) / sqrt(c) (False: only the state's propagation is inflated), or the inflated one (True)
    inflation_in_statistics: bool = False
    # the inflation is armed only once the learning gate has been open this long (s, in total) since the start
    # or the last restart (derivations, "Surprise inflation"): before, a surprise is the start's own error (the prior far
    # from the truth, a v^Y / stiffness pair not yet separated by the steer), not a change; 0: from the start
    inflation_after: float = 5.0
    # c at most the prior's relative variance of the stiffness over the last estimate's deviation spread ("Surprise inflation":
    # keeps a start from inflating; with `inflation_after` the start is disarmed anyway, "Surprise inflation")
    inflation_prior_bound: bool = False
    # > 0: c from the surprise over its own level, z_k / max(1, zbar_k), zbar the innovation statistic smoothed
    # over this many seconds (a persistent model error is no change either, "Surprise inflation"); 0: z_k against 1
    inflation_baseline_time: float = 0.0
    x0_vx_from_wheels: bool = True  # full model: centre vx on R_w omega of the undriven axle
    x0_vx_wheel_std: float = 0.02  # m/s, spread around it (the free-rolling wheel's slip)
    # observability gate (Sec. V) and linear-region gate
    gate_speed: float = 5.0  # m/s
    gate_steer: float = 0.0035  # rad (0.2 deg)
    gate_ay_max: float = 4.0  # m/s^2
    gate_alpha_max: float = 0.08  # rad
    gate_vy_std: float = 0.15  # m/s: learn only once the lateral velocity is known this well
    gate_warmup: float = 1.0  # s after the first sample with learning off: the state settles first
    # the stiffness statistics drawn again from the prior (derivations, "State noise from the data") at the end of gate_warmup
    # ("warmup") or after the learning gate's first open sample ("gate"): the weights of the settling state
    # select particles, and with them stiffness, without information on it; "off": never (the paper)
    warmup_redraw: str = "off"
    # the a^Y of the linear-region test (derivations, "Linear-region test"): "predicted": the filter's one-step prediction
    # of the a^Y sample (free of the sample's own noise, which selects the learning samples otherwise);
    # "measured": the sample; "measured-zero": the sample, a missing one (the guard's held and outlying
    # samples) counting as 0, which opens the gate at any load. A missing sample holds the last value.
    gate_ay: str = "measured"
    # the acceleration of the linear-region test (derivations, "State noise from the data"): "lateral": |a^Y| alone (the paper);
    # "combined": the horizontal magnitude sqrt(a^X^2 + a^Y^2) (the friction circle: braking and traction use
    # the tire's grip and move load between the axles), a missing a^X holding the last one; "auto": combined
    # in the lateral model, which models no longitudinal force, lateral in the full one (it learns Cx there)
    gate_accel: str = "lateral"
    informed_start: bool = True  # initial (r, vy) of each particle conditioned on the first samples
    outlier_prob: float = 1.0  # < 1: a particle skips learning when its residual is beyond this
    # chi-square quantile (off by default: it also rejects the residuals of a real surface change)
    # plausibility (not in the paper): a particle whose state leaves the physically possible
    # region (sideslip beyond plausible_beta, |yaw rate| beyond plausible_yaw_rate, non-finite)
    # gets weight zero; when every particle has left it the filter restarts from its prior
    plausible_beta: float = 0.35  # rad (20 deg; the linear tire model ends far earlier)
    plausible_yaw_rate: float = 2.0  # rad/s
    restart_alpha: float = 0.15  # rad: estimated slip beyond this while |a^Y| < gate_ay_max ...
    restart_after: float = 0.5  # s: ... for this long also restarts (0 disables)
    # a posterior mean pinned at a stiffness bound (within 1% of the reference) for this long restarts
    # too: the cloud locked onto a wrong start and the projection holds it there (0 disables)
    restart_at_bound_after: float = 2.0  # s
    # parameter projection (Sec. V): stiffness bounds relative to the reference
    bound_low: float = 0.2
    bound_high: float = 3.0
    # the roll gradient k of the IMU's a^Y gain 1 + k g (derivations, "The roll gain from the data"): a vehicle
    # file without `roll_gradient` has it estimated as a parameter of each particle (True; False: k = 0 there),
    # drawn uniform over roll_gradient_prior (rad per m/s^2) and walking by roll_gradient_rw per sqrt(s)
    # (reflected at the prior's bounds) so that resampling does not collapse it
    roll_estimate: bool = True
    roll_gradient_prior: tuple[float, float] = (0.0, 0.02)
    roll_gradient_rw: float = 5e-4
    # the load transfer's effective axle stiffness (derivations, "Load transfer"): the lateral axle forces
    # (C_n + w) alpha (1 - kappa a^Y^2), a^Y the last measured one over the roll gain, kappa (s^4/m^2) a
    # parameter of each particle (True; False: the paper's linear axle, kappa = 0) drawn uniform over
    # load_sensitivity_prior and walking by load_sensitivity_rw per sqrt(s), reflected at the bounds (a vehicle
    # file's `load_sensitivity` fixes it); the reported stiffness is then the axle's at a^Y = 0, the static load
    load_sensitivity_estimate: bool = False
    load_sensitivity_prior: tuple[float, float] = (0.0, 0.015)
    load_sensitivity_rw: float = 1e-3
    # sensors
    sigma: tuple[float, float, float] = (0.05, 0.05, 0.0035)  # ax, ay, yaw rate white noise
    # IMU bias (eq. (29)-(30)): prior std and random walk per sqrt(s) of ax, ay, yaw rate;
    # the defaults are the automotive MEMS figures of `sensors` (a scenario or a vehicle
    # TOML sets its own; all zero: no bias estimation, the paper's Sec. VI)
    bias_rw: tuple[float, float, float] = MEMS_BIAS_RW
    bias0_std: tuple[float, float, float] = MEMS_BIAS0_STD
    # unmodelled offsets that wander (road bank and crown, body roll): a random walk per
    # sqrt(s) added to the bias's (derivations, "Bias defaults and wandering offsets"); zero: the paper's bias model
    disturbance_rw: tuple[float, float, float] = DISTURBANCE_RW
    # wheel-speed white noise (rad/s): > 0 filters the wheel speeds before the model takes them (full model;
    # `wheel_filter.WheelSpeedFilter`, derivations, "Wheel-speed pre-filter": noisy wheel speeds bias Cx low); 0: taken as exact
    # (the paper). A replay sets it from the log's wheel speeds, a scenario from its sensor spec
    sigma_omega: float = 0.0
    wheel_slip_rw: float = 0.02  # m/s per sqrt(s): random walk of an axle's slip speed R_w omega - v^X in that filter
    sample_period: float = 0.01  # s, used for the first step and as the bias-RW time base
    max_step: float = 0.02  # s, longest propagation step: longer sample intervals are sub-stepped
    gap_after: float = 0.5  # s: a longer time step is a gap: v^X drawn again from the wheel speeds (0: never)
    backend: str = "numba"  # "numba": the compiled step (compiled.py, kernels.py) | "numpy": the reference
    # the posterior std of the lateral stiffness means (derivations, "Batch-means sandwich"): "sandwich": `*_std` of eq. (27)
    # times the batch-means sandwich factor of the scores of the a^Y residual, sqrt of their integrated
    # autocorrelation time (the misfit that a linear tire leaves over the visited slips is correlated in
    # time; the model assumes it white); "off": the paper's posterior of the mean
    std_calibration: str = "sandwich"
    calibration_batch: float = 0.75  # s of open gate per batch of the sandwich's long-run covariance
    # the sandwich's memory in units of the statistics' (eq. (20)): its batches forget with lambda_k^(1 / this)
    calibration_memory: float = 2.0

    def validated(self) -> "MPFConfig":
        def bad(key, problem):
            raise ConfigError("mpf configuration", key, problem)

        if int(self.particles) != self.particles or self.particles < 1:
            bad("particles", f"N must be an integer >= 1, got {self.particles!r}")
        if not 0.0 < self.forgetting <= 1.0:
            bad("forgetting", f"lambda must be in (0, 1], got {self.forgetting!r}")
        if self.warmup_redraw not in ("off", "warmup", "gate"):
            bad("warmup_redraw", f"expected off, warmup or gate, got {self.warmup_redraw!r}")
        if self.gate_accel not in ("auto", "combined", "lateral"):
            bad("gate_accel", f"expected auto, combined or lateral, got {self.gate_accel!r}")
        if self.gate_ay not in ("predicted", "measured", "measured-zero"):
            bad("gate_ay", f"expected predicted, measured or measured-zero, got {self.gate_ay!r}")
        if self.forgetting_mode not in ("adaptive", "fixed"):
            bad("forgetting_mode", f"expected adaptive or fixed, got {self.forgetting_mode!r}")
        if not 0.0 < self.forgetting_min <= self.forgetting_max <= 1.0:
            bad("forgetting_min", "need 0 < forgetting_min <= forgetting_max <= 1")
        for key in ("surprise_time", "drift_time"):
            if not getattr(self, key) > 0:
                bad(key, f"must be > 0, got {getattr(self, key)!r}")
        if self.model not in ("full", "lateral"):
            bad("model", f"expected full or lateral, got {self.model!r}")
        if self.integrator not in ("euler", "heun"):
            bad("integrator", f"expected euler or heun, got {self.integrator!r}")
        if self.slip_hold not in ("interval", "start"):
            bad("slip_hold", f"expected interval or start, got {self.slip_hold!r}")
        if self.undriven_stiffness not in ("learned", "surface", "nominal"):
            bad("undriven_stiffness", f"expected learned, surface or nominal, got {self.undriven_stiffness!r}")
        if not (self.cx_excitation_time > 0 and math.isfinite(self.cx_excitation_time)):
            bad("cx_excitation_time", f"must be finite and > 0, got {self.cx_excitation_time!r}")
        if self.init_distribution not in ("normal", "uniform"):
            bad("init_distribution", f"expected normal or uniform, got {self.init_distribution!r}")
        for key in ("init_std", "init_half_width", "init_sigma", "gate_speed", "gate_steer", "gate_ay_max",
                    "gate_alpha_max", "gate_vy_std", "gate_warmup", "nu0_margin", "plausible_beta",
                    "plausible_yaw_rate", "restart_alpha", "restart_after", "restart_at_bound_after",
                    "x0_vx_wheel_std", "vy_jitter", "wheel_slip_rw", "surprise_inflation", "inflation_after",
                    "inflation_baseline_time", "state_noise_time"):
            if not getattr(self, key) >= 0:
                bad(key, f"must be >= 0, got {getattr(self, key)!r}")
        for key in ("sigma", "bias_rw", "bias0_std", "disturbance_rw", "x0_std", "state_noise"):
            if any(not v >= 0 for v in getattr(self, key)):
                bad(key, f"noise values must be >= 0, got {getattr(self, key)!r}")
        if min(self.sigma) <= 0:
            bad("sigma", f"sensor noise must be > 0, got {self.sigma!r}")
        if not 0 < self.outlier_prob <= 1:
            bad("outlier_prob", f"must be in (0, 1], got {self.outlier_prob!r}")
        if not 0 < self.within_share < 1:
            bad("within_share", f"must be in (0, 1), got {self.within_share!r}")
        if self.init_sigma <= 0:
            bad("init_sigma", "must be > 0")
        if not 0 < self.bound_low < self.bound_high:
            bad("bound_low", "need 0 < bound_low < bound_high")
        if not (self.sigma_omega >= 0 and math.isfinite(self.sigma_omega)):
            bad("sigma_omega", f"must be finite and >= 0 (0: wheel speeds taken as exact), got {self.sigma_omega!r}")
        if not math.isfinite(self.wheel_slip_rw):
            bad("wheel_slip_rw", f"must be finite, got {self.wheel_slip_rw!r}")
        if self.sample_period <= 0:
            bad("sample_period", "must be > 0")
        if not self.max_step > 0:
            bad("max_step", f"must be > 0, got {self.max_step!r}")
        if not (self.gap_after >= 0 and math.isfinite(self.gap_after)):
            bad("gap_after", f"must be finite and >= 0 (0: never), got {self.gap_after!r}")
        prior = tuple(self.roll_gradient_prior)
        if len(prior) != 2 or not 0.0 <= prior[0] <= prior[1] <= 0.05:
            bad("roll_gradient_prior", f"needs (low, high) with 0 <= low <= high <= 0.05 rad per m/s^2, got "
                f"{self.roll_gradient_prior!r}")
        if not (self.roll_gradient_rw >= 0 and math.isfinite(self.roll_gradient_rw)):
            bad("roll_gradient_rw", f"must be finite and >= 0, got {self.roll_gradient_rw!r}")
        prior = tuple(self.load_sensitivity_prior)
        if len(prior) != 2 or not 0.0 <= prior[0] <= prior[1] <= 0.05:
            bad("load_sensitivity_prior", f"needs (low, high) with 0 <= low <= high <= 0.05 s^4/m^2, got "
                f"{self.load_sensitivity_prior!r}")
        if not (self.load_sensitivity_rw >= 0 and math.isfinite(self.load_sensitivity_rw)):
            bad("load_sensitivity_rw", f"must be finite and >= 0, got {self.load_sensitivity_rw!r}")
        if self.backend not in ("numba", "numpy"):
            bad("backend", f"expected numba or numpy, got {self.backend!r}")
        if not (self.calibration_memory > 0 and math.isfinite(self.calibration_memory)):
            bad("calibration_memory", f"must be finite and > 0, got {self.calibration_memory!r}")
        if self.std_calibration not in ("sandwich", "off"):
            bad("std_calibration", f"expected sandwich or off, got {self.std_calibration!r}")
        if not (self.calibration_batch > 0 and math.isfinite(self.calibration_batch)):
            bad("calibration_batch", f"must be finite and > 0, got {self.calibration_batch!r}")
        return self
