"""Kalman filter + recursive least squares (RLS): the regression baseline of the stiffness
paper (Berntorp & Di Cairano, IEEE TCST 2018) Sec. VI-A, after Lundquist and Schon (2009): a Kalman filter for the
lateral dynamics feeds a forgetting-factor linear regression for the lateral axle stiffness.

1. Kalman filter: the linear single-track filter of `linear_kf` (state [vy, r], v^X given:
   in a co-simulation the true v^X, as in the paper, "we also use the true longitudinal
   velocity"), run at every sample with the current RLS estimate as its stiffness.
2. Regression (theta = [Cf_y, Cr_y], absolute N/rad): with the filtered vy, r at sample k,
   alpha_f = delta - (vy + lf r)/v, alpha_r = (lr r - vy)/v (v = max(vx, vx_min)), eq. (1b),
   (1c), (2) and (4) give two linear equations in theta,

     a^Y_meas / g_roll = [cos(delta) alpha_f, alpha_r] / m        theta + e1,
     r'                = [lf cos(delta) alpha_f, -lr alpha_r] / I  theta + e2,

   the measured lateral acceleration (g_roll = 1 + k g, the roll gain of docs/design.md) and the
   yaw acceleration built from the filtered yaw rates, r' = (r_k - r_{k-1}) / dt, whose
   regressor is the mean of the regressors at k-1 and k (r' is the mean slope over the
   interval). Weights W = diag(1/sigma_ay'^2, 1/sigma_yaw_acc^2) (sigma_ay' = sigma_ay /
   g_roll). A missing a^Y sample drops equation 1, a missing yaw-rate sample equation 2.
   With the IMU at (imu_x, imu_y) off the centre of gravity the accelerometer reads
   g_roll a^Y + imu_x r' - imu_y r^2 (`single_track.measurement`); r' is the second equation's
   regressor times theta, so equation 1 becomes (a^Y_meas + imu_y r^2) / g_roll =
   ([cos(delta) alpha_f, alpha_r] / m + imu_x / g_roll [lf cos(delta) alpha_f, -lr alpha_r] / I) theta.
3. Weighted RLS with forgetting lambda (`rls_update`): the minimiser of
   sum_j lambda^(k-j) |y_j - Phi_j theta|^2_W + lambda^k |theta - theta_0|^2_(P_0^-1),
     K = P Phi^T (lambda W^-1 + Phi P Phi^T)^-1, theta += K (y - Phi theta),
     P = (P - K Phi P) / lambda.
   Only while the MPF's learning gate is open (`baseline_common.gate_open`, with vy's std
   from the Kalman filter); closed, theta and P are frozen.
4. Parameter projection (Sec. V): after each update theta is clipped to
   [bound_low, bound_high] times the reference stiffness (defaults 0.2 and 3.0: from snow,
   about a fifth of dry-asphalt stiffness, to three times the reference); the paper notes
   the projection "proved valuable when implementing the linear estimators".

Reported: `Cf_y, Cr_y` = theta; `*_std` = sqrt(s2 P_ii), P scaled by the residual variance
estimate s2 = (sum_j lambda^(k-j) e_j^T W e_j) / (sum_j lambda^(k-j) m_j) (a priori
residuals e, m_j equations at j; 1 before any); `*_sigma` NaN (a regression has no model of
the per-step deviations); `Cx`, biases and ESS NaN (lateral regression, no IMU bias states:
an accelerometer or gyro bias enters the regression as an error). Deterministic: the rng
is unused; no particles (`--particles` is accepted and ignored).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate, Inputs, Measurement, Posterior
from tirefilter.estimators.baseline_common import (GateOptions, check_common, discretize_zoh, gate_open, held_ay,
                                                    small_solve, stiffness_prior)
from tirefilter.estimators.linear_kf import KFConfig, LinearKF
from tirefilter.vehicle import single_track
from tirefilter.vehicle.params import VehicleParams
from tirefilter.vehicle.single_track import GRAVITY

NAN = math.nan


@dataclass(frozen=True)
class RLSConfig(GateOptions):
    """Options of the KF + RLS baseline (the `[rls]` table of --config). Fields named as in
    MPFConfig mean the same and are taken from the scenario or log the same way."""

    model: str = "lateral"  # the lateral model only (v^X given)
    forgetting: float = 0.99  # lambda of the RLS (the scenario's, as the MPF's)
    init_center: tuple[float, ...] | None = None  # theta_0, absolute (default: the reference)
    init_distribution: str = "normal"  # sets P_0 = diag(std^2), std as baseline_common.stiffness_prior
    init_std: float = 0.3
    init_half_width: float = 0.1
    init_reference: tuple[float, ...] | None = None
    kf_stiffness: str = "estimate"  # "estimate" (the current RLS estimate) | "nominal" (the vehicle's)
    regressor_state: str = "predicted"  # "predicted" | "filtered": the KF state the slip angles use
    sigma_yaw_acc: float = 0.3  # rad/s^2, noise std of the yaw-acceleration equation
    q_vy: float = 0.25  # m^2/s^3, the Kalman filter's process noise (KFConfig)
    q_r: float = 0.02  # rad^2/s^3
    x0_mean: tuple[float, ...] | None = None  # [vy, r] (a 3-tuple's last two values)
    x0_std: tuple[float, ...] = (1.0, 0.5, 0.0175)  # its last two values: vy, r
    vx_min: float = 1.0  # m/s, speed floor of the slip angles
    sigma: tuple[float, float, float] = (0.05, 0.05, 0.0035)  # ax, ay, yaw-rate white noise

    def validated(self) -> "RLSConfig":
        def bad(key, problem):
            raise ConfigError("rls configuration", key, problem)

        if self.model != "lateral":
            bad("model", f"the rls baseline has the lateral model only, got {self.model!r}")
        check_common(self, bad)
        if self.kf_stiffness not in ("estimate", "nominal"):
            bad("kf_stiffness", f"expected estimate or nominal, got {self.kf_stiffness!r}")
        if self.regressor_state not in ("predicted", "filtered"):
            bad("regressor_state", f"expected predicted or filtered, got {self.regressor_state!r}")
        for key in ("sigma_yaw_acc", "vx_min"):
            if not (getattr(self, key) > 0 and math.isfinite(getattr(self, key))):
                bad(key, f"must be finite and > 0, got {getattr(self, key)!r}")
        for key in ("q_vy", "q_r"):
            if not (getattr(self, key) >= 0 and math.isfinite(getattr(self, key))):
                bad(key, f"must be finite and >= 0, got {getattr(self, key)!r}")
        if len(self.x0_std) < 2 or (self.x0_mean is not None and len(self.x0_mean) < 2):
            bad("x0_std", "needs at least the 2 values vy, r")
        return self


def rls_update(theta: np.ndarray, P: np.ndarray, Phi: np.ndarray, y: np.ndarray, w: np.ndarray, lam: float):
    """One weighted RLS step with forgetting lam (module docstring, 3.): Phi (m, p), y (m,),
    w (m,) the weights (inverse noise variances). Returns theta (p,), P (p, p) and the a
    priori residual e (m,)."""
    e = y - Phi @ theta
    PPt = P @ Phi.T
    S = lam * np.diag(1.0 / w) + Phi @ PPt
    K = small_solve(S, PPt.T).T  # P Phi^T S^-1 (S symmetric)
    theta = theta + K @ e
    P = (P - K @ PPt.T) / lam
    return theta, 0.5 * (P + P.T), e


class _KF(LinearKF):
    """`LinearKF` with the LAPACK-free discretisation of `baseline_common` (the same maths)."""

    _discretize = staticmethod(discretize_zoh)


class RLSEstimator:
    """Kalman filter for the lateral dynamics feeding a forgetting-factor RLS of (Cf_y, Cr_y)."""

    name = "rls"

    def __init__(self, vehicle: VehicleParams, config: RLSConfig = RLSConfig()):
        self.vehicle = vehicle
        self.cfg = cfg = config.validated()
        self.params = ("Cf_y", "Cr_y")
        self.C_nom = np.array([vehicle.Cf_y, vehicle.Cr_y], float)
        self.C_ref, self.theta0, std = stiffness_prior(cfg, self.C_nom, self.params, "rls configuration")
        self.P0 = np.diag(np.maximum(std, 1e-9 * self.C_ref) ** 2)
        self.lo, self.hi = cfg.bound_low * self.C_ref, cfg.bound_high * self.C_ref
        self.roll_gain = vehicle.imu_roll_gain(GRAVITY)
        x0 = tuple(cfg.x0_mean[-2:]) if cfg.x0_mean is not None else (0.0, 0.0)
        kf_C = self.theta0 if cfg.kf_stiffness == "estimate" else self.C_nom
        self.kf_config = KFConfig(Cf_y=float(kf_C[0]), Cr_y=float(kf_C[1]), q_vy=cfg.q_vy, q_r=cfg.q_r,
                                  sigma_ay=cfg.sigma[1], sigma_yaw_rate=cfg.sigma[2], x0_mean=x0,
                                  x0_std=tuple(cfg.x0_std[-2:]), vx_min=cfg.vx_min)
        self.w_eq = np.array([(self.roll_gain / cfg.sigma[1]) ** 2, 1.0 / cfg.sigma_yaw_acc**2])
        self.record = False  # keep every regression (Phi, y, w) in self.rows (tests)
        self.reset()

    def config_dict(self) -> dict:
        d = asdict(self.cfg)
        d.update(params=list(self.params), C_nominal=self.C_nom.tolist(), theta0=self.theta0.tolist(),
                 roll_gain=self.roll_gain)
        return d

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Back to theta_0, P_0 and the Kalman filter's prior. Deterministic: rng unused."""
        self.theta = self.theta0.copy()
        self.P = self.P0.copy()
        self.kf = _KF(self.vehicle, self.kf_config)
        self.s_res, self.n_res = 0.0, 0.0
        self.t_prev = None
        self.t_start = None
        self.ay_last = math.nan  # the last finite a^Y of the linear-region test (`held_ay`)
        self.r_prev = None
        self.phi2_prev = None
        self.active = False
        self.rows = []

    def _phi2(self, vx, delta, vy, r):
        """The regressors of the two equations at (vx, delta, vy, r): (2,) each."""
        v = self.vehicle
        af, ar = single_track.small_slip_angles(vx, vy, r, delta, v.lf, v.lr, self.cfg.vx_min)
        cf = math.cos(delta) * af
        return np.array([cf, ar]) / v.mass, np.array([v.lf * cf, -v.lr * ar]) / v.yaw_inertia, af, ar

    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        cfg = self.cfg
        if cfg.kf_stiffness == "estimate":  # the KF runs on the current estimate, else on the nominal values
            self.kf.Cf, self.kf.Cr = float(self.theta[0]), float(self.theta[1])
        est, (vy, r) = self._kf_step(t, u, y)
        vx, delta = self.kf.u_prev
        phi1, phi2, af, ar = self._phi2(vx, delta, vy, r)
        rows, ys, ws = [], [], []
        if math.isfinite(y.ay):
            ix, iy = self.vehicle.imu_x, self.vehicle.imu_y
            if ix != 0.0 or iy != 0.0:  # the IMU's lever arm: y.ay = g a^Y + imu_x r' - imu_y r^2 (r' = phi2 C)
                rows.append(phi1 + (ix / self.roll_gain) * phi2), ys.append((y.ay + iy * r * r) / self.roll_gain)
            else:
                rows.append(phi1), ys.append(y.ay / self.roll_gain)
            ws.append(self.w_eq[0])
        if self.t_prev is not None and math.isfinite(y.yaw_rate) and self.r_prev is not None:
            rows.append(0.5 * (phi2 + self.phi2_prev)), ys.append((r - self.r_prev) / (t - self.t_prev))
            ws.append(self.w_eq[1])
        if self.t_start is None:
            self.t_start = t
        vy_std = math.sqrt(max(self.kf.P[0, 0], 0.0))
        ay_gate = self.ay_last = held_ay(y.ay, self.ay_last)
        self.active = gate_open(cfg, t=t, t_start=self.t_start, vx=vx, delta=delta, ay_meas=ay_gate,
                                alpha=max(abs(af), abs(ar)), vy_std=vy_std)
        if self.active and rows:
            Phi, yv, wv = np.array(rows), np.array(ys), np.array(ws)
            if self.record:
                self.rows.append((Phi, yv, wv))
            self.theta, self.P, e = rls_update(self.theta, self.P, Phi, yv, wv, cfg.forgetting)
            self.theta = np.clip(self.theta, self.lo, self.hi)  # parameter projection (Sec. V)
            self.s_res = cfg.forgetting * self.s_res + float(e @ (wv * e))
            self.n_res = cfg.forgetting * self.n_res + len(yv)
        self.t_prev = t
        if math.isfinite(y.yaw_rate):
            self.r_prev, self.phi2_prev = r, phi2
        return self._estimate(est)

    def _kf_step(self, t, u, y):
        """The Kalman filter's step (`LinearKF.step`: checks of t and vx, a missing steer or
        vx sample held), returning its estimate and the state the regressors use: the
        predicted one (`regressor_state = "predicted"`, before this sample's update) or the
        filtered one."""
        kf = self.kf
        if self.cfg.regressor_state == "filtered":
            est = kf.step(t, u, y)
            return est, tuple(kf.x)
        captured = []
        update = kf.update

        def capture(vx, delta, yv):
            captured.append(tuple(kf.x))
            update(vx, delta, yv)

        kf.update = capture
        try:
            est = kf.step(t, u, y)
        finally:
            del kf.update
        return est, captured[0]

    def residual_variance(self) -> float:
        """s2: the forgetting-weighted mean of the whitened squared residuals (1 before any)."""
        return self.s_res / self.n_res if self.n_res > 0 else 1.0

    def _estimate(self, kf_est: Estimate) -> Estimate:
        std = np.sqrt(np.maximum(np.diagonal(self.P), 0.0) * self.residual_variance())
        return Estimate(
            active=self.active, vx=kf_est.vx, vy=kf_est.vy, yaw_rate=kf_est.yaw_rate,
            Cf_y=float(self.theta[0]), Cr_y=float(self.theta[1]), Cx=NAN,
            Cf_y_std=float(std[0]), Cr_y_std=float(std[1]), Cx_std=NAN,
            Cf_y_sigma=NAN, Cr_y_sigma=NAN, Cx_sigma=NAN,
            b_ax=NAN, b_ay=NAN, b_yaw_rate=NAN, ess=NAN, state_std=kf_est.state_std,
        )

    def posterior(self) -> Posterior:
        """The Gaussian state posterior as one 'particle' with log-weight 0; stats: its
        covariance `cov` (1, 2, 2), the RLS estimate `theta` (2,) and covariance `theta_cov`
        (2, 2, scaled by the residual variance)."""
        return Posterior(self.kf.x[None].copy(), np.zeros(1),
                         {"cov": self.kf.P[None].copy(), "theta": self.theta.copy(),
                          "theta_cov": self.P * self.residual_variance(), "params": self.params})
