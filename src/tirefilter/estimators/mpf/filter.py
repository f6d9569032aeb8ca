"""StiffnessMPF, the noise-adaptive marginalized particle filter of the stiffness paper
(the package docstring gives the algorithm): the particles and their initialisation, the
vehicle model's calls (`vehicle.single_track`, or its compiled twin with the numba backend),
the numpy reference step (steps 1-5), the estimate, and the learned stiffness carried from one
drive to the next. The learning gate, plausibility and restarts are in `supervision`, the
adaptive parts in `adaptation`, the compiled step in `compiled`."""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate, Inputs, Measurement, Posterior, particle_estimate
from tirefilter.estimators.mpf.adaptation import LOAD_GAIN_MIN, Adaptation
from tirefilter.estimators.mpf.compiled import NAN, CompiledStep, _sqrt_or_nan
from tirefilter.estimators.mpf import predictive
from tirefilter.estimators.mpf.config import MPFConfig
from tirefilter.estimators.mpf.supervision import Supervision
from tirefilter.estimators.wheel_filter import WheelSpeedFilter
from tirefilter.stats import NiW, effective_sample_size, normalize_log_weights, systematic_resample
from tirefilter.stats.linalg import chol, chol_solve, logdet_chol, solve_lower
from tirefilter.stats.sandwich import BatchMeansSandwichPair
from tirefilter.stats.student_t import t_conditional, t_logpdf_whitened, t_sample
from tirefilter.vehicle import single_track
from tirefilter.vehicle.params import VehicleParams
from tirefilter.vehicle.single_track import GRAVITY


_NO_RELAX = np.zeros((2, 0))  # the compiled twin's "no relaxed slip angles"
# the prior of the stiffness statistics (derivations, "Initialisation"):
INIT_SIGMA = 0.1  # relative prior guess of the deviation spread (Lambda_0): twice paper-sim's true 5%
WITHIN_SHARE = 0.25  # share of the prior variance of the mean inside each particle's NiW (the means carry the rest)
NU0_MARGIN = 4.0  # nu_0 = n_w + 1 + this: > 0 for a finite inverse-Wishart mean, small: the prior weighs a few samples


def _reflected_walk(k: np.ndarray, bounds, rw: float, dt: float, rng: np.random.Generator) -> np.ndarray:
    """k plus a normal step of std rw sqrt(dt), reflected at the bounds (low, high) (which keeps a
    uniform prior over them invariant) and clipped into them."""
    lo, hi = bounds
    k = k + (rw * math.sqrt(dt)) * rng.standard_normal(len(k))
    k = np.where(k < lo, 2.0 * lo - k, k)
    return np.clip(np.where(k > hi, 2.0 * hi - k, k), lo, hi)


