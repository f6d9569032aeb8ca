"""Noise-adaptive marginalized particle filter for tire stiffness, vehicle state and IMU
bias: Algorithm 1 of Berntorp & Di Cairano, "Tire-stiffness and vehicle-state estimation based on
noise-adaptive particle filtering" (IEEE TCST 2018), with the corrections listed in
docs/design.md and derived in docs/derivations.md.

Per particle: the state x (full model [vx, vy, r], lateral model [vy, r]), NiW statistics
of the stiffness deviations w (full [dC_x, dCf_y, dCr_y], lateral [dCf_y, dCr_y]), and a
Gaussian bias estimate (b, P) of the IMU channels. One step at sample k:

  1. propagate x with the w sampled at k-1 (eq. (9), Euler or Heun), predict the bias
     (eq. (29)) and, while learning, forget the statistics (eq. (20));
  2. weight with the Student-t likelihood of eq. (36) (consistent scaling, see
     derivations), normalise in log space, resample when ESS < threshold (every
     per-particle quantity is copied);
  3. Kalman update of the bias, eq. (30);
  4. sample w_k from the conditional Student-t of eq. (39)-(41) given the accelerometer
     residuals, and (gate open) update the statistics with that same w_k, eq. (19);
     project the means onto the stiffness bounds (Sec. V);
  5. report eq. (26)-(27): stiffness mean, posterior std of the mean, deviation spread.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate, Inputs, Measurement, Posterior, particle_estimate
from tirefilter.estimators.baseline_common import gate_open, held_ay
from tirefilter.estimators.sensors import DISTURBANCE_RW, MEMS_BIAS0_STD, MEMS_BIAS_RW
from tirefilter.estimators.wheel_filter import WheelSpeedFilter
from tirefilter.stats import NiW, effective_sample_size, normalize_log_weights, systematic_resample
from tirefilter.stats.linalg import chol, chol_solve, logdet_chol, solve_lower
from tirefilter.stats.sandwich import BatchMeansSandwichPair
from tirefilter.stats.student_t import t_conditional, t_logpdf_whitened, t_sample
from tirefilter.vehicle import single_track
from tirefilter.vehicle.params import VehicleParams
from tirefilter.vehicle.single_track import GRAVITY

NAN = math.nan
_new_object = object.__new__  # (`StiffnessMPF._estimate_fused`)


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
    backend: str = "numba"  # "numba": the compiled step (mpf_numba.py) | "numpy": the reference
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
        if self.backend not in ("numba", "numpy"):
            bad("backend", f"expected numba or numpy, got {self.backend!r}")
        if not (self.calibration_memory > 0 and math.isfinite(self.calibration_memory)):
            bad("calibration_memory", f"must be finite and > 0, got {self.calibration_memory!r}")
        if self.std_calibration not in ("sandwich", "off"):
            bad("std_calibration", f"expected sandwich or off, got {self.std_calibration!r}")
        if not (self.calibration_batch > 0 and math.isfinite(self.calibration_batch)):
            bad("calibration_batch", f"must be finite and > 0, got {self.calibration_batch!r}")
        return self


class StiffnessMPF:
    """Algorithm 1 of the stiffness paper, vectorised over particles."""

    name = "mpf"

    def __init__(self, vehicle: VehicleParams, config: MPFConfig = MPFConfig()):
        self.vehicle = vehicle
        self.cfg = config.validated()
        v = vehicle
        self.rear_drive = v.drive == "rear"
        # nominal axle stiffness: driven axle's Cx is estimated, the other axle's is nominal
        self.C_nom_fx, self.C_nom_rx = single_track.longitudinal_stiffness(v)
        other = self.C_nom_fx if self.rear_drive else self.C_nom_rx
        # "surface": the undriven axle's longitudinal stiffness moves with the driven axle's estimate,
        # C_u = C_u,nom (1 + w_x / C_x,nom): its force adds share * slip_u * w_x to B's first column;
        # "learned": C_u = C_u,nom (1 + rho w_x / C_x,nom), share = rho * C_u,nom / C_x,nom with rho the
        # excitation weight of Cx (`_excite_cx`, derivations, "The undriven axle"), 0 until the wheel slip has taught Cx
        self.full_share = other / v.Cx if self.cfg.undriven_stiffness in ("surface", "learned") else 0.0
        self.undriven_share = self.full_share if self.cfg.undriven_stiffness == "surface" else 0.0
        self.full = self.cfg.model == "full"
        self._gate_combined = self.cfg.gate_accel == "combined" or (self.cfg.gate_accel == "auto" and not self.full)
        self.params = ("Cx", "Cf_y", "Cr_y") if self.full else ("Cf_y", "Cr_y")
        self.C_nom = np.array([v.Cx, v.Cf_y, v.Cr_y] if self.full else [v.Cf_y, v.Cr_y])
        self.n_w = len(self.params)
        self.channels = (0, 1, 2) if self.full else (1, 2)  # ax, ay, yaw rate
        self.roll_gain = 1.0 + v.roll_gradient * GRAVITY  # measured a^Y ~ (1 + k g) a^Y
        sig = np.asarray(self.cfg.sigma)[list(self.channels)]
        self.R = np.diag(sig**2)
        ch = list(self.channels)
        q_sensor, q_road = np.square(self.cfg.bias_rw)[ch], np.square(self.cfg.disturbance_rw)[ch]  # per s
        self.bias_on = bool(np.any(q_sensor + q_road > 0) or np.any(np.asarray(self.cfg.bias0_std) > 0))
        # the road offsets wander only where the linear tire model holds: beyond it the
        # residual is the model's error, not the road's (derivations, "Bias defaults and wandering offsets")
        self.q_bias, self.q_bias_nonlinear = q_sensor + q_road, q_sensor
        q = np.asarray(self.cfg.state_noise, float)[-(3 if self.full else 2):]
        self.state_noise = q if np.any(q > 0) or self.cfg.vy_jitter > 0 or self.cfg.state_noise_from_data else None
        ref = np.asarray(self.cfg.init_reference if self.cfg.init_reference is not None else self.C_nom, float)
        center = np.asarray(self.cfg.init_center if self.cfg.init_center is not None else ref, float)
        if ref.shape != (self.n_w,) or center.shape != (self.n_w,):
            raise ConfigError("mpf configuration", "init_center",
                              f"needs {self.n_w} values ({', '.join(self.params)})")
        self.C_ref, self.C_center = ref, center
        self._C_nom_list = self.C_nom.tolist()  # (`_estimate_fused`)
        self._cx_p0 = self._cx_prior_var() if self.full else 0.0  # (`_excite_cx`)
        self._lf, self._lr = float(v.lf), float(v.lr)  # (`_calibrate_moments`)
        self._calib_power = 1.0 / self.cfg.calibration_memory  # (`_calibrate`)
        self._carried = None
        self._nb = self._st = None
        # the model's packed parameters (`single_track.model_params`; `_set_undriven_share` updates the share)
        self._vp = single_track.model_params(v, self.undriven_share)
        # the settling of the wheel slip (slip_hold = "interval"): spin inertia per axle over R_w^2, and the
        # floor of the axle stiffness in its time constant (the lower projection bound)
        self._jw = np.array([v.wheel_inertia_f, v.wheel_inertia_r], float) / v.wheel_radius**2
        self._c_floor = self.cfg.bound_low * np.array([self.C_nom_fx, self.C_nom_rx], float)
        if self.cfg.backend == "numba":  # the compiled stages; the numpy methods stay the reference
            self._load_kernels()

    def _load_kernels(self) -> None:
        from tirefilter.estimators import mpf_numba
        from tirefilter.vehicle import single_track_numba

        self._nb, self._st = mpf_numba, single_track_numba

    def __getstate__(self):  # (copies and FMU states: the kernel modules are not state)
        return {**self.__dict__, "_nb": None, "_st": None}

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self.cfg.backend == "numba":
            self._load_kernels()

    def _outlier_bound(self, nc: int) -> float:
        cache = self.__dict__.setdefault("_bounds", {})
        if nc not in cache:
            from scipy.stats import chi2  # only with the outlier gate on; scipy.stats imports slowly

            cache[nc] = float(chi2.ppf(self.cfg.outlier_prob, nc))
        return cache[nc]

    def config_dict(self) -> dict:
        d = asdict(self.cfg)
        d.update(params=list(self.params), C_nominal=self.C_nom.tolist())
        q = self.state_noise_estimated()
        if q is not None:
            d["state_noise_estimated"] = q
        return d

    def state_noise_estimated(self) -> dict | None:
        """The state's process noise as estimated from the data so far (`state_noise_from_data`,
        derivations, "State noise from the data"), std per sqrt(s) by state component; None when it is not estimated."""
        if not self.cfg.state_noise_from_data or not hasattr(self, "q_state"):
            return None
        names = ("vx", "vy", "yaw_rate") if self.full else ("vy", "yaw_rate")
        return {n: math.sqrt(float(q)) for n, q in zip(names, self.q_state)}

    # ---- initialisation ---------------------------------------------------------------
    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self._draw_prior(x0_mean=None)
        self.w_prev = None
        self.u_prev = None
        self.t_prev = None
        self.active = False
        self.resamples = 0
        self.restarts = 0
        self._redrawn = False  # `warmup_redraw` done
        self.q_state = np.zeros(3 if self.full else 2)  # the state noise intensity from the data, per s
        self.gap_redraws = 0  # gaps after which v^X was drawn again from the wheel speeds
        self._contradiction_since = None
        self._bound_since = None  # time since which a stiffness mean sits at a projection bound
        self.surprise = 1.0  # z_k of the adaptive forgetting: 1 while the data fit the predictive
        self.surprise_level = 1.0  # z smoothed over `inflation_baseline_time` (`_draw_inflation`)
        self.linear_region = True  # |a^Y| below the gate's linear-region bound at the last sample
        self.ay_last = math.nan  # the last finite a^Y of the linear-region test (`gate_ay`)
        self.ax_last = math.nan  # the last finite a^X of the linear-region test (`gate_accel` combined)
        self.ay_pred = math.nan  # the one-step prediction of this sample's a^Y (`gate_ay = "predicted"`)
        self.lam = self.cfg.forgetting  # the forgetting factor applied at the next propagation
        self.drift = np.zeros(self.n_w)  # smoothed whitened w_k - mu_{k|k-1} (adaptive forgetting)
        self._sigma2_rel = 0.0  # largest relative deviation spread of the last estimate (`_draw_inflation`)
        self.learned_time = 0.0  # s with the learning gate open since the start or the last restart
        self._t_gate = None  # the time of the last gate decision (`_gate_or_restart`)
        self.cx_weight_max = 0.0 if self.full else None  # the largest excitation weight of Cx so far (`_excite_cx`)
        self._reset_cx_excitation()
        # the wheel-speed pre-filter (sigma_omega > 0, full model) and the last sample's measured a^X that drives it
        self.wheels = (WheelSpeedFilter(self.cfg.sigma_omega, self.vehicle.wheel_radius, self.cfg.sigma[0],
                                        self.cfg.wheel_slip_rw) if self.full and self.cfg.sigma_omega > 0 else None)
        self._ax_prev = NAN
        self._e_ay = NAN  # this sample's a^Y residual, predictive-weighted mean (`_predict_ay`)
        self._calib = (BatchMeansSandwichPair(self.cfg.calibration_batch, math.inf)
                       if self.cfg.std_calibration == "sandwich" else None)
        self._calib_in_step = False  # this step's `_step_compiled` has fed the sandwich (`step` does not)

    def _draw_prior(self, x0_mean) -> None:
        """Particles from the initial distribution: stiffness statistics (or the carried
        ones), state around x0_mean (default: the configured one), bias, equal weights."""
        self._draw_prior_stats()
        self._draw_prior_state(x0_mean)

    def _draw_prior_stats(self) -> None:
        """The stiffness statistics of every particle from the prior (or the carried ones)."""
        cfg, N, n, rng = self.cfg, self.cfg.particles, self.n_w, self.rng
        # prior spread of the mean, split between particles and each particle's NiW
        if cfg.init_distribution == "normal":
            s = cfg.init_std
            u = rng.standard_normal((N, n)) * s
        else:
            s = cfg.init_half_width / math.sqrt(3.0)
            u = rng.uniform(-cfg.init_half_width, cfg.init_half_width, (N, n))
        share = cfg.within_share if s > 0 else 0.0
        means = self.C_center + np.sqrt(1.0 - share) * u * self.C_ref
        sigma0 = cfg.init_sigma * self.C_ref  # prior guess of the deviation std
        nu0 = n + 1.0 + cfg.nu0_margin
        self.nu0 = nu0
        Lam0 = np.diag(sigma0**2) * (nu0 - n - 1.0)  # so that E[Sigma] = diag(sigma0^2)
        gamma0 = max(share * s * s / cfg.init_sigma**2, 1e-6)  # gamma E[Sigma] = share s^2 C_ref^2
        self.stats = NiW(np.full(N, gamma0), means - self.C_nom, np.broadcast_to(Lam0, (N, n, n)).copy(),
                         np.full(N, nu0))
        if self._carried is not None:  # statistics learned on an earlier drive replace the prior
            logw, stats = self._carried
            same = len(logw) == N and np.ptp(logw) == 0
            self.stats = stats.take(np.arange(N) if same else systematic_resample(logw, rng, N))
            self.stats.nu = np.maximum(self.stats.nu, nu0)

    def _draw_prior_state(self, x0_mean) -> None:
        cfg, N, rng = self.cfg, self.cfg.particles, self.rng
        x0_std = np.asarray(cfg.x0_std, float)
        if x0_mean is None:
            x0_mean = cfg.x0_mean if cfg.x0_mean is not None else ((20.0, 0.0, 0.0) if self.full else (0.0, 0.0))
        nx = 3 if self.full else 2
        self.x = np.asarray(x0_mean, float)[-nx:] + rng.standard_normal((N, nx)) * x0_std[-nx:]
        m = len(self.channels)
        self.b = np.zeros((N, m))
        self.P = np.broadcast_to(np.diag(np.asarray(cfg.bias0_std)[list(self.channels)] ** 2), (N, m, m)).copy()
        self.logw = np.full(N, -math.log(N))

    # ---- model: `vehicle.single_track` (numpy) or its compiled twin ---------------------
    def _model(self, x, u, slip=None):
        """`single_track.accelerations`: a (N, 3), B (N, 3, n_w), af, ar, the wheel slip (2, N)
        (None in the lateral model; `slip` given: held from an earlier evaluation)."""
        if self._nb is not None and slip is None:
            a, B, af, ar, slip = self._st.accelerations(x, u, self._vp, self.full, self.rear_drive, self.n_w)
            return a, B, af, ar, slip if self.full else None
        return single_track.accelerations(x, u, self._vp, self.full, self.rear_drive, slip)

    def _propagate(self, x, u, w, dt, first):
        """`single_track.propagate` (eq. (9)) with `first` = (a, B, af, ar, slip) at x_k."""
        heun = self.cfg.integrator == "heun"
        if self._nb is not None:
            a, B, _, _, slip = first
            return self._st.propagate(x, u, w, a, B, np.zeros((2, len(x))) if slip is None else slip, dt,
                                      self.cfg.max_step, heun, self._vp, self.full, self.rear_drive, self.n_w)
        return single_track.propagate(x, u, w, dt, first, self._vp, self.full, self.rear_drive, self.cfg.max_step,
                                      heun)

    def _slip_over_step(self, x, u0, u1, w, first, dt):
        """`single_track.slip_over_step`: the first stage of the propagation from t_k to t_k + dt
        with the wheel slip averaged over the interval (slip_hold = "interval")."""
        if self._nb is not None:
            a, B, _, _, slip0 = first
            return self._st.slip_over_step(x, u0, u1, w, a, B, slip0, dt, self._vp, self._jw, self._c_floor,
                                           self.rear_drive, self.n_w)
        return single_track.slip_over_step(x, u0, u1, w, first, dt, self._vp, self._jw, self._c_floor,
                                           self.rear_drive)

    def _measurement(self, a, B, x):
        """`single_track.measurement`: h (N, m) and d (N, m, n_w) of eq. (12)."""
        return single_track.measurement(a, B, x, self.roll_gain, self.full)

    # ---- the filter -------------------------------------------------------------------
    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        dt = t - self.t_prev if self.t_prev is not None else self.cfg.sample_period
        self._e_ay = NAN
        self._calib_in_step = False
        est = self._step(t, u, y)
        return est if self._calib is None or self._calib_in_step else self._calibrate(est, dt)

    def _calibrate(self, est: Estimate, dt: float) -> Estimate:
        """`*_std` of the lateral stiffnesses times the batch-means sandwich factor (derivations
        "Batch-means sandwich", `stats.sandwich`): while learning, the score of this sample's a^Y residual e (the
        predictive-weighted mean of the weighting's residuals) for the two lateral deviations is
        d e with d = (alpha_f cos delta, alpha_r), the slips at the posterior-mean state (the
        columns of eq. (12)'s d up to the factor (1 + k g) / m, which cancels in the ratio)."""
        cal = self._calib
        if self.active and math.isfinite(self._e_ay) and dt > 0:
            v = self.vehicle
            delta = float(self.u_prev[0])
            af, ar = single_track.small_slip_angles(est.vx, est.vy, est.yaw_rate, delta, v.lf, v.lr)
            d = np.array([af * math.cos(delta), ar])
            # forgotten with the statistics' factor (eq. (20)), over calibration_memory times their memory
            cal.update(d * self._e_ay, d, dt, self._lam_step ** self._calib_power)
        f = cal.factor
        if f[0] == 1.0 and f[1] == 1.0:
            return est
        return replace(est, Cf_y_std=est.Cf_y_std * float(f[0]), Cr_y_std=est.Cr_y_std * float(f[1]))

    def _calibrate_moments(self, vx: float, vy: float, r: float, dt: float) -> tuple[float, float]:
        """`_calibrate` for the fused step, on the posterior-mean state (floats) before the Estimate
        is built: the same arithmetic on floats (`BatchMeansSandwichPair.update_pair`, no arrays, no copy of
        the Estimate); returns the factors of Cf_y_std and Cr_y_std."""
        cal = self._calib
        self._calib_in_step = True
        if self.active and math.isfinite(self._e_ay):  # (dt > 0 in the fused step)
            delta = float(self.u_prev[0])
            af, ar = single_track.small_slip_angles(vx, vy, r, delta, self._lf, self._lr)
            d0, e = af * math.cos(delta), self._e_ay
            cal.update_pair(d0 * e, ar * e, d0, ar, dt, self._lam_step ** self._calib_power)
        return cal.factor_pair

    def _step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        cfg = self.cfg
        self._lam_step = self.lam  # the factor this step forgets the statistics with (`_excite_cx`)
        u_now = np.array([u.delta, u.omega_f, u.omega_r, u.vx], float)
        if self.wheels is not None:
            self._filter_wheels(t, u_now, y)
        uk = u_now
        if self.u_prev is not None and not math.isfinite(u.delta + u.omega_f + u.omega_r + u.vx):
            # hold the last finite input where a sample is missing
            uk = np.where(np.isfinite(u_now), u_now, self.u_prev)
        if not self.full and not math.isfinite(uk[3]):
            raise ConfigError("inputs", "vx", f"the lateral model needs vx; none given up to t = {t} s")
        if self.u_prev is None and self.full and self.cfg.x0_vx_from_wheels:
            self._draw_vx_from_wheels(uk)
        if not math.isfinite(uk[0]):
            uk = uk.copy() if uk is u_now else uk
            uk[0] = 0.0

        # the stiffness statistics drawn again from the prior once the state has settled (`warmup_redraw`)
        if cfg.warmup_redraw != "off" and not self._redrawn and self.t_prev is not None and (
                self.active if cfg.warmup_redraw == "gate" else t - self.t_start >= cfg.gate_warmup):
            self._redrawn = True
            self._draw_prior_stats()
        # 1. propagate from the previous sample
        dt = t - self.t_prev if self.t_prev is not None else cfg.sample_period
        if self.t_prev is not None:
            if dt <= 0:
                raise ConfigError("inputs", "t", f"time must increase: {t} after {self.t_prev}")
            if self._nb is not None and not self._gap(dt):  # the usual sample: three compiled passes
                return self._step_compiled(t, uk, y, dt)
            first = self._at_x
            if self.full and cfg.slip_hold == "interval":
                first = self._slip_over_step(self.x, self.u_prev, uk, self.w_prev, first, dt)
            self.x = self._propagate(self.x, self.u_prev, self.w_prev, dt, first)
            self._redraw_after_gap(dt, u_now)  # (a gap: the compiled backend comes this way too)
            if self.state_noise is not None:  # optional regularisation against sample impoverishment
                self.x = self.x + self._state_noise_scale(dt) * self.rng.standard_normal(self.x.shape)
            if self.bias_on:
                q = self.q_bias if self.linear_region else self.q_bias_nonlinear
                self.P = self.P + np.diag(q * dt)
            if self.active:
                self.stats.forget(self.lam, nu_min=self.nu0)
        yk = np.array([y.ax, y.ay, y.yaw_rate], float)[list(self.channels)]
        start_logw = None
        if self.t_prev is None:
            self.t_start = t
            if cfg.informed_start:
                start_logw = self._informed_start(uk, yk)
        self.t_prev, self.u_prev = t, uk

        a = np.flatnonzero(np.isfinite(yk))  # available channels, in the order ax, ay, yaw rate
        nc = int(sum(self.channels[j] in (0, 1) for j in a))  # accelerometer channels lead
        model_k = self._model(self.x, uk)
        af, ar = model_k[2], model_k[3]
        h, D = self._measurement(model_k[0], model_k[1], self.x)
        mu_w, L11, nu_w = self.stats.predictive()

        # 2. weights, eq. (36): the joint Student-t of (w, residual) with the common dof
        #    nu~ = nu - n_w + 1 and every block scaled alike (derivations, "Weight and conditional")
        if a.size:
            every = a.size == len(self.channels)  # the usual case: no indexing needed
            Da = D if every else D[:, a]
            DL = Da @ L11  # (N, |a|, n_w) = L21
            L12 = np.swapaxes(DL, 1, 2)
            R = self.R if every else self.R[np.ix_(a, a)]
            noise = (R + (self.P if every else self.P[:, a][:, :, a])) if self.bias_on else R
            S = DL @ np.swapaxes(Da, 1, 2) + ((nu_w - 2.0) / nu_w)[:, None, None] * noise
            Lc = chol(S)
            e = yk[a] - (h + self.b if every else h[:, a] + self.b[:, a]) - np.einsum("nij,nj->ni", Da, mu_w)
            v = solve_lower(Lc, e)
            self._predict_ay(yk, a, e)
            logw_pred = self.logw
            if nc and start_logw is None:
                self._adapt_forgetting(v[:, :nc], nu_w, dt)
            if start_logw is None:
                self.logw = normalize_log_weights(self.logw + t_logpdf_whitened(v, logdet_chol(Lc), nu_w))
        if start_logw is not None:
            self.logw = normalize_log_weights(start_logw)
        plausible = self._plausible(uk)
        if plausible is False:
            return self._restart(t, uk, y)
        if cfg.state_noise_from_data and start_logw is None and a.size:
            self._match_state_noise(logw_pred, dt)
        ess = float(effective_sample_size(self.logw))
        if ess < cfg.resample_threshold * cfg.particles:
            idx = systematic_resample(self.logw, self.rng)
            self.x, self.b, self.P = self.x[idx], self.b[idx], self.P[idx]
            self.stats = self.stats.take(idx)
            h, D, af, ar = h[idx], D[idx], af[idx], ar[idx]
            a_k, B_k, _, _, slip_k = model_k
            model_k = (a_k[idx], B_k[idx], af, ar, None if slip_k is None else slip_k[:, idx])
            mu_w, L11, nu_w = mu_w[idx], L11[idx], nu_w[idx]
            if a.size:
                L12, Lc, e, v = L12[idx], Lc[idx], e[idx], v[idx]
            self.logw = np.full(cfg.particles, -math.log(cfg.particles))
            self.resamples += 1

        # gate: observability (speed, steering) and linear tire region (Sec. V)
        q = np.exp(self.logw)
        vx_est = float(q @ self.x[:, 0]) if self.full else uk[3]
        vy = self.x[:, 1 if self.full else 0]
        vy_std = math.sqrt(max(float(q @ (vy - q @ vy) ** 2), 0.0))
        alpha = max(abs(float(q @ af)), abs(float(q @ ar)))
        pinned = cfg.restart_at_bound_after > 0 and self._pinned(q @ self.stats.mu)
        if self._gate_or_restart(t, uk, y, vx_est, alpha, vy_std, pinned):
            return self._restart(t, uk, y)

        # 3. sample w_k from the conditional given the accelerometer residuals, eq. (39)-(41);
        #    the yaw-rate residual carries no information on w (d row 0) and is left out.
        #    The leading nc x nc block of Lc is the Cholesky factor of their scale matrix.
        if nc:
            mu_c, Lam_c, nu_c = t_conditional(mu_w, 0.0, L11, L12[:, :, :nc], None, nu_w, e[:, :nc],
                                              L22_chol=Lc[:, :nc, :nc], x2_white=v[:, :nc])
        else:
            mu_c, Lam_c, nu_c = mu_w, L11, nu_w
        c_draw = self._draw_inflation()
        w = t_sample(mu_c, Lam_c * c_draw if c_draw != 1.0 else Lam_c, nu_c, self.rng)
        # the draw the statistics learn from: the same one, or at c = 1 (`inflation_in_statistics`)
        w_learn = w if c_draw == 1.0 or cfg.inflation_in_statistics else mu_c + (w - mu_c) / math.sqrt(c_draw)
        learn = None
        if nc and cfg.outlier_prob < 1:  # per-particle outlier gate on the accelerometer residuals
            vc = solve_lower(Lc[:, :nc, :nc], e[:, :nc])
            learn = np.sum(vc * vc, axis=1) < self._outlier_bound(nc)

        # 4. bias, eq. (30), with the predicted statistics (docs/derivations.md, "Order of Algorithm 1")
        if a.size and self.bias_on:
            self._bias_update(yk, h, D, a)
        if self.active:
            if nc:
                self._track_drift(w_learn - mu_w, L11, dt)  # before the update: mu_w may be the statistics' own array
            lo = cfg.bound_low * self.C_ref - self.C_nom
            hi = cfg.bound_high * self.C_ref - self.C_nom
            self.stats.update(w_learn, learn)  # eq. (19) with the w_k that drives the state (or its uninflated twin)
            self.stats.mu = np.clip(self.stats.mu, lo, hi)  # parameter projection (Sec. V)
        self.w_prev = w
        self._at_x = model_k  # the first stage of the next propagation, at this x and u
        if self.full:
            self._excite_cx(float(np.exp(self.logw) @ self.x[:, 0]), uk, dt)
        return self._estimate(ess)

    def _filter_wheels(self, t: float, u_now: np.ndarray, y: Measurement) -> None:
        """The measured wheel speeds u_now[1:3] replaced in place by the pre-filter's estimates
        (`wheel_filter.WheelSpeedFilter`, derivations, "Wheel-speed pre-filter"; a missing one stays missing). Its
        drive over the step from the last sample: that sample's measured a^X minus the posterior
        mean of its bias, plus the posterior mean of v^Y r (the particles as they stand, before
        this sample's propagation). The first sample and the sample after a gap (`_gap`) start
        the filter again at the measurements."""
        f = self.wheels
        if self.t_prev is None:
            f.reset()
            dt = self.cfg.sample_period
        else:
            dt = t - self.t_prev
            if not dt > 0:  # (`step` reports it)
                return
            if self._gap(dt):
                f.reset()
        drive = NAN
        if self.t_prev is not None and math.isfinite(self._ax_prev):
            q = np.exp(self.logw)
            b = float(q @ self.b[:, 0]) if self.bias_on else 0.0
            drive = self._ax_prev - b + float(q @ (self.x[:, 1] * self.x[:, 2]))
        self._ax_prev = y.ax
        u_now[1:3] = f.step(dt, u_now[1:3], drive)

    def _match_state_noise(self, logw_pred: np.ndarray, dt: float) -> None:
        """`state_noise_from_data` (derivations, "State noise from the data"): with the predictive weights logw_pred and
        the weights after this sample's likelihood, both over the propagated particles x, the
        correction of the state's mean d = m+ - m- and the spreads P-, P+ per component give
        g = (d^2 - (P- - P+)) / dt + q, q the intensity applied in this propagation: the intensity
        under which the corrections have the size the removed spread says (E[d^2] = P- - P+ for a
        consistent filter). g is smoothed over `state_noise_time` into q_state (>= 0)."""
        x = self.x
        q0, q1 = np.exp(logw_pred), np.exp(self.logw)
        q0, q1 = q0 / q0.sum(), q1 / q1.sum()
        m0, m1 = q0 @ x, q1 @ x
        p0, p1 = q0 @ (x - m0) ** 2, q1 @ (x - m1) ** 2
        applied = np.square(self._state_noise_scale(dt)) / dt
        g = ((m1 - m0) ** 2 - (p0 - p1)) / dt + applied
        if np.all(np.isfinite(g)):
            a = -math.expm1(-dt / self.cfg.state_noise_time)
            self.q_state = np.maximum(self.q_state + a * (g - self.q_state), 0.0)

    def _state_noise_scale(self, dt: float) -> np.ndarray:
        """Std of the additive state noise over a step dt (nx,): `state_noise` sqrt(dt), and on
        v^Y also vy_jitter sqrt(z - z_on) sqrt(dt) while the adaptive forgetting's smoothed
        innovation statistic z of the previous sample exceeds z_on, the z that puts lambda at its
        floor `forgetting_min` (a change: docs/results.md, "Options of the MPF")."""
        cfg, q = self.cfg, self.state_noise
        if cfg.state_noise_from_data:
            q = np.sqrt(np.maximum(q * q, self.q_state))
        # z at which the forgetting reaches its floor, 1 - (1 - lambda) z = lambda_min: the change statistic fires
        z_on = (1.0 - cfg.forgetting_min) / max(1.0 - cfg.forgetting, 1e-12)
        if cfg.vy_jitter > 0 and cfg.forgetting_mode == "adaptive" and self.surprise > z_on:
            q = q.copy()
            iy = 1 if self.full else 0
            q[iy] = math.sqrt(q[iy] ** 2 + cfg.vy_jitter**2 * (self.surprise - z_on))
        return math.sqrt(dt) * q

    # ---- the undriven axle's share of the learned Cx (undriven_stiffness = "learned") ----------
    def _reset_cx_excitation(self) -> None:
        """No excitation of Cx yet: information 0, weight 0 (with "learned" the undriven axle at
        its nominal stiffness), the slip level unknown."""
        self.cx_info = 0.0  # I_k, information on dC_x from the changes of the driven axle's slip, 1/N^2
        self.cx_weight = 0.0  # rho_k = cx_excitation_weight(I_k, prior variance)
        self._slip_level = NAN  # the slip smoothed over cx_excitation_time
        self._set_undriven_share()

    def _cx_prior_var(self) -> float:
        """Prior variance of the mean of dC_x, (s C_ref,x)^2 ("Initialisation": the particles' spread plus
        the within-particle share), s = init_std or init_half_width / sqrt(3)."""
        cfg = self.cfg
        s = cfg.init_std if cfg.init_distribution == "normal" else cfg.init_half_width / math.sqrt(3.0)
        return float((s * self.C_ref[0]) ** 2)

    def _set_undriven_share(self) -> None:
        if self.cfg.undriven_stiffness == "learned":
            self.undriven_share = self.full_share * self.cx_weight
            self._vp[single_track.P_UNDRIVEN_SHARE] = self.undriven_share

    def _excite_cx(self, vx: float, uk: np.ndarray, dt: float) -> None:
        """The excitation weight of Cx after sample k (derivations, "The undriven axle"), full model.

        The driven axle's slip at the posterior-mean v^X, lambda_k, minus its level smoothed over
        `cx_excitation_time` T (a level held longer is confounded with the a^X bias and v^X
        errors) is the regressor of dC_x in a^X, b_k = (lambda_k - level_k) / m. While the gate is
        open its information accumulates with the statistics' forgetting factor lambda_k (eq. (20)),
        I_k = lambda_k I_{k-1} + b_k^2 / sigma_ax^2, frozen while the gate is closed, and
        rho_k = I_k P_0 / (1 + I_k P_0) = 1 - P_k / P_0 is the contraction of the linear-Gaussian
        posterior variance of dC_x from its prior variance P_0. With undriven_stiffness =
        "learned" the undriven axle takes the share rho_k of the driven axle's relative deviation
        from the next propagation on."""
        omega = uk[2] if self.rear_drive else uk[1]
        slip = single_track.floored_wheel_slip(vx, self.vehicle.wheel_radius * omega)
        if not math.isfinite(slip):
            return
        if not math.isfinite(self._slip_level):
            self._slip_level = slip
        self._slip_level += -math.expm1(-dt / self.cfg.cx_excitation_time) * (slip - self._slip_level)
        if self.active:
            b = (slip - self._slip_level) / self.vehicle.mass
            self.cx_info = self._lam_step * self.cx_info + b * b / self.R[0, 0]
        self.cx_weight = cx_excitation_weight(self.cx_info, self._cx_p0)
        self.cx_weight_max = max(self.cx_weight_max, self.cx_weight)
        self._set_undriven_share()

    def _pin_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The deviations (n_w,) at or beyond which a posterior mean counts as held at a
        projection bound (Sec. V): within 1% of the reference stiffness of it."""
        cfg = self.cfg
        tol = 0.01 * self.C_ref
        return cfg.bound_low * self.C_ref - self.C_nom + tol, cfg.bound_high * self.C_ref - self.C_nom - tol

    def _gate_or_restart(self, t: float, uk: np.ndarray, y: Measurement, vx_est: float, alpha: float,
                         vy_std: float, pinned: bool) -> bool:
        """Opens or closes the learning gate (observability and the linear tire region, Sec. V)
        and says whether the cloud must restart: a large slip angle with a small measured a^Y
        for `restart_after` s (no tire explains that: the state has locked onto a wrong
        sideslip, which the sampled w explains regardless), or a stiffness mean `pinned` at a
        projection bound for `restart_at_bound_after` s."""
        cfg = self.cfg
        ay = self.ay_pred if cfg.gate_ay == "predicted" else y.ay
        self.ay_pred = math.nan
        if cfg.gate_ay != "measured-zero":  # a missing sample is no evidence of the linear region ("Linear-region test")
            ay = self.ay_last = held_ay(ay, self.ay_last)
        if self._gate_combined:  # the friction circle's load, sqrt(a^X^2 + a^Y^2) ("State noise from the data")
            ax = self.ax_last = held_ay(y.ax, self.ax_last)
            if math.isfinite(ax) and math.isfinite(ay):
                ay = math.hypot(ax, ay)
        ay_m = ay if math.isfinite(ay) else 0.0
        self.linear_region = abs(ay_m) < cfg.gate_ay_max
        self.active = gate_open(cfg, t=t, t_start=self.t_start, vx=vx_est, delta=uk[0], ay_meas=ay, alpha=alpha,
                                vy_std=vy_std)
        if self.active and self._t_gate is not None:  # (`inflation_after`)
            self.learned_time += t - self._t_gate
        self._t_gate = t
        # (the measured a^Y: a state locked onto a wrong slip predicts the large a^Y of that slip)
        ay_y = y.ay if math.isfinite(y.ay) else 0.0
        contradiction = cfg.restart_alpha > 0 and alpha > cfg.restart_alpha and abs(ay_y) < cfg.gate_ay_max
        self._contradiction_since = (self._contradiction_since or t) if contradiction else None
        if contradiction and t - self._contradiction_since >= cfg.restart_after:
            return True
        return cfg.restart_at_bound_after > 0 and self._pinned_too_long(t, pinned)

    def _pinned(self, mbar: np.ndarray) -> bool:
        lo, hi = self._pin_bounds()
        return bool(np.any((mbar <= lo) | (mbar >= hi)))

    def _pinned_too_long(self, t: float, pinned: bool) -> bool:
        """A posterior mean held at a projection bound (`pinned`, `_pinned`) since
        `restart_at_bound_after` s or longer: the cloud has locked onto a wrong stiffness that
        the projection keeps it at, and the filter starts again."""
        cfg = self.cfg
        if not pinned:
            self._bound_since = None
        elif self._bound_since is None:
            self._bound_since = t
        elif t - self._bound_since >= cfg.restart_at_bound_after:
            return True
        return False

    def _step_compiled(self, t: float, uk: np.ndarray, y: Measurement, dt: float) -> Estimate:
        """Steps 1-5 of `step` for every sample after the first, by three compiled passes over
        the particles (`mpf_numba.predict_weigh`, `resample_gate`, `sample_update`) on arrays
        allocated once (`_MPFWork`), with the random numbers drawn here by the reference's
        generator calls in the reference's order: the same numbers as the numpy path
        (tests/test_kernels.py). The rare branches (restarts) go through the reference methods."""
        cfg, nb, rng, st = self.cfg, self._nb, self.rng, self.stats
        wk = self._work()
        if self.state_noise is not None:  # optional regularisation against sample impoverishment
            noise, noise_scale = rng.standard_normal(self.x.shape), self._state_noise_scale(dt)
        else:
            noise, noise_scale = wk.no_noise, wk.no_scale
        q = self.q_bias if self.linear_region else self.q_bias_nonlinear
        ch = self.channels
        yl = [y.ax, y.ay, y.yaw_rate] if self.full else [y.ay, y.yaw_rate]
        yk = np.array(yl, float)
        if math.isfinite(sum(yl)):  # the kernels compiled for this model's sizes (mpf_numba.SIZES_FULL ...)
            a, nc, sizes = wk.avail_all, wk.nc_all, wk.sizes_all
        else:
            sizes = wk.sizes_any
            a = np.flatnonzero(np.isfinite(yk))
            nc = int(sum(ch[j] in (0, 1) for j in a))
        adaptive = cfg.forgetting_mode == "adaptive"
        u_prev = self.u_prev
        self.t_prev, self.u_prev = t, uk
        # the predictive weights (`_predict_ay`: the gate's a^Y prediction, the residual of `_calibrate`;
        # `_match_state_noise`), into a buffer
        logw_pred = None
        if wk.keep_pred:
            logw_pred = wk.logw_pred
            np.copyto(logw_pred, self.logw)
        innovation, ess, count, nu_common = nb.predict_weigh(
            self.x, u_prev, self.w_prev, wk.a, wk.B, wk.af, wk.ar, wk.slip, dt, cfg.max_step, wk.heun, wk.interval,
            self._jw, self._c_floor, noise, noise_scale, self.b, self.P, q, self.bias_on, self.active, self.lam,
            self.nu0, st.gamma, st.mu, st.Lam, st.nu, uk, yk, a, self.R, self.roll_gain, self._vp, self.full,
            self.rear_drive, wk.h, wk.D, wk.L11, wk.nu_w, wk.L12, wk.Lc, wk.e, wk.v, wk.ll, wk.ok, self.logw, nc,
            adaptive, cfg.plausible_beta, cfg.plausible_yaw_rate, cfg.gate_speed, sizes)
        if math.isfinite(innovation):  # adaptive forgetting (`_adapt_forgetting`)
            self._smooth_surprise(innovation, dt)
        if wk.predicted_ay and a.size:  # (the calibration's residual alone waits for the gate: `_ay_residual`)
            self._predict_ay(yk, a, wk.e, logw_pred)
        self.w_prev = wk.w
        # af, ar in the order before any resampling: the next propagation reads only a, B and slip
        self._at_x = (wk.a, wk.B, wk.af, wk.ar, wk.slip if self.full else None)
        if count == 0:
            return self._restart(t, uk, y)
        if count < cfg.particles:  # some particles left the plausible region (`_plausible`)
            self.logw = normalize_log_weights(np.where(wk.ok, self.logw, -np.inf))
            ess = -1.0
        if cfg.state_noise_from_data and a.size:
            self._match_state_noise(logw_pred, dt)
        if ess < 0:
            ess = float(effective_sample_size(self.logw))
        resample = ess < cfg.resample_threshold * cfg.particles
        u0 = float(rng.random((1,))[0]) if resample else 0.0
        vx_est, vy_std, alpha, pinned = nb.resample_gate(
            self.logw, u0, resample, wk.idx, self.x, self.b, self.P, st.gamma, st.mu, st.Lam, st.nu, wk.a, wk.B,
            wk.slip, *wk.spares, wk.af, wk.ar, self.full, wk.pin_lo, wk.pin_hi, wk.q)
        if resample:
            self._swap_work(wk)
            self.resamples += 1
        vx_est = vx_est if self.full else uk[3]
        if self._gate_or_restart(t, uk, y, vx_est, alpha, vy_std, pinned):
            return self._restart(t, uk, y)
        if self.active and self._calib is not None and not wk.predicted_ay and a.size:
            self._ay_residual(a, logw_pred, wk)
        N = cfg.particles
        z = rng.standard_normal((N, self.n_w))
        if nu_common > 0:
            nu_draw = wk.nu_draw
            nu_draw.fill(nu_common + nc)
            chi = rng.chisquare(nu_common + nc, N)
        else:
            nu_draw = wk.nu_w[wk.idx] + nc if nc else wk.nu_w[wk.idx]
            chi = rng.chisquare(nu_draw)
        use_mask = bool(nc and cfg.outlier_prob < 1)
        st = self.stats
        drift = bool(self.active and nc and adaptive)
        if drift and self.drift is not wk.drift_checked:  # (the kernel writes into it)
            if not (self.drift.flags.c_contiguous and self.drift.dtype == np.float64):
                self.drift = np.array(self.drift, float)
            wk.drift_checked = self.drift
        zd = nb.sample_update(
            wk.idx, self.x, self.logw, st.gamma, st.mu, st.Lam, st.nu, self.b, self.P, wk.h, wk.D, wk.L11, wk.nu_w,
            wk.L12, wk.Lc, wk.v, nc, z, chi, nu_draw, wk.w, use_mask, self._outlier_bound(nc) if use_mask else 0.0,
            bool(a.size and self.bias_on), self.R, a, yk, self.active, drift, self.drift,
            -math.expm1(-dt / cfg.drift_time), wk.lo, wk.hi, wk.mom, wk.q, self._draw_factors(wk.ones2), sizes)
        if zd == zd:  # `_track_drift` (the statistic is NaN when not computed)
            self._cap_forgetting(zd)
        if self.full:
            self._excite_cx(float(wk.mom[0, 0]), uk, dt)
        return self._estimate_fused(ess, wk.mom, dt)

    def _estimate_fused(self, ess: float, mom: np.ndarray, dt: float | None = None) -> Estimate:
        """`_estimate_from` on the moments that `sample_update` left in the rows of mom, written out
        for the fused step: the same Estimate (tests/test_kernels.py compares every field) in a
        third of the time. With `dt` (the fused step) and `std_calibration = "sandwich"`, the
        calibration's update and factors (`_calibrate_moments`) go into the one Estimate built.
        The frozen dataclass's fields are filled directly (every field: its generated __init__
        sets each through object.__setattr__, several us per step); Estimate has no
        __post_init__ and no __slots__ (tests/test_kernels.py checks both and compares the
        object with the constructor's)."""
        xm, xs, mb, vm, s2, bm = mom.tolist()
        if self.cfg.inflation_prior_bound:  # (`_draw_inflation`'s bound)
            self._sigma2_rel = max(v / c**2 for v, c in zip(s2, self.C_ref.tolist()))
        root, C = _sqrt_or_nan, self._C_nom_list
        f0 = f1 = 1.0
        est = _new_object(Estimate)
        if self.full:  # params Cx, Cf_y, Cr_y; bias ax, ay, yaw rate
            if dt is not None and self._calib is not None:
                f0, f1 = self._calibrate_moments(xm[0], xm[1], xm[2], dt)
            est.__dict__.update(active=bool(self.active), vx=xm[0], vy=xm[1], yaw_rate=xm[2], Cf_y=C[1] + mb[1],
                                Cr_y=C[2] + mb[2], Cx=C[0] + mb[0], Cf_y_std=root(vm[1]) * f0,
                                Cr_y_std=root(vm[2]) * f1, Cx_std=root(vm[0]), Cf_y_sigma=root(s2[1]),
                                Cr_y_sigma=root(s2[2]), Cx_sigma=root(s2[0]), b_ax=bm[0], b_ay=bm[1], b_yaw_rate=bm[2],
                                ess=float(ess), state_std=(xs[0], xs[1], xs[2]))
            return est
        vx = float(self.u_prev[3])
        if dt is not None and self._calib is not None:
            f0, f1 = self._calibrate_moments(vx, xm[0], xm[1], dt)
        est.__dict__.update(active=bool(self.active), vx=vx, vy=xm[0], yaw_rate=xm[1], Cf_y=C[0] + mb[0],
                            Cr_y=C[1] + mb[1], Cx=NAN, Cf_y_std=root(vm[0]) * f0, Cr_y_std=root(vm[1]) * f1, Cx_std=NAN,
                            Cf_y_sigma=root(s2[0]), Cr_y_sigma=root(s2[1]), Cx_sigma=NAN, b_ax=NAN, b_ay=bm[0],
                            b_yaw_rate=bm[1], ess=float(ess), state_std=(0.0, xs[0], xs[1]))
        return est

    def _ay_residual(self, a: np.ndarray, logw_pred: np.ndarray, wk: "_MPFWork") -> None:
        """`_predict_ay`'s `_e_ay` for the fused step, the residual of the calibration ("Batch-means sandwich"):
        the same expression on the column of a^Y (looked up once when every channel is there) and
        a buffer for the predictive weights; NaN when the a^Y sample is missing. Computed only
        once the gate is open: a closed gate does not feed the sandwich."""
        j = wk.ay_col if a is wk.avail_all else next((j for j in range(len(a)) if self.channels[a[j]] == 1), -1)
        if j >= 0:
            self._e_ay = float(np.dot(np.exp(logw_pred, out=wk.q_pred), wk.e[:, j]))  # (`@`'s own dot, bit for bit)

    def _work(self) -> "_MPFWork":
        """The fused step's arrays, the particles' own arrays among them: an array that the
        reference path replaced (first sample, restart, a loaded state) is copied in."""
        wk = self.__dict__.get("_wk")
        st = self.stats
        if (wk is not None and self.x is wk.x and self.w_prev is wk.w and st.mu is wk.mu and st.Lam is wk.Lam
                and st.gamma is wk.gamma and st.nu is wk.nu and self.b is wk.b and self.P is wk.P
                and self._at_x[0] is wk.a):  # the last sample's fused step left them all in place
            return wk
        nx = self.x.shape[1]
        if wk is None or wk.x.shape != self.x.shape:
            wk = self._wk = _MPFWork(self, len(self.x), nx, self.n_w, len(self.channels))
        for name, arr in (("x", self.x), ("b", self.b), ("P", self.P), ("gamma", st.gamma), ("mu", st.mu),
                          ("Lam", st.Lam), ("nu", st.nu), ("w", self.w_prev)):
            buf = getattr(wk, name)
            if arr is not buf:
                buf[...] = arr
        self.x, self.b, self.P, self.w_prev = wk.x, wk.b, wk.P, wk.w
        st.gamma, st.mu, st.Lam, st.nu = wk.gamma, wk.mu, wk.Lam, wk.nu
        first = self._at_x
        if first[0] is not wk.a:
            wk.a[...], wk.B[...] = first[0], first[1]
            wk.slip[...] = 0.0 if first[4] is None else first[4]
        return wk

    def _swap_work(self, wk: "_MPFWork") -> None:
        """After `resample_gate`: the spares hold the resampled particles."""
        wk.swap()
        st = self.stats
        self.x, self.b, self.P = wk.x, wk.b, wk.P
        st.gamma, st.mu, st.Lam, st.nu = wk.gamma, wk.mu, wk.Lam, wk.nu
        self._at_x = (wk.a, wk.B, wk.af, wk.ar, wk.slip if self.full else None)

    def _predict_ay(self, yk: np.ndarray, a: np.ndarray, e: np.ndarray, logw: np.ndarray | None = None) -> None:
        """`ay_pred`, the one-step prediction of the a^Y sample that the linear-region test reads
        with `gate_ay = "predicted"` (derivations, "Linear-region test"): the sample less the residuals e
        (N, |a|) of the weighting, averaged with the predictive weights (`logw`, default the
        particles' before this sample's likelihood), i.e. sum_i w_{k-1}^i (h + b + d mu)^i_ay.
        NaN when the sample is missing."""
        if self.cfg.gate_ay != "predicted" and self._calib is None:
            return
        q = [j for j in range(len(a)) if self.channels[a[j]] == 1]
        if q:
            lw = self.logw if logw is None else logw
            self._e_ay = float(np.exp(lw) @ e[:, q[0]])  # (the residual of `_calibrate`, "Batch-means sandwich")
            if self.cfg.gate_ay == "predicted":
                self.ay_pred = float(yk[a[q[0]]] - self._e_ay)

    def _adapt_forgetting(self, v: np.ndarray, nu: np.ndarray, dt: float) -> None:
        """The forgetting factor of the next propagation from how well the accelerometers
        fit the predictive (derivations, "Adaptive forgetting"). `v` (N, nc) are the whitened residuals of
        the weighting, Student-t with nu (N,) dof: E[v^T v] = nc nu / (nu - 2). Their
        normalised square, averaged with the predictive weights (before this sample's
        likelihood), is smoothed over `surprise_time` into z_k; lambda_k = 1 - (1 - lambda) z_k,
        clipped: z = 1 gives the configured lambda, a surface change (z >> 1) forgets fast,
        a drive that fits better than its noise figures (z < 1) forgets slowly."""
        cfg = self.cfg
        if cfg.forgetting_mode == "fixed":
            return
        nis = np.sum(v * v, axis=1) * (nu - 2.0) / (nu * v.shape[1])
        s_k = float(np.exp(self.logw) @ nis)
        if math.isfinite(s_k):
            self._smooth_surprise(s_k, dt)

    def _draw_inflation(self) -> float:
        """c of the surprise inflation (derivations, "Surprise inflation"): the factor on the conditional scale of
        the draw of w_k, max(1, 1 + surprise_inflation (z - 1)) with z the smoothed innovation
        statistic of this sample (`_smooth_surprise`; over its own level with `inflation_baseline_time`),
        bounded by the prior (`inflation_prior_bound`); 1 when
        off, with fixed forgetting, or before the learning gate has been open `inflation_after` s since the
        start or the last restart."""
        cfg = self.cfg
        if cfg.surprise_inflation <= 0 or cfg.forgetting_mode != "adaptive" or self.learned_time < cfg.inflation_after:
            return 1.0
        z = self.surprise / max(1.0, self.surprise_level) if cfg.inflation_baseline_time > 0 else self.surprise
        c = 1.0 + cfg.surprise_inflation * (z - 1.0)
        # at most the prior's uncertainty of the stiffness, s^2 + init_sigma^2 (relative), over the
        # deviation spread of the last estimate (eq. (27b))
        s = cfg.init_std if cfg.init_distribution == "normal" else cfg.init_half_width / math.sqrt(3.0)
        spread = self._sigma2_rel
        if spread > 0 and cfg.inflation_prior_bound:
            c = min(c, (s * s + cfg.init_sigma**2) / spread)
        return max(1.0, c)

    def _draw_factors(self, ones: np.ndarray | None = None) -> np.ndarray:
        """The compiled draw's std factors (2,): sqrt(c) for the draw that drives the state, and for
        the one the statistics learn from sqrt(c) or 1 (`inflation_in_statistics`); `ones` (the
        array [1, 1], returned as it is when c = 1) saves the allocation in the usual case."""
        c = self._draw_inflation()
        if c == 1.0 and ones is not None:
            return ones
        root = math.sqrt(c)
        return np.array([root, root if self.cfg.inflation_in_statistics else 1.0])

    def _smooth_surprise(self, s_k: float, dt: float) -> None:
        """z_k: s_k smoothed over `surprise_time`; lambda_k = 1 - (1 - lambda) z_k, clipped."""
        cfg = self.cfg
        self.surprise += -math.expm1(-dt / cfg.surprise_time) * (s_k - self.surprise)
        if cfg.inflation_baseline_time > 0:
            self.surprise_level += -math.expm1(-dt / cfg.inflation_baseline_time) * (s_k - self.surprise_level)
        self.lam = min(max(1.0 - (1.0 - cfg.forgetting) * self.surprise, cfg.forgetting_min), cfg.forgetting_max)

    def _cap_forgetting(self, z: float) -> None:
        """lambda_k no larger than 1 - (1 - lambda) z (the drift statistic z, `_track_drift`)."""
        cfg = self.cfg
        self.lam = min(self.lam, max(1.0 - (1.0 - cfg.forgetting) * z, cfg.forgetting_min))

    def _track_drift(self, dw: np.ndarray, L11: np.ndarray, dt: float) -> None:
        """The second surprise statistic of the adaptive forgetting (derivations, "Adaptive forgetting"):
        w_k - mu_{k|k-1} (N, n_w), whitened by the predictive scale L11 (N, n_w, n_w), has
        mean zero while the statistics' mean is right, whatever the deviation spread; a
        stale mean makes it lean one way sample after sample. Its weighted mean over the
        particles is smoothed into `drift` (n_w,), whose square, scaled by (2 - a) / a for
        the smoothing a = 1 - exp(-dt / drift_time), is about 1 per component under the
        model (the per-sample whitened values have unit variance up to nu / (nu - 2))."""
        cfg = self.cfg
        if cfg.forgetting_mode == "fixed":
            return
        u = solve_lower(chol(L11), dw)
        ubar = np.exp(self.logw) @ u
        if not np.all(np.isfinite(ubar)):
            return
        a = -math.expm1(-dt / cfg.drift_time)
        self.drift = self.drift + a * (ubar - self.drift)
        self._cap_forgetting(float(self.drift @ self.drift) * (2.0 - a) / (a * len(ubar)))

    def _informed_start(self, uk, yk) -> np.ndarray:
        """Draw each particle's initial (r, vy) from its prior conditioned on the first yaw
        rate and a^Y samples, given the particle's own stiffness mean (Gaussian, a^Y
        linearised in vy), and return the log marginal likelihood of those samples as the
        first weights (they replace the step's weighting: the samples are used once).

        Why: weighting prior draws by the first a^Y collapses the cloud onto the few
        particles whose vy happens to fit their stiffness (ESS of a handful out of 500), and
        a biased stiffness prior then locks in a vy offset (derivations, "Start-up, plausibility and restart"). Drawn
        this way, every stiffness hypothesis keeps a consistent state and the yaw dynamics
        decide between them."""
        logw = np.zeros(len(self.x))
        jr, jy = len(self.channels) - 1, len(self.channels) - 2  # yaw rate, a^Y
        ix_r, ix_vy = self.x.shape[1] - 1, self.x.shape[1] - 2
        std = np.asarray(self.cfg.x0_std, float)[-2:]
        var_vy, var_r = std[0] ** 2, std[1] ** 2
        if math.isfinite(yk[jr]) and var_r > 0:
            s2 = self.R[jr, jr]
            gain = var_r / (var_r + s2)
            e = yk[jr] - self.b[:, jr] - self.x[:, ix_r]
            logw += -0.5 * (e * e / (var_r + s2) + math.log(2 * math.pi * (var_r + s2)))
            self.x[:, ix_r] += gain * e + math.sqrt(var_r * (1 - gain)) * self.rng.standard_normal(len(self.x))
        if math.isfinite(yk[jy]) and var_vy > 0:
            a, B, *_ = self._model(self.x, uk)
            h, D = self._measurement(a, B, self.x)
            x1 = self.x.copy()
            x1[:, ix_vy] += 1.0
            h1, _ = self._measurement(*self._model(x1, uk)[:2], x1)
            k = (h1 - h)[:, jy]  # d a^Y / d vy at w = 0 (the w-dependent part is left out)
            mu_w, L11, nu_w = self.stats.predictive()
            d = D[:, jy]
            S = np.einsum("ni,nij,nj->n", d, L11, d) * nu_w / (nu_w - 2.0) + self.R[jy, jy] + self.P[:, jy, jy]
            e = yk[jy] - h[:, jy] - self.b[:, jy] - np.einsum("ni,ni->n", d, mu_w)
            Se = k * k * var_vy + S
            gain = k * var_vy / Se
            logw += -0.5 * (e * e / Se + np.log(2 * math.pi * Se))
            self.x[:, ix_vy] += gain * e + np.sqrt(np.maximum(var_vy * (1 - gain * k), 0.0)) * self.rng.standard_normal(
                len(self.x))
        return logw

    def _plausible(self, uk) -> bool:
        """Zero the weight of particles outside the physically possible region; False when
        none is left."""
        vx = self.x[:, 0] if self.full else uk[3]
        vy, r = self.x[:, -2], self.x[:, -1]
        ok = (np.abs(vy) <= self.cfg.plausible_beta * np.maximum(np.abs(vx), self.cfg.gate_speed)) & (
            np.abs(r) <= self.cfg.plausible_yaw_rate)
        if ok.all():
            return True
        if not ok.any():
            return False
        self.logw = normalize_log_weights(np.where(ok, self.logw, -np.inf))
        return None  # some left: the weights changed

    def _vx_from_wheels(self, uk) -> float:
        """`single_track.vx_from_wheels`: R_w omega of the undriven axle; NaN without that wheel speed."""
        return single_track.vx_from_wheels(uk, self._vp, self.rear_drive)

    def _draw_vx_from_wheels(self, uk) -> bool:
        """The particles' v^X drawn around `_vx_from_wheels(uk)` with std `x0_vx_wheel_std`;
        False (nothing drawn) without the wheel speed."""
        vx = self._vx_from_wheels(uk)
        if not math.isfinite(vx):
            return False
        self.x[:, 0] = vx + self.cfg.x0_vx_wheel_std * self.rng.standard_normal(len(self.x))
        return True

    def _gap(self, dt: float) -> bool:
        """A time step after which `_redraw_after_gap` draws v^X again (full model)."""
        return self.full and 0 < self.cfg.gap_after < dt

    def _redraw_after_gap(self, dt: float, u_now) -> bool:
        """After a gap in the data (a time step `dt` longer than `gap_after`), with the
        particles propagated across it: their v^X drawn again around the speed of the
        undriven wheels at the sample after the gap (derivations, "After a gap in the data"); `u_now` is that
        sample's inputs as measured (no held value: without the wheel speed nothing is drawn). Over the gap the
        filter held its last inputs, so its v^X misses the acceleration it did not see, and
        through the driven axle's wheel slip that error becomes a longitudinal force error
        that the weights and the learning take for a wrong state or stiffness. Full model
        only; True when drawn (counted in `gap_redraws`)."""
        if not self._gap(dt):
            return False
        if not self._draw_vx_from_wheels(u_now):
            return False
        self.gap_redraws += 1
        return True

    def _restart(self, t, uk, y) -> Estimate:
        """Every particle has left the plausible region (the state diverged, typically after
        learning an unstable stiffness from a wrong start): draw the particles from the prior
        again, around the current speed and the measured yaw rate, and go on from there."""
        if self.full:
            vx = self._vx_from_wheels(uk)
            vx = vx if math.isfinite(vx) else float(np.median(self.x[:, 0]))
        r0 = y.yaw_rate if math.isfinite(y.yaw_rate) else 0.0
        self._draw_prior((vx, 0.0, r0) if self.full else (0.0, r0))
        if self.cfg.informed_start:
            yk = np.array([y.ax, y.ay, y.yaw_rate], float)[list(self.channels)]
            self.logw = normalize_log_weights(self._informed_start(uk, yk))
        self.restarts += 1
        self._reset_cx_excitation()  # the prior again: nothing of Cx learned
        if self._calib is not None:
            self._calib.reset()
        self.t_start, self.t_prev, self.u_prev, self.active = t, t, uk, False
        self._contradiction_since = self._bound_since = None
        self.learned_time, self._t_gate = 0.0, None  # a new start: the inflation disarmed (`inflation_after`)
        self.ay_pred = math.nan  # (the old cloud's prediction)
        self._at_x = self._model(self.x, uk)
        self.w_prev = self.stats.mu.copy()  # the next propagation uses the prior means
        return self._estimate(float(self.cfg.particles))

    def _bias_update(self, yk, h, D, a):
        """Per-particle Kalman update of the bias, eq. (30):
        S = P + R + d Sigma_hat d^T, K = P S^-1, b += K (y - h - d mu - b), P -= K S K^T
        (= P - P_{:,a} K^T)."""
        Da = D[:, a]
        S = self.P[:, a][:, :, a] + self.R[np.ix_(a, a)] + Da @ self.stats.mean_sigma() @ np.swapaxes(Da, 1, 2)
        Pa = self.P[:, a, :]  # (N, |a|, m)
        Kt = chol_solve(chol(S), Pa)  # K^T = S^-1 P_{a,:}
        innov = yk[a] - h[:, a] - np.einsum("nij,nj->ni", Da, self.stats.mu) - self.b[:, a]
        self.b = self.b + np.einsum("nki,nk->ni", Kt, innov)
        P = self.P - np.swapaxes(Pa, 1, 2) @ Kt
        self.P = 0.5 * (P + np.swapaxes(P, 1, 2))

    def _estimate(self, ess: float) -> Estimate:
        q = np.exp(self.logw)
        x_mean = q @ self.x
        x_std = np.sqrt(np.maximum(q @ (self.x - x_mean) ** 2, 0.0))
        mu = self.stats.mu
        mbar = q @ mu
        spread = q @ (mu - mbar) ** 2
        Esig = np.diagonal(self.stats.Lam, axis1=1, axis2=2) / (self.stats.nu - self.n_w - 1.0)[:, None]  # E[Sigma]
        var_mean = q @ (self.stats.gamma[:, None] * Esig) + spread  # posterior variance of the mean
        sigma2 = q @ Esig + spread  # eq. (27b), diagonal, with nu - n_w - 1
        if self.cfg.inflation_prior_bound:  # (`_draw_inflation`'s bound)
            self._sigma2_rel = float(np.max(sigma2 / self.C_ref**2))
        return self._estimate_from(ess, x_mean, x_std, mbar, var_mean, sigma2, q @ self.b)

    def _estimate_from(self, ess, x_mean, x_std, mbar, var_mean, sigma2, b_mean) -> Estimate:
        """The Estimate from the moments (sequences of floats: n_w for mbar, var_mean and
        sigma2): the stiffness C_nom + mbar, the std of its mean and the deviation spread."""
        root = _sqrt_or_nan
        vals = {p: (c + mb, root(vm), root(s2)) for p, c, mb, vm, s2 in zip(self.params, self.C_nom.tolist(), mbar,
                                                                             var_mean, sigma2)}
        bias = dict(zip(("ax", "ay", "yaw_rate") if self.full else ("ay", "yaw_rate"), b_mean))
        return particle_estimate(active=self.active, ess=ess, x_mean=x_mean, x_std=x_std, stiffness=vals, bias=bias,
                                 vx_input=NAN if self.u_prev is None else self.u_prev[3])

    # ---- carrying the learned stiffness from one drive to the next ----------------------
    def learned_state(self) -> dict:
        """The learned stiffness posterior (per-particle NiW statistics and weights, not the
        vehicle state), as plain lists: what a car keeps between drives."""
        if not hasattr(self, "stats"):
            raise ConfigError("--save-state", "", "the filter has not been reset or run: nothing learned to save")
        st = self.stats
        return {"model": self.cfg.model, "params": list(self.params), "C_nominal": self.C_nom.tolist(),
                "log_weights": self.logw.tolist(), "gamma": st.gamma.tolist(), "mu": st.mu.tolist(),
                "Lam": st.Lam.tolist(), "nu": st.nu.tolist()}

    def carry_over(self, state: dict, source: str = "state") -> None:
        """Start the next `reset` from a `learned_state()` instead of the configured prior.

        N may differ (the saved particles are resampled by weight). A full-model state
        initialises a lateral-model filter by marginalising out dC_x: mu and gamma of the
        lateral block are kept, Lambda's block is taken and nu drops by one (the
        inverse-Wishart marginal of a sub-block). Nominal stiffness must be the same."""
        def bad(key, problem):
            raise ConfigError(source, key, problem)

        try:
            params = tuple(state["params"])
            logw = np.asarray(state["log_weights"], float)
            stats = NiW(np.asarray(state["gamma"], float), np.asarray(state["mu"], float),
                        np.asarray(state["Lam"], float), np.asarray(state["nu"], float))
            C_nom = np.asarray(state["C_nominal"], float)
        except (KeyError, TypeError, ValueError) as exc:
            bad("", f"not a stiffness state ({exc})")
        n, N = len(params), len(logw)
        if (stats.mu.shape != (N, n) or stats.Lam.shape != (N, n, n) or stats.gamma.shape != (N,)
                or stats.nu.shape != (N,) or C_nom.shape != (n,)):
            bad("", "array shapes do not match the parameter list and the number of particles")
        if not all(np.all(np.isfinite(a)) for a in (stats.gamma, stats.mu, stats.Lam, stats.nu)):
            bad("", "statistics contain non-finite values")
        keep = [params.index(p) for p in self.params if p in params]
        if len(keep) != self.n_w:
            bad("params", f"saved for {', '.join(params)}; this filter estimates {', '.join(self.params)}")
        if not np.allclose(C_nom[keep], self.C_nom, rtol=1e-12):
            bad("C_nominal", f"saved nominal stiffness {C_nom[keep].tolist()} differs from the vehicle's "
                f"{self.C_nom.tolist()}")
        if len(keep) < n:
            ix = np.array(keep)
            stats = NiW(stats.gamma, stats.mu[:, ix], stats.Lam[:, ix][:, :, ix], stats.nu - (n - len(keep)))
        if np.any(stats.nu <= self.n_w + 1):
            bad("nu", f"degrees of freedom must exceed {self.n_w + 1}")
        self._carried = (normalize_log_weights(logw), stats)

    def posterior(self) -> Posterior:
        stats = {"gamma": self.stats.gamma.copy(), "mu": self.stats.mu.copy(), "Lam": self.stats.Lam.copy(),
                 "nu": self.stats.nu.copy(), "bias": self.b.copy(), "bias_cov": self.P.copy(),
                 "C_nominal": self.C_nom.copy(), "params": self.params}
        if self._calib is not None:  # the factor of the calibrated lateral *_std ("Batch-means sandwich"), 1 for Cx
            stats["std_factor"] = np.concatenate([np.ones(len(self.params) - 2), self._calib.factor])
        return Posterior(self.x.copy(), self.logw.copy(), stats)


class _MPFWork:
    """The arrays of `StiffnessMPF._step_compiled`, allocated once per filter: the
    particles' own arrays (x, b, P, the NiW statistics, the model's first stage a, B, slip)
    with a spare of each for resampling, and the weighting's per-particle arrays for all m
    channels (the first na columns are used when samples are missing)."""

    OWN = ("x", "b", "P", "gamma", "mu", "Lam", "nu", "a", "B", "slip")
    OWN2 = tuple(name + "2" for name in OWN)

    def __init__(self, mpf: "StiffnessMPF", N: int, nx: int, n_w: int, m: int):
        shapes = dict(x=(N, nx), b=(N, m), P=(N, m, m), gamma=(N,), mu=(N, n_w), Lam=(N, n_w, n_w), nu=(N,),
                      a=(N, 3), B=(N, 3, n_w), slip=(2, N))
        for name, shape in shapes.items():
            setattr(self, name, np.zeros(shape))
            setattr(self, name + "2", np.zeros(shape))
        self.af, self.ar, self.nu_w, self.ll, self.nu_draw, self.q = (np.zeros(N) for _ in range(6))
        self.h, self.e, self.v = np.zeros((N, m)), np.zeros((N, m)), np.zeros((N, m))
        self.D, self.L11 = np.zeros((N, m, n_w)), np.zeros((N, n_w, n_w))
        self.L12, self.Lc = np.zeros((N, n_w, m)), np.zeros((N, m, m))
        self.w = np.zeros((N, n_w))
        self.ok = np.zeros(N, bool)
        self.idx = np.arange(N)
        self.mom = np.zeros((6, max(nx, n_w, m)))
        self.pin_lo, self.pin_hi = mpf._pin_bounds()
        self.no_noise, self.no_scale = np.zeros((0, nx)), np.zeros(nx)
        self.avail_all = np.arange(m)
        self.nc_all = sum(c in (0, 1) for c in mpf.channels)
        self.heun = mpf.cfg.integrator == "heun"
        self.interval = mpf.full and mpf.cfg.slip_hold == "interval"
        cfg = mpf.cfg
        # the kernels' sizes when every channel is there, as constants (`mpf_numba.predict_weigh`'s `sizes`), and
        # otherwise from the arrays
        self.sizes_all = np.empty((0, 0, 0)) if mpf.full else np.empty((0, 0))
        self.sizes_any = np.empty(0)
        # the predictive weights kept for `_predict_ay` and `_match_state_noise` (the calibration's residual,
        # `_ay_residual`, "Batch-means sandwich"; the gate's a^Y prediction, "Linear-region test"; the state noise from the data, "State noise from the data")
        self.predicted_ay = cfg.gate_ay == "predicted"
        self.keep_pred = self.predicted_ay or cfg.state_noise_from_data or mpf._calib is not None
        self.logw_pred, self.q_pred = np.zeros(N), np.zeros(N)
        self.ay_col = mpf.channels.index(1)  # the a^Y column of e when every channel is there
        self.ones2 = np.ones(2)  # `_draw_factors` without the surprise inflation
        self.drift_checked = None  # the drift statistic's array once checked C-contiguous float64
        self.lo = cfg.bound_low * mpf.C_ref - mpf.C_nom
        self.hi = cfg.bound_high * mpf.C_ref - mpf.C_nom

        self.spares = tuple(getattr(self, name + "2") for name in self.OWN)

    def swap(self) -> None:
        """The spares become the particles' arrays and the other way round (`spares` is always
        the tuple of the arrays named OWN2)."""
        d = self.__dict__
        own, self.spares = self.spares, tuple(map(d.__getitem__, self.OWN))
        d.update(zip(self.OWN, own))
        d.update(zip(self.OWN2, self.spares))


def cx_excitation_weight(info: float, prior_var: float) -> float:
    """rho = 1 - P / P_0 for the posterior variance P = 1 / (1 / P_0 + info) of a scalar
    linear-Gaussian parameter with prior variance P_0 and data information `info` (derivations
    "The undriven axle"), written I P_0 / (1 + I P_0): 0 without information or with a certain prior."""
    if not (info >= 0 and prior_var >= 0):
        raise ValueError(f"information and prior variance must be >= 0, got {info!r}, {prior_var!r}")
    ip = info * prior_var
    return ip / (1.0 + ip) if math.isfinite(ip) else 1.0


def _sqrt_or_nan(v: float) -> float:
    """np.sqrt on a float: NaN below zero."""
    return math.sqrt(v) if v >= 0 else NAN
