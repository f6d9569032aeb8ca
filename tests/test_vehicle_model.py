"""The FMU against an independent numpy integration of the same equations, and the
linear single-track model against its closed-form steady state."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import NOISE_OFF
from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.cosim.run import run_scenario
from tirefilter.cosim.results import ESTIMATE_COLUMNS, truth_column
from tirefilter.scenarios import load_scenario
from tirefilter.vehicle.single_track import STATE_NAMES, rk4_step, steady_state_cornering

COMPARED = ("vx", "vy", "yaw_rate", "omega_f", "omega_r", "x", "y", "psi")


def _numpy_trajectory(scenario, inputs, x0, h, substeps):
    """RK4 with `substeps` steps per communication step of length h, inputs held."""
    x = np.asarray(x0, dtype=float)
    out = [x.copy()]
    names = ("delta", "drive_torque", "brake_torque", "surface", "bank")
    for uk in inputs[:-1]:
        u = dict(zip(names, uk))
        for _ in range(substeps):
            x = rk4_step(x, u, scenario.model, h / substeps)
        out.append(x.copy())
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
