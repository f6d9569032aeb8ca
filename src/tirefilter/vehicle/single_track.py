"""The single-track (bicycle) model, batch-first: the truth's and the estimators'.

The truth (`derivatives`, `rk4_step`): the same equations as the vehicle FMU
(vehicle_fmu/c/vehicle_model.c) with wheel spin and load transfer, written independently in
numpy; tests integrate both and compare. State (..., 9): [vx, vy, yaw_rate, omega_f, omega_r, x,
y, psi, a_lt] (a_lt: the lagged longitudinal acceleration that sets the load transfer).

The estimators' model (`accelerations`, `state_derivative`, `propagate`, `slip_over_step`,
`measurement`): eq. (1)-(4), (7), (9) and (12) of the stiffness paper with linear tires whose
stiffness is nominal plus the deviations w, the accelerations split as a(x, u) + B(x, u) w.
State x (N, 3) = [vx, vy, r] (full model) or (N, 2) = [vy, r] (lateral model, vx an input);
inputs u (4,) = [delta, omega_f, omega_r, vx]; w (N, n_w) = [dC_x, dCf_y, dCr_y] (full) or
[dCf_y, dCr_y] (lateral); params p (13,) packed by `model_params` (the compiled twin,
`single_track_numba`, reads the same array). Particles lie on the leading axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from tirefilter.vehicle.params import PacejkaParams, VehicleParams
from tirefilter.vehicle.tires import linear_forces, pacejka_forces

GRAVITY = 9.80665
WHEEL_OMEGA_EPS = 0.5  # rad/s, smoothing of the brake-torque sign
STATE_NAMES = ("vx", "vy", "yaw_rate", "omega_f", "omega_r", "x", "y", "psi", "a_lt")
VX, VY, R, WF, WR, PX, PY, PSI, ALT = range(9)


@dataclass(frozen=True)
class TruthModel:
    """Everything the simulated truth needs beyond the inputs: vehicle, tires, sensors."""

    vehicle: VehicleParams
    tire_model: str = "linear"  # "linear" | "pacejka"
    pacejka: PacejkaParams | None = None
    load_transfer_time_constant: float = 0.1  # s

    def axle_stiffness(self):
        """Linear-model axle stiffness (Cf_y, Cr_y, Cf_x, Cr_x) at surface 1: the vehicle's
        Cx on the driven axle (front for all-wheel drive), Cx_undriven on the other."""
        v = self.vehicle
        return (v.Cf_y, v.Cr_y) + longitudinal_stiffness(v)


def longitudinal_stiffness(vehicle: VehicleParams) -> tuple[float, float]:
    """Nominal longitudinal axle stiffness (front, rear), N: the vehicle's Cx on the driven axle
    (front for all-wheel drive), Cx_undriven (default Cx) on the other."""
    v = vehicle
    other = v.Cx if v.Cx_undriven is None else v.Cx_undriven
    return (other, v.Cx) if v.drive == "rear" else (v.Cx, other)


def slip_angles(vx, vy, r, delta, lf, lr):
    """Front and rear slip angles, alpha_f = delta - atan((vy + lf r)/vx),
    alpha_r = -atan((vy - lr r)/vx) (eq. (4) of the stiffness paper without the
    small-angle approximation)."""
    return delta - np.arctan((vy + lf * r) / vx), -np.arctan((vy - lr * r) / vx)


def wheel_slip(vx, rw_omega):
    """Wheel slip (R_w omega - vx) / max(|vx|, |R_w omega|): eq. (3) of the stiffness
    paper with the sign that makes traction positive (docs/design.md)."""
    den = np.maximum(np.abs(vx), np.abs(rw_omega))
    return np.where(den > 0, (rw_omega - vx) / np.where(den > 0, den, 1.0), 0.0)


def derivatives(x, u, model: TruthModel, dev=(0.0, 0.0, 0.0, 0.0)):
    """Right-hand side dx/dt and the algebraic quantities.

    x: (..., 9) state; u: dict with delta, drive_torque, brake_torque, surface, bank
    (arrays broadcastable to x[..., 0]); dev: relative stiffness deviations
    (front lateral, rear lateral, front longitudinal, rear longitudinal).
    """
    v = model.vehicle
    vx, vy, r = x[..., VX], x[..., VY], x[..., R]
    delta, surface = u["delta"], u["surface"]
    cd, sd = np.cos(delta), np.sin(delta)
    L, Rw = v.wheelbase, v.wheel_radius

    alpha_f, alpha_r = slip_angles(vx, vy, r, delta, v.lf, v.lr)
    lam_f, lam_r = wheel_slip(vx, Rw * x[..., WF]), wheel_slip(vx, Rw * x[..., WR])
    Fz_f = np.maximum(0.0, v.mass * (GRAVITY * v.lr - v.cg_height * x[..., ALT]) / L)
    Fz_r = np.maximum(0.0, v.mass * (GRAVITY * v.lf + v.cg_height * x[..., ALT]) / L)

    if model.tire_model == "linear":
        Cf_y, Cr_y, Cf_x, Cr_x = model.axle_stiffness()
        Fy_f, Fx_f = linear_forces(surface * Cf_y * (1 + dev[0]), surface * Cf_x * (1 + dev[2]), alpha_f, lam_f)
        Fy_r, Fx_r = linear_forces(surface * Cr_y * (1 + dev[1]), surface * Cr_x * (1 + dev[3]), alpha_r, lam_r)
    else:
        p = model.pacejka
        Fy_f, Fx_f = pacejka_forces(p, Fz_f, alpha_f, lam_f, dev[0], dev[2])
        Fy_r, Fx_r = pacejka_forces(p, Fz_r, alpha_r, lam_r, dev[1], dev[3])
        Fy_f, Fx_f, Fy_r, Fx_r = (surface * F for F in (Fy_f, Fx_f, Fy_r, Fx_r))

    F_resist = v.rolling_resistance * v.mass * GRAVITY * np.tanh(vx) + v.drag_coefficient * vx * np.abs(vx)
    ax = (Fx_f * cd - Fy_f * sd + Fx_r - F_resist) / v.mass
    ay = (Fy_f * cd + Fx_f * sd + Fy_r) / v.mass

    front = {"front": 1.0, "rear": 0.0, "all": v.awd_front_share}[v.drive]
    T, Tb = u["drive_torque"], u["brake_torque"]
    dx = np.empty(np.broadcast(x, ax[..., None]).shape)
    dx[..., VX] = vy * r + ax  # the stiffness paper's eq. (1a)
    dx[..., VY] = -vx * r + ay - GRAVITY * np.sin(u["bank"])  # eq. (1b), plus road bank
    dx[..., R] = (v.lf * (Fy_f * cd + Fx_f * sd) - v.lr * Fy_r) / v.yaw_inertia  # eq. (1c)
    dx[..., WF] = (front * T - v.brake_front_share * Tb * np.tanh(x[..., WF] / WHEEL_OMEGA_EPS) - Rw * Fx_f) / v.wheel_inertia_f
    dx[..., WR] = ((1 - front) * T - (1 - v.brake_front_share) * Tb * np.tanh(x[..., WR] / WHEEL_OMEGA_EPS) - Rw * Fx_r) / v.wheel_inertia_r
    dx[..., PX] = vx * np.cos(x[..., PSI]) - vy * np.sin(x[..., PSI])
    dx[..., PY] = vx * np.sin(x[..., PSI]) + vy * np.cos(x[..., PSI])
    dx[..., PSI] = r
    dx[..., ALT] = (ax - x[..., ALT]) / model.load_transfer_time_constant
    aux = {"alpha_f": alpha_f, "alpha_r": alpha_r, "lambda_f": lam_f, "lambda_r": lam_r,
           "Fz_f": Fz_f, "Fz_r": Fz_r, "Fx_f": Fx_f, "Fx_r": Fx_r, "Fy_f": Fy_f, "Fy_r": Fy_r,
           "ax": ax, "ay": ay}
    return dx, aux


def rk4_step(x, u, model: TruthModel, h: float, dev=(0.0, 0.0, 0.0, 0.0)):
    """One classical Runge-Kutta step of length h with inputs held."""
    k1, _ = derivatives(x, u, model, dev)
    k2, _ = derivatives(x + 0.5 * h * k1, u, model, dev)
    k3, _ = derivatives(x + 0.5 * h * k2, u, model, dev)
    k4, _ = derivatives(x + h * k3, u, model, dev)
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def steady_state_cornering(vehicle: VehicleParams, vx: float, delta: float):
    """Closed-form steady state of the linear single-track model (small angles):
    yaw rate r = vx delta / (L + K vx^2) with the understeer gradient
    K = m (lr Cr - lf Cf) / (L Cf Cr), and sideslip beta = r (lr / vx - m vx lf / (L Cr)).
    Returns (yaw_rate, beta)."""
    m, lf, lr, L = vehicle.mass, vehicle.lf, vehicle.lr, vehicle.wheelbase
    Cf, Cr = vehicle.Cf_y, vehicle.Cr_y
    K = m * (lr * Cr - lf * Cf) / (L * Cf * Cr)
    r = vx * delta / (L + K * vx**2)
    beta = r * (lr / vx - m * vx * lf / (L * Cr))
    return r, beta


# ---- the estimators' model -------------------------------------------------------------------
# the packed parameters p of the estimators' model (`model_params`; the compiled twin reads the same)
(P_MASS, P_YAW_INERTIA, P_LF, P_LR, P_CF_Y, P_CR_Y, P_CX_F, P_CX_R, P_WHEEL_RADIUS, P_UNDRIVEN_SHARE, P_IMU_X,
 P_IMU_Y, P_RELAX) = range(13)


def model_params(vehicle: VehicleParams, undriven_share: float = 0.0) -> np.ndarray:
    """The packed parameters p (13,) of the estimators' model: mass (kg), yaw inertia (kg m^2),
    lf, lr (m), nominal Cf_y, Cr_y (N/rad), nominal longitudinal stiffness front, rear (N,
    `longitudinal_stiffness`), wheel radius (m), the undriven axle's share of the driven
    axle's deviation dC_x (d F_undriven / d w_x per unit slip, relative to the driven axle's:
    0 keeps the undriven axle at its nominal stiffness), and the IMU's position imu_x, imu_y (m,
    ahead of and left of the centre of gravity: the lever arm of `measurement`), and the tyres' lateral
    relaxation length (m, 0: none; `accelerations`' relax). An array, not a
    dataclass, so that a filter can update the share in place and the compiled kernels read it as
    it is."""
    v = vehicle
    c_fx, c_rx = longitudinal_stiffness(v)
    return np.array([v.mass, v.yaw_inertia, v.lf, v.lr, v.Cf_y, v.Cr_y, c_fx, c_rx, v.wheel_radius, undriven_share,
                     v.imu_x, v.imu_y, v.relaxation_length], float)


def small_slip_angles(vx, vy, r, delta, lf, lr, vx_min: float = 1.0):
    """Front and rear slip angles in the small-angle form of eq. (4) of the stiffness paper,
    alpha_f = delta - (vy + lf r) / v, alpha_r = (lr r - vy) / v with the speed floor
    v = max(vx, vx_min), computed as products with 1 / v. Arrays or floats."""
    inv_vx = 1.0 / (np.maximum(vx, vx_min) if isinstance(vx, np.ndarray) else max(vx, vx_min))
    return delta - (vy + lf * r) * inv_vx, (lr * r - vy) * inv_vx


def floored_wheel_slip(vx, rw_omega):
    """Wheel slip of eq. (3) of the stiffness paper (traction positive) with a floor of 1 m/s
    on the denominator: (R_w omega - vx) / max(|vx|, |R_w omega|, 1). Arrays (broadcast) or floats."""
    if isinstance(vx, np.ndarray) or isinstance(rw_omega, np.ndarray):
        return (rw_omega - vx) / np.maximum(np.maximum(np.abs(vx), np.abs(rw_omega)), 1.0)
    return (rw_omega - vx) / max(abs(vx), abs(rw_omega), 1.0)


def vx_from_wheels(u, p: np.ndarray, rear_drive: bool):
    """R_w omega of the undriven axle (it hardly slips): the speed the wheels measure; NaN
    without that wheel speed. u = [delta, omega_f, omega_r, vx]."""
    omega = u[1] if rear_drive else u[2]
    return p[P_WHEEL_RADIUS] * omega


def accelerations(x, u, p: np.ndarray, full: bool, rear_drive: bool, slip=None, load_gain=None, relax=None):
    """The accelerations of eq. (1) with F = (C_n + w) slip (eq. (2), (7)), split as
    a(x, u) + B(x, u) w: returns a (N, 3) = (a^X, a^Y, r') at w = 0, B = d a / d w
    (N, 3, n_w), the slip angles af, ar (N,) and the wheel slip (2, N) of eq. (3)-(4)
    (small-angle form of the paper; None in the lateral model; `slip` given: held from an
    earlier evaluation). x (N, 3) full or (N, 2) lateral; u (4,); p from `model_params`.
    `load_gain` (N,) or None: the lateral axle forces (C_n + w) alpha times g = 1 - kappa a^Y^2
    per particle, the load transfer's effective stiffness (derivations, "Load transfer"; None: 1).
    `relax` = (prev (2, N), h) with a relaxation length sigma = p[P_RELAX] > 0: the slip angles the forces
    follow, relaxed from prev (their values h seconds earlier) towards the kinematic ones,
    prev + (1 - exp(-max(v^X, 1) h / sigma)) (alpha - prev) (derivations, "Tyre relaxation"); af, ar
    returned are these. None, or sigma = 0: the kinematic slip angles."""
    if full:
        vx, vy, r = x[:, 0], x[:, 1], x[:, 2]
    else:
        vx, vy, r = u[3], x[:, 0], x[:, 1]
    m, I, lf, lr = p[P_MASS], p[P_YAW_INERTIA], p[P_LF], p[P_LR]
    af, ar = small_slip_angles(vx, vy, r, u[0], lf, lr)
    if relax is not None and p[P_RELAX] > 0:
        prev, h = relax
        share = -np.expm1(-(np.maximum(vx, 1.0) * (h / p[P_RELAX])))
        af = prev[0] + share * (af - prev[0])
        ar = prev[1] + share * (ar - prev[1])
    cd, sd = math.cos(u[0]), math.sin(u[0])
    # the slips the lateral stiffness multiplies: times the load-transfer gain where there is one
    sf, sr = (af, ar) if load_gain is None else (af * load_gain, ar * load_gain)
    Ffy, Fry = p[P_CF_Y] * sf, p[P_CR_Y] * sr
    n_w = 3 if full else 2
    B = np.zeros((len(x), 3, n_w))
    j = 0
    if full:
        if slip is None:
            slip = floored_wheel_slip(vx, p[P_WHEEL_RADIUS] * u[1:3, None])  # (2, 1) against vx (N,)
        lam_f, lam_r = slip
        Ffx, Frx = p[P_CX_F] * lam_f, p[P_CX_R] * lam_r
        s = p[P_UNDRIVEN_SHARE]  # d F_undriven / d w_x per unit slip ("learned"; 0: "nominal")
        if rear_drive:
            B[:, 0, 0] = lam_r * (1.0 / m) + (s * lam_f) * (cd / m)
            B[:, 1, 0] = (s * lam_f) * (sd / m)
            B[:, 2, 0] = (s * lam_f) * (lf * sd / I)
        else:
            B[:, 0, 0] = lam_f * (cd / m) + (s * lam_r) * (1.0 / m)
            B[:, 1, 0] = lam_f * (sd / m)
            B[:, 2, 0] = lam_f * (lf * sd / I)
        j = 1
        Fy_f = Ffy * cd + Ffx * sd
        aX = (Ffx * cd - Ffy * sd + Frx) * (1.0 / m)
    else:
        Fy_f = Ffy * cd
        aX = np.zeros_like(af)
    B[:, 0, j] = sf * (-sd / m)
    B[:, 1, j] = sf * (cd / m)
    B[:, 2, j] = sf * (lf * cd / I)
    B[:, 1, j + 1] = sr * (1.0 / m)
    B[:, 2, j + 1] = sr * (-lr / I)
    a = np.array([aX, (Fy_f + Fry) * (1.0 / m), (lf * Fy_f - lr * Fry) * (1.0 / I)]).T
    return a, B, af, ar, slip


def state_derivative(x, u, a, B, w, full: bool):
    """x' of eq. (1) from the accelerations a + B w (`accelerations`), w (N, n_w)."""
    acc = a + np.einsum("nij,nj->ni", B, w)
    if full:
        vy, r = x[:, 1], x[:, 2]
        return np.array([vy * r + acc[:, 0], acc[:, 1] - x[:, 0] * r, acc[:, 2]]).T
    return np.array([acc[:, 1] - u[3] * x[:, 1], acc[:, 2]]).T


def propagate(x, u, w, dt: float, first, p: np.ndarray, full: bool, rear_drive: bool, max_step: float,
              heun: bool, load_gain=None, relaxed=None):
    """x_{k+1} = f(x_k) + g(x_k) w_k (eq. (9)): Euler, or Heun (`heun`) with the same w and the
    wheel slip held over the step. `first` = (a, B, af, ar, slip) of `accelerations` at x_k
    (from the measurement step). A step longer than `max_step` (a gap in a log) is split into
    equal sub-steps with u, w and `load_gain` (of `accelerations`) held. `relaxed` (2, N): the relaxed
    slip angles at x_k, which every later stage relaxes from over the time since t_k (`accelerations`'
    relax)."""
    n_sub = max(1, math.ceil(dt / max_step - 1e-9))
    h = dt / n_sub
    for i in range(n_sub):
        a, B, _, _, slip = first if i == 0 else accelerations(x, u, p, full, rear_drive, load_gain=load_gain,
                                                              relax=_since(relaxed, i * h))
        k1 = state_derivative(x, u, a, B, w, full)
        if not heun:
            x = x + h * k1
            continue
        x1 = x + h * k1
        a2, B2, *_ = accelerations(x1, u, p, full, rear_drive, slip, load_gain, _since(relaxed, (i + 1) * h))
        x = x + (0.5 * h) * (k1 + state_derivative(x1, u, a2, B2, w, full))
    return x


def _since(relaxed, h: float):
    """`accelerations`' relax from the relaxed slips at the step's start (None: none), h s later."""
    return None if relaxed is None else (relaxed, h)


def slip_over_step(x, u0, u1, w, first, dt: float, p: np.ndarray, jw: np.ndarray, c_floor: np.ndarray,
                   rear_drive: bool, load_gain=None, relaxed=None):
    """The first stage of the propagation from t_k to t_k+1 = t_k + dt with the wheel slip
    averaged over the interval (full model; derivations, "Wheel slip").

    x (N, 3) at t_k, u0 / u1 the inputs at t_k / t_k+1, w (N, n_w) the deviations held over
    the step, first = (a, B, af, ar, slip) of `accelerations(x, u0)`; jw (2,) the front and
    rear spin inertia over R_w^2, c_floor (2,) the lowest axle stiffness in the time constant.
    The wheel settles from the slip at t_k, slip_0, towards the one at t_k+1,
    slip_1 = (R_w omega_k+1 - v^X_k+1) / max(...), with v^X_k+1 = v^X_k + dt (v^Y r + a^X + B_0 w)
    (its error O(dt^2)), as slip(t) = slip_1 + (slip_0 - slip_1) exp(-(t - t_k) / tau),
    tau = J D / (R_w^2 C) per axle (J its spin inertia, D = max(|v^X|, |R_w omega_k|, 1), C its
    stiffness: nominal plus the particle's w where it is estimated, floored at c_floor); the
    mean over the interval is slip_1 + (slip_0 - slip_1) (tau / dt) (1 - exp(-dt / tau)).
    Returns (a, B, af, ar, slip) at x_k with that slip (and `load_gain` of `accelerations`; the slip
    angles `relaxed` (2, N) at x_k where the tyres relax), which `propagate` then holds."""
    a, B, _, _, slip0 = first
    Rw = p[P_WHEEL_RADIUS]
    vx = x[:, 0]
    acc0 = a[:, 0] + np.einsum("nj,nj->n", B[:, 0], w)
    vx1 = vx + dt * (x[:, 1] * x[:, 2] + acc0)  # eq. (1a), first stage
    slip1 = floored_wheel_slip(vx1, Rw * u1[1:3, None])
    wx, s = w[:, 0], p[P_UNDRIVEN_SHARE]
    C = np.array([p[P_CX_F] + (s * wx if rear_drive else wx), p[P_CX_R] + (wx if rear_drive else s * wx)])
    C = np.maximum(C, c_floor[:, None])
    D = np.maximum(np.maximum(np.abs(vx), np.abs(Rw * u0[1:3, None])), 1.0)
    tau = np.maximum(jw[:, None] * D / C, 1e-12)
    share = (tau / dt) * -np.expm1(-dt / tau)  # (1 / dt) int_0^dt exp(-t / tau) dt
    slip = slip1 + (slip0 - slip1) * share
    return accelerations(x, u0, p, True, rear_drive, slip, load_gain, _since(relaxed, 0.0))


def measurement(a, B, x, roll_gain, full: bool, p: np.ndarray | None = None):
    """h(x, u) (N, m) and d(x, u) (N, m, n_w) of eq. (12) for the model's IMU channels (full:
    a^X, a^Y, yaw rate; lateral: a^Y, yaw rate), from the accelerations of `accelerations`
    (docs/derivations.md, "The single-track model and the measurement"). The IMU sits at
    (imu_x, imu_y) of p (`model_params`; None: at the centre of gravity) on the rolling body:

        h^X = a^X - imu_y r' - imu_x r^2,   h^Y = g a^Y + imu_x r' - imu_y r^2,   h^r = r

    (the rigid body's a + r' z x p + r z x (r z x p) in 2-D; r' = a[:, 2], the model's yaw
    acceleration), g = 1 + k g_0 the roll gain: a float, or (N,) one per particle (the MPF's
    estimated roll gradient). r' is affine in w too, so d = d h / d w = [B_0 - imu_y B_2;
    g B_1 + imu_x B_2; 0] (no Ts: eq. (12), "The single-track model and the measurement").
    With the IMU at the centre of gravity the lever-arm terms are skipped, not added as zeros."""
    r = x[:, -1]
    g = roll_gain if np.ndim(roll_gain) == 0 else np.asarray(roll_gain)[:, None]
    ix, iy = (0.0, 0.0) if p is None else (float(p[P_IMU_X]), float(p[P_IMU_Y]))
    lever = ix != 0.0 or iy != 0.0
    if full:
        h = np.array([a[:, 0], roll_gain * a[:, 1], r]).T
        D = B.copy()
        D[:, 1] *= g
        D[:, 2] = 0.0
        jx, jy = 0, 1
    else:
        h = np.array([roll_gain * a[:, 1], r]).T
        D = np.zeros((len(x), 2, B.shape[2]))
        D[:, 0] = g * B[:, 1]
        jx, jy = None, 0
    if lever:  # the lever arm: the yaw acceleration r' = a_2 + B_2 w and the centripetal r^2
        rd, r2 = a[:, 2], r * r
        if jx is not None:
            h[:, jx] = (a[:, 0] - iy * rd) - ix * r2
            D[:, jx] = B[:, 0] - iy * B[:, 2]
        h[:, jy] = (h[:, jy] + ix * rd) - iy * r2
        D[:, jy] = D[:, jy] + ix * B[:, 2]
    return h, D
