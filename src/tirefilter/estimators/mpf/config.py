"""Options of the stiffness MPF: `MPFConfig`. Its user options, `OPTIONS` (grouped as the table of
docs/usage.md, "Options of the MPF"), are what the `[mpf]` table of --config sets
(`estimators.apply_overrides` accepts those keys and no other): each a switch back to the paper's model
or a quantity a user can know. The other fields are what the scenario or the log tells the filter, set
by the builders (`estimators.mpf_config_for_scenario`, `mpf_config_for_log`), and the method's fixed
values, each with its unit and the reason for its value (not options; the tests of exact answers set
some of them to isolate one mechanism)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from tirefilter.errors import ConfigError
from tirefilter.estimators.sensors import DISTURBANCE_RW, MEMS_BIAS0_STD, MEMS_BIAS_RW

# the `[mpf]` options by group: the one table of docs/usage.md lists each with its unit and what it changes
OPTIONS = {
    "filter": ("particles", "model", "backend"),
    "paper switches": ("forgetting", "forgetting_mode", "integrator", "slip_hold", "undriven_stiffness",
                       "std_calibration", "roll_estimate", "load_sensitivity_estimate", "state_noise_from_data"),
    "sensors": ("sigma", "bias0_std", "bias_rw", "disturbance_rw", "sigma_omega"),
    "prior and state": ("init_std", "x0_std", "state_noise"),
    "gate and bounds": ("gate_speed", "gate_ay_max", "bound_low", "bound_high"),
}
USER_OPTIONS = tuple(key for group in OPTIONS.values() for key in group)
# what a scenario tells the filter about its start, beyond the options (set by `mpf_config_for_scenario`; the
# estimator FMU of an SSP takes them from its config's `[mpf_start]` table)
START_FIELDS = ("x0_mean", "x0_given", "init_center", "init_reference", "init_distribution", "init_half_width")


@dataclass(frozen=True)
class MPFConfig:
    """Options of the stiffness MPF: the `[mpf]` options (`OPTIONS`), what the scenario or the log
    tells the filter, and the method's fixed values."""

    # ---- [mpf] options: the filter ------------------------------------------------------------
    particles: int = 500
    model: str = "full"  # "full" (wheel speeds) | "lateral" (vx given)
    # "c": the compiled step (compiled.py) on the C core (native.py, native/*.c, built on first use with the
    # system C compiler) | "numba": the same step on the numba kernels (kernels.py) | "numpy": the reference
    backend: str = "c"
    # ---- [mpf] options: switches back to the paper's model ---------------------------------------
    forgetting: float = 0.99  # lambda of eq. (20); with adaptive forgetting its value when the data fit
    # adaptive forgetting (derivations, "Adaptive forgetting"): lambda_k = clip(1 - (1 - forgetting) z_k,
    # adaptation.FORGETTING_MIN, FORGETTING_MAX), z_k the smoothed normalised innovation of the accelerometers (1
    # when the data fit the predictive): a surface change forgets fast, a drive that fits keeps a long memory.
    # "fixed": the paper's
    forgetting_mode: str = "adaptive"  # "adaptive" | "fixed"
    integrator: str = "heun"  # "euler" (the paper) | "heun" (same w, wheel slip held)
    # wheel slip in the propagation from t_k to t_k+1 (derivations, "Wheel slip"): "interval": its mean over
    # the interval, the wheel settling (time constant J v^X / (R_w^2 C), a few ms) from the slip at t_k to
    # the one the wheel speeds at t_k+1 give; "start": the slip at t_k held (the paper)
    slip_hold: str = "interval"
    # longitudinal stiffness of the undriven axle: "learned": its nominal value scaled by the share rho of the
    # driven axle's deviation that the wheel-slip excitation has taught (0: nominal, 1: the driven axle's
    # relative deviation; derivations, "The undriven axle"); "nominal": its nominal value (the paper)
    undriven_stiffness: str = "learned"
    # the posterior std of the lateral stiffness means (derivations, "Batch-means sandwich"): "sandwich": `*_std` of
    # eq. (27) times the batch-means sandwich factor of the scores of the a^Y residual, sqrt of their integrated
    # autocorrelation time (the misfit that a linear tire leaves over the visited slips is correlated in
    # time; the model assumes it white); "off": the paper's posterior of the mean
    std_calibration: str = "sandwich"
    # the roll gradient k of the IMU's a^Y gain 1 + k g (derivations, "The roll gain from the data"): a vehicle
    # file without `roll_gradient` has it estimated as a parameter of each particle (True; False: k = 0 there,
    # the paper's), drawn uniform over roll_gradient_prior and walking by roll_gradient_rw per sqrt(s)
    # (reflected at the prior's bounds) so that resampling does not collapse it
    roll_estimate: bool = True
    # the load transfer's effective axle stiffness (derivations, "Load transfer"): the lateral axle forces
    # (C_n + w) alpha (1 - kappa a^Y^2), a^Y the last measured one over the roll gain, kappa (s^4/m^2) a
    # parameter of each particle (True; False: the paper's linear axle, kappa = 0) drawn uniform over
    # load_sensitivity_prior and walking by load_sensitivity_rw per sqrt(s), reflected at the bounds (a vehicle
    # file's `load_sensitivity` fixes it); the reported stiffness is then the axle's at a^Y = 0, the static load
    load_sensitivity_estimate: bool = False
    # process noise of the state from the data (derivations, "State noise from the data"): the intensity per
    # component that makes the corrections the weights make to the state's mean consistent with the spread they
    # remove (covariance matching of the state corrections, Myers and Tapley 1976), smoothed over
    # state_noise_time s; the applied intensity is the larger of it and state_noise's. False: state_noise
    # alone (the paper: none)
    state_noise_from_data: bool = False
    # ---- [mpf] options: sensors -------------------------------------------------------------------
    sigma: tuple[float, float, float] = (0.05, 0.05, 0.0035)  # ax, ay (m/s^2), yaw rate (rad/s) white noise
    # IMU bias (eq. (29)-(30)): prior std and random walk per sqrt(s) of ax, ay, yaw rate;
    # the defaults are the automotive MEMS figures of `sensors` (a scenario or a vehicle
    # TOML sets its own; all zero: no bias estimation, the paper's Sec. VI)
    bias0_std: tuple[float, float, float] = MEMS_BIAS0_STD
    bias_rw: tuple[float, float, float] = MEMS_BIAS_RW
    # unmodelled offsets that wander (road bank and crown, body roll): a random walk per
    # sqrt(s) added to the bias's (derivations, "Bias defaults and wandering offsets"); zero: the paper's bias model
    disturbance_rw: tuple[float, float, float] = DISTURBANCE_RW
    # wheel-speed white noise (rad/s): > 0 filters the wheel speeds before the model takes them (full model;
    # `wheel_filter.WheelSpeedFilter`, derivations, "Wheel-speed pre-filter": noisy wheel speeds bias Cx low);
    # 0: taken as exact (the paper). A replay sets it from the log's wheel speeds, a scenario from its sensor spec
    sigma_omega: float = 0.0
    # ---- [mpf] options: prior and state -----------------------------------------------------------
    init_std: float = 0.3  # relative spread of the initial stiffness means around init_center
    x0_std: tuple[float, ...] = (1.0, 0.5, 0.0175)  # initial state std, full: vx, vy (m/s), r (rad/s)
    state_noise: tuple[float, ...] = (0.0, 0.0, 0.0)  # additive process noise per sqrt(s), full: vx, vy, r
    # ---- [mpf] options: learning gate (Sec. V) and parameter projection ---------------------------
    gate_speed: float = 5.0  # m/s: the lateral dynamics are observable above it
    gate_ay_max: float = 4.0  # m/s^2: learn only below it, in the linear tire region (Sec. V)
    bound_low: float = 0.2  # stiffness bounds relative to the reference (Sec. V)
    bound_high: float = 3.0

    # ---- what the scenario or the log tells the filter (set by the builders) ----------------------
    # initial stiffness: per-particle means drawn around `init_center` (absolute, per parameter, default
    # nominal) with a relative spread of the reference stiffness `init_reference` (default nominal): normal
    # (init_std) or, where a scenario draws its start uniform, uniform (init_half_width)
    init_center: tuple[float, ...] | None = None
    init_reference: tuple[float, ...] | None = None
    init_distribution: str = "normal"  # "normal" (init_std) | "uniform" (init_half_width)
    init_half_width: float = 0.1  # relative
    x0_mean: tuple[float, ...] | None = None  # initial state mean (full: vx, vy, r)
    # the initial state is known (a scenario's). False: taken from a log's first samples, v^Y unknown: the
    # stiffness statistics are drawn again from the prior after the learning gate's first open sample, since
    # until then the weights of the settling state select particles, and with them stiffness, without
    # information on it (derivations, "State noise from the data, the stiffness redraw and braking samples")
    x0_given: bool = True
    sample_period: float = 0.01  # s, used for the first step and as the bias-RW time base

    # ---- the method's fixed values (not options) ------------------------------------------------
    resample_threshold: float = 0.5  # resample when ESS < threshold * N (the usual half)
    state_noise_time: float = 10.0  # s, smoothing of the state noise from the data: 1000 corrections at 100 Hz
    x0_vx_wheel_std: float = 0.02  # m/s, spread of the initial v^X around R_w omega (the free-rolling wheel's slip)
    gate_steer: float = 0.0035  # rad (0.2 deg): below it the stiffness is not observable (Sec. V)
    gate_alpha_max: float = 0.08  # rad: the linear tire region's slip angle
    gate_vy_std: float = 0.15  # m/s: learn only once the lateral velocity is known this well
    gate_warmup: float = 1.0  # s after the first sample with learning off: the state settles first
    informed_start: bool = True  # initial (r, vy) of each particle conditioned on the first samples
    # plausibility (not in the paper): a particle whose state leaves the physically possible
    # region (sideslip beyond plausible_beta, |yaw rate| beyond plausible_yaw_rate, non-finite)
    # gets weight zero; when every particle has left it the filter restarts from its prior
    plausible_beta: float = 0.35  # rad (20 deg; the linear tire model ends far earlier)
    plausible_yaw_rate: float = 2.0  # rad/s
    # s: a slip beyond supervision.RESTART_ALPHA with a small |a^Y| for this long restarts (0: never)
    restart_after: float = 0.5
    # a posterior mean pinned at a stiffness bound (within 1% of the reference) for this long restarts
    # too: the cloud locked onto a wrong start and the projection holds it there (0 disables)
    restart_at_bound_after: float = 2.0  # s
    roll_gradient_prior: tuple[float, float] = (0.0, 0.02)  # rad per m/s^2: passenger cars' roll gradients
    roll_gradient_rw: float = 5e-4  # per sqrt(s): keeps the particles' k apart through resampling
    load_sensitivity_prior: tuple[float, float] = (0.0, 0.015)  # s^4/m^2: at most a 24% loss at 4 m/s^2
    load_sensitivity_rw: float = 1e-3  # per sqrt(s)
    wheel_slip_rw: float = 0.02  # m/s per sqrt(s): random walk of an axle's slip speed R_w omega - v^X in that filter
    max_step: float = 0.02  # s, longest propagation step: longer sample intervals are sub-stepped
    gap_after: float = 0.5  # s: a longer time step is a gap: v^X drawn again from the wheel speeds (0: never)
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
        if self.forgetting_mode not in ("adaptive", "fixed"):
            bad("forgetting_mode", f"expected adaptive or fixed, got {self.forgetting_mode!r}")
        if self.model not in ("full", "lateral"):
            bad("model", f"expected full or lateral, got {self.model!r}")
        if self.integrator not in ("euler", "heun"):
            bad("integrator", f"expected euler or heun, got {self.integrator!r}")
        if self.slip_hold not in ("interval", "start"):
            bad("slip_hold", f"expected interval or start, got {self.slip_hold!r}")
        if self.undriven_stiffness not in ("learned", "nominal"):
            bad("undriven_stiffness", f"expected learned or nominal, got {self.undriven_stiffness!r}")
        if self.init_distribution not in ("normal", "uniform"):
            bad("init_distribution", f"expected normal or uniform, got {self.init_distribution!r}")
        for key in ("init_std", "init_half_width", "gate_speed", "gate_steer", "gate_ay_max",
                    "gate_alpha_max", "gate_vy_std", "gate_warmup", "plausible_beta",
                    "plausible_yaw_rate", "restart_after", "restart_at_bound_after",
                    "x0_vx_wheel_std", "wheel_slip_rw", "state_noise_time"):
            if not getattr(self, key) >= 0:
                bad(key, f"must be >= 0, got {getattr(self, key)!r}")
        for key in ("sigma", "bias_rw", "bias0_std", "disturbance_rw", "x0_std", "state_noise"):
            if any(not v >= 0 for v in getattr(self, key)):
                bad(key, f"noise values must be >= 0, got {getattr(self, key)!r}")
        if min(self.sigma) <= 0:
            bad("sigma", f"sensor noise must be > 0, got {self.sigma!r}")
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
        if self.backend not in ("numba", "c", "numpy"):
            bad("backend", f"expected numba, c or numpy, got {self.backend!r}")
        if not (self.calibration_memory > 0 and math.isfinite(self.calibration_memory)):
            bad("calibration_memory", f"must be finite and > 0, got {self.calibration_memory!r}")
        if self.std_calibration not in ("sandwich", "off"):
            bad("std_calibration", f"expected sandwich or off, got {self.std_calibration!r}")
        if not (self.calibration_batch > 0 and math.isfinite(self.calibration_batch)):
            bad("calibration_batch", f"must be finite and > 0, got {self.calibration_batch!r}")
        return self
