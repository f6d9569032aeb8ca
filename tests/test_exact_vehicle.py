"""The vehicle model's maths (vehicle/tires.py, single_track.py, params.py) against exact
answers: the Magic Formula's initial slope and peak, the friction truth as the pure lateral
force per load, and the single-track right-hand side on the branches the co-simulation tests
leave out. Found by mutation testing (benchmarks/mutation.py): each test kills mutants the
other tests let through."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from test_vehicle_model import _rhs_floats
from tirefilter.scenarios import load_scenario
from tirefilter.errors import ConfigError
from tirefilter.vehicle.params import PacejkaParams, vehicle_from_dict
from tirefilter.vehicle.single_track import (GRAVITY, STATE_NAMES, WHEEL_OMEGA_EPS, TruthModel, derivatives,
                                            wheel_slip)
from tirefilter.vehicle.tires import magic_formula, pacejka_forces, pure_lateral_friction

PAC = PacejkaParams(mu_x=1.1, B_x=12.0, C_x=1.65, E_x=0.2, mu_y=0.95, B_y=9.0, C_y=1.35, E_y=-0.4)


def _slope_at_zero(f) -> float:
    """f'(0) of an odd function by the central difference at 1e-7 (error O(1e-14) relative)."""
    h = 1e-7
    return (f(h) - f(-h)) / (2 * h)


@pytest.mark.parametrize("dev", [0.0, 0.2, -0.15])
def test_magic_formula_stiffness_deviation_scales_the_slope_not_the_peak(dev):
    """Pure slip (no combined-slip weighting): the initial slope of each axle force is
    (1 + dev) B C D (the vehicle's stiffness deviation scales B), and the peak is D = mu Fz
    whatever dev is (C > 1: the curve reaches its peak)."""
    Fz = 4000.0
    slope_y = _slope_at_zero(lambda a: pacejka_forces(PAC, Fz, a, 0.0, dev_y=dev)[0])
    slope_x = _slope_at_zero(lambda s: pacejka_forces(PAC, Fz, 0.0, s, dev_x=dev)[1])
    assert slope_y == pytest.approx((1 + dev) * PAC.lateral_stiffness(Fz), rel=1e-8)
    assert slope_x == pytest.approx((1 + dev) * PAC.longitudinal_stiffness(Fz), rel=1e-8)
    grid = np.linspace(0.0, 1.0, 200001)
    Fy, _ = pacejka_forces(PAC, Fz, grid, 0.0, dev_y=dev)
    _, Fx = pacejka_forces(PAC, Fz, 0.0, grid, dev_x=dev)
    assert Fy.max() == pytest.approx(PAC.mu_y * Fz, rel=1e-8)
    assert Fx.max() == pytest.approx(PAC.mu_x * Fz, rel=1e-8)
    # no deviation given: none; the other direction's deviation leaves a force alone
    assert _slope_at_zero(lambda s: pacejka_forces(PAC, Fz, 0.0, s)[1]) == pytest.approx(
        PAC.longitudinal_stiffness(Fz), rel=1e-8)
    assert _slope_at_zero(lambda a: pacejka_forces(PAC, Fz, a, 0.0)[0]) == pytest.approx(
        PAC.lateral_stiffness(Fz), rel=1e-8)
    np.testing.assert_array_equal(pacejka_forces(PAC, Fz, grid[:50], 0.0, dev_x=dev)[0],
                                  pacejka_forces(PAC, Fz, grid[:50], 0.0)[0])
    np.testing.assert_array_equal(pacejka_forces(PAC, Fz, 0.0, grid[:50], dev_y=dev)[1],
                                  pacejka_forces(PAC, Fz, 0.0, grid[:50])[1])


