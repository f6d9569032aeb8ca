"""State-augmented particle filter (AUGPF): the baseline of the stiffness paper (Berntorp & Di Cairano, IEEE TCST 2018),
Sec. VI-A, that models the stiffness deviations' mean and variance as extra states.

Per particle i the state is the vehicle state x (full model [vx, vy, r], lateral [vy, r]),
the mean m of the stiffness deviations w (full [dC_x, dCf_y, dCr_y], lateral [dCf_y, dCr_y],
deviations from nominal) and their variances s2 (one per component, diagonal): 9 states for
the full model, 6 for the lateral one, as the paper's "x in R^9". A bootstrap filter
(proposal = the dynamics) with these artificial dynamics, while learning is on:

  m_k  = m_{k-1} + e_k,          e_k ~ N(0, diag((mean_rw C_ref)^2) dt / Ts)
  s2_k ~ iG(alpha, beta) per component, alpha = 2 + 1 / var_rel_std^2,
         beta = (alpha - 1) s2_{k-1}:  E[s2_k] = s2_{k-1}, std(s2_k) = var_rel_std s2_{k-1}

(the paper: random-walk std 2% of the true value, inverse-Wishart, 1-D = inverse-gamma,
"mean held constant, deviation 1% of the previous value"; C_ref is `init_reference`, the
true surface-1 stiffness in a scenario, nominal for a log). The per-step deviation is then
sampled as process noise, w_k ~ N(m_k, diag(s2_k)), and drives both the accelerations the
IMU measures at k (eq. (12) with d = d a / d w, no Ts: docs/derivations.md, "Model") and the state propagation
to k+1 (eq. (9), the MPF's Euler or Heun step). One step at sample k:

  1. propagate x with w_{k-1}; random walk of m and inverse-gamma draw of s2 (gate open);
     project m onto the stiffness bounds (Sec. V); predict the bias (eq. (29));
  2.-3. `proposal = "bootstrap"` (the textbook standard PF): sample w_k ~ N(m_k, s2_k) and
     weight with N(y_k; h(x_k) + D(x_k) w_k + b, R + P_b) (the bias marginalised per
     particle, as the MPF does). `proposal = "conditional"` (default): weight with w_k
     marginalised, N(y_k; h + D m_k + b, D diag(s2_k) D^T + R + P_b), and draw w_k from its
     Gaussian conditional given y_k (`conditional_deviation`: the optimal proposal for the
     process noise w_k; model and artificial dynamics unchanged). Normalise in log space,
     resample when ESS < threshold.
     Why the default is not the bootstrap: the measured accelerations pin w_k about ten
     times tighter than its prior spread (sigma_ay = 0.05 m/s^2 against ~0.1-0.2 m/s^2 of
     a^X or a^Y per 10% of stiffness), in three dimensions, so a blind draw leaves an ESS of
     about 1 at every step; the cloud then wanders along the (stiffness scale, vy offset)
     direction and diverges after paper-sim's surface change (docs/results.md, "Baselines on paper-sim"),
     unlike the paper's AUGPF (Fig. 4: tracking, with larger variability than the MPF);
  4. per-particle Kalman update of the bias given w_k (eq. (30) with Sigma = 0);
  5. report: stiffness = nominal + weighted mean of m, `*_std` the weighted std of the
     particle means, `*_sigma` the weighted mean of sqrt(s2).

While the MPF's learning gate is closed (`baseline_common.gate_open`) m and s2 are frozen
(no artificial dynamics); weighting and resampling go on. The vehicle model is the MPF's own
(`vehicle.single_track`: `accelerations`, `propagate` with the wheel slip of the step's start,
`measurement`), so the two filters differ in the inference only. Kept from the MPF (not in the paper): the plausibility check and restart.
Left out: the MPF's informed start. IMU bias: as in the MPF, a Gaussian per particle.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate, Inputs, Measurement, Posterior, particle_estimate
from tirefilter.estimators.baseline_common import GateOptions, check_common, gate_open, held_ay, stiffness_prior
from tirefilter.stats import effective_sample_size, normalize_log_weights, systematic_resample
from tirefilter.stats.linalg import chol, chol_solve, logdet_chol, solve_lower
from tirefilter.vehicle import single_track
from tirefilter.vehicle.params import VehicleParams
from tirefilter.vehicle.single_track import GRAVITY

NAN = math.nan
LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class AUGPFConfig(GateOptions):
    """Options of the AUGPF (the `[augpf]` table of --config). Fields named as in
    MPFConfig mean the same and are taken from the scenario or log the same way."""

    particles: int = 500
    model: str = "full"  # "full" (wheel speeds) | "lateral" (vx given)
    integrator: str = "heun"  # "euler" | "heun", the MPF's propagation
    resample_threshold: float = 0.5  # resample when ESS < threshold * N
    # "bootstrap": w_k ~ N(m_k, s2_k) blindly, weight N(y; h + D w_k + b, R + P_b) (the
    # paper's standard PF); "conditional": weight with w_k marginalised, N(y; h + D m + b,
    # D s2 D^T + R + P_b), then draw w_k from its Gaussian conditional given y_k (the
    # optimal proposal for w_k; same model and artificial dynamics)
    proposal: str = "conditional"
    mean_rw: float = 0.02  # random-walk std of each mean per sample period, relative to C_ref (paper: 2%)
    var_rel_std: float = 0.01  # std of the inverse-gamma variance step, relative to the variance (paper: 1%)
    init_center: tuple[float, ...] | None = None  # absolute, per parameter (default: the reference)
    init_distribution: str = "normal"  # "normal" (init_std) | "uniform" (init_half_width)
    init_std: float = 0.3  # relative to init_reference
    init_half_width: float = 0.1  # relative
    init_reference: tuple[float, ...] | None = None  # C_ref: stiffness the relative values refer to
    init_sigma: float = 0.1  # initial deviation std sqrt(s2_0), relative to C_ref
    init_sigma_spread: float = 0.5  # relative std of s2_0 across particles (inverse-gamma; 0: all equal)
    x0_mean: tuple[float, ...] | None = None  # full: vx, vy, r
    x0_std: tuple[float, ...] = (1.0, 0.5, 0.0175)
    state_noise: tuple[float, ...] = (0.0, 0.0, 0.0)  # additive process noise per sqrt(s), full: vx, vy, r
    x0_vx_from_wheels: bool = True  # full model: centre vx on R_w omega of the undriven axle
    x0_vx_wheel_std: float = 0.1  # m/s
    plausible_beta: float = 0.35  # rad: the MPF's plausibility region (sideslip, yaw rate); a particle
    plausible_yaw_rate: float = 2.0  # rad/s  outside it gets weight zero, all outside: restart
    sigma: tuple[float, float, float] = (0.05, 0.05, 0.0035)  # ax, ay, yaw-rate white noise
    bias_rw: tuple[float, float, float] = (0.0, 0.0, 0.0)  # per sqrt(s)
    bias0_std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sample_period: float = 0.01  # s: the period the random-walk std refers to
    max_step: float = 0.02  # s, longest propagation step (longer gaps are sub-stepped)
    # the model maths (`vehicle.single_track`): "numpy" (default: the per-particle work here is numpy anyway, and
    # importing numba and LLVM alone costs ~130 MB of resident memory) | "numba" (its compiled twin)
    backend: str = "numpy"

    def validated(self) -> "AUGPFConfig":
        def bad(key, problem):
            raise ConfigError("augpf configuration", key, problem)

        if int(self.particles) != self.particles or self.particles < 1:
            bad("particles", f"N must be an integer >= 1, got {self.particles!r}")
        if self.proposal not in ("bootstrap", "conditional"):
            bad("proposal", f"expected bootstrap or conditional, got {self.proposal!r}")
        if self.integrator not in ("euler", "heun"):
            bad("integrator", f"expected euler or heun, got {self.integrator!r}")
        if self.backend not in ("numba", "numpy"):
            bad("backend", f"expected numba or numpy, got {self.backend!r}")
        check_common(self, bad)
        for key in ("mean_rw", "var_rel_std", "init_sigma_spread"):
            if not (getattr(self, key) >= 0 and math.isfinite(getattr(self, key))):
                bad(key, f"must be finite and >= 0, got {getattr(self, key)!r}")
        if not self.init_sigma > 0:
            bad("init_sigma", f"must be > 0, got {self.init_sigma!r}")
        if any(not v >= 0 for v in self.state_noise):
            bad("state_noise", f"values must be >= 0, got {self.state_noise!r}")
        if not 0 <= self.resample_threshold <= 1:
            bad("resample_threshold", f"must be in [0, 1], got {self.resample_threshold!r}")
        return self


def inverse_gamma_step(s2: np.ndarray, rel_std: float, rng: np.random.Generator) -> np.ndarray:
    """Draw s2' ~ iG(alpha, beta) with E[s2'] = s2 and std(s2') = rel_std * s2 (elementwise):
    alpha = 2 + 1/rel_std^2, beta = (alpha - 1) s2, s2' = beta / Gamma(alpha, 1).
    (iG mean beta/(alpha-1), variance mean^2/(alpha-2).) rel_std = 0 returns s2."""
    if rel_std == 0:
        return s2
    alpha = 2.0 + 1.0 / (rel_std * rel_std)
    return (alpha - 1.0) * s2 / rng.gamma(alpha, size=s2.shape)


def conditional_deviation(mu, s2, D, noise, r):
    """The per-step deviation given the measurement, for y = D w + e' with w ~ N(mu,
    diag(s2)) and e' ~ N(0, noise) (the bias marginalised into `noise`), r = y - h - b:
    returns the log marginal likelihood log N(r; D mu, S), S = D diag(s2) D^T + noise, and
    the conditional mean mu + diag(s2) D^T S^-1 (r - D mu) and covariance
    diag(s2) - diag(s2) D^T S^-1 D diag(s2).

    mu, s2 (N, n); D (N, m, n); noise (m, m) or (N, m, m); r (N, m)."""
    DS = D * s2[:, None, :]  # D diag(s2)
    Lc = chol(DS @ np.swapaxes(D, 1, 2) + noise)
    e = r - np.einsum("nij,nj->ni", D, mu)
    v = solve_lower(Lc, e)
    loglik = -0.5 * np.sum(v * v, axis=1) - 0.5 * logdet_chol(Lc) - 0.5 * D.shape[1] * LOG_2PI
    Gt = chol_solve(Lc, DS)  # S^-1 D diag(s2): the gain, transposed
    mean = mu + np.einsum("nki,nk->ni", Gt, e)
    cov = s2[:, :, None] * np.eye(mu.shape[1]) - np.swapaxes(DS, 1, 2) @ Gt
    return loglik, mean, cov


class AugmentedPF:
    """The state-augmented bootstrap particle filter of Sec. VI-A, vectorised over particles."""

    name = "augpf"

    def __init__(self, vehicle: VehicleParams, config: AUGPFConfig = AUGPFConfig()):
        self.vehicle = v = vehicle
        self.cfg = cfg = config.validated()
        self.full = cfg.model == "full"
        self.rear_drive = v.drive == "rear"
        self.params = ("Cx", "Cf_y", "Cr_y") if self.full else ("Cf_y", "Cr_y")
        self.C_nom = np.array([v.Cx, v.Cf_y, v.Cr_y] if self.full else [v.Cf_y, v.Cr_y])
        self.n_w = len(self.params)
        self.channels = (0, 1, 2) if self.full else (1, 2)  # ax, ay, yaw rate
        self.roll_gain = v.imu_roll_gain(GRAVITY)  # measured a^Y ~ (1 + k g) a^Y
        # the model's parameters: the undriven axle at its nominal stiffness (the paper's model)
        self._vp = single_track.model_params(v)
        self._st = None
        if cfg.backend == "numba":
            self._load_kernels()
        sig = np.asarray(cfg.sigma)[list(self.channels)]
        self.R = np.diag(sig**2)
        self.bias_on = bool(np.any(np.asarray(cfg.bias_rw) > 0) or np.any(np.asarray(cfg.bias0_std) > 0))
        self.q_bias = np.asarray(cfg.bias_rw)[list(self.channels)] ** 2
        q = np.asarray(cfg.state_noise, float)[-(3 if self.full else 2):]
        self.state_noise = q if np.any(q > 0) else None
        self.C_ref, self.C_center, self.C_std = stiffness_prior(cfg, self.C_nom, self.params, "augpf configuration")
        self.lo = cfg.bound_low * self.C_ref - self.C_nom  # projection bounds on the deviation means
        self.hi = cfg.bound_high * self.C_ref - self.C_nom

    def _load_kernels(self) -> None:
        from tirefilter.vehicle import single_track_numba

        self._st = single_track_numba

    def __getstate__(self):  # (copies and FMU states: the kernel module is not state)
        return {**self.__dict__, "_st": None}

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self.cfg.backend == "numba":
            self._load_kernels()

    def config_dict(self) -> dict:
        d = asdict(self.cfg)
        d.update(params=list(self.params), C_nominal=self.C_nom.tolist())
        return d

    # ---- model: `vehicle.single_track` (numpy) or its compiled twin ---------------------
    def _model(self, x, u):
        """`single_track.accelerations`: a, B, af, ar, the wheel slip (None in the lateral model)."""
        if self._st is not None:
            a, B, af, ar, slip = self._st.accelerations(x, u, self._vp, self.full, self.rear_drive, self.n_w,
                                                        np.ones(len(x)), np.zeros((2, 0)), -1.0)
            return a, B, af, ar, slip if self.full else None
        return single_track.accelerations(x, u, self._vp, self.full, self.rear_drive)

    def _propagate(self, x, u, w, dt, first):
        """`single_track.propagate` (eq. (9)), the wheel slip of the step's start held (`first`)."""
        heun = self.cfg.integrator == "heun"
        if self._st is not None:
            a, B, _, _, slip = first
            return self._st.propagate(x, u, w, (a, B, np.zeros((2, len(x))) if slip is None else slip), dt,
                                      self.cfg.max_step, heun, self._vp, self.full, self.rear_drive, self.n_w,
                                      (np.ones(len(x)), np.zeros((2, 0))))
        return single_track.propagate(x, u, w, dt, first, self._vp, self.full, self.rear_drive, self.cfg.max_step,
                                      heun)

    # ---- initialisation ---------------------------------------------------------------
    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self._draw_prior(None)
        self.w_prev = None
        self.u_prev = None
        self.t_prev = None
        self.t_start = None
        self.ay_last = math.nan  # the last finite a^Y of the linear-region test (`held_ay`)
        self.active = False
        self.resamples = 0
        self.restarts = 0

    def _draw_prior(self, x0_mean) -> None:
        """Particles from the initial distribution (state around x0_mean, default the
        configured one), equal weights."""
        cfg, N, n, rng = self.cfg, self.cfg.particles, self.n_w, self.rng
        if cfg.init_distribution == "normal":
            u = rng.standard_normal((N, n)) * cfg.init_std
        else:
            u = rng.uniform(-cfg.init_half_width, cfg.init_half_width, (N, n))
        self.mu = np.clip(self.C_center + u * self.C_ref - self.C_nom, self.lo, self.hi)
        s2 = np.broadcast_to((cfg.init_sigma * self.C_ref) ** 2, (N, n)).copy()
        self.s2 = inverse_gamma_step(s2, cfg.init_sigma_spread, rng)
        nx = 3 if self.full else 2
        if x0_mean is None:
            x0_mean = cfg.x0_mean if cfg.x0_mean is not None else ((20.0, 0.0, 0.0) if self.full else (0.0, 0.0))
        self.x = np.asarray(x0_mean, float)[-nx:] + rng.standard_normal((N, nx)) * np.asarray(cfg.x0_std, float)[-nx:]
        m = len(self.channels)
        self.b = np.zeros((N, m))
        self.P = np.broadcast_to(np.diag(np.asarray(cfg.bias0_std)[list(self.channels)] ** 2), (N, m, m)).copy()
        self.logw = np.full(N, -math.log(N))

    # ---- the filter -------------------------------------------------------------------
    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        cfg, rng = self.cfg, self.rng
        uk = np.array([u.delta, u.omega_f, u.omega_r, u.vx], float)
        if self.u_prev is not None:
            uk = np.where(np.isfinite(uk), uk, self.u_prev)  # hold the last finite input
        if not self.full and not math.isfinite(uk[3]):
            raise ConfigError("inputs", "vx", f"the lateral model needs vx; none given up to t = {t} s")
        if self.u_prev is None and self.full and cfg.x0_vx_from_wheels:
            vx = single_track.vx_from_wheels(uk, self._vp, self.rear_drive)
            if math.isfinite(vx):
                self.x[:, 0] = vx + cfg.x0_vx_wheel_std * rng.standard_normal(len(self.x))
        if not math.isfinite(uk[0]):
            uk[0] = 0.0

        # 1. propagate x with w_{k-1} (eq. (9)); artificial dynamics of m and s2 (gate open)
        if self.t_prev is not None:
            dt = t - self.t_prev
            if not dt > 0:
                raise ConfigError("inputs", "t", f"time must increase: {t} after {self.t_prev}")
            self.x = self._propagate(self.x, self.u_prev, self.w_prev, dt, self._at_x)
            if self.state_noise is not None:
                self.x = self.x + math.sqrt(dt) * self.state_noise * rng.standard_normal(self.x.shape)
            if self.bias_on:
                self.P = self.P + np.diag(self.q_bias * dt)
            if self.active:
                scale = cfg.mean_rw * self.C_ref * math.sqrt(dt / cfg.sample_period)
                self.mu = np.clip(self.mu + scale * rng.standard_normal(self.mu.shape), self.lo, self.hi)
                self.s2 = inverse_gamma_step(self.s2, cfg.var_rel_std, rng)
        else:
            self.t_start = t
        self.t_prev, self.u_prev = t, uk

        # 2.-3. the per-step deviation w_k (process noise of the augmented model) and the weights
        yk = np.array([y.ax, y.ay, y.yaw_rate], float)[list(self.channels)]
        a = np.flatnonzero(np.isfinite(yk))
        model_k = self._model(self.x, uk)
        h, D = single_track.measurement(model_k[0], model_k[1], self.x, self.roll_gain, self.full, self._vp)
        if cfg.proposal == "bootstrap":
            w = self.mu + np.sqrt(self.s2) * rng.standard_normal(self.mu.shape)  # w_k ~ N(m_k, s2_k)
            pred = h + np.einsum("nij,nj->ni", D, w)
            if a.size:  # N(y; h + D w + b, R + P_b)
                e = yk[a] - pred[:, a] - self.b[:, a]
                if self.bias_on:
                    Lc = chol(self.P[:, a][:, :, a] + self.R[np.ix_(a, a)])
                    v = solve_lower(Lc, e)
                    loglik = -0.5 * np.sum(v * v, axis=1) - 0.5 * logdet_chol(Lc) - 0.5 * a.size * LOG_2PI
                else:
                    r = np.diagonal(self.R)[a]
                    loglik = -0.5 * np.sum(e * e / r, axis=1) - 0.5 * float(np.sum(np.log(r))) - 0.5 * a.size * LOG_2PI
                self.logw = normalize_log_weights(self.logw + loglik)
            w_cond = None
        else:  # conditional: weight with w_k marginalised, then draw w_k from p(w_k | y_k)
            w_mean, w_cov = self.mu, self.s2[:, :, None] * np.eye(self.n_w)
            if a.size:
                Da = D[:, a]
                noise = self.R[np.ix_(a, a)] + (self.P[:, a][:, :, a] if self.bias_on else 0.0)
                r_a = yk[a] - h[:, a] - self.b[:, a]
                loglik, w_mean, w_cov = conditional_deviation(self.mu, self.s2, Da, noise, r_a)
                self.logw = normalize_log_weights(self.logw + loglik)
            w_cond = (w_mean, w_cov)
        if not self._plausible(uk):
            return self._restart(t, uk, y)
        ess = float(effective_sample_size(self.logw))
        if ess < cfg.resample_threshold * cfg.particles:
            idx = systematic_resample(self.logw, rng)
            self.x, self.mu, self.s2, self.b, self.P = self.x[idx], self.mu[idx], self.s2[idx], self.b[idx], self.P[idx]
            h, D = h[idx], D[idx]
            if w_cond is None:
                w, pred = w[idx], pred[idx]
            else:
                w_cond = (w_cond[0][idx], w_cond[1][idx])
            a_k, B_k, af, ar, slip_k = model_k
            # (slip (2, N) copied in C order, as the kernel's model gives it: indexing its columns gives
            # Fortran order, for which single_track_numba.propagate would compile a second signature)
            model_k = (a_k[idx], B_k[idx], af[idx], ar[idx],
                       None if slip_k is None else np.ascontiguousarray(slip_k[:, idx]))
            self.logw = np.full(cfg.particles, -math.log(cfg.particles))
            self.resamples += 1
        if w_cond is not None:
            L = chol(0.5 * (w_cond[1] + np.swapaxes(w_cond[1], 1, 2)))
            w = w_cond[0] + np.einsum("nij,nj->ni", L, rng.standard_normal(self.mu.shape))
            pred = h + np.einsum("nij,nj->ni", D, w)

        # 4. bias, eq. (30) given w_k: S = P + R, K = P S^-1
        if a.size and self.bias_on:
            S = self.P[:, a][:, :, a] + self.R[np.ix_(a, a)]
            Pa = self.P[:, a, :]
            Kt = chol_solve(chol(S), Pa)
            innov = yk[a] - pred[:, a] - self.b[:, a]
            self.b = self.b + np.einsum("nki,nk->ni", Kt, innov)
            P = self.P - np.swapaxes(Pa, 1, 2) @ Kt
            self.P = 0.5 * (P + np.swapaxes(P, 1, 2))

        # the MPF's gate, evaluated on this filter's estimates; it acts from the next step
        q = np.exp(self.logw)
        vx_est = float(q @ self.x[:, 0]) if self.full else uk[3]
        vy = self.x[:, -2]
        vy_std = math.sqrt(max(float(q @ (vy - q @ vy) ** 2), 0.0))
        alpha = max(abs(float(q @ model_k[2])), abs(float(q @ model_k[3])))
        ay_gate = self.ay_last = held_ay(y.ay, self.ay_last)
        self.active = gate_open(cfg, t=t, t_start=self.t_start, vx=vx_est, delta=uk[0], ay_meas=ay_gate, alpha=alpha,
                                vy_std=vy_std)
        self.w_prev = w
        self._at_x = model_k
        return self._estimate(ess)

    def _plausible(self, uk) -> bool:
        """The MPF's plausibility check (`StiffnessMPF._plausible`): weight zero outside the
        physically possible region; False when no particle is left."""
        vx = self.x[:, 0] if self.full else uk[3]
        ok = (np.abs(self.x[:, -2]) <= self.cfg.plausible_beta * np.maximum(np.abs(vx), self.cfg.gate_speed)) & (
            np.abs(self.x[:, -1]) <= self.cfg.plausible_yaw_rate) & np.all(np.isfinite(self.x), axis=1)
        if ok.all():
            return True
        if not ok.any():
            return False
        self.logw = normalize_log_weights(np.where(ok, self.logw, -np.inf))
        return True

    def _restart(self, t, uk, y) -> Estimate:
        """Every particle left the plausible region (a learned unstable stiffness): draw
        from the prior again around the current speed (undriven wheel) and the measured yaw
        rate, as the MPF does; the next propagation uses the prior means."""
        if self.full:
            vx = single_track.vx_from_wheels(uk, self._vp, self.rear_drive)
            vx = vx if math.isfinite(vx) else float(np.median(self.x[:, 0]))
        r0 = y.yaw_rate if math.isfinite(y.yaw_rate) else 0.0
        self._draw_prior((vx, 0.0, r0) if self.full else (0.0, r0))
        self.restarts += 1
        self.t_start, self.t_prev, self.u_prev, self.active = t, t, uk, False
        self._at_x = self._model(self.x, uk)
        self.w_prev = self.mu.copy()
        return self._estimate(float(self.cfg.particles))

    def _estimate(self, ess: float) -> Estimate:
        q = np.exp(self.logw)
        x_mean = q @ self.x
        x_std = np.sqrt(np.maximum(q @ (self.x - x_mean) ** 2, 0.0))
        mbar = q @ self.mu
        std = np.sqrt(np.maximum(q @ (self.mu - mbar) ** 2, 0.0))  # spread of the particle means
        sigma = q @ np.sqrt(self.s2)  # weighted mean of the deviation std
        vals = dict(zip(self.params, zip(self.C_nom + mbar, std, sigma)))
        bias = dict(zip(("ax", "ay", "yaw_rate")[-len(self.channels):], q @ self.b))
        return particle_estimate(active=self.active, ess=ess, x_mean=x_mean, x_std=x_std, stiffness=vals, bias=bias,
                                 vx_input=NAN if self.u_prev is None else self.u_prev[3])

    def posterior(self) -> Posterior:
        """Particles [x, m, s2] (N, nx + 2 n_w) with their log-weights; stats: the means `mu`
        and variances `var` of the deviations, bias mean and covariance, nominal stiffness."""
        return Posterior(np.concatenate([self.x, self.mu, self.s2], axis=1), self.logw.copy(),
                         {"mu": self.mu.copy(), "var": self.s2.copy(), "bias": self.b.copy(),
                          "bias_cov": self.P.copy(), "C_nominal": self.C_nom.copy(), "params": self.params})
