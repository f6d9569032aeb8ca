"""The two-track peer model (tirefilter.peer.two_track) against exact answers: the linear
single-track steady state, symmetry, the static load-transfer formulas and moment
balances, the IMU's lever arm and tilt by an independent computation, the power balance,
and the tyres' relaxation; then `peer-drive --model tt` end to end (a short drive)."""

from __future__ import annotations

import dataclasses
import math
import tomllib

import numpy as np
import pytest

from tirefilter.cli import main
from tirefilter.io.log import read_log
from tirefilter.peer.score import read_columns
from tirefilter.peer.two_track import (AX_LAG, AY_LAG, G, NX, OMEGA, R_, SLIP_X, SLIP_Y, VEHICLES_TT, VX, VY,
                                       LinearTyre, forces, load_two_track, make_model, rhs, rk4, sample,
                                       specific_force_body, static_stiffness, straight_state, wheel_loads)
from tirefilter.vehicle.params import load_vehicle


def _steady(model, delta: np.ndarray, v: np.ndarray, seconds: float, h: float = 0.002, accel: float = 0.0):
    """States after `seconds` of constant steer delta (B,) from straight driving at v (B,),
    the speed held at v (or raised at `accel` m/s^2) by a proportional wheel torque."""
    p = model.p
    x = np.stack([straight_state(vi, model) for vi in v])
    t = 0.0

    def law_at(tk):
        def u(x):
            target = v + accel * tk
            T = p.wheel_radius * (p.mass * (accel + 2.0 * (target - x[:, VX])) + p.drag * x[:, VX] ** 2
                                  + p.rolling_resistance * p.mass * G)
            return np.stack([delta, T], axis=-1)
        return u

    for _ in range(int(round(seconds / h))):
        x = rk4(x, h, law_at(t), law_at(t + h / 2), law_at(t + h), model)
        t += h
    return x, law_at(t)(x)


def _linear_car(c_f: float = 16.0, c_r: float = 19.0, **changes):
    p = dataclasses.replace(VEHICLES_TT[2], tyre_f=LinearTyre(c_f, 20.0), tyre_r=LinearTyre(c_r, 20.0), ackermann=0.0,
                            drag=0.0, rolling_resistance=0.0, **changes)
    return make_model(p)


def test_steady_state_with_linear_tyres_is_the_understeer_gradient_formula():
    """Linear tyres with stiffness proportional to the load (so lateral load transfer keeps
    each axle's stiffness), parallel steer: the steady yaw-rate gain is v / (L + K_us v^2),
    K_us = m (l_r / C_f - l_f / C_r) / L, and the sideslip r (l_r / v - m l_f v / (L C_r))
    (Gillespie ch. 6), with C_f, C_r at the axle loads of the turn (the sideslip's
    centripetal a^X = -r v^Y moves a little load: 2e-3 of K_us at 30 m/s)."""
    c_f, c_r = 16.0, 19.0
    model = _linear_car(c_f, c_r)
    p = model.p
    v = np.array([10.0, 20.0, 30.0])
    L = p.wheelbase
    Cf, Cr, _ = static_stiffness(model)
    delta = 1.0 * (L + p.mass * (p.lr / Cf - p.lf / Cr) / L * v**2) / v**2  # a^Y of 1 m/s^2
    x, u = _steady(model, delta, v, 6.0)
    Fz = forces(x, u, model).Fz
    Cf, Cr = c_f * (Fz[:, 0] + Fz[:, 1]), c_r * (Fz[:, 2] + Fz[:, 3])
    k_us = p.mass * (p.lr / Cf - p.lf / Cr) / L
    vx, r = x[:, VX], x[:, R_]
    gain_err = (r / delta) / (vx / (L + k_us * vx**2)) - 1.0
    beta = np.arctan2(x[:, VY], vx)
    beta_lin = r * (p.lr / vx - p.mass * p.lf * vx / (L * Cr))
    # measured 2.7e-4 (the two tracks' second-order terms: left and right slip angles differ by
    # r t / (2 v) where the loads differ; the front wheels' cos(delta)); without K_us: 4-26 %
    assert np.max(np.abs(gain_err)) < 8e-4
    assert np.max(np.abs(beta - beta_lin)) < 7e-6  # rad; measured 2.4e-6 (beta up to 9e-3)


