"""The stiffness MPF's adaptive parts (a mixin of `StiffnessMPF`, on its attributes): the
adaptive forgetting and its surprise statistics (derivations, "Adaptive forgetting"), the
state noise from the data, the calibration of the std
of the lateral stiffness (batch-means sandwich), and the undriven axle's share of the learned
Cx (derivations, "The undriven axle")."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from tirefilter.estimators.base import Estimate
from tirefilter.stats.linalg import chol, solve_lower
from tirefilter.vehicle import single_track

NAN = math.nan
LOAD_GAIN_MIN = 0.3  # the floor of the load-transfer gain 1 - kappa a^Y^2 (`StiffnessMPF._load_gains`, `_load_band`)
# adaptive forgetting (derivations, "Adaptive forgetting"): lambda_k within [FORGETTING_MIN, FORGETTING_MAX]
FORGETTING_MIN = 0.97  # a memory of 0.33 s at 100 Hz after a surface change
FORGETTING_MAX = 0.999  # a memory of 10 s at 100 Hz on a drive that fits
SURPRISE_TIME = 0.15  # s, smoothing of z_k: a step change shows within a tenth of a second
DRIFT_TIME = 1.0  # s, smoothing of z'_k (the lean of the sampled w): a stale mean leans for seconds
# s: a driven-axle slip level held longer than this is confounded with the a^X bias and v^X errors; only its
# changes within it count as excitation of Cx (derivations, "The undriven axle")
CX_EXCITATION_TIME = 1.0


class Adaptation:
    """Forgetting, state noise, calibration and the undriven axle's Cx share of `StiffnessMPF`."""

    # ---- the a^Y residual of the calibration, adaptive forgetting ---------------------------
    def _predict_ay(self, yk: np.ndarray, a: np.ndarray, e: np.ndarray, logw: np.ndarray | None = None) -> None:
        """`_e_ay`, the a^Y residual of `_calibrate` ("Batch-means sandwich"): the residuals e (N, |a|) of
        the weighting averaged with the predictive weights (`logw`, default the particles' before this
        sample's likelihood). Left NaN when the sample is missing or without the calibration."""
        if self._calib is None:
            return
        q = [j for j in range(len(a)) if self.channels[a[j]] == 1]
        if q:
            lw = self.logw if logw is None else logw
            self._e_ay = float(np.exp(lw) @ e[:, q[0]])

    def _adapt_forgetting(self, v: np.ndarray, nu: np.ndarray, dt: float) -> None:
        """The forgetting factor of the next propagation from how well the accelerometers
        fit the predictive (derivations, "Adaptive forgetting"). `v` (N, nc) are the whitened residuals of
        the weighting, Student-t with nu (N,) dof: E[v^T v] = nc nu / (nu - 2). Their
        normalised square, averaged with the predictive weights (before this sample's
        likelihood), is smoothed over `SURPRISE_TIME` into z_k; lambda_k = 1 - (1 - lambda) z_k,
        clipped: z = 1 gives the configured lambda, a surface change (z >> 1) forgets fast,
        a drive that fits better than its noise figures (z < 1) forgets slowly."""
        cfg = self.cfg
        if cfg.forgetting_mode == "fixed":
            return
        nis = np.sum(v * v, axis=1) * (nu - 2.0) / (nu * v.shape[1])
        s_k = float(np.exp(self.logw) @ nis)
        if math.isfinite(s_k):
            self._smooth_surprise(s_k, dt)

    def _smooth_surprise(self, s_k: float, dt: float) -> None:
        """z_k: s_k smoothed over `SURPRISE_TIME`; lambda_k = 1 - (1 - lambda) z_k, clipped."""
        self.surprise += -math.expm1(-dt / SURPRISE_TIME) * (s_k - self.surprise)
        self.lam = min(max(1.0 - (1.0 - self.cfg.forgetting) * self.surprise, FORGETTING_MIN), FORGETTING_MAX)

    def _cap_forgetting(self, z: float) -> None:
        """lambda_k no larger than 1 - (1 - lambda) z (the drift statistic z, `_track_drift`)."""
        cfg = self.cfg
        self.lam = min(self.lam, max(1.0 - (1.0 - cfg.forgetting) * z, FORGETTING_MIN))

    def _track_drift(self, dw: np.ndarray, L11: np.ndarray, dt: float) -> None:
        """The second surprise statistic of the adaptive forgetting (derivations, "Adaptive forgetting"):
        w_k - mu_{k|k-1} (N, n_w), whitened by the predictive scale L11 (N, n_w, n_w), has
        mean zero while the statistics' mean is right, whatever the deviation spread; a
        stale mean makes it lean one way sample after sample. Its weighted mean over the
        particles is smoothed into `drift` (n_w,), whose square, scaled by (2 - a) / a for
        the smoothing a = 1 - exp(-dt / DRIFT_TIME), is about 1 per component under the
        model (the per-sample whitened values have unit variance up to nu / (nu - 2))."""
        cfg = self.cfg
        if cfg.forgetting_mode == "fixed":
            return
        u = solve_lower(chol(L11), dw)
        ubar = np.exp(self.logw) @ u
        if not np.all(np.isfinite(ubar)):
            return
        a = -math.expm1(-dt / DRIFT_TIME)
        self.drift = self.drift + a * (ubar - self.drift)
        self._cap_forgetting(float(self.drift @ self.drift) * (2.0 - a) / (a * len(ubar)))

    # ---- state noise from the data ---------------------------------------------------------
    def state_noise_estimated(self) -> dict | None:
        """The state's process noise as estimated from the data so far (`state_noise_from_data`,
        derivations, "State noise from the data"), std per sqrt(s) by state component; None when it is not estimated."""
        if not self.cfg.state_noise_from_data or not hasattr(self, "q_state"):
            return None
        names = ("vx", "vy", "yaw_rate") if self.full else ("vy", "yaw_rate")
        return {n: math.sqrt(float(q)) for n, q in zip(names, self.q_state)}

    def _match_state_noise(self, logw_pred: np.ndarray, dt: float, scale: np.ndarray | None = None) -> None:
        """`state_noise_from_data` (derivations, "State noise from the data"): with the predictive weights logw_pred and
        the weights after this sample's likelihood, both over the propagated particles x, the
        correction of the state's mean d = m+ - m- and the spreads P-, P+ per component give
        g = (d^2 - (P- - P+)) / dt + q, q the intensity applied in this propagation: the intensity
        under which the corrections have the size the removed spread says (E[d^2] = P- - P+ for a
        consistent filter). g is smoothed over `state_noise_time` into q_state (>= 0). `scale`: q as the std
        over dt (`_state_noise_scale(dt)`) where the caller has it; the compiled step's sums run in
        `kernels.match_state_noise`."""
        if scale is None:
            scale = self._state_noise_scale(dt)
        a = -math.expm1(-dt / self.cfg.state_noise_time)
        if self._nb is not None:
            if not (self.q_state.flags.writeable and self.q_state.dtype == np.float64):  # (the kernel writes into it)
                self.q_state = np.array(self.q_state, float)
            self._nb.match_state_noise(logw_pred, self.logw, self.x, scale, dt, a, self.q_state)
            return
        x = self.x
        q0, q1 = np.exp(logw_pred), np.exp(self.logw)
        q0, q1 = q0 / q0.sum(), q1 / q1.sum()
        m0, m1 = q0 @ x, q1 @ x
        p0, p1 = q0 @ (x - m0) ** 2, q1 @ (x - m1) ** 2
        applied = np.square(scale) / dt
        g = ((m1 - m0) ** 2 - (p0 - p1)) / dt + applied
        if np.all(np.isfinite(g)):
            self.q_state = np.maximum(self.q_state + a * (g - self.q_state), 0.0)

    def _state_noise_scale(self, dt: float) -> np.ndarray:
        """Std of the additive state noise over a step dt (nx,): the larger of `state_noise` and, with
        `state_noise_from_data`, the intensity estimated from the data (`q_state`), times sqrt(dt)."""
        q = self.state_noise.tolist()  # (on Python floats: a few numpy calls on 3 values cost more, bit for bit the same)
        if self.cfg.state_noise_from_data:
            q = [math.sqrt(max(a * a, b)) for a, b in zip(q, self.q_state.tolist())]
        root = math.sqrt(dt)
        return np.array([root * v for v in q])

    # ---- calibration of the std of the lateral stiffness (batch-means sandwich) ------------
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
            self._track_load_level(float(d[0]), ar)
        f = cal.factor
        if self.k_load is not None:  # kappa's share of the band ("Load transfer", the band)
            e0, e1 = self._load_band(est.Cf_y, est.Cr_y)
            return replace(est, Cf_y_std=math.hypot(est.Cf_y_std * float(f[0]), e0),
                           Cr_y_std=math.hypot(est.Cr_y_std * float(f[1]), e1))
        if f[0] == 1.0 and f[1] == 1.0:
            return est
        return replace(est, Cf_y_std=est.Cf_y_std * float(f[0]), Cr_y_std=est.Cr_y_std * float(f[1]))

    def _track_load_level(self, d0: float, d1: float) -> None:
        """With the load sensitivity: the information-weighted a^Y^2 of the statistics' memory per axle,
        m = sum lambda^.. d^2 a^2 / sum lambda^.. d^2 (d the axle's slip regressor of the sandwich, a^Y the
        step's over the mean roll gain), forgotten as the sandwich is."""
        if self.k_load is None:
            return
        k = self._roll_moments()[0]
        a2 = (self._ay_step / (self.roll_gain if k != k else 1.0 + k * single_track.GRAVITY)) ** 2
        lam = self._lam_step ** self._calib_power
        s = self._load_level
        w0, w1 = d0 * d0, d1 * d1
        s[:] = (lam * s[0] + w0 * a2, lam * s[1] + w0, lam * s[2] + w1 * a2, lam * s[3] + w1)

    def _load_band(self, Cf: float, Cr: float) -> tuple[float, float]:
        """kappa's share of the std of the stiffness at a^Y = 0: the data fix C_0 (1 - kappa m) (m the
        information-weighted a^Y^2, `_track_load_level`), so C_0 moves by C_0 m / (1 - kappa m) per unit of
        kappa; times kappa's posterior std over the particles (derivations, "Load transfer")."""
        k, k_std = self._load_moments()
        s = self._load_level
        out = []
        for C, num, den in ((Cf, s[0], s[1]), (Cr, s[2], s[3])):
            m = num / den if den > 0 else 0.0
            out.append(abs(C) * m * k_std / max(1.0 - k * m, LOAD_GAIN_MIN))
        return out[0], out[1]

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
            self._track_load_level(d0, ar)
        return cal.factor_pair

    # ---- the undriven axle's share of the learned Cx (undriven_stiffness = "learned") ------
    def _reset_cx_excitation(self) -> None:
        """No excitation of Cx yet: information 0, weight 0 (with "learned" the undriven axle at
        its nominal stiffness), the slip level unknown."""
        self.cx_info = 0.0  # I_k, information on dC_x from the changes of the driven axle's slip, 1/N^2
        self.cx_weight = 0.0  # rho_k = cx_excitation_weight(I_k, prior variance)
        self._slip_level = NAN  # the slip smoothed over CX_EXCITATION_TIME
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
        `CX_EXCITATION_TIME` T (a level held longer is confounded with the a^X bias and v^X
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
        self._slip_level += -math.expm1(-dt / CX_EXCITATION_TIME) * (slip - self._slip_level)
        if self.active:
            b = (slip - self._slip_level) / self.vehicle.mass
            self.cx_info = self._lam_step * self.cx_info + b * b / self.R[0, 0]
        self.cx_weight = cx_excitation_weight(self.cx_info, self._cx_p0)
        self.cx_weight_max = max(self.cx_weight_max, self.cx_weight)
        self._set_undriven_share()


def cx_excitation_weight(info: float, prior_var: float) -> float:
    """rho = 1 - P / P_0 for the posterior variance P = 1 / (1 / P_0 + info) of a scalar
    linear-Gaussian parameter with prior variance P_0 and data information `info` (derivations
    "The undriven axle"), written I P_0 / (1 + I P_0): 0 without information or with a certain prior."""
    if not (info >= 0 and prior_var >= 0):
        raise ValueError(f"information and prior variance must be >= 0, got {info!r}, {prior_var!r}")
    ip = info * prior_var
    return ip / (1.0 + ip) if math.isfinite(ip) else 1.0
