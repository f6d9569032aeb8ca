"""Online tire-friction learning by a reduced-rank GP state-space model in a particle
filter: Algorithm 1 of Berntorp, "Online Bayesian tire-friction learning by Gaussian-process
state-space models" (IFAC 2020), with the corrections of docs/derivations.md and the
combined pipeline the paper proposes but does not build (docs/derivations.md, "Combined pipeline").

Per particle: the lateral state x = [v^Y, r] (inputs u = [delta, v^X]), MNIW statistics of
the friction deviation Delta mu(alpha) = A phi(alpha) (eq. (14), (24)-(29)), the friction
realised over the current step, and Kalman filters of the a^Y and yaw-rate biases (`bias`).
Friction mu = mu~(alpha) + Delta mu (Sec. 4): mu~ is a Pacejka prior (peak 0.05 by default, a
replay's slope from the vehicle file); `combined` sets its slope from the stiffness MPF.

One step at sample k (the order of docs/derivations.md, "The filter step": weight with the current predictive, resample,
then update the statistics with the same sample that drives the state):
  1. propagate x_k = x_{k-1} + T_s f(x_{k-1}, u_{k-1}, mu_{k-1}) (eq. (1), Euler with the
     friction held, sub-steps of at most `max_step`: `dynamics`), forget the statistics (eq. (29));
  2. slip angles alpha_k (eq. (4)), clipped to [-L, L] (counted), features phi(alpha_k);
  3. predictive of zeta_k = A phi + w integrating A and Q (eq. (31)-(32), multivariate t);
     measurement y = [a^Y, r] (eq. (8)): a^Y = (F^z_f mu_f cos delta + F^z_r mu_r) / m with
     mu = mu~ + zeta ("learned", default) or mu = mu~ ("prior", the paper's Sec. 2.3);
  4. weight: Student-t likelihood of a^Y (zeta and the bias integrated out) times the Gaussian
     yaw-rate likelihood (eq. (22)); normalise, resample when ESS < threshold (Algorithm 1, 6-10);
  5. draw zeta_k from its t conditional given the a^Y residual (the locally optimal
     proposal for the a^Y part; "prior": from the predictive), update the statistics with
     (zeta_k, phi(alpha_k)) while learning (eq. (27)/(28)); mu_k = mu~(alpha_k) + zeta_k; with
     `force_hold = "linear"` x_k gains what the forces' linear growth from mu_{k-1} to the
     conditional mean of mu_k adds over the step (`dynamics.linear_hold_remainder`,
     docs/derivations.md, "F4. The filter step"); the bias filters given mu_k and r_k (docs/derivations.md, "F7. IMU bias").
Around the step: v^X from the wheel speeds where there is no vx input (`speed`), and the
divergence supervision (`supervision`, "F9. Divergence: detection and recovery").
"""

from __future__ import annotations

import math
from bisect import bisect_left
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.special import gammaln

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate, FrictionCurve, Inputs, Measurement, Posterior
from tirefilter.estimators.gpssm.bias import AY, AY_VAR, R, R_VAR, bias_moments, bias_predict, bias_prior, bias_update
from tirefilter.estimators.gpssm.config import DEG, GPSSMConfig, PacejkaPrior, slip_slope_prior
from tirefilter.estimators.gpssm.dynamics import force_rates, linear_hold_remainder, propagate
from tirefilter.estimators.gpssm.slip_record import SlipRecord
from tirefilter.estimators.gpssm.speed import WheelSpeedVx
from tirefilter.estimators.gpssm.supervision import CAUSES, Checkpoints, Divergence, DivergenceMonitor
from tirefilter.stats import effective_sample_size, normalize_log_weights, systematic_resample
from tirefilter.stats.gp import GPBasis1D, make_basis
from tirefilter.stats.mniw import make_mniw
from tirefilter.stats.sandwich import BatchMeansSandwichPair
from tirefilter.stats.student_t import t_sample
from tirefilter.vehicle.params import VehicleParams
from tirefilter.vehicle.single_track import GRAVITY, slip_angles

NAN = math.nan