def test_zero_steer_drives_straight_with_no_lateral_force():
    """Symmetric car, zero steer, accelerating: v^Y, r and every lateral force stay exactly 0."""
    model = load_two_track(2, imu_y=0.0)
    x, u = _steady(model, np.zeros(2), np.array([15.0, 25.0]), 2.0, accel=1.0)
    f = forces(x, u, model)
    assert np.all(x[:, VY] == 0.0) and np.all(x[:, R_] == 0.0)
    assert np.all(f.Fy == 0.0) and np.all(f.ay == 0.0) and np.all(f.yaw_acc == 0.0)
    assert np.all(x[:, VX] > np.array([15.0, 25.0]) + 1.5)  # it did accelerate (2 s at 1 m/s^2)


@pytest.mark.parametrize("vehicle", [1, 3])
def test_loads_sum_to_the_weight_and_balance_the_moments(vehicle):
    """For any a^X, a^Y: the loads sum to m g; the pitch moment sum x_i dF_z,i = -m a^X h;
    the roll moment sum -y_i dF_z,i = m a^Y h + m g h' phi (the rolled centre of gravity,
    phi = m a^Y h' / (K - m g h')); the front axle carries K_f phi + F_yf z_f with
    F_yf = m a^Y l_r / L (Gillespie ch. 8)."""
    model = load_two_track(vehicle)
    p = model.p
    rng = np.random.default_rng(3)
    ax, ay = rng.uniform(-4, 4, 50), rng.uniform(-7, 7, 50)
    Fz = wheel_loads(ax, ay, model)
    dF = Fz - p.static_wheel_loads()
    Kf, Kr = p.roll_stiffness()
    h1 = p.roll_arm
    phi = p.mass * ay * h1 / (Kf + Kr - p.mass * G * h1)
    np.testing.assert_allclose(Fz.sum(-1), p.mass * G, rtol=1e-13)
    np.testing.assert_allclose(dF @ model.x, -p.mass * ax * p.cg_height, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(-dF @ model.y, p.mass * ay * p.cg_height + p.mass * G * h1 * phi, rtol=1e-12,
                               atol=1e-9)
    np.testing.assert_allclose((dF[:, 1] - dF[:, 0]) / 2 * p.track_f,
                               Kf * phi + p.mass * ay * p.lr / p.wheelbase * p.roll_centre_f, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(model.roll_per_ay, p.roll_gradient, rtol=1e-12)


def test_steady_turn_has_the_static_loads():
    """In a steady turn of the Magic Formula car the lagged accelerations the loads follow
    are the body's own, so the loads are the static formulas' at the actual a^Y."""
    model = load_two_track(3)
    delta = np.array([0.03, -0.05])
    x, u = _steady(model, delta, np.array([20.0, 15.0]), 6.0)
    f = forces(x, u, model)
    assert np.all(np.abs(f.ay) > 3.0)
    np.testing.assert_allclose(x[:, AY_LAG], f.ay, rtol=1e-6)
    np.testing.assert_allclose(f.Fz, wheel_loads(f.ax, f.ay, model), rtol=1e-6)
    np.testing.assert_allclose(f.Fz.sum(-1), model.p.mass * G, rtol=1e-12)
    assert np.all(f.Fz[0, [1, 3]] > f.Fz[0, [0, 2]]) and np.all(f.Fz[1, [0, 2]] > f.Fz[1, [1, 3]])  # outer wheels


def _random_states(model, n=40, seed=0):
    rng = np.random.default_rng(seed)
    x = np.zeros((n, NX))
    x[:, VX] = rng.uniform(8, 35, n)
    x[:, VY] = rng.uniform(-0.5, 0.5, n)
    x[:, R_] = rng.uniform(-0.6, 0.6, n)
    x[:, OMEGA] = x[:, VX, None] / model.p.wheel_radius * (1 + rng.uniform(-0.02, 0.02, (n, 4)))
    x[:, SLIP_Y] = rng.uniform(-0.05, 0.05, (n, 4))
    x[:, SLIP_X] = rng.uniform(-0.02, 0.02, (n, 4))
    x[:, AX_LAG] = rng.uniform(-3, 3, n)
    x[:, AY_LAG] = rng.uniform(-6, 6, n)
    u = np.stack([rng.uniform(-0.1, 0.1, n), rng.uniform(-1500, 1500, n)], axis=-1)
    return x, u


def test_imu_lever_arm_and_tilt_by_an_independent_computation():
    """The IMU's reading: a_cg + domega x p + omega x (omega x p) (numpy cross products) as
    a specific force in the axes of the body pitched and rolled (rotation matrices)."""
    model = load_two_track(3, imu_x=0.45, imu_y=-0.2)
    x, u = _random_states(model)
    s = sample(x, u, model)
    f = forces(x, u, model)
    pos = np.array([0.45, -0.2, 0.0])
    w = np.zeros((x.shape[0], 3))
    w[:, 2] = x[:, R_]
    dw = np.zeros_like(w)
    dw[:, 2] = f.yaw_acc
    a = np.stack([f.ax, f.ay, np.zeros_like(f.ax)], -1) + np.cross(dw, pos) + np.cross(w, np.cross(w, pos))
    spec = a + np.array([0.0, 0.0, G])
    roll, up = -s["roll"], s["pitch"]  # left side up, nose up
    for k in range(x.shape[0]):
        c, sn = math.cos(-up[k]), math.sin(-up[k])
        Ry = np.array([[c, 0, sn], [0, 1, 0], [-sn, 0, c]])
        c, sn = math.cos(roll[k]), math.sin(roll[k])
        Rx = np.array([[1, 0, 0], [0, c, -sn], [0, sn, c]])
        body = (Ry @ Rx).T @ spec[k]
        assert body[0] == pytest.approx(s["ax_imu"][k], abs=1e-12)
        assert body[1] == pytest.approx(s["ay_imu"][k], abs=1e-12)
        assert (Ry @ Rx).T[2, 2] * x[k, R_] == pytest.approx(s["yaw_rate_imu"][k], abs=1e-15)
    assert np.all(np.abs(s["roll"]) > 0)  # the states have roll and pitch
    level = specific_force_body(f.ax, f.ay, 0.0, 0.0)
    np.testing.assert_array_equal(level[0], f.ax)


def test_power_balance():
    """dE/dt of E = m (v^X^2 + v^Y^2)/2 + I_z r^2/2 + sum I_w omega_i^2/2 from the
    right-hand side is the tyres' slip power sum F_x (V_x - R omega) + F_y V_y, plus the
    wheel torques' power, less drag and rolling-resistance power."""
    model = load_two_track(1)
    p = model.p
    x, u = _random_states(model, seed=5)
    f = forces(x, u, model)
    dx = rhs(x, u, model)
    omega = x[:, OMEGA]
    dE = (p.mass * (x[:, VX] * dx[:, VX] + x[:, VY] * dx[:, VY]) + p.yaw_inertia * x[:, R_] * dx[:, R_]
          + p.wheel_inertia * np.sum(omega * dx[:, OMEGA], -1))
    power = (np.sum(f.Fxw * (f.vxw - p.wheel_radius * omega) + f.Fyw * f.vyw, -1) + np.sum(f.torque * omega, -1)
             - p.drag * np.abs(x[:, VX]) ** 3
             - np.sum(p.rolling_resistance * p.wheel_radius * f.Fz * np.tanh(omega) * omega, -1))
    np.testing.assert_allclose(dE, power, rtol=1e-9, atol=1e-6 * np.max(np.abs(power)))


def test_coasting_loses_energy():
    model = load_two_track(2)
    p = model.p
    x = np.stack([straight_state(25.0, model)])
    u = lambda x: np.array([[0.02, 0.0]])  # noqa: E731 - no torque
    energy = []
    for _ in range(500):
        x = rk4(x, 0.002, u, u, u, model)
        energy.append(0.5 * p.mass * (x[0, VX] ** 2 + x[0, VY] ** 2) + 0.5 * p.yaw_inertia * x[0, R_] ** 2
                      + 0.5 * p.wheel_inertia * np.sum(x[0, OMEGA] ** 2))
    assert np.all(np.diff(energy[100:]) < 0)  # after the steer's transient: drag, rolling resistance, slip


def test_relaxation_is_first_order_in_the_distance_travelled():
    """The relaxed lateral slip of the right-hand side, the rest of the state held (straight
    at 20 m/s) after a steer step: it approaches the kinematic slip tan(delta) as
    1 - exp(-V_x t / sigma_alpha), V_x = 20 cos(delta) (Pacejka ch. 7)."""
    model = make_model(dataclasses.replace(VEHICLES_TT[1], ackermann=0.0))
    x0 = straight_state(20.0, model)
    step, h = 0.01, 0.001
    u = np.array([step, 0.0])

    def rate(s):
        x = x0.copy()
        x[SLIP_Y] = s
        return rhs(x, u, model)[SLIP_Y]

    s = np.zeros(4)
    sigma, v = model.sigma_alpha[0], 20.0 * math.cos(step)
    for k in range(1, 51):
        k1 = rate(s)
        k2 = rate(s + 0.5 * h * k1)
        k3 = rate(s + 0.5 * h * k2)
        s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + rate(s + h * k3))
        if k % 10 == 0:
            assert s[0] == pytest.approx(math.tan(step) * (1 - math.exp(-v * k * h / sigma)), rel=1e-6)
    assert s[0] == s[1] and s[2] == 0.0  # both front wheels, not the rear ones


def test_tyre_stiffness_at_the_load_is_the_slope_of_the_force():
    model = load_two_track(3)
    Fz = np.array([1500.0, 3000.0, 4500.0, 6000.0])
    a = 1e-6
    slope = (model.tyre.lateral(a, Fz) - model.tyre.lateral(-a, Fz)) / (2 * a)
    np.testing.assert_allclose(slope, model.tyre.cornering_stiffness(Fz), rtol=1e-6)
    slope_x = (model.tyre.longitudinal(a, Fz) - model.tyre.longitudinal(-a, Fz)) / (2 * a)
    np.testing.assert_allclose(slope_x, model.tyre.slip_stiffness(Fz), rtol=1e-6)
    Cf, Cr, Cx = static_stiffness(model)
    Fz0 = model.Fz0
    assert Cf == pytest.approx(2 * float(model.tyre.cornering_stiffness(Fz0)[0]))
    # load sensitivity: the axle loses stiffness to lateral load transfer
    dF = 1000.0
    C = VEHICLES_TT[3].tyre_f.cornering_stiffness(np.array([Fz0[0] - dF, Fz0[0] + dF]))
    assert C.sum() < Cf


def test_peer_drive_tt_writes_a_log_with_dropouts_and_a_data_sheet_vehicle(tmp_path, capsys):
    log, vehicle = tmp_path / "tt.csv", tmp_path / "tt.toml"
    assert main(["peer-drive", "--model", "tt", "--vehicle", "3", "--maneuver", "steps", "--duration", "12",
                 "--seed", "4", "--ay", "4", "--out", str(log), "--vehicle-toml", str(vehicle)]) == 0
    out = capsys.readouterr().out
    assert "two-track: IMU at (0.4, -0.1) m" in out and "logger dropouts" in out
    data = tomllib.loads(vehicle.read_text())
    assert set(data) == {"mass", "yaw_inertia", "lf", "lr", "wheel_radius", "cg_height", "drive", "Cf_y", "Cr_y",
                         "Cx", "imu_x", "imu_y"}
    assert (data["imu_x"], data["imu_y"]) == (0.4, -0.1)
    cols = read_columns(log, ("t", "ax", "ay", "yaw_rate", "delta", "vx", "omega_f", "omega_r", "beta_true",
                              "Cf_y_true", "Cr_y_true", "Cf_y_load_true", "ay_true"))
    dt = np.diff(cols["t"])
    assert 0.5 <= dt.max() <= 1.01 and dt.min() == pytest.approx(0.01)  # one gap, else 100 Hz
    assert cols["t"][0] == 0.0 and cols["t"][-1] == pytest.approx(12.0)
    blank = sum(int(np.isnan(cols[c]).sum()) for c in ("ax", "ay", "yaw_rate", "delta", "vx", "omega_f", "omega_r"))
    assert blank > 0 and not np.isnan(cols["beta_true"]).any()
    assert np.all(cols["Cf_y_true"] == cols["Cf_y_true"][0]) and np.max(cols["Cf_y_load_true"]) <= cols["Cf_y_true"][0]
    assert np.max(np.abs(cols["ay_true"])) > 3.0
    read_log(log, load_vehicle(vehicle))  # the replay's reader takes it


def test_imu_position_is_for_the_two_track_model_only():
    from tirefilter.errors import TirefilterError
    from tirefilter.peer.drive import DriveSpec, simulate

    with pytest.raises(TirefilterError, match="two-track"):
        simulate(DriveSpec(model="std", imu_x=0.3))
    with pytest.raises(TirefilterError, match="dropouts"):
        simulate(DriveSpec(model="tt", dropouts="sometimes"))


@pytest.mark.parametrize("vehicle", [1, 2, 3])
def test_axle_stiffness_under_lateral_load_transfer_is_quadratic_in_ay(vehicle):
    """The load-transfer model of the MPF (derivations, "Load transfer") against the two-track
    tyres' axle stiffness computed directly: the sum of the two wheels' BCD at the loads of a
    steady a^Y is C_0 (1 - kappa a^Y^2) + O(a^Y^4) with kappa = -C''(F_0) t^2 / (2 C(F_0)) per axle
    (C one wheel's stiffness at its static load F_0, t = dF_z / da^Y its load transfer, C'' by
    central differences: 3.0-5.3e-3 on the three cars, the load's share of the anatomy's kappa);
    the fourth-order rest stays below 0.5 % of C_0 up to 4 m/s^2."""
    model = load_two_track(vehicle)
    C = model.tyre.cornering_stiffness
    for axle in (0, 2):  # FL (the front axle), RL (the rear)
        F0, t = model.Fz0[axle], abs(model.transfer_y[axle])
        dF = 50.0
        c0 = float(C(F0)[axle])
        c2 = float((C(F0 + dF)[axle] - 2 * c0 + C(F0 - dF)[axle]) / dF**2)
        kappa = -c2 * t * t / (2 * c0)
        assert 0.0025 < kappa < 0.007  # s^4/m^2 (measured 3.0-5.3e-3)
        for ay in (0.5, 2.0, 4.0):
            loads = wheel_loads(0.0, ay, model)
            axle_c = float(C(loads)[axle] + C(loads)[axle + 1])
            # (measured: 2.1e-3 at most at 4 m/s^2, below 2e-4 at 2)
            assert axle_c / (2 * c0) == pytest.approx(1 - kappa * ay * ay, abs=5e-3 if ay > 2 else 5e-4)
