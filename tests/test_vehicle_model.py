"""The FMU against an independent numpy integration of the same equations, and the
linear single-track model against its closed-form steady state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import NOISE_OFF
from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.cosim.run import run_scenario
from tirefilter.io.results import ESTIMATE_COLUMNS, truth_column
from tirefilter.scenarios import load_scenario
from tirefilter.vehicle.single_track import GRAVITY, STATE_NAMES, WHEEL_OMEGA_EPS, rk4_step, steady_state_cornering

COMPARED = ("vx", "vy", "yaw_rate", "omega_f", "omega_r", "x", "y", "psi")


def _rhs_floats(model):
    """`single_track.derivatives` on plain floats (the `math` module): the right-hand side of one
    state (a list of 9 floats) with inputs held, written out independently of the numpy model
    (numpy's per-call cost on (9,) arrays made the reference integration 30 CPU s of the suite);
    `_numpy_trajectory` checks every step of it against the numpy model's `rk4_step`."""
    v = model.vehicle
    L, Rw, m, g = v.wheelbase, v.wheel_radius, v.mass, GRAVITY
    lf, lr, h_cg, Iz, Jf, Jr = v.lf, v.lr, v.cg_height, v.yaw_inertia, v.wheel_inertia_f, v.wheel_inertia_r
    front = {"front": 1.0, "rear": 0.0, "all": v.awd_front_share}[v.drive]
    bf, tau, roll, drag = v.brake_front_share, model.load_transfer_time_constant, v.rolling_resistance, v.drag_coefficient
    Cf_y, Cr_y, Cf_x, Cr_x = model.axle_stiffness()
    p, linear = model.pacejka, model.tire_model == "linear"
    atan, sin, cos, tanh = math.atan, math.sin, math.cos, math.tanh

    def slip(vx, rw_omega):
        den = max(abs(vx), abs(rw_omega))
        return (rw_omega - vx) / den if den > 0 else 0.0

    def mf(B, C, D, E, s):
        Bs = B * s
        return D * sin(C * atan(Bs - E * (Bs - atan(Bs))))

    def forces(Fz, alpha, lam, surface, Cy, Cx):
        if linear:
            return surface * Cy * alpha, surface * Cx * lam
        Fy0, Fx0 = mf(p.B_y, p.C_y, p.mu_y * Fz, p.E_y, alpha), mf(p.B_x, p.C_x, p.mu_x * Fz, p.E_x, lam)
        G_yk = cos(p.Cyk * atan(p.rBy1 * cos(atan(p.rBy2 * alpha)) * lam))
        G_xa = cos(p.Cxa * atan(p.rBx1 * cos(atan(p.rBx2 * lam)) * alpha))
        return surface * (Fy0 * G_yk), surface * (Fx0 * G_xa)

    def rhs(x, delta, T, Tb, surface, bank):
        vx, vy, r, wf, wr, _, _, psi, alt = x
        cd, sd = cos(delta), sin(delta)
        alpha_f, alpha_r = delta - atan((vy + lf * r) / vx), -atan((vy - lr * r) / vx)
        Fz_f = max(0.0, m * (g * lr - h_cg * alt) / L)
        Fz_r = max(0.0, m * (g * lf + h_cg * alt) / L)
        Fy_f, Fx_f = forces(Fz_f, alpha_f, slip(vx, Rw * wf), surface, Cf_y, Cf_x)
        Fy_r, Fx_r = forces(Fz_r, alpha_r, slip(vx, Rw * wr), surface, Cr_y, Cr_x)
        ax = (Fx_f * cd - Fy_f * sd + Fx_r - (roll * m * g * tanh(vx) + drag * vx * abs(vx))) / m
        ay = (Fy_f * cd + Fx_f * sd + Fy_r) / m
        return [vy * r + ax, -vx * r + ay - g * sin(bank), (lf * (Fy_f * cd + Fx_f * sd) - lr * Fy_r) / Iz,
                (front * T - bf * Tb * tanh(wf / WHEEL_OMEGA_EPS) - Rw * Fx_f) / Jf,
                ((1 - front) * T - (1 - bf) * Tb * tanh(wr / WHEEL_OMEGA_EPS) - Rw * Fx_r) / Jr,
                vx * cos(psi) - vy * sin(psi), vx * sin(psi) + vy * cos(psi), r, (ax - alt) / tau]

    return rhs


def _numpy_trajectory(scenario, inputs, x0, h, substeps):
    """RK4 with `substeps` steps per communication step of length h, inputs held: the right-hand
    side on floats (`_rhs_floats`); then every one of its steps, from the state it started at, is
    the numpy model's `rk4_step` to 1e-12 (one batched call over all steps), so the trajectory is
    the numpy model's."""
    rhs, dt = _rhs_floats(scenario.model), h / substeps
    x = [float(v) for v in x0]
    states, out = [x], [x]
    for uk in inputs[:-1].tolist():
        for _ in range(substeps):
            k1 = rhs(x, *uk)
            k2 = rhs([a + 0.5 * dt * b for a, b in zip(x, k1)], *uk)
            k3 = rhs([a + 0.5 * dt * b for a, b in zip(x, k2)], *uk)
            k4 = rhs([a + dt * b for a, b in zip(x, k3)], *uk)
            x = [a + dt / 6.0 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4)]
            states.append(x)
        out.append(x)
    X = np.array(states)
    u = dict(zip(("delta", "drive_torque", "brake_torque", "surface", "bank"),
                 np.repeat(np.asarray(inputs[:-1], float), substeps, axis=0).T))
    step = rk4_step(X[:-1], u, scenario.model, dt)
    err = np.max(np.abs(X[1:] - step), axis=0) / np.maximum(np.max(np.abs(X), axis=0), 1e-300)
    assert np.all(err <= 1e-12), dict(zip(STATE_NAMES, err))
    return np.array(out)