class FrictionGPSSM:
    """Algorithm 1 of the friction paper, vectorised over particles; `mpf` given: the
    combined pipeline (name "combined")."""

    def __init__(self, vehicle: VehicleParams, config: GPSSMConfig = GPSSMConfig(), *, tire_shape=None, mpf=None):
        self.vehicle = vehicle
        self.cfg = cfg = config.validated()
        self.mpf = mpf
        self.name = "combined" if mpf is not None else "gpssm"
        self.Fz = np.array(vehicle.static_axle_loads(GRAVITY))  # eq. (2)
        self.b1 = GPBasis1D(cfg.L, cfg.m, cfg.lengthscale, cfg.s_f)
        self.basis = make_basis(cfg.basis, self.b1, cfg.symmetry == "odd")
        self.d = 2 if cfg.basis == "tensor" else 1
        self.nu0 = self.d + 1.0 + cfg.nu0_margin
        shape = tire_shape or (10.0, 1.3, 0.0)
        B = cfg.prior_B if cfg.prior_B is not None else shape[0]
        C = cfg.prior_C if cfg.prior_C is not None else shape[1]
        E = cfg.prior_E if cfg.prior_E is not None else shape[2]
        if cfg.prior_slope == "vehicle":
            self.prior0 = slip_slope_prior(vehicle.Cf_y / self.Fz[0], vehicle.Cr_y / self.Fz[1], C,
                                           cfg.saturation_slip)
        else:
            self.prior0 = PacejkaPrior((cfg.prior_peak, cfg.prior_peak), (B, B), C, E)
        self.R = np.array(cfg.sigma, float) ** 2
        self.q_bias = np.square(np.asarray(cfg.bias_rw, float))  # per s
        self.bias_on = bool(np.any(self.q_bias > 0) or np.any(np.asarray(cfg.bias0_std, float) > 0))
        half = cfg.slip_range if cfg.slip_range is not None else cfg.L
        n = int(math.floor(half / cfg.grid_step + 1e-9))
        self.grid = np.arange(-n, n + 1) * cfg.grid_step
        if self.grid[-1] < half - 1e-12:
            self.grid = np.concatenate([[-half], self.grid, [half]])
        self._grid_list = self.grid.tolist()  # for `_bin`

    def config_dict(self) -> dict:
        d = asdict(self.cfg)
        d.update(estimator=self.name, prior_initial=asdict(self.prior0), basis_size=self.basis.size,
                 static_axle_loads=self.Fz.tolist())
        if hasattr(self, "prior"):
            d["prior_final"] = asdict(self.prior)
            d["diagnostics"] = self.diagnostics()
        if self.mpf is not None:
            d["mpf"] = self.mpf.config_dict()
        return d

    def forgetting_factor(self, dt: float) -> float:
        """The factor of eq. (29) over a step dt: lambda^(dt / forgetting_period) (lambda itself
        at that period)."""
        cfg = self.cfg
        ratio = dt / cfg.forgetting_period
        return cfg.forgetting if abs(ratio - 1.0) <= 1e-9 else cfg.forgetting ** ratio

    def _prior_stats(self):
        """The MNIW statistics of every particle at their prior (eq. (24))."""
        cfg, N = self.cfg, self.cfg.particles
        batch = (N,) if self.d == 2 else (N, 2)
        Lam0 = np.eye(self.d) * cfg.q0**2 * (self.nu0 - self.d - 1.0)  # E[Q] = q0^2 I
        return make_mniw(cfg.stats, batch, self.d, self.basis.S, Lam0, self.nu0, cfg.backend)

    def diagnostics(self) -> dict:
        """Counts a user should see: slip clipping at +-L, resampling, the handover, the
        divergences (each with its onset, detection, symptom and what was done) and the
        largest value each symptom of divergence reached (`supervision`)."""
        mon = getattr(self, "monitor", None)
        return {"slip_clipped_samples": int(self.clipped), "slip_clipped_steps": int(self.clipped_steps),
                "particle_slip_evaluations": int(self.slip_evaluations), "resamples": int(self.resamples),
                "handover_time": self.handover_time, "divergences": [d.to_dict() for d in self.divergences],
                "symptom_max": None if mon is None else {k: float(v) for k, v in mon.worst.items()},
                "vx_source": self.vx_source}

    def run_warnings(self) -> list[str]:
        """One line per divergence, for the run summary's warnings (`runs.Metrics`)."""
        return [d.message() for d in self.divergences]

    @property
    def stats(self):
        """The MNIW statistics (`stats.mniw`); the compiled step's pending update applied."""
        if getattr(self, "_compiled", None) is not None:
            self._compiled.flush()
        return self._stats

    @stats.setter
    def stats(self, value) -> None:
        compiled = getattr(self, "_compiled", None)
        if compiled is not None and value is not getattr(self, "_stats", None):
            compiled.flush()  # the compiled step's pending work belongs to the statistics replaced
        self._stats = value

    # ---- initialisation ---------------------------------------------------------------
    def reset(self, rng: np.random.Generator) -> None:
        cfg, N = self.cfg, self.cfg.particles
        self.rng = rng
        if self.mpf is not None:
            self.mpf.reset(rng)
        self._compiled = None  # before the statistics change: an old compiled step must not flush into them
        self.stats = self._prior_stats()
        self.x = np.asarray(cfg.x0_mean, float) + rng.standard_normal((N, 2)) * np.asarray(cfg.x0_std, float)
        self.bias = bias_prior(N, cfg.bias0_std)  # (N, 4): b_ay, b_r, their variances (`bias`)
        self.logw = np.full(N, -math.log(N))
        self.vx_wheels = WheelSpeedVx(self.vehicle, cfg.sigma_omega, cfg.sigma_ax, cfg.wheel_slip_rw)
        self.vx_source = None  # "input" (the vx signal) or "wheels", once a step has taken one
        self.monitor = DivergenceMonitor(cfg.diverge_clip_share, cfg.diverge_beta, cfg.diverge_nis,
                                         cfg.diverge_window, cfg.diverge_after)
        self.checkpoints = Checkpoints(cfg.checkpoint_every)
        self.divergences: list[Divergence] = []
        self.clip_share = 0.0  # share of particles with a slip angle clipped at the last sample
        self.lam_step = 1.0  # the forgetting factor of the last step (1: none)
        self.mean_slip = (NAN, NAN)  # the posterior-mean slip angles of the last step (after resampling)
        self._calib = (BatchMeansSandwichPair(cfg.calibration_batch, math.inf) if cfg.band == "calibrated" else None)
        self.prediction_var = (NAN, NAN)  # variance of the one-step prediction of (a^Y, r)
        self._t_calib = None  # the time of the last sample the sandwich saw
        self.mu = np.zeros((N, 2))  # friction realised over the current step
        self.prior = self.prior0
        self.t_prev = self.u_prev = None
        self.active = False
        self.learning_started = self.mpf is None
        self.handover_time = None
        self.mpf_active_time = 0.0
        self.mpf_estimate = None
        self.clipped = self.clipped_steps = self.slip_evaluations = self.resamples = 0
        self.visited = [math.inf, -math.inf, math.inf, -math.inf]
        self.last_t = NAN
        self.prediction = (NAN, NAN)  # one-step-ahead (a^Y, r) before the last measurement
        self._path = np.zeros((2, len(self.grid), 2))  # (axle, grid bin, [count, sum of the other slip])
        # the slips' posterior variance and the held forces' slip error at the learning samples (F5)
        self.slips = SlipRecord(self.grid, cfg.lengthscale)
        self._slope = (NAN, NAN, NAN, NAN)
        self._dphi0 = self._slope_features()
        if cfg.backend == "numba":
            from tirefilter.estimators.gpssm.compiled import CompiledStep

            self._compiled = CompiledStep(self)

    def _slope_features(self):
        """d phi / d alpha at alpha = 0 for each axle's curve: (2, size) (tensor: d/d alpha_f of
        phi(alpha_f, alpha_r) at (0, 0) for the front row, d/d alpha_r for the rear)."""
        b, j = self.b1, self.b1.j
        k = math.pi / (2 * b.L)
        d1 = k * j * np.cos(k * b.L * j) / math.sqrt(b.L)  # phi_j'(0)
        p0 = b.phi(0.0)
        keep = self.basis.keep
        if self.d == 2:
            return np.stack([(d1[:, None] * p0[None, :]).ravel()[keep], (p0[:, None] * d1[None, :]).ravel()[keep]])
        return np.stack([d1[keep], d1[keep]])

    # ---- model ------------------------------------------------------------------------
    def _slip(self, x, delta, vx):
        """Slip angles of eq. (4) (single track): alpha_f = delta - atan((vy + lf r) / vx),
        alpha_r = -atan((vy - lr r) / vx)."""
        v = self.vehicle
        return slip_angles(max(vx, 1.0), x[:, 0], x[:, 1], delta, v.lf, v.lr)

    def _rates(self, mu, delta: float) -> np.ndarray:
        """(N, 2): a^Y and r' of the frictions mu at steering angle delta (`dynamics.force_rates`)."""
        v = self.vehicle
        return force_rates(mu, math.cos(delta), self.Fz, v.mass, v.lf, v.lr, v.yaw_inertia)

    def _features(self, af, ar):
        """phi(alpha): tensor (N, size); axle (N, 2, size)."""
        if self.cfg.backend == "numba":
            from tirefilter.stats.mniw_numba import basis_features

            return basis_features(self.basis, af, ar)
        return self.basis.features(af, ar)

    def _predictive(self, phi):
        """Joint predictive of zeta = (zeta_f, zeta_r): loc (N, 2), scale (N, 2, 2), dof (N,).
        Per-axle basis: the two scalar t's (equal dof: both axles are updated and forgotten
        together) as one bivariate t with diagonal scale."""
        loc, scale, dof = self.stats.predictive(phi)
        if self.d == 2:
            return loc, scale, dof
        S = np.zeros((len(loc), 2, 2))
        S[:, 0, 0], S[:, 1, 1] = scale[:, 0, 0, 0], scale[:, 1, 0, 0]
        return loc[:, :, 0], S, dof[:, 0]

    # ---- the filter -------------------------------------------------------------------
    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        delta, vx = self._inputs(t, u)
        uk = np.array([delta, vx])
        if self.mpf is not None:  # (v^X from the wheels where the log has none: the MPF's lateral model gets it too)
            self.mpf_estimate = self.mpf.step(t, u if u.vx == u.vx else replace(u, vx=vx), y)
            self._combined_prior(t)
        if self._compiled is not None:  # the same step, compiled (estimators/gpssm/compiled.py)
            est = self._compiled.step(t, uk, delta, vx, y)
        else:
            est = self._step(t, uk, delta, vx, y)
        if self.vx_wheels.filter is not None:  # the wheel-speed pre-filter's drive over the next step
            q = np.exp(self.logw)
            self.vx_wheels.set_drive(y.ax, float(q @ (self.x[:, 0] * self.x[:, 1])))
        if self._calib is not None and self.active and y.ay == y.ay and self._t_calib is not None:
            # the score of this sample's a^Y residual for the two axles' local slopes (`_band_factor`)
            e = y.ay - self.prediction[0]
            d0, d1 = self.mean_slip[0] * math.cos(delta), self.mean_slip[1]
            self._calib.update_pair(d0 * e, d1 * e, d0, d1, t - self._t_calib,
                                    self.lam_step ** (1.0 / self.cfg.calibration_memory))
        self._t_calib = t
        if self.cfg.supervise:
            est = self._supervise(t, uk, y, est)
        return est

    def _inputs(self, t: float, u: Inputs) -> tuple[float, float]:
        """delta and v^X of this sample: v^X from the `vx` input, else from the undriven axle's
        wheel speed (`speed.WheelSpeedVx`); a missing input: the previous one (scalars: a few us
        a step)."""
        delta, vx = float(u.delta), float(u.vx)
        if vx == vx:
            self.vx_source = self.vx_source or "input"
        elif u.omega_f == u.omega_f or u.omega_r == u.omega_r or self.vx_source == "wheels":
            vx = self.vx_wheels.step(t, float(u.omega_f), float(u.omega_r))
            if vx == vx:
                self.vx_source = "wheels"
        if self.u_prev is not None:
            delta = delta if math.isfinite(delta) else float(self.u_prev[0])
            vx = vx if math.isfinite(vx) else float(self.u_prev[1])
        if not math.isfinite(vx):
            raise ConfigError("inputs", "vx", "the friction GP-SSM (lateral model) needs vx or the undriven axle's "
                              f"wheel speed; neither given up to t = {t} s")
        if not math.isfinite(delta):
            delta = 0.0
        return delta, vx

    def _step(self, t: float, uk, delta: float, vx: float, y: Measurement) -> Estimate:
        """The numpy reference step (the module docstring's steps 1-5)."""
        cfg, N, rng = self.cfg, self.cfg.particles, self.rng
        lam = 1.0  # the forgetting factor of this step (1: none)
        held = None  # the rates a^Y, r' held over the step from k-1 (none at the first sample)

        # 1. propagate with the friction drawn at k-1, forget (eq. (29)); the bias's random walk
        if self.t_prev is None:
            if math.isfinite(y.yaw_rate):  # start the yaw rate at the first sample
                self.x[:, 1] = y.yaw_rate + math.sqrt(self.R[1]) * rng.standard_normal(N)
        else:
            dt = t - self.t_prev
            if dt <= 0:
                raise ConfigError("inputs", "t", f"time must increase: {t} after {self.t_prev}")
            held = self._rates(self.mu, self.u_prev[0])  # 1. eq. (1) with the friction mu_{k-1} held
            self.x = propagate(self.x, held, self.u_prev[1], dt, cfg.max_step)
            sn = np.asarray(cfg.state_noise, float)
            if np.any(sn > 0):
                self.x = self.x + math.sqrt(dt) * sn * rng.standard_normal(self.x.shape)
            if self.active:
                lam = self.forgetting_factor(dt)
                self.stats.forget(lam, nu_min=self.nu0)
            if self.bias_on:
                bias_predict(self.bias, self.q_bias, dt)
        self.active = bool(vx > cfg.gate_speed and self.learning_started)

        # 2. slip angles, clipped to the basis domain (counted), features
        af, ar = self._slip(self.x, delta, vx)
        L = cfg.L
        out = (np.abs(af) > L) | (np.abs(ar) > L)
        n_out = int(np.count_nonzero(out))
        self.slip_evaluations += N
        self.clip_share = n_out / N
        if n_out:
            self.clipped += n_out
            self.clipped_steps += 1
            af, ar = np.clip(af, -L, L), np.clip(ar, -L, L)
        phi = self._features(af, ar)
        pf, pr = self.prior(af, ar)

        # 3.-4. predictive of zeta, weights (eq. (22) with zeta integrated out, the bias with its Kalman
        #       filter's prediction: derivations, "F7. IMU bias")
        loc, S, dof = self._predictive(phi)
        c = np.array([self.Fz[0] * math.cos(delta), self.Fz[1]]) / self.vehicle.mass  # a^Y = c . mu
        h0 = c[0] * pf + c[1] * pr
        b = self.bias
        logl = np.zeros(N)
        have_ay, have_r = math.isfinite(y.ay), math.isfinite(y.yaw_rate)
        learned = cfg.measurement_friction == "learned"
        q_prev = np.exp(self.logw)  # one-step-ahead prediction of y_k (before y_k is used)
        ay_pred = (h0 + loc @ c if learned else h0) + b[:, AY]
        if learned:
            Sc = S @ c  # (N, 2)
            # scale of the a^Y marginal (the consistent joint t), the bias's variance with the white noise's
            s_y = Sc @ c + (self.R[0] + b[:, AY_VAR]) * (dof - 2.0) / dof
            var_ay = s_y * dof / (dof - 2.0)
        else:
            var_ay = self.R[0] + b[:, AY_VAR]
        if have_ay:
            e = (y.ay - h0 - loc @ c if learned else y.ay - h0) - b[:, AY]
            if learned:
                logl += _t1_logpdf(e, s_y, dof)
            else:
                logl += -0.5 * (e * e / var_ay + np.log(2 * math.pi * var_ay))
        var_r = self.R[1] + b[:, R_VAR]
        if have_r:
            e_r = y.yaw_rate - self.x[:, 1] - b[:, R]
            logl += -0.5 * (e_r * e_r / var_r + np.log(2 * math.pi * var_r))
        r_pred = self.x[:, 1] + b[:, R]
        self.prediction = (float(q_prev @ ay_pred), float(q_prev @ r_pred))
        self.prediction_var = (float(q_prev @ (var_ay + ay_pred**2)) - self.prediction[0] ** 2,
                               float(q_prev @ (var_r + r_pred**2)) - self.prediction[1] ** 2)
        self.logw = normalize_log_weights(self.logw + logl)
        ess = float(effective_sample_size(self.logw))
        if ess < cfg.resample_threshold * N:
            idx = systematic_resample(self.logw, rng)
            self.x, self.stats, self.bias = self.x[idx], self.stats.take(idx), self.bias[idx]
            held = None if held is None else held[idx]
            af, ar, phi, pf, pr, loc, S, dof = (a[idx] for a in (af, ar, phi, pf, pr, loc, S, dof))
            if have_ay and learned:
                Sc, s_y, e = Sc[idx], s_y[idx], e[idx]
            self.logw = np.full(N, -math.log(N))
            self.resamples += 1

        # 5. draw zeta_k (t conditional given the a^Y residual), learn, store mu_k; the bias given zeta_k
        if have_ay and learned:
            g = Sc / s_y[:, None]
            loc_c = loc + g * e[:, None]
            scale_c = ((dof + e * e / s_y) / (dof + 1.0))[:, None, None] * (S - Sc[:, :, None] * g[:, None, :])
            zeta = t_sample(loc_c, 0.5 * (scale_c + np.swapaxes(scale_c, 1, 2)), dof + 1.0, rng)
        else:
            loc_c = loc
            zeta = t_sample(loc, S, dof, rng)
        if self.active:
            self.stats.update(zeta if self.d == 2 else zeta[:, :, None], phi)
            q = np.exp(self.logw)
            mf, mr = float(q @ af), float(q @ ar)
            self.visited = [min(self.visited[0], mf), max(self.visited[1], mf),
                            min(self.visited[2], mr), max(self.visited[3], mr)]
            jf, jr = self._bin(mf), self._bin(mr)
            if self.d == 2:  # the visited path: mean alpha_r per alpha_f bin and vice versa
                self._path[0, jf] += (1.0, mr)
                self._path[1, jr] += (1.0, mf)
            self._slip_spread(lam, jf, jr, float(q @ (af - mf) ** 2), float(q @ (ar - mr) ** 2),
                              self._hold_slip_error(t, y, vx))
            self.mean_slip = (mf, mr)
        self.lam_step = lam
        self.mu = np.stack([pf, pr], axis=1) + zeta
        r_seen = self.x[:, 1].copy()  # the yaw rate the weights saw (before the linear hold's remainder)
        if held is not None and cfg.force_hold == "linear":  # the forces linear from mu_{k-1} to E[mu_k] over the step
            mean = np.stack([pf, pr], axis=1) + loc_c  # the friction's conditional mean at sample k
            self.x += linear_hold_remainder(held, self._rates(mean, delta), float(self.u_prev[1]), dt)
        if self.bias_on:
            self._bias_update(y, self.mu @ c if learned else c[0] * pf + c[1] * pr, r_seen)
        self.t_prev, self.u_prev, self.last_t = t, uk, t
        return self._estimate(ess, vx)

    def _bias_update(self, y: Measurement, h_ay: np.ndarray, r: np.ndarray) -> None:
        """The bias's Kalman update given each particle's trajectory (derivations, "F7. IMU
        bias"): a^Y against the particle's h_ay = c . mu_k ("learned": mu~ + zeta_k; "prior":
        mu~ alone, the measurement the weights used), the yaw rate against the r_k the weights
        used (before the linear hold's remainder, "F4. The filter step")."""
        if math.isfinite(y.ay):
            bias_update(self.bias, AY, y.ay - h_ay, float(self.R[0]))
        if math.isfinite(y.yaw_rate):
            bias_update(self.bias, R, y.yaw_rate - r, float(self.R[1]))

    def _combined_prior(self, t: float) -> None:
        """Combined pipeline: until the handover the prior's slope follows the MPF's current
        cornering stiffness (C_y / F^z per axle) with peak slope x saturation_slip; the GP
        statistics stay at their prior meanwhile. Handover (the prior is fixed and learning
        starts) once the MPF has learned for `handover_after` s and the posterior std of both
        stiffness means is below `handover_std` of the mean."""
        est, cfg = self.mpf_estimate, self.cfg
        if self.learning_started or est is None:
            return
        if self.t_prev is not None and est.active:
            self.mpf_active_time += t - self.t_prev
        sf, sr = est.Cf_y / self.Fz[0], est.Cr_y / self.Fz[1]
        if not (math.isfinite(sf) and math.isfinite(sr) and sf > 0 and sr > 0):
            return
        self.prior = slip_slope_prior(sf, sr, self.prior0.C, cfg.saturation_slip)
        settled = max(est.Cf_y_std / est.Cf_y, est.Cr_y_std / est.Cr_y) < cfg.handover_std
        if self.mpf_active_time >= cfg.handover_after and settled:
            self.learning_started = True
            self.handover_time = t

    def _estimate(self, ess: float, vx: float, moments=None) -> Estimate:
        """`moments`: (mean vy, mean r, std vy, std r) when the caller has them (compiled step)."""
        q = np.exp(self.logw) if moments is None or self.cfg.stats == "rank1" else None
        if moments is None:
            xm = q @ self.x
            xs = np.sqrt(np.maximum(q @ (self.x - xm) ** 2, 0.0))
        else:
            xm, xs = moments[:2], moments[2:]
        m = self.mpf_estimate
        if m is not None:  # combined: the MPF's stiffness
            stiff = dict(Cf_y=m.Cf_y, Cr_y=m.Cr_y, Cf_y_std=m.Cf_y_std, Cr_y_std=m.Cr_y_std, Cf_y_sigma=m.Cf_y_sigma,
                         Cr_y_sigma=m.Cr_y_sigma)
        else:  # the learned curve's slope at zero slip times the static axle load
            M, _ = self.stats.posterior() if self.cfg.stats == "rank1" else (None, None)
            stiff = self._curve_slope(q, M)
        b_ay, b_r = self.bias_mean() if self.bias_on else (NAN, NAN)
        return Estimate(active=self.active, vx=vx, vy=float(xm[0]), yaw_rate=float(xm[1]), ess=ess,
                        state_std=(0.0, float(xs[0]), float(xs[1])), b_ay=b_ay, b_yaw_rate=b_r,
                        **{k: float(v) for k, v in stiff.items()})

    def bias_mean(self) -> tuple[float, float]:
        """The posterior means of the a^Y and yaw-rate biases (m/s^2, rad/s)."""
        q = np.exp(self.logw)
        return float(q @ self.bias[:, AY]), float(q @ self.bias[:, R])

    # ---- divergence: detection, report, recovery (`supervision`) ----------------------
    def _supervise(self, t: float, uk, y: Measurement, est: Estimate) -> Estimate:
        """The symptoms of this sample to the monitor; a checkpoint of the statistics while
        healthy and learning; on a confirmed divergence the report and the restart
        (`_recover`), whose estimate replaces this sample's."""
        vx = float(uk[1])
        beta = math.atan(abs(est.vy) / max(abs(vx), self.cfg.gate_speed)) if est.vy == est.vy else math.inf
        z = [(m - p) ** 2 / v for m, p, v in zip((y.ay, y.yaw_rate), self.prediction, self.prediction_var)
             if m == m and v > 0]
        found = self.monitor.observe(t, self.clip_share, beta, sum(z) / len(z) if z else NAN)
        if found is None:
            if self.active and self.monitor.healthy and self.checkpoints.due(t):
                self.checkpoints.add(t, self.stats.take(np.arange(self.cfg.particles)))
            return est
        cause, onset = found
        v = self.monitor.values[cause]
        detail = CAUSES[cause].format(value=math.degrees(v) if cause == "beta" else v, L=math.degrees(self.cfg.L),
                                      vx=vx) + f" for {t - onset:.1f} s"
        div = Divergence(t_onset=onset, t_detected=t, cause=cause, detail=detail)
        self.divergences.append(div)
        div.action = self._recover(t, uk, y, onset)
        return self._estimate(float(self.cfg.particles), vx)

    def _recover(self, t: float, uk, y: Measurement, onset: float) -> str:
        """Start the particles again (derivations, "F9. Divergence: detection and recovery"):
        the state and the bias from the prior and this sample's yaw rate (`combined`: from the
        MPF's posterior), equal weights, the friction deviation zero; the statistics from the
        newest checkpoint taken before the onset, else from their prior (`combined`: handed
        back to the MPF, whose next handover starts the learning again). Returns what was done."""
        cfg, N, rng = self.cfg, self.cfg.particles, self.rng
        vy0, vy_std = float(cfg.x0_mean[0]), float(cfg.x0_std[0])
        b0 = np.array([0.0, 0.0])
        b_var = np.square(np.asarray(cfg.bias0_std, float))
        mpf, m = self.mpf, self.mpf_estimate
        source = "the prior and the measured yaw rate"
        if mpf is not None and m is not None and math.isfinite(m.vy):
            vy0, vy_std = m.vy, max(m.state_std[1], 0.02)
            source = "the MPF's posterior"
            if getattr(mpf, "bias_on", False) and self.bias_on:  # the MPF's lateral model: channels (a^Y, yaw rate)
                w = np.exp(mpf.logw)
                b0 = w @ mpf.b[:, -2:]
                P = np.diagonal(mpf.P, axis1=1, axis2=2)[:, -2:]
                b_var = w @ (P + (mpf.b[:, -2:] - b0) ** 2)
        if not self.bias_on:
            b_var = np.zeros(2)
        self.bias[:, AY], self.bias[:, R] = b0
        self.bias[:, AY_VAR], self.bias[:, R_VAR] = b_var
        r0, r_std = float(np.exp(self.logw) @ self.x[:, 1]), math.sqrt(self.R[1] + b_var[1])
        if math.isfinite(y.yaw_rate):
            r0 = y.yaw_rate - b0[1]
        self.x[:, 0] = vy0 + vy_std * rng.standard_normal(N)
        self.x[:, 1] = r0 + r_std * rng.standard_normal(N)
        self.logw[:] = -math.log(N)
        ck = self.checkpoints.before(onset - cfg.checkpoint_every)
        if ck is not None:
            self.stats = ck[1].take(np.arange(N))
            curve = f"the learned curve from t = {ck[0]:.1f} s (before the onset)"
        elif mpf is not None:
            self.stats = self._prior_stats()
            self.learning_started, self.active, self.mpf_active_time, self.prior = False, False, 0.0, self.prior0
            curve = "the curve handed back to the MPF (learning starts again at its next handover)"
        else:
            self.stats = self._prior_stats()
            curve = "the learned curve back to its prior (no checkpoint before the onset)"
        self.checkpoints.clear()
        delta, vx = float(uk[0]), float(uk[1])
        af, ar = self._slip(self.x, delta, vx)
        L = cfg.L
        self.mu[:] = np.stack(self.prior(np.clip(af, -L, L), np.clip(ar, -L, L)), axis=1)
        self.monitor.reset()
        return f"restarted: the state and the bias from {source}, {curve}"

    def _curve_slope(self, q, M) -> dict:
        """Cornering stiffness of the learned curve, F^z (mu~'(0) + E[A] phi'(0)); the
        particle spread of E[A] phi'(0) as its std. With the exact statistics M needs a
        solve: it is refreshed only at snapshots (`friction()`), the prior slope otherwise."""
        if M is None:
            f, sf, r, sr = self._slope
            if not math.isfinite(f):
                s0 = self.prior.slope()
                return dict(Cf_y=self.Fz[0] * s0[0], Cr_y=self.Fz[1] * s0[1])
            return dict(Cf_y=f, Cf_y_std=sf, Cr_y=r, Cr_y_std=sr)
        s0 = np.array(self.prior.slope())
        if self.d == 2:
            sl = np.stack([M[:, 0] @ self._dphi0[0], M[:, 1] @ self._dphi0[1]], axis=1)
        else:
            sl = np.stack([M[:, 0, 0] @ self._dphi0[0], M[:, 1, 0] @ self._dphi0[1]], axis=1)
        mean = q @ sl
        std = np.sqrt(np.maximum(q @ (sl - mean) ** 2, 0.0))
        C = self.Fz * (s0 + mean)
        self._slope = (C[0], self.Fz[0] * std[0], C[1], self.Fz[1] * std[1])
        return dict(Cf_y=C[0], Cf_y_std=self.Fz[0] * std[0], Cr_y=C[1], Cr_y_std=self.Fz[1] * std[1])

    def _bin(self, a: float) -> int:
        """The grid bin of slip angle a: np.searchsorted(grid, a) (side "left"; NaN sorts last) clipped
        to the last bin, by bisection on the grid as a list (np.searchsorted on a scalar costs 2-15 us
        a call, twice per step; np.clip another 10)."""
        g = self._grid_list
        return min(bisect_left(g, a) if a == a else len(g), len(g) - 1)

    def _hold_slip_error(self, t: float, y: Measurement, vx: float) -> float:
        """The held forces' slip error at this sample, (T_s / 2) a^Y / v^X (a^Y the measured one
        less the mean bias, T_s the step just taken): the held force lags the sampled a^Y by half a
        step and v^Y integrates the lag into -(T_s / 2) a^Y, so both slips come out (T_s / 2) a^Y
        / v^X too large (derivations, "F4. The filter step"). 0 with the linear hold, at the first
        sample, without a^Y and with the paper's band."""
        if self.cfg.force_hold != "zero" or self.t_prev is None or not math.isfinite(y.ay) or self._calib is None:
            return 0.0
        ay = y.ay - (self.bias_mean()[0] if self.bias_on else 0.0)
        return 0.5 * (t - self.t_prev) * ay / max(vx, 1.0)

    def _slip_spread(self, lam: float, jf: int, jr: int, var_f: float, var_r: float, lag: float = 0.0) -> None:
        """A learning sample's slip variances and held-force slip error (`slip_record.SlipRecord.add`)."""
        self.slips.add(lam, jf, jr, var_f, var_r, lag)

    def slip_variance(self) -> np.ndarray:
        """(2, G): the slip's posterior variance at the learning samples near each grid point."""
        return self.slips.variance()

    def lag_shift(self) -> np.ndarray:
        """(2, G): the mean held-force slip error (`_hold_slip_error`) of the learning samples near
        each grid point."""
        return self.slips.shift()

    def path(self) -> tuple[np.ndarray, np.ndarray]:
        """Tensor basis: the other axle's slip along which each axle's curve is evaluated,
        on the grid: the mean alpha_r seen with alpha_f in each grid bin (front curve) and the
        mean alpha_f seen with alpha_r (rear curve), while learning; alpha itself where a
        bin has no data (steady cornering with equal tires: alpha_f = alpha_r)."""
        out = []
        for axle in range(2):
            n, total = self._path[axle, :, 0], self._path[axle, :, 1]
            out.append(np.where(n > 0, total / np.maximum(n, 1.0), self.grid))
        return out[0], out[1]

    # ---- the friction estimate ---------------------------------------------------------
    def friction(self) -> FrictionCurve:
        """mu(alpha) = mu~(alpha) + sum_i q^i M^i phi(alpha) on the fixed grid with its posterior
        std (Algorithm 1, line 12, and eq. (30): the mixture over particles of the MNIW
        posterior of A phi, E[Q] phi^T Sigma* phi within each particle plus the spread of the
        particle means; `band = "calibrated"`: each particle's data information Sigma divided by
        the sandwich's tau, plus the slip's variance at the learning samples times the squared
        slope, derivations, "F5. The friction estimate"). Tensor basis: mu_f(alpha_f, alpha_r)
        is a function of both slips; each axle's curve is taken along the visited path
        (`path()`), and along alpha_f = alpha_r = alpha where nothing was visited."""
        q = np.exp(self.logw)
        g = self.grid
        G = len(g)
        calibrated = self.cfg.band == "calibrated"
        tau = np.square(self._calib.factor_pair) if calibrated else np.ones(2)
        if self.d == 2:  # front row along (alpha, path_f(alpha)), rear row along (path_r(alpha), alpha)
            other_f, other_r = self.path()
            phi = np.concatenate([self.basis.features(g, other_f), self.basis.features(other_r, g)])  # (2G, size)
            mean2, cov2 = self.stats.function_moments(phi[None])  # (N, 2G, 2), (N, 2G, 2, 2)
            mean = np.stack([mean2[:, :G, 0], mean2[:, G:, 1]], axis=-1)
            var = np.stack([cov2[:, :G, 0, 0], cov2[:, G:, 1, 1]], axis=-1)
            if calibrated:
                var = self._calibrated_variance((phi[:G], phi[G:]), tau)
        else:
            phi = self.basis.phi(g)[None, None]  # (1, 1, G, m)
            mean, cov = self.stats.function_moments(phi)  # (N, 2, G, 1), (N, 2, G, 1, 1)
            mean, var = np.moveaxis(mean[..., 0], 1, 2), np.moveaxis(cov[..., 0, 0], 1, 2)
            if calibrated:
                var = self._calibrated_variance((phi[0, 0], phi[0, 0]), tau)
        mbar = np.einsum("n,ngk->gk", q, mean)
        vbar = np.einsum("n,ngk->gk", q, var + mean**2) - mbar**2
        pf, pr = self.prior(g, g)
        if calibrated:  # the slip each value was learned at is uncertain: its variance there times the squared slope
            slope = np.stack([np.gradient(pf + mbar[:, 0], g), np.gradient(pr + mbar[:, 1], g)], axis=1)
            vbar = vbar + slope**2 * self.slip_variance().T
        std = np.sqrt(np.maximum(vbar, 0.0))
        mu = np.stack([pf + mbar[:, 0], pr + mbar[:, 1]], axis=1)
        if calibrated and np.any(self.slips.lag):  # the held forces' slip error: the truth at alpha was learned at alpha + lag
            shift = self.lag_shift()
            for a in range(2):
                mu[:, a], std[:, a] = np.interp(g + shift[a], g, mu[:, a]), np.interp(g + shift[a], g, std[:, a])
        M, _ = self.stats.posterior()
        self._curve_slope(q, M)
        vis = tuple(float(v) if math.isfinite(v) else NAN for v in self.visited)
        return FrictionCurve(t=float(self.last_t), alpha=g.copy(), mu_f=mu[:, 0], mu_f_std=std[:, 0],
                             mu_r=mu[:, 1], mu_r_std=std[:, 1], visited=vis)

    def _calibrated_variance(self, phi_axles, tau) -> np.ndarray:
        """(N, G, 2): per particle and axle a the posterior variance of A phi given the
        measurements rather than the draws, (E[Q]_aa + r_a) phi^T (Sigma / tau_a + V)^-1 phi
        (eq. (30): r_a = 0, tau_a = 1; derivations, "F5. The friction estimate"): r_a =
        sigma_ay^2 c_a^2 / |c|^4 the a^Y noise along the measured direction c = (F^z_f, F^z_r)
        / m, which the drawn zeta carry only in the particles' spread that resampling removes,
        and tau_a the sandwich factor of the residuals' correlation. phi_axles: the features
        (G, m) along which each axle's curve is taken. Rank-one statistics: Sigma + V taken as
        the inverse of their P (their V is forgotten with the data: approximate)."""
        st = self.stats
        _, Lam = st.posterior()
        V = np.diag(st.V)
        K = st.K if self.cfg.stats == "exact" else np.linalg.inv(st.P)
        EQ = Lam / (np.asarray(st.nu) - self.d - 1.0)[..., None, None]
        c = self.Fz / self.vehicle.mass
        r = self.R[0] * c**2 / float(c @ c) ** 2
        out = []
        for a, (ph, ta) in enumerate(zip(phi_axles, tau)):
            if self.d == 2:
                Ka, Qa = K, EQ[:, a, a]
            else:
                Ka, Qa = K[:, a], EQ[:, a, 0, 0]
            Kt = (Ka - V) / ta + V if ta != 1.0 else Ka
            X = np.linalg.solve(Kt, np.broadcast_to(ph.T, Kt.shape[:-1] + ph.shape[:1]))  # (N, m, G)
            out.append(np.einsum("gj,njg->ng", ph, X) * (Qa + r[a])[:, None])
        return np.stack(out, axis=-1)

    def posterior(self) -> Posterior:
        M, Lam = self.stats.posterior()
        return Posterior(self.x.copy(), self.logw.copy(),
                         {"M": M, "Lam": Lam, "nu": np.asarray(self.stats.nu).copy(), "mu": self.mu.copy(),
                          "basis": self.cfg.basis, "bias": self.bias.copy()})


def _t1_logpdf(e, s, nu):
    """log of the univariate Student-t St(e; 0, s, nu) (scale s, variance nu s / (nu - 2))."""
    return (gammaln(0.5 * (nu + 1.0)) - gammaln(0.5 * nu) - 0.5 * np.log(nu * math.pi * s)
            - 0.5 * (nu + 1.0) * np.log1p(e * e / (nu * s)))
