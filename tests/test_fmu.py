"""The vehicle FMU: validation, FMI 2 = FMI 3, state save/restore, errors."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.cosim.run import run_scenario
from tirefilter.errors import FMUError
from tirefilter.scenarios import load_scenario


@pytest.mark.parametrize("version", ["2", "3"])
def test_fmu_validates(fmu_paths, version):
    assert validate_fmu(str(fmu_paths[version])) == []


@pytest.mark.parametrize("name", ["paper-sim", "snow-sine"])
def test_fmi2_and_fmi3_give_the_same_outputs(fmu_paths, name):
    scenario = load_scenario(name)
    rows = {}
    for version in ("2", "3"):
        _, rows[version] = run_scenario(scenario, seed=11, fmi_version=version, keep_rows=True)
    a, b = rows["2"], rows["3"]
    assert a.shape == b.shape
    finite = np.isfinite(a)
    np.testing.assert_array_equal(finite, np.isfinite(b))
    np.testing.assert_allclose(b[finite], a[finite], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("version", ["2", "3"])
def test_state_restore_reproduces_the_random_stream(fmu_paths, version):
    scenario = load_scenario("snow-sine")  # noise, bias random walk and deviations all on
    with VehicleFMU(version) as fmu:
        fmu.reset(scenario.fmu_parameters(seed=5))
        u = [0.01, 200.0, 0.0, 1.0, 0.0]
        for k in range(100):
            fmu.step(k * 0.01, 0.01, u)
        state = fmu.get_state()
        blob = fmu.serialize_state(state)
        first = np.array([fmu.step((100 + k) * 0.01, 0.01, u).copy() for k in range(50)])
        fmu.set_state(state)
        second = np.array([fmu.step((100 + k) * 0.01, 0.01, u).copy() for k in range(50)])
        fmu.set_state(fmu.deserialize_state(blob))
        third = np.array([fmu.step((100 + k) * 0.01, 0.01, u).copy() for k in range(50)])
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(first, third)
    assert np.ptp(first[:, 0]) > 0  # the noisy ax sensor really changed


def test_same_seed_same_run_other_seed_other_run(fmu_paths):
    scenario = load_scenario("paper-sim")
    _, a = run_scenario(scenario, seed=3, keep_rows=True)
    _, b = run_scenario(scenario, seed=3, keep_rows=True)
    _, c = run_scenario(scenario, seed=4, keep_rows=True)
    np.testing.assert_array_equal(np.nan_to_num(a), np.nan_to_num(b))
    assert not np.allclose(np.nan_to_num(a), np.nan_to_num(c))


def test_communication_step_does_not_change_the_samples(fmu_paths):
    """Noise and deviations are drawn per sample period, not per communication step."""
    scenario = load_scenario("paper-sim")
    out = {}
    for h in (0.01, 0.005):
        with VehicleFMU("2") as fmu:
            fmu.reset(scenario.fmu_parameters(seed=9))
            n = int(round(1.0 / h))
            for k in range(n):
                y = fmu.step(k * h, h, [0.01, 300.0, 0.0, 1.0, 0.0])
            out[h] = y.copy()
    names = VehicleFMU("2").output_names
    for name in ("ax_meas", "ay_meas", "yaw_rate_meas", "true_Cf_y"):
        j = names.index(name)
        assert out[0.005][j] == pytest.approx(out[0.01][j], rel=1e-9, abs=1e-12), name


@pytest.mark.parametrize("version", ["2", "3"])
def test_bad_parameter_is_rejected_with_its_name(fmu_paths, version):
    with VehicleFMU(version) as fmu:
        with pytest.raises(FMUError, match="mass = -5 is outside"):
            fmu.reset({"mass": -5.0})


@pytest.mark.parametrize("version", ["2", "3"])
def test_failing_step_reports_time_and_reason(fmu_paths, version):
    with VehicleFMU(version) as fmu:
        fmu.reset({"vx0": 5.0})
        with pytest.raises(FMUError, match=r"v_min.*t = \d"):
            for k in range(1000):
                fmu.step(k * 0.01, 0.01, [0.0, 0.0, 20000.0, 1.0, 0.0])


def test_missing_fmu_says_how_to_build(tmp_path):
    with pytest.raises(FMUError, match="tirefilter fmu build vehicle"):
        VehicleFMU("2", tmp_path / "nothing.fmu")