@pytest.mark.parametrize("name,duration", [("paper-sim", 34.0), ("friction-snow", 30.0)])  # the cut at 30 s included
def test_fmu_matches_numpy_integration(fmu_paths, name, duration):
    """Noise off: FMU (C, RK4 at 1 ms) and numpy model agree to 1e-6 relative."""
    scenario = load_scenario(name)
    with VehicleFMU("2") as fmu:
        cols = {c: j for j, c in enumerate(ESTIMATE_COLUMNS + tuple(map(truth_column, fmu.output_names))
                                            + ("true_delta", "true_drive_torque", "true_brake_torque",
                                               "true_surface", "true_bank"))}
        from dataclasses import replace

        short = replace(scenario, duration=duration, estimator_rate=1.0 / scenario.communication_step)
        _, rows = run_scenario(short, seed=0, fmu=fmu, keep_rows=True, parameter_overrides=NOISE_OFF)
    inputs = rows[:, [cols[c] for c in ("true_delta", "true_drive_torque", "true_brake_torque", "true_surface",
                                        "true_bank")]]
    vx0 = scenario.truth.get("vx0", 22.0)
    x0 = [vx0, 0.0, 0.0, vx0 / scenario.vehicle.wheel_radius, vx0 / scenario.vehicle.wheel_radius, 0, 0, 0, 0]
    ref = _numpy_trajectory(scenario, inputs, x0, scenario.communication_step, 10)
    for name_ in COMPARED:
        fmu_series = rows[:, cols["true_" + name_]]
        ref_series = ref[:, STATE_NAMES.index(name_)]
        scale = np.max(np.abs(ref_series))
        err = np.max(np.abs(fmu_series - ref_series)) / scale
        assert err <= 1e-6, f"{name_}: relative error {err:.2e}"
    # the comparison covers real dynamics, not a straight line
    assert np.ptp(rows[:, cols["true_yaw_rate"]]) > 0.05


@pytest.mark.parametrize("vx,delta", [(15.0, 0.01), (25.0, 0.005), (30.0, -0.004)])
def test_steady_state_matches_closed_form(fmu_paths, vx, delta):
    """Linear tires: yaw-rate gain and sideslip of the single-track steady state
    (understeer gradient) within 1%."""
    scenario = load_scenario("paper-sim")
    params = scenario.fmu_parameters(seed=0) | NOISE_OFF | {"vx0": vx}
    with VehicleFMU("2") as fmu:
        fmu.reset(params)
        names = fmu.output_names
        for k in range(1500):  # 15 s: many yaw-mode time constants
            y = fmu.step(k * 0.01, 0.01, [delta, 0.0, 0.0, 1.0, 0.0])
        v_end = y[names.index("vx")]
        r_expected, beta_expected = steady_state_cornering(scenario.vehicle, v_end, delta)
        assert y[names.index("yaw_rate")] == pytest.approx(r_expected, rel=0.01)
        assert y[names.index("beta")] == pytest.approx(beta_expected, rel=0.01)
        # the car really turns and the yaw rate has settled
        r_before = y[names.index("yaw_rate")]
        y = fmu.step(1500 * 0.01, 0.01, [delta, 0.0, 0.0, 1.0, 0.0])
        assert abs(y[names.index("yaw_rate")] - r_before) < 1e-4 * abs(r_before)
