"""Linear single-track Kalman filter with fixed axle cornering stiffness: the baseline that
the stiffness MPF has to beat (sideslip RMSE on a real recording).

Model: the lateral model of the stiffness MPF (`StiffnessMPF._accelerations` with
`model="lateral"`, the stiffness paper's eq. (1b)-(1c), (2), (4) with small angles), state x = [vy, r],
inputs delta (road-wheel steer) and vx (from other logic), fixed stiffness Cf, Cr:

    alpha_f = delta - (vy + lf r) / v,   alpha_r = (lr r - vy) / v,   v = max(vx, vx_min)
    a^Y = (Cf alpha_f cos(delta) + Cr alpha_r) / m
    vy' = -vx r + a^Y + w_vy,            r' = (lf Cf alpha_f cos(delta) - lr Cr alpha_r) / I + w_r
    y = [(1 + k g) a^Y, r] + e           (k = roll_gradient: the IMU's lateral axis sees the
                                          roll, docs/design.md; e ~ N(0, diag(sigma_ay^2, sigma_r^2)))

With the IMU at (imu_x, imu_y) off the centre of gravity its a^Y reads imu_x r' - imu_y r^2 more
(`single_track.measurement`): r' is affine in x; r^2 enters linearised at the prior's yaw rate r0,
r^2 ~ 2 r0 r - r0^2 (an extended Kalman update of that one term; exact with imu_y = 0).

The speed floor v = max(vx, vx_min) applies to the slip formulas only (as in the MPF); the
kinematic term -vx r uses vx itself. For given (vx, delta) the model is affine in x:

    x' = A x + b + w,   y = C x + d + e,   w white with intensity Qc = diag(q_vy, q_r)

(`lateral_model`; b and d carry the steer term Cf cos(delta) delta). Between samples the
inputs of the earlier sample are held (zero-order hold), so over dt = t_k - t_{k-1} the
exact discretisation is (`discretize_zoh`, Van Loan 1978)

    x_k = Ad x_{k-1} + bd + w_k,   Ad = e^{A dt},   bd = int_0^dt e^{A s} ds b,
    w_k ~ N(0, Qd),   Qd = int_0^dt e^{A s} Qc e^{A^T s} ds.

With F = [[A, b], [0, 0]] (3x3) and Qf = blkdiag(Qc, 0), one matrix exponential gives all
three: expm(dt [[-F, Qf], [0, F^T]]) = [[G11, G12], [0, G22]] with e^{F dt} = G22^T =
[[Ad, bd], [0, 1]] and int_0^dt e^{F s} Qf e^{F^T s} ds = e^{F dt} G12, whose upper-left
2x2 block is Qd (the last row of e^{F s} is [0, 0, 1] and Qf has no third row), i.e.
Qd = Ad G12[:2, :2] (G12's third row is zero for the same reason).

The filter is the textbook Kalman filter on that model: the prior N(x0_mean, diag(x0_std^2))
holds at the first sample time; each later sample predicts with the previous sample's inputs
and then updates with the measurement components that are finite (a missing component is
left out of that update; with none, there is no update). A non-finite steer angle or vx
holds the last finite one, as the MPF and the EKF do: the steer angle is 0 before any, and
a vx missing before any finite one is an error (the lateral model needs it).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.linalg import expm

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate, Inputs, Measurement, Posterior
from tirefilter.estimators.sensors import FALLBACK_SIGMA
from tirefilter.vehicle.params import VehicleParams
from tirefilter.vehicle.single_track import GRAVITY

NAN = math.nan


@dataclass(frozen=True)
class KFConfig:
    """Options of the linear Kalman filter (settable from a `[kf]` table of --config).

    Process noise: white accelerations standing for the forces the linear fixed-stiffness
    model leaves out (stiffness error, road bank, roll and load transfer, tire saturation).
    Those are coloured, not white; a coloured acceleration error of std s and correlation
    time tau drives a velocity error like white noise of intensity q = 2 s^2 tau. The
    defaults take s = 0.5 m/s^2 on a^Y (a 20% stiffness error at 1 deg of slip on a mid-size
    car, ~0.4 m/s^2, plus a 2% bank, ~0.2 m/s^2) and s = 0.15 rad/s^2 on r' (the same force
    error times the axle arm over the yaw inertia), with tau = 0.5 s (the time scale of
    steering manoeuvres): q_vy = 0.25 m^2/s^3 and q_r = 0.02 rad^2/s^3. Over one 10 ms step
    that is a vy spread of sqrt(q_vy dt) = 0.05 m/s.
    """

    Cf_y: float | None = None  # N/rad, front axle cornering stiffness (None: the vehicle's)
    Cr_y: float | None = None  # N/rad, rear axle (None: the vehicle's)
    q_vy: float = 0.25  # m^2/s^3 ((m/s^2)^2 per Hz), white-noise intensity on vy'
    q_r: float = 0.02  # rad^2/s^3 ((rad/s^2)^2 per Hz), white-noise intensity on r'
    sigma_ay: float | None = None  # m/s^2, accelerometer noise std (None: the vehicle's)
    sigma_yaw_rate: float | None = None  # rad/s, gyro noise std (None: the vehicle's)
    x0_mean: tuple[float, float] = (0.0, 0.0)  # m/s, rad/s: prior mean of [vy, r]
    x0_std: tuple[float, float] = (0.5, 0.0175)  # m/s, rad/s: prior std (as the MPF's lateral model)
    vx_min: float = 1.0  # m/s, speed floor of the slip-angle formulas

    def __post_init__(self):
        self.validated()

    def validated(self) -> "KFConfig":
        def bad(key, problem):
            raise ConfigError("kf configuration", key, problem)

        def number(key, value):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                bad(key, f"must be a number, got {value!r}")
            return float(value)

        for key in ("Cf_y", "Cr_y", "sigma_ay", "sigma_yaw_rate"):
            value = getattr(self, key)
            if value is not None and not number(key, value) > 0:
                bad(key, f"must be > 0 (or unset for the vehicle's value), got {value!r}")
        for key in ("q_vy", "q_r"):
            value = number(key, getattr(self, key))
            if not (value >= 0 and math.isfinite(value)):
                bad(key, f"process-noise intensity must be finite and >= 0, got {getattr(self, key)!r}")
        if not (number("vx_min", self.vx_min) > 0 and math.isfinite(self.vx_min)):
            bad("vx_min", f"speed floor must be finite and > 0, got {self.vx_min!r}")
        for key in ("x0_mean", "x0_std"):
            value = getattr(self, key)
            if not isinstance(value, (tuple, list)) or len(value) != 2:
                bad(key, f"needs 2 values (vy, yaw_rate), got {value!r}")
            vals = [number(key, v) for v in value]
            if not all(math.isfinite(v) for v in vals):
                bad(key, f"values must be finite, got {value!r}")
            if key == "x0_std" and min(vals) < 0:
                bad(key, f"std values must be >= 0, got {value!r}")
        return self


def lateral_model(vx: float, delta: float, Cf: float, Cr: float, vehicle: VehicleParams,
                  roll_gain: float = 1.0, vx_min: float = 1.0, r0: float = 0.0):
    """The affine lateral single-track model at given (vx, delta): x' = A x + b,
    y = C x + d for x = [vy, r], y = [measured a^Y, r] (module docstring; the IMU's lever arm's
    r^2 linearised at r0).

    Returns A (2, 2), b (2,), C (2, 2), d (2,)."""
    m, I, lf, lr = vehicle.mass, vehicle.yaw_inertia, vehicle.lf, vehicle.lr
    v = max(vx, vx_min)  # floor of the slip formulas
    cf = Cf * math.cos(delta)  # front force per unit slip, projected on the body y axis
    # d(a^Y)/d[vy, r] and d(r')/d[vy, r] from alpha_f = delta - (vy + lf r)/v, alpha_r = (lr r - vy)/v
    ay_row = np.array([-(cf + Cr) / (m * v), (lr * Cr - lf * cf) / (m * v)])
    rdot_row = np.array([(lr * Cr - lf * cf) / (I * v), -(lf * lf * cf + lr * lr * Cr) / (I * v)])
    A = np.array([ay_row + (0.0, -vx), rdot_row])  # vy' = -vx r + a^Y (eq. (1b)), r' (eq. (1c))
    b = np.array([cf * delta / m, lf * cf * delta / I])  # the steer term of alpha_f
    C = np.array([roll_gain * ay_row, (0.0, 1.0)])
    d = np.array([roll_gain * b[0], 0.0])
    ix, iy = vehicle.imu_x, vehicle.imu_y
    if ix != 0.0 or iy != 0.0:  # the lever arm: + imu_x r' - imu_y (2 r0 r - r0^2)
        C[0] += ix * rdot_row - (0.0, 2.0 * iy * r0)
        d[0] += ix * b[1] + iy * r0 * r0
    return A, b, C, d


def discretize_zoh(A: np.ndarray, b: np.ndarray, Qc: np.ndarray, dt: float, expm=expm):
    """Exact discretisation over dt of x' = A x + b + w (b held, w white with intensity
    Qc): Ad = e^{A dt}, bd = int_0^dt e^{A s} ds b, Qd = int_0^dt e^{A s} Qc e^{A^T s} ds,
    from one matrix exponential of Van Loan's block matrix built on the augmented
    F = [[A, b], [0, 0]] (module docstring).

    A (n, n), b (n,), Qc (n, n); returns Ad (n, n), bd (n,), Qd (n, n). `expm` is the
    matrix exponential (scipy's; the baselines pass `baseline_common.expm_small`)."""
    n = A.shape[0]
    M = np.zeros((2 * n + 2, 2 * n + 2))  # dt [[-F, Qf], [0, F^T]], F = [[A, b], [0, 0]]
    M[:n, :n] = -dt * A
    M[:n, n] = -dt * b
    M[:n, n + 1 : 2 * n + 1] = dt * Qc
    M[n + 1 : 2 * n + 1, n + 1 : 2 * n + 1] = dt * A.T
    M[2 * n + 1, n + 1 : 2 * n + 1] = dt * b
    G = expm(M)
    Phi = G[n + 1 :, n + 1 :].T  # e^{F dt} = [[Ad, bd], [0, 1]]
    Ad, bd = Phi[:n, :n], Phi[:n, n]
    Qd = Ad @ G[:n, n + 1 : 2 * n + 1]
    return Ad, bd, 0.5 * (Qd + Qd.T)


class LinearKF:
    """Kalman filter of the linear single-track model with fixed axle stiffness."""

    name = "kf"
    _discretize = staticmethod(discretize_zoh)  # exact ZOH discretisation; rls swaps in a LAPACK-free expm

    def __init__(self, vehicle: VehicleParams, config: KFConfig = KFConfig()):
        self.vehicle = vehicle
        self.cfg = cfg = config.validated()
        self.Cf = float(cfg.Cf_y if cfg.Cf_y is not None else vehicle.Cf_y)
        self.Cr = float(cfg.Cr_y if cfg.Cr_y is not None else vehicle.Cr_y)
        # the configured noise, else the vehicle's, else the fallback of `sensors` (a replay
        # passes the figures estimated from the log)
        sig = tuple(c if c is not None else (v if v is not None else f) for c, v, f in zip(
            (cfg.sigma_ay, cfg.sigma_yaw_rate), (vehicle.sigma_ay, vehicle.sigma_yaw_rate), FALLBACK_SIGMA[1:]))
        for key, s in zip(("sigma_ay", "sigma_yaw_rate"), sig):
            if not s > 0:
                raise ConfigError("kf configuration", key,
                                  f"measurement noise must be > 0; the vehicle's is {s!r}, set it here")
        sig = tuple(map(float, sig))
        self.sigma = sig
        self.R = np.diag(np.square(sig))
        self.Qc = np.diag([cfg.q_vy, cfg.q_r])
        self.roll_gain = vehicle.imu_roll_gain(GRAVITY)  # measured a^Y ~ (1 + k g) a^Y
        self.reset()

    def config_dict(self) -> dict:
        d = asdict(self.cfg)
        d.update(model="lateral", Cf_y=self.Cf, Cr_y=self.Cr, sigma_ay=self.sigma[0],
                 sigma_yaw_rate=self.sigma[1], roll_gain=self.roll_gain)
        return d

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Back to the prior. The filter is deterministic: rng is accepted and unused."""
        self.x = np.array(self.cfg.x0_mean, float)
        self.P = np.diag(np.square(np.asarray(self.cfg.x0_std, float)))
        self.t_prev = None
        self.u_prev = None  # (vx, delta) of the previous sample, held over the step
        self.delta_last = 0.0

    def _model(self, vx: float, delta: float, r0: float = 0.0):
        return lateral_model(vx, delta, self.Cf, self.Cr, self.vehicle, self.roll_gain, self.cfg.vx_min, r0)

    def predict(self, vx: float, delta: float, dt: float) -> None:
        """Time update over dt with (vx, delta) held: x <- Ad x + bd, P <- Ad P Ad^T + Qd."""
        A, b, _, _ = self._model(vx, delta)
        Ad, bd, Qd = self._discretize(A, b, self.Qc, dt)
        self.x = Ad @ self.x + bd
        P = Ad @ self.P @ Ad.T + Qd
        self.P = 0.5 * (P + P.T)

    def update(self, vx: float, delta: float, y: np.ndarray) -> None:
        """Measurement update with the finite components of y = [a^Y, r] (2,). R is
        diagonal, so the components are taken one scalar row at a time, which equals the
        joint update: k = P c^T / s, s = c P c^T + R_ii, P <- P - s k k^T (kept symmetric)."""
        avail = [i for i in range(2) if math.isfinite(y[i])]
        if not avail:
            return
        _, _, C, d = self._model(vx, delta, float(self.x[1]))
        x, P = self.x, self.P
        for i in avail:
            c, r = C[i], self.R[i, i]
            Pc = P @ c
            k = Pc / (c @ Pc + r)
            x = x + k * (y[i] - c @ x - d[i])
            P = P - np.outer(k, Pc)  # s k k^T = k (P c^T)^T
        self.x, self.P = x, 0.5 * (P + P.T)

    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        t = float(t)
        if not math.isfinite(t):
            raise ConfigError("inputs", "t", f"time must be finite, got {t!r}")
        vx = float(u.vx)
        if not math.isfinite(vx):  # a missing vx sample holds the last one (u_prev's is finite)
            if self.u_prev is None:
                raise ConfigError("inputs", "vx", f"the lateral model needs vx; none given up to t = {t} s")
            vx = self.u_prev[0]
        if math.isfinite(u.delta):
            self.delta_last = float(u.delta)
        delta = self.delta_last  # a missing steer sample holds the last one
        if self.t_prev is not None:
            dt = t - self.t_prev
            if not dt > 0:
                raise ConfigError("inputs", "t", f"time must increase: t = {t} s after {self.t_prev} s")
            self.predict(*self.u_prev, dt)
        self.update(vx, delta, np.array([y.ay, y.yaw_rate], float))
        self.t_prev, self.u_prev = t, (vx, delta)
        return self._estimate(vx)

    def _estimate(self, vx: float) -> Estimate:
        std = np.sqrt(np.maximum(np.diagonal(self.P), 0.0))
        return Estimate(
            active=False, vx=vx, vy=float(self.x[0]), yaw_rate=float(self.x[1]),
            Cf_y=self.Cf, Cr_y=self.Cr, Cx=NAN,
            Cf_y_std=0.0, Cr_y_std=0.0, Cx_std=NAN,
            Cf_y_sigma=0.0, Cr_y_sigma=0.0, Cx_sigma=NAN,
            b_ax=NAN, b_ay=NAN, b_yaw_rate=NAN, ess=NAN,
            state_std=(0.0, float(std[0]), float(std[1])),
        )

    def posterior(self) -> Posterior:
        """The Gaussian posterior as one 'particle' (its mean) with log-weight 0 and its
        covariance in stats["cov"] (1, 2, 2)."""
        return Posterior(self.x[None].copy(), np.zeros(1), {"cov": self.P[None].copy()})
