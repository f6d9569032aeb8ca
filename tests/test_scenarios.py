"""Scenario and vehicle files: every built-in one loads; bad files get clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from tirefilter.errors import ConfigError
from tirefilter.scenarios import list_scenarios, load_scenario
from tirefilter.scenarios.profiles import FilteredNoise, Sine, Square, Steps
from tirefilter.vehicle.params import load_vehicle

VEHICLE = """
mass = 2050.0
yaw_inertia = 3850.0
lf = 1.3
lr = 1.6
wheel_radius = 0.36
cg_height = 0.7
Cf_y = 1e5
Cr_y = 1.15e5
Cx = 2.6e5
"""


def test_builtin_scenarios_load_and_state_their_schedule():
    scenarios = {s.name: s for s in list_scenarios()}
    assert set(scenarios) == {"paper-sim", "snow-sine", "asphalt-normal", "friction-snow"}
    for s in scenarios.values():
        assert s.duration > 0 and s.estimator_rate > 0 and s.excitation and s.sensors
        assert s.steps_per_sample >= 1
    assert scenarios["paper-sim"].surface_changes == (30.0,)
    assert scenarios["friction-snow"].sample_period == pytest.approx(0.04)
    assert scenarios["snow-sine"].model.tire_model == "pacejka"


def test_paper_sim_inputs_are_the_papers_square_waves():
    s = load_scenario("paper-sim")
    t = np.arange(0, 60, 0.01)
    u = s.inputs.open_loop(t)
    delta, torque, surface = u[:, 0], u[:, 1], u[:, 3]
    assert set(np.round(np.unique(delta), 6)) == {-0.025, 0.025}
    assert np.count_nonzero(np.diff(np.sign(delta))) == 29  # period 4 s: a sign change every 2 s
    assert np.count_nonzero(np.diff(np.sign(torque))) == 23  # period 5 s
    assert np.all(surface[t < 30] == 1.0) and np.all(surface[t >= 30] == 0.5)


def test_profile_components():
    t = np.array([0.0, 0.5, 1.0, 1.5, 2.0])
    np.testing.assert_allclose(Square(2.0, 2.0).evaluate(t), [2, 2, -2, -2, 2])
    np.testing.assert_allclose(Sine(1.0, 4.0, start=1.0, end=2.0).evaluate(t), [0, 0, 0, np.sin(np.pi / 4), 0])
    np.testing.assert_allclose(Steps((0.0, 1.0), (1.0, 0.5)).evaluate(t), [1, 1, 0.5, 0.5, 0.5])
    noise = FilteredNoise(std=0.1, correlation_time=1.0, seed=3, dt=0.01)
    long = noise.evaluate(np.arange(0, 2000, 0.01))
    assert np.std(long) == pytest.approx(0.1, rel=0.1)  # stationary std
    np.testing.assert_array_equal(noise.evaluate(t), noise.evaluate(t))  # a fixed signal


def test_unknown_scenario_lists_the_known_ones():
    with pytest.raises(ConfigError, match="known scenarios: asphalt-normal, friction-snow, paper-sim, snow-sine"):
        load_scenario("moon-drive")


@pytest.mark.parametrize("line,match", [
    ("mass = -5.0", r"mass: -5.0 is out of range: expected > 0"),
    ("lf = 0.0", r"lf: 0.0 is out of range: expected > 0"),
    ("mass = 'heavy'", r"mass: expected a number, got 'heavy'"),
    ("drive = 'sideways'", r"drive: expected one of front, rear, all"),
    ("wings = 2", r"wings: unknown key"),
])
def test_bad_vehicle_file_names_file_key_and_expectation(tmp_path, line, match):
    key = line.split("=")[0].strip()
    text = "\n".join(l for l in VEHICLE.splitlines() if not l.startswith(key + " ")) + "\n" + line + "\n"
    path = tmp_path / "car.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match) as info:
        load_vehicle(path)
    assert str(path) in str(info.value)


def test_missing_vehicle_key(tmp_path):
    path = tmp_path / "car.toml"
    path.write_text(VEHICLE.replace("yaw_inertia = 3850.0", ""))
    with pytest.raises(ConfigError, match="yaw_inertia: missing"):
        load_vehicle(path)


@pytest.mark.parametrize("body,match", [
    ("duration = -1.0\nestimator_rate = 100.0", r"duration: -1.0 is out of range"),
    ("duration = 10.0\nestimator_rate = 100.0\ncommunication_step = 0.003", r"communication_step: .* whole number"),
    ("duration = 10.0\nestimator_rate = 100.0\nsensors = ['ax', 'gps']", r"sensors: expected a list drawn from"),
    ("duration = 10.0\nestimator_rate = 100.0\nexcitation = [[5.0, 20.0]]", r"excitation: expected a list of"),
    ("duration = 10.0\nestimator_rate = 100.0\n[[inputs.delta]]\ntype = 'constant'\nvalue = 2.0",
     r"inputs.delta: value 2 at t = 0.000 s is outside .*steer beyond \+-90 deg"),
    ("duration = 10.0\nestimator_rate = 100.0\n[[inputs.delta]]\ntype = 'zigzag'",
     r"inputs.delta\[0\].type: expected one of"),
    ("duration = 10.0\nestimator_rate = 100.0\n[[inputs.delta]]\ntype = 'sine'\namplitude = 0.1",
     r"inputs.delta\[0\].period: missing"),
    ("duration = 10.0\nestimator_rate = 100.0\n[[inputs.steer]]\ntype = 'constant'\nvalue = 0.1",
     r"inputs.steer: unknown input"),
    ("duration = 10.0\nestimator_rate = 100.0\n[tires]\nmodel = 'pacejka'", r"tires.set: missing"),
    ("duration = 10.0\nestimator_rate = 100.0\nvehicle = 'tractor'", r"vehicle: unknown vehicle 'tractor'"),
    ("duration = 10.0\nestimator_rate = 100.0\n[truth]\nstiffness_dev_std = 2.0", r"truth.stiffness_dev_std: 2.0 is out"),
    ("duration = 10.0\nestimator_rate = [100.0]", r"estimator_rate: expected a number"),
    ("duration = 10.0\nestimator_rate = 100.0\n[[inputs.surface]]\ntype = 'steps'\ntimes = [0.0, 5.0, 4.0]\n"
     "values = [1.0, 0.5, 1.0]", r"inputs.surface\[0\].times: times must be strictly increasing"),
    ("duration = 10.0\nestimator_rate = 100.0\nthis is not toml", r"not valid TOML"),
])
def test_bad_scenario_file_names_file_key_and_expectation(tmp_path, body, match):
    path = tmp_path / "bad.toml"
    path.write_text(body + "\n")
    with pytest.raises(ConfigError, match=match) as info:
        load_scenario(path)
    assert str(path) in str(info.value)