class StiffnessMPF(CompiledStep, Adaptation, Supervision):
    """Algorithm 1 of the stiffness paper, vectorised over particles."""

    name = "mpf"
    # the one-step predictive of a^Y and the yaw rate kept at every step for the model check
    # (`one_step_predictive`; set by `model_check.ModelCheck`)
    predictive_wanted = False

    def __init__(self, vehicle: VehicleParams, config: MPFConfig = MPFConfig()):
        self.vehicle = vehicle
        self.cfg = config.validated()
        v = vehicle
        self.rear_drive = v.drive == "rear"
        # nominal axle stiffness: driven axle's Cx is estimated, the other axle's is nominal
        self.C_nom_fx, self.C_nom_rx = single_track.longitudinal_stiffness(v)
        other = self.C_nom_fx if self.rear_drive else self.C_nom_rx
        # "learned": the undriven axle's longitudinal stiffness C_u = C_u,nom (1 + rho w_x / C_x,nom): its force
        # adds share * slip_u * w_x to B's first column, share = rho * C_u,nom / C_x,nom with rho the excitation
        # weight of Cx (`_excite_cx`, derivations, "The undriven axle"), 0 until the wheel slip has taught Cx
        self.full_share = other / v.Cx if self.cfg.undriven_stiffness == "learned" else 0.0
        self.undriven_share = 0.0
        self.full = self.cfg.model == "full"
        self.params = ("Cx", "Cf_y", "Cr_y") if self.full else ("Cf_y", "Cr_y")
        self.C_nom = np.array([v.Cx, v.Cf_y, v.Cr_y] if self.full else [v.Cf_y, v.Cr_y])
        self.n_w = len(self.params)
        self.channels = (0, 1, 2) if self.full else (1, 2)  # ax, ay, yaw rate
        self.roll_gain = v.imu_roll_gain(GRAVITY)  # measured a^Y ~ (1 + k g) a^Y
        # no roll_gradient in the vehicle file: k a parameter of each particle (`k_roll`, derivations, "The roll gain
        # from the data"), the roll gain 1 + k g per particle
        self.roll_estimated = v.roll_gradient is None and self.cfg.roll_estimate
        # the load transfer's gain 1 - kappa a^Y^2 on the lateral axle forces, kappa per particle (`k_load`,
        # derivations, "Load transfer"): estimated where the vehicle file does not state it, the file's value
        # (the same for every particle, no walk) where it does; neither with the switch off or a stated 0
        self.load_estimated = self.cfg.load_sensitivity_estimate and v.load_sensitivity is None
        self.load_given = (float(v.load_sensitivity) if self.cfg.load_sensitivity_estimate and v.load_sensitivity
                           else None)
        self.k_load, self._ay_step = None, 0.0  # (drawn by `reset`)
        # the tyres' relaxation (derivations, "Tyre relaxation"): the relaxed slip angles (2, N) at the last sample
        self.relaxing = v.relaxation_length > 0
        self.relaxed = None
        sig = np.asarray(self.cfg.sigma)[list(self.channels)]
        self.R = np.diag(sig**2)
        ch = list(self.channels)
        q_sensor, q_road = np.square(self.cfg.bias_rw)[ch], np.square(self.cfg.disturbance_rw)[ch]  # per s
        self.bias_on = bool(np.any(q_sensor + q_road > 0) or np.any(np.asarray(self.cfg.bias0_std) > 0))
        # the road offsets wander only where the linear tire model holds: beyond it the
        # residual is the model's error, not the road's (derivations, "Bias defaults and wandering offsets")
        self.q_bias, self.q_bias_nonlinear = q_sensor + q_road, q_sensor
        q = np.asarray(self.cfg.state_noise, float)[-(3 if self.full else 2):]
        self.state_noise = q if np.any(q > 0) or self.cfg.state_noise_from_data else None
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
        if self.cfg.backend != "numpy":  # the compiled stages; the numpy methods stay the reference
            self._load_kernels()

    def _load_kernels(self) -> None:
        """The compiled stages: the numba kernels, or their C twin (`native`, which does not import numba)."""
        if self.cfg.backend == "c":
            from tirefilter.estimators.mpf import native

            native.library()  # (built on first use: a missing compiler is reported here, at construction)
            self._nb = self._st = native
            return
        from tirefilter.estimators.mpf import kernels
        from tirefilter.vehicle import single_track_numba

        self._nb, self._st = kernels, single_track_numba

    def __getstate__(self):  # (copies and FMU states: the kernel modules are not state)
        return {**self.__dict__, "_nb": None, "_st": None}

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self.cfg.backend != "numpy":
            self._load_kernels()

    def config_dict(self) -> dict:
        d = asdict(self.cfg)
        d.update(params=list(self.params), C_nominal=self.C_nom.tolist())
        q = self.state_noise_estimated()
        if q is not None:
            d["state_noise_estimated"] = q
        return d

    # ---- initialisation --------------------------------------------------------------------
    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self._draw_prior(x0_mean=None)
        self.w_prev = None
        self.u_prev = None
        self.t_prev = None
        self.active = False
        self.resamples = 0
        self.restarts = 0
        self._redrawn = False  # the redraw of `x0_given = False` done
        self.q_state = np.zeros(3 if self.full else 2)  # the state noise intensity from the data, per s
        self.gap_redraws = 0  # gaps after which v^X was drawn again from the wheel speeds
        self._contradiction_since = None
        self._bound_since = None  # time since which a stiffness mean sits at a projection bound
        self.surprise = 1.0  # z_k of the adaptive forgetting: 1 while the data fit the predictive
        self.linear_region = True  # |a^Y| below the gate's linear-region bound at the last sample
        self.ay_last = math.nan  # the last finite a^Y of the linear-region test (`held_ay`)
        self.ay_load = self._ay_step = 0.0  # the measured a^Y of the load transfer (`_next_ay_load`)
        self.lam = self.cfg.forgetting  # the forgetting factor applied at the next propagation
        self.drift = np.zeros(self.n_w)  # smoothed whitened w_k - mu_{k|k-1} (adaptive forgetting)
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
        self._pred = None  # this step's one-step predictive (`one_step_predictive`)
        self._load_level = np.zeros(4)  # (`_track_load_level`)

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
        share = WITHIN_SHARE if s > 0 else 0.0
        means = self.C_center + np.sqrt(1.0 - share) * u * self.C_ref
        sigma0 = INIT_SIGMA * self.C_ref  # prior guess of the deviation std
        nu0 = n + 1.0 + NU0_MARGIN
        self.nu0 = nu0
        Lam0 = np.diag(sigma0**2) * (nu0 - n - 1.0)  # so that E[Sigma] = diag(sigma0^2)
        gamma0 = max(share * s * s / INIT_SIGMA**2, 1e-6)  # gamma E[Sigma] = share s^2 C_ref^2
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
        # the roll gradient of each particle, uniform over the prior (None: the vehicle file's, `roll_gain`)
        self.k_roll = rng.uniform(*cfg.roll_gradient_prior, N) if self.roll_estimated else None
        # the load sensitivity of each particle, uniform over the prior, or the vehicle file's (None: the paper's
        # linear axle)
        self.k_load = (rng.uniform(*cfg.load_sensitivity_prior, N) if self.load_estimated else
                       None if self.load_given is None else np.full(N, self.load_given))
        self.relaxed = None  # (the first model evaluation's kinematic slip angles, `_keep_relaxed`)

    # ---- the roll gain (derivations, "The roll gain from the data") --------------------------
    def _roll_gains(self):
        """The IMU's a^Y gain 1 + k g: (N,) per particle where k is estimated, else the float."""
        return self.roll_gain if self.k_roll is None else 1.0 + self.k_roll * GRAVITY

    def _walk_roll(self, dt: float) -> None:
        """The random walk of k over dt (`roll_gradient_rw` per sqrt(s)), reflected at the prior's bounds:
        without it, resampling would leave every particle with the k of a few ancestors."""
        self.k_roll = _reflected_walk(self.k_roll, self.cfg.roll_gradient_prior, self.cfg.roll_gradient_rw, dt,
                                      self.rng)

    # ---- the load transfer (derivations, "Load transfer") ----------------------------------
    def _next_ay_load(self, y_ay: float) -> None:
        """This step's a^Y of the load transfer (`_ay_step`): the last finite measured one before this
        sample; `ay_load` then takes this sample's (when finite)."""
        self._ay_step = self.ay_load
        if math.isfinite(y_ay):
            self.ay_load = y_ay

    def _load_gains(self):
        """The gain 1 - kappa (a^Y / (1 + k g))^2 of each particle's lateral axle forces in this step (a^Y
        the step's `_ay_step`, over the particle's roll gain), floored at `LOAD_GAIN_MIN`; None without
        the load sensitivity."""
        if self.k_load is None:
            return None
        a2 = (self._ay_step / self._roll_gains()) ** 2
        return np.maximum(1.0 - self.k_load * a2, LOAD_GAIN_MIN)

    def _keep_relaxed(self, model_k) -> None:
        """With the tyres' relaxation: the slip angles of the model at this sample (`af`, `ar` of
        `accelerations`, relaxed), which the next propagation relaxes from."""
        if self.relaxing:
            self.relaxed = np.array([model_k[2], model_k[3]])

    def _particle_args(self, n: int):
        """The compiled twin's per-particle arguments for n particles: (load-transfer gains, relaxed slip angles)."""
        return self._load_gains_or_ones(n), _NO_RELAX if self.relaxed is None else self.relaxed

    def _load_gains_or_ones(self, n: int):
        """`_load_gains`, n ones without the load sensitivity (the compiled twin's argument)."""
        g = self._load_gains()
        return np.ones(n) if g is None else g

    def _walk_load(self, dt: float) -> None:
        """The random walk of kappa over dt (`load_sensitivity_rw` per sqrt(s)), reflected at the prior's bounds."""
        self.k_load = _reflected_walk(self.k_load, self.cfg.load_sensitivity_prior, self.cfg.load_sensitivity_rw, dt,
                                      self.rng)

    def _load_moments(self) -> tuple[float, float]:
        """The posterior mean and std of kappa (NaN, NaN where it is not estimated)."""
        return self._weighted_moments(self.k_load)

    def _roll_moments(self) -> tuple[float, float]:
        """The posterior mean and std of k (NaN, NaN where it is not estimated; the compiled step has
        them from `sample_update`)."""
        return self._weighted_moments(self.k_roll)

    def _weighted_moments(self, k) -> tuple[float, float]:
        """The mean and std of a per-particle parameter k (N,) under the weights (NaN, NaN for None)."""
        if k is None:
            return NAN, NAN
        q = np.exp(self.logw)
        mean = float(q @ k)
        return mean, math.sqrt(max(float(q @ (k - mean) ** 2), 0.0))

    # ---- model: `vehicle.single_track` (numpy) or its compiled twin ------------------------
    def _model(self, x, u, slip=None, relax=None):
        """`single_track.accelerations`: a (N, 3), B (N, 3, n_w), af, ar, the wheel slip (2, N)
        (None in the lateral model; `slip` given: held from an earlier evaluation; `relax` = (relaxed slip
        angles, h) with the tyres' relaxation, None: the kinematic slip angles)."""
        if self._nb is not None and slip is None:
            rel, h = (_NO_RELAX, -1.0) if relax is None else relax
            a, B, af, ar, slip = self._st.accelerations(x, u, self._vp, self.full, self.rear_drive, self.n_w,
                                                        self._load_gains_or_ones(len(x)), rel, h)
            return a, B, af, ar, slip if self.full else None
        return single_track.accelerations(x, u, self._vp, self.full, self.rear_drive, slip, self._load_gains(), relax)

    def _propagate(self, x, u, w, dt, first):
        """`single_track.propagate` (eq. (9)) with `first` = (a, B, af, ar, slip) at x_k."""
        heun = self.cfg.integrator == "heun"
        if self._nb is not None:
            a, B, _, _, slip = first
            return self._st.propagate(x, u, w, (a, B, np.zeros((2, len(x))) if slip is None else slip), dt,
                                      self.cfg.max_step, heun, self._vp, self.full, self.rear_drive, self.n_w,
                                      self._particle_args(len(x)))
        return single_track.propagate(x, u, w, dt, first, self._vp, self.full, self.rear_drive, self.cfg.max_step,
                                      heun, self._load_gains(), self.relaxed)

    def _slip_over_step(self, x, u0, u1, w, first, dt):
        """`single_track.slip_over_step`: the first stage of the propagation from t_k to t_k + dt
        with the wheel slip averaged over the interval (slip_hold = "interval")."""
        if self._nb is not None:
            a, B, _, _, slip0 = first
            return self._st.slip_over_step(x, u0, u1, w, (a, B, slip0), dt, self._vp, self._jw, self._c_floor,
                                           self.rear_drive, self.n_w, self._particle_args(len(x)))
        return single_track.slip_over_step(x, u0, u1, w, first, dt, self._vp, self._jw, self._c_floor,
                                           self.rear_drive, self._load_gains(), self.relaxed)

    def _measurement(self, a, B, x):
        """`single_track.measurement`: h (N, m) and d (N, m, n_w) of eq. (12), the IMU's lever arm and roll
        gain (per particle where it is estimated) included."""
        return single_track.measurement(a, B, x, self._roll_gains(), self.full, self._vp)

    # ---- the filter: the numpy reference step ----------------------------------------------
    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        dt = t - self.t_prev if self.t_prev is not None else self.cfg.sample_period
        self._e_ay = NAN
        self._calib_in_step = False
        self._pred = None
        est = self._step(t, u, y)
        return est if self._calib is None or self._calib_in_step else self._calibrate(est, dt)

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
        if self.u_prev is None and self.full:  # v^X centred on R_w omega of the undriven axle
            self._draw_vx_from_wheels(uk)
        if not math.isfinite(uk[0]):
            uk = uk.copy() if uk is u_now else uk
            uk[0] = 0.0

        # without a given initial state, the stiffness statistics drawn again from the prior once the gate has
        # first opened (`x0_given`)
        if not cfg.x0_given and not self._redrawn and self.t_prev is not None and self.active:
            self._redrawn = True
            self._draw_prior_stats()
        # 1. propagate from the previous sample
        dt = t - self.t_prev if self.t_prev is not None else cfg.sample_period
        if self.t_prev is not None and dt <= 0:
            raise ConfigError("inputs", "t", f"time must increase: {t} after {self.t_prev}")
        if self.load_estimated and self.t_prev is not None:  # kappa's walk, the step's first draw on both paths
            self._walk_load(dt)
        self._next_ay_load(y.ay)
        if self._nb is not None:  # every sample by three compiled passes; the numpy code below is the reference
            return self._step_compiled(t, uk, y, dt, u_now)
        if self.t_prev is not None:
            first = self._at_x
            if self.full and cfg.slip_hold == "interval":
                first = self._slip_over_step(self.x, self.u_prev, uk, self.w_prev, first, dt)
            self.x = self._propagate(self.x, self.u_prev, self.w_prev, dt, first)
            self._redraw_after_gap(dt, u_now)
            if self.state_noise is not None:  # optional regularisation against sample impoverishment
                self.x = self.x + self._state_noise_scale(dt) * self.rng.standard_normal(self.x.shape)
            if self.k_roll is not None:
                self._walk_roll(dt)
            if self.bias_on:
                q = self.q_bias if self.linear_region else self.q_bias_nonlinear
                self.P = self.P + np.diag(q * dt)
            if self.active:
                self.stats.forget(self.lam, nu_min=self.nu0)
        yk = np.array([y.ax, y.ay, y.yaw_rate], float)[list(self.channels)]
        start_logw = None
        first = self.t_prev is None
        if first:
            self.t_start = t
            if cfg.informed_start:
                start_logw = self._informed_start(uk, yk)
        self.t_prev, self.u_prev = t, uk

        a = np.flatnonzero(np.isfinite(yk))  # available channels, in the order ax, ay, yaw rate
        nc = int(sum(self.channels[j] in (0, 1) for j in a))  # accelerometer channels lead
        # the model at x_k (with the tyres' relaxation: the slip angles relaxed over dt from the last sample's)
        model_k = self._model(self.x, uk, relax=None if self.relaxed is None else (self.relaxed, dt))
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
            if self.predictive_wanted and not first:  # (the model check)
                predictive.keep(self, t, yk, a, e, S, nu_w, logw_pred)
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
            if self.k_roll is not None:
                self.k_roll = self.k_roll[idx]
            if self.k_load is not None:
                self.k_load = self.k_load[idx]
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
        w = t_sample(mu_c, Lam_c, nu_c, self.rng)

        # 4. bias, eq. (30), with the predicted statistics (docs/derivations.md, "Order of Algorithm 1")
        if a.size and self.bias_on:
            self._bias_update(yk, h, D, a)
        if self.active:
            if nc:
                self._track_drift(w - mu_w, L11, dt)  # before the update: mu_w may be the statistics' own array
            lo = cfg.bound_low * self.C_ref - self.C_nom
            hi = cfg.bound_high * self.C_ref - self.C_nom
            self.stats.update(w)  # eq. (19) with the w_k that drives the state
            self.stats.mu = np.clip(self.stats.mu, lo, hi)  # parameter projection (Sec. V)
        self.w_prev = w
        self._at_x = model_k  # the first stage of the next propagation, at this x and u
        self._keep_relaxed(model_k)
        if self.full:
            self._excite_cx(float(np.exp(self.logw) @ self.x[:, 0]), uk, dt)
        return self._estimate(ess)

    def one_step_predictive(self):
        """This step's one-step predictive of the measurements, before they were weighed (with
        `predictive_wanted`; `estimators.mpf.predictive`): (t, mean (2,), variance (2,), measured
        (2,)) of a^Y and the yaw rate, NaN for a missing one; None at the first sample, without an
        a^Y sample or when not wanted."""
        return self._pred

    def _filter_wheels(self, t: float, u_now: np.ndarray, y: Measurement) -> None:
        """The measured wheel speeds u_now[1:3] replaced in place by the pre-filter's estimates
        (`wheel_filter.WheelSpeedFilter`, derivations, "Wheel-speed pre-filter"; a missing one stays missing). Its
        drive over the step from the last sample: that sample's measured a^X minus the posterior
        mean of its bias, plus the posterior mean of v^Y r (the particles as they stand, before
        this sample's propagation; the compiled step leaves these two means in `_drive_moments`).
        The first sample and the sample after a gap (`_gap`) start the filter again at the measurements."""
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
        moments, self._drive_moments = self.__dict__.get("_drive_moments"), None
        if self.t_prev is not None and math.isfinite(self._ax_prev):
            if moments is not None:  # (the last compiled step's sums, `kernels.sample_update`)
                b, vyr = moments
                drive = self._ax_prev - (b if self.bias_on else 0.0) + vyr
            else:
                q = np.exp(self.logw)
                b = float(q @ self.b[:, 0]) if self.bias_on else 0.0
                drive = self._ax_prev - b + float(q @ (self.x[:, 1] * self.x[:, 2]))
        self._ax_prev = y.ax
        u_now[1:3] = f.step(dt, u_now[1:3], drive)

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
        return self._estimate_from(ess, x_mean, x_std, mbar, var_mean, sigma2, q @ self.b)

    def _estimate_from(self, ess, x_mean, x_std, mbar, var_mean, sigma2, b_mean) -> Estimate:
        """The Estimate from the moments (sequences of floats: n_w for mbar, var_mean and
        sigma2): the stiffness C_nom + mbar, the std of its mean and the deviation spread."""
        root = _sqrt_or_nan
        vals = {p: (c + mb, root(vm), root(s2)) for p, c, mb, vm, s2 in zip(self.params, self.C_nom.tolist(), mbar,
                                                                             var_mean, sigma2)}
        bias = dict(zip(("ax", "ay", "yaw_rate") if self.full else ("ay", "yaw_rate"), b_mean))
        return particle_estimate(active=self.active, ess=ess, x_mean=x_mean, x_std=x_std, stiffness=vals, bias=bias,
                                 vx_input=NAN if self.u_prev is None else self.u_prev[3], roll=self._roll_moments())

    # ---- carrying the learned stiffness from one drive to the next -------------------------
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
        n, N = len(params), (len(logw) if logw.ndim == 1 else -1)
        if (stats.mu.shape != (N, n) or stats.Lam.shape != (N, n, n) or stats.gamma.shape != (N,)
                or stats.nu.shape != (N,) or C_nom.shape != (n,)):
            bad("", "array shapes do not match the parameter list and the number of particles")
        if not all(np.all(np.isfinite(a)) for a in (stats.gamma, stats.mu, stats.Lam, stats.nu)):
            bad("", "statistics contain non-finite values")
        if np.any(np.isnan(logw) | (logw == np.inf)):
            bad("log_weights", "expected finite log-weights (or -inf for a particle of weight zero)")
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
        if self.k_roll is not None:
            stats["roll_gradient"] = self.k_roll.copy()
        if self.k_load is not None:
            stats["load_sensitivity"] = self.k_load.copy()
        if self._calib is not None:  # the factor of the calibrated lateral *_std ("Batch-means sandwich"), 1 for Cx
            stats["std_factor"] = np.concatenate([np.ones(len(self.params) - 2), self._calib.factor])
        return Posterior(self.x.copy(), self.logw.copy(), stats)
