"""A peer drive of the two-track model (`two_track`; `tirefilter peer-drive --model tt`).

The same maneuvers, sample rate, settling and sensors as the CommonRoad drives (`drive`):
RK4 with a fixed step of 1 ms (10 steps per sample), 2 s of settling straight at the start
speed. The driver sets the road-wheel steer of the maneuver directly (the car has no
steering-rate limit) and a total wheel torque for the set speed, R (m (dv/dt + K_SPEED
(v - v^X)) + drag + rolling resistance): on the driven axle when positive, on the brakes
of all four wheels (65 % front) when negative.

Log CSV: the columns of the other peer drives. `Cf_y_true, Cr_y_true` are the axles'
linear cornering stiffness at the static loads (sums of the two tyres' BCD, constant);
`Cf_y_load_true, Cr_y_load_true` the same at the current wheel loads (lateral load
transfer lowers it: BCD is concave in the load); `C*_y_eff_true` the drive's effective
axle stiffness (least squares of the axle forces a single-track model infers from the
accelerations on the single-track slip angles, `model.axle_stiffness_fit`). `Cx_true` is
the driven axle's slip stiffness at the static loads. The IMU sits at (imu_x, imu_y) on
the rolling body. By default the logger drops cells, rows and one 0.5-1 s gap
(`sensors.DropoutSpec`).
"""

from __future__ import annotations

import math

import numpy as np

from tirefilter.errors import TirefilterError
from tirefilter.peer.maneuvers import Profile, make_profile
from tirefilter.peer.model import axle_stiffness_fit
from tirefilter.peer.two_track import (AX_LAG, NX, VX, Model, load_two_track, rk4, sample, static_stiffness,
                                       straight_state)

TT_TRUE_EXTRA = ("Cf_y_load", "Cr_y_load")


def steer_gain_tt(model: Model):
    """v -> steady-state road-wheel steer per m/s^2 of a^Y, (L + K_us v^2) / v^2, with the
    axles' linear cornering stiffness at the static loads."""
    p = model.p
    Cf, Cr, _ = static_stiffness(model)
    L = p.wheelbase
    k_us = p.mass * (p.lr / Cf - p.lf / Cr) / L
    return lambda v: (L + k_us * v * v) / (v * v)


def integrate_tt(model: Model, profile: Profile, rate: float, substeps: int, settle: float,
                 k_speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States and inputs at the samples t = k / rate of the profile: (t (n,), X (n, NX),
    U (n, 2)). The profile's grid must be h / 2 with h = 1 / (rate substeps)."""
    h = 1.0 / (rate * substeps)
    if abs(profile.dt - h / 2) > 1e-12:
        raise ValueError(f"profile grid {profile.dt} s, expected {h / 2} s")
    p = model.p
    d, v, dv = profile.delta.tolist(), profile.speed.tolist(), profile.speed_rate.tolist()
    mass, R, drag, roll_res = p.mass, p.wheel_radius, p.drag, p.rolling_resistance * p.mass * 9.81

    def law(delta, v_set, dv_set):
        def u(x):
            vx = float(x[VX])
            return np.array([delta, R * (mass * (dv_set + k_speed * (v_set - vx)) + drag * vx * abs(vx) + roll_res)])
        return u

    x = straight_state(v[0], model)
    hold = law(d[0], v[0], 0.0)
    for _ in range(int(round(settle / h))):
        x = rk4(x, h, hold, hold, hold, model)
    n = int(math.floor(profile.t[-1] * rate + 1e-6)) + 1
    X, U = np.empty((n, NX)), np.empty((n, 2))
    for k in range(n):
        X[k] = x
        U[k] = law(d[2 * k * substeps], v[2 * k * substeps], dv[2 * k * substeps])(x)
        if k == n - 1:
            break
        for s in range(substeps):
            j = 2 * (k * substeps + s)
            x = rk4(x, h, law(d[j], v[j], dv[j]), law(d[j + 1], v[j + 1], dv[j + 1]),
                     law(d[j + 2], v[j + 2], dv[j + 2]), model)
        if not np.all(np.isfinite(x)):
            raise TirefilterError(f"two-track model (vehicle {p.name}) diverged at t = {k / rate:g} s")
    return np.arange(n) / rate, X, U


def trajectory_tt(spec, model: Model, *, rate: float, substeps: int, settle: float, k_speed: float):
    """The drive's maneuver integrated on the two-track `model`: (t, X, U, sensor seed), the
    seeds spawned as in `drive.trajectory`."""
    maneuver_seed, sensor_seed = np.random.SeedSequence(spec.seed).spawn(2)
    profile = make_profile(spec.maneuver, spec.duration, speed=spec.speed, ay=spec.ay, steer_gain=steer_gain_tt(model),
                           straight=spec.straight, dt=0.5 / (rate * substeps), rng=np.random.default_rng(maneuver_seed))
    t, X, U = integrate_tt(model, profile, rate, substeps, settle, k_speed)
    return t, X, U, sensor_seed


def true_values(model: Model, X: np.ndarray, U: np.ndarray) -> dict:
    """The reference quantities of the samples (n,) each: `two_track.sample` plus the static
    stiffness (constant columns) and the load-transfer states."""
    true = sample(X, U, model)
    Cf, Cr, Cx = static_stiffness(model)
    n = X.shape[0]
    true.update(Cf_y=np.full(n, Cf), Cr_y=np.full(n, Cr), Cx=np.full(n, Cx), ax_lag=X[:, AX_LAG])
    return true


def effective_stiffness_tt(model: Model, true: dict) -> tuple[float, float]:
    p = model.p
    return axle_stiffness_fit(p.mass, p.yaw_inertia, p.lf, p.lr, true)


def load(spec) -> Model:
    return load_two_track(spec.vehicle, spec.imu_x, spec.imu_y)