def test_friction_truth_is_the_pure_lateral_force_per_load():
    """mu_y(alpha) = Fy / Fz of the pure-lateral Magic Formula times the surface scale (1 by
    default)."""
    alpha = np.linspace(-0.3, 0.3, 61)
    Fz = 3500.0
    per_load = pacejka_forces(PAC, Fz, alpha, 0.0)[0] / Fz
    np.testing.assert_allclose(pure_lateral_friction(PAC, alpha), per_load, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(pure_lateral_friction(PAC, alpha, 0.4), 0.4 * per_load, rtol=1e-12, atol=1e-15)
    assert pure_lateral_friction(PAC, 0.02) == pytest.approx(magic_formula(PAC.B_y, PAC.C_y, PAC.mu_y, PAC.E_y, 0.02))
    assert math.isclose(_slope_at_zero(lambda a: pure_lateral_friction(PAC, a)), PAC.B_y * PAC.C_y * PAC.mu_y,
                        rel_tol=1e-8)


# ---- vehicle/single_track.py -------------------------------------------------------------------

def _variant(name: str, drive: str, tire: str) -> TruthModel:
    """A scenario's truth model with the drive `drive`, rolling resistance and drag, the
    brake share off its default and (for all-wheel drive) an uneven torque split."""
    model = load_scenario(name).model
    v = replace(model.vehicle, drive=drive, rolling_resistance=0.015, drag_coefficient=0.45, brake_front_share=0.7,
                awd_front_share=0.35, Cx_undriven=0.6 * model.vehicle.Cx)
    return replace(model, vehicle=v, tire_model=tire)


def _states_and_inputs(rng, n: int = 40):
    """Random states across the regimes: speeds from a crawl (wheel speeds near zero, where
    the brake torque's sign is smoothed) to 35 m/s, slip angles up to saturation, wheel slip
    in traction and braking, load transfer up to lifting an axle; inputs with drive and brake
    torque, a banked road and a low-friction surface."""
    vx = np.concatenate([rng.uniform(0.05, 0.8, n // 4), rng.uniform(3.0, 35.0, n - n // 4)])
    X = np.zeros((n, 9))
    X[:, 0] = vx
    X[:, 1] = rng.uniform(-0.15, 0.15, n) * vx
    X[:, 2] = rng.uniform(-0.6, 0.6, n)
    X[:, 3] = vx / 0.31 * (1 + rng.uniform(-0.2, 0.2, n))
    X[:, 4] = vx / 0.31 * (1 + rng.uniform(-0.2, 0.2, n))
    X[:, 5:7] = rng.uniform(-50.0, 50.0, (n, 2))
    X[:, 7] = rng.uniform(-math.pi, math.pi, n)
    X[:, 8] = rng.uniform(-9.0, 9.0, n)
    X[-2:, 8] = (-40.0, 40.0)  # beyond what the static loads carry: an axle lifts (Fz = 0)
    U = np.column_stack([rng.uniform(-0.1, 0.1, n), rng.uniform(-600.0, 900.0, n), rng.uniform(0.0, 1500.0, n),
                         rng.choice([1.0, 0.35], n), rng.uniform(-0.08, 0.08, n)])
    return X, U


@pytest.mark.parametrize("tire", ["linear", "pacejka"])
@pytest.mark.parametrize("drive", ["front", "rear", "all"])
def test_derivatives_equal_the_equations_on_floats(drive, tire):
    """`derivatives` on a batch of states against the single-track equations written on
    floats (tests/test_vehicle_model.py's independent reference), for every drive, both tire
    models, with rolling resistance, drag, braking, bank and surface scaling; and the
    algebraic outputs (slips, loads, forces, accelerations) against their definitions."""
    model = _variant("friction-snow" if tire == "pacejka" else "paper-sim", drive, tire)
    rhs = _rhs_floats(model)
    X, U = _states_and_inputs(np.random.default_rng({"front": 60, "rear": 61, "all": 62}[drive]))
    u = dict(zip(("delta", "drive_torque", "brake_torque", "surface", "bank"), U.T))
    dx, aux = derivatives(X, u, model)
    ref = np.array([rhs(x, *uk) for x, uk in zip(X.tolist(), U.tolist())])
    err = np.abs(dx - ref) / np.maximum(np.abs(ref), 1e-300).max(axis=0)  # relative to each component's scale
    assert err.max() <= 1e-12, dict(zip(STATE_NAMES, err.max(axis=0)))
    v = model.vehicle
    assert np.all(aux["Fz_f"][-2:] * aux["Fz_r"][-2:] == 0.0) and np.all(aux["Fz_f"] >= 0) and np.all(aux["Fz_r"] >= 0)
    both = (aux["Fz_f"] > 0) & (aux["Fz_r"] > 0)  # load transfer moves load between the axles, keeps m g
    assert both[:-2].all()
    np.testing.assert_allclose((aux["Fz_f"] + aux["Fz_r"])[both], v.mass * GRAVITY, rtol=1e-12)
    np.testing.assert_allclose(aux["ay"], (aux["Fy_f"] * np.cos(U[:, 0]) + aux["Fx_f"] * np.sin(U[:, 0])
                                           + aux["Fy_r"]) / v.mass, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(aux["lambda_r"], wheel_slip(X[:, 0], v.wheel_radius * X[:, 4]), rtol=1e-15)


def test_stiffness_deviations_scale_the_axle_stiffness():
    """dev = (front lateral, rear lateral, front longitudinal, rear longitudinal) relative
    deviations: the linear model with dev equals the model whose axle stiffnesses are
    multiplied by 1 + dev; the Magic Formula model with the same deviation on both axles
    equals the one whose B_y, B_x are multiplied by it. No dev given: none."""
    X, U = _states_and_inputs(np.random.default_rng(63), 12)
    u = dict(zip(("delta", "drive_torque", "brake_torque", "surface", "bank"), U.T))
    model = _variant("paper-sim", "front", "linear")
    v, dev = model.vehicle, (0.1, -0.2, 0.3, -0.15)
    scaled = replace(model, vehicle=replace(v, Cf_y=v.Cf_y * 1.1, Cr_y=v.Cr_y * 0.8, Cx=v.Cx * 1.3,
                                            Cx_undriven=v.Cx_undriven * 0.85))
    np.testing.assert_allclose(derivatives(X, u, model, dev)[0], derivatives(X, u, scaled)[0], rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(derivatives(X, u, model)[0], derivatives(X, u, model, (0.0, 0.0, 0.0, 0.0))[0])
    pac = _variant("friction-snow", "front", "pacejka")
    p = pac.pacejka
    scaled = replace(pac, pacejka=replace(p, B_y=p.B_y * 1.1, B_x=p.B_x * 0.8))
    np.testing.assert_allclose(derivatives(X, u, pac, (0.1, 0.1, -0.2, -0.2))[0], derivatives(X, u, scaled)[0],
                               rtol=1e-12, atol=1e-9)
    # a deviation per axle and direction: each axle's forces are the Magic Formula's with its own
    a = derivatives(X, u, pac, dev)[1]
    for axle, dy, dx in (("f", dev[0], dev[2]), ("r", dev[1], dev[3])):
        Fy, Fx = pacejka_forces(p, a[f"Fz_{axle}"], a[f"alpha_{axle}"], a[f"lambda_{axle}"], dy, dx)
        np.testing.assert_allclose(a[f"Fy_{axle}"], u["surface"] * Fy, rtol=1e-14, atol=1e-9)
        np.testing.assert_allclose(a[f"Fx_{axle}"], u["surface"] * Fx, rtol=1e-14, atol=1e-9)


def test_wheel_slip_at_standstill_and_crawling_speeds():
    """(R_w omega - vx) / max(|vx|, |R_w omega|): 0 when both are 0; its value below 1 m/s."""
    assert wheel_slip(np.array(0.0), np.array(0.0)) == 0.0
    np.testing.assert_allclose(wheel_slip(np.array([0.5, 0.4, 0.0]), np.array([0.6, 0.3, 0.2])),
                               [0.1 / 0.6, -0.1 / 0.4, 1.0], rtol=1e-15)


def test_constants_are_the_c_models():
    """g and the brake torque's sign smoothing are the vehicle FMU's (the truth the numpy
    model is checked against)."""
    src = Path(__file__).resolve().parents[1] / "src" / "tirefilter" / "vehicle_fmu" / "c"
    h = (src / "vehicle_model.h").read_text()
    c = (src / "vehicle_model.c").read_text()
    assert GRAVITY == float(re.search(r"#define VM_GRAVITY ([0-9.eE+-]+)", h).group(1))
    assert WHEEL_OMEGA_EPS == float(re.search(r"#define WHEEL_OMEGA_EPS ([0-9.eE+-]+)", c).group(1))


# ---- vehicle/params.py -------------------------------------------------------------------------

def test_static_axle_loads_balance_weight_and_moment():
    """The static loads carry the weight, F_f + F_r = m g, with no pitching moment about the
    CG, F_f l_f = F_r l_r; g defaults to the standard 9.80665 m/s^2 (the models' g)."""
    v = load_scenario("paper-sim").vehicle
    Ff, Fr = v.static_axle_loads()
    assert Ff + Fr == pytest.approx(v.mass * GRAVITY, rel=1e-14)
    assert Ff * v.lf == pytest.approx(Fr * v.lr, rel=1e-14)
    Ff2, Fr2 = v.static_axle_loads(g=1.62)
    assert Ff2 + Fr2 == pytest.approx(v.mass * 1.62, rel=1e-14) and Ff2 * v.lf == pytest.approx(Fr2 * v.lr, rel=1e-14)


def test_roll_gradient_is_limited_to_005():
    """roll_gradient in [0, 0.05] rad per m/s^2 (0.05: some 29 deg of roll at 10 m/s^2)."""
    base = {"mass": 1500.0, "yaw_inertia": 2500.0, "lf": 1.2, "lr": 1.5, "wheel_radius": 0.31, "cg_height": 0.55,
            "Cf_y": 8e4, "Cr_y": 9e4, "Cx": 1.5e5}
    assert vehicle_from_dict({**base, "roll_gradient": 0.05}, "v.toml").roll_gradient == 0.05
    with pytest.raises(ConfigError, match="roll_gradient"):
        vehicle_from_dict({**base, "roll_gradient": 0.0502}, "v.toml")


def test_relaxation_and_load_sensitivity_keys():
    """A vehicle file without `relaxation_length` has none (0, the paper's model), one without
    `load_sensitivity` has kappa estimated where the MPF's switch is on (None); a stated value, 0 included,
    is kept; kappa in [0, 0.05] s^4/m^2."""
    base = {"mass": 1500.0, "yaw_inertia": 2500.0, "lf": 1.2, "lr": 1.5, "wheel_radius": 0.31, "cg_height": 0.55,
            "Cf_y": 8e4, "Cr_y": 9e4, "Cx": 1.5e5}
    v = vehicle_from_dict(base, "v.toml")
    assert (v.relaxation_length, v.load_sensitivity) == (0.0, None)
    v = vehicle_from_dict({**base, "relaxation_length": 0.5, "load_sensitivity": 0.0}, "v.toml")
    assert (v.relaxation_length, v.load_sensitivity) == (0.5, 0.0)
    assert vehicle_from_dict({**base, "load_sensitivity": 0.05}, "v.toml").load_sensitivity == 0.05
    for bad in (-1e-4, 0.0502):
        with pytest.raises(ConfigError, match="load_sensitivity"):
            vehicle_from_dict({**base, "load_sensitivity": bad}, "v.toml")
