"""Single-track (bicycle) dynamics with wheel spin and load transfer, batch-first.

The same equations as the vehicle FMU (vehicle_fmu/c/vehicle_model.c), written
independently in numpy; tests integrate both and compare. State (..., 9):
[vx, vy, yaw_rate, omega_f, omega_r, x, y, psi, a_lt] (a_lt: the lagged longitudinal
acceleration that sets the load transfer).
"""

from __future__ import annotations

from dataclasses import dataclass

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
        other = v.Cx if v.Cx_undriven is None else v.Cx_undriven
        if v.drive == "rear":
            return v.Cf_y, v.Cr_y, other, v.Cx
        return v.Cf_y, v.Cr_y, v.Cx, other


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
