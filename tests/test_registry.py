"""The estimator registry (`estimators.build`): every estimator by name, for a co-simulated
scenario and for a recorded log, and the defaults in which the two settings differ."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tirefilter.errors import ConfigError
from tirefilter.estimators import ESTIMATORS, REGISTRY, build, for_log, for_scenario
from tirefilter.estimators.guard import MeasurementGuard
from tirefilter.estimators.sensors import SensorModel
from tirefilter.scenarios import DATA_DIR, load_scenario
from tirefilter.vehicle.params import load_vehicle

VEHICLE = load_vehicle(DATA_DIR / "vehicles" / "midsize-suv.toml")
NO_NOISE_FIGURES = dataclasses.replace(VEHICLE, sigma_ax=None, sigma_ay=None, sigma_yaw_rate=None)


def _log(n: int = 400, period: float = 0.02):
    """Two seconds of a straight drive at 20 m/s with white sensor noise: (t, signals)."""
    rng = np.random.default_rng(4)
    t = np.arange(n) * period
    w = 20.0 / VEHICLE.wheel_radius
    signals = {"delta": np.zeros(n), "ax": 0.05 * rng.standard_normal(n), "ay": 0.1 * rng.standard_normal(n),
               "yaw_rate": 0.002 * rng.standard_normal(n), "vx": np.full(n, 20.0),
               "omega_f": w + 0.1 * rng.standard_normal(n), "omega_r": w + 0.1 * rng.standard_normal(n)}
    return t, signals


SETTINGS = {"scenario": lambda: for_scenario(load_scenario("friction-snow")), "log": lambda: for_log(VEHICLE, *_log())}


@pytest.mark.parametrize("source", SETTINGS)
@pytest.mark.parametrize("name", ESTIMATORS)
def test_every_estimator_is_built_by_name_with_its_sensors_and_guard(name, source):
    est = build(name, SETTINGS[source](), model="auto", particles=7, config={})
    if name == "none":
        assert est is None
        return
    assert est.name == name
    assert isinstance(est.sensors, SensorModel) and isinstance(est.guard, MeasurementGuard)
    if hasattr(est.cfg, "particles"):
        assert est.cfg.particles == 7


def test_the_registry_names_are_the_command_lines_choices():
    from tirefilter.cli import build_parser

    choices = next(a.choices for a in build_parser()._subparsers._group_actions[0].choices["run"]._actions
                   if a.dest == "estimator")
    assert tuple(choices) == ESTIMATORS == tuple(REGISTRY)
    with pytest.raises(ConfigError, match="unknown estimator 'mpff'"):
        build("mpff", SETTINGS["log"](), model="auto", particles=None, config={})


def test_the_defaults_that_differ_between_a_scenario_and_a_log():
    scenario = load_scenario("friction-snow")
    sim, log = for_scenario(scenario), for_log(NO_NOISE_FIGURES, *_log())
    # the GP-SSM: the scenario's N, rate, noise and true initial state; the log's median step, its noise
    g_sim = build("gpssm", sim, model="auto", particles=None, config={})
    g_log = build("gpssm", log, model="auto", particles=None, config={})
    assert g_sim.cfg.particles == scenario.estimator["particles"] == 200
    assert g_sim.cfg.sample_period == scenario.sample_period == 0.04
    assert g_sim.cfg.sigma == (scenario.sensor_spec.sigma_ay, scenario.sensor_spec.sigma_yaw_rate)
    assert g_log.cfg.particles == type(g_log.cfg)().particles
    assert g_log.cfg.sample_period == pytest.approx(0.02, rel=1e-12)
    assert g_log.cfg.sigma == log.sensors.sigma[1:] and g_log.cfg.x0_mean == (0.0, 0.0)
    # the MPF: the same filter; a log gives no initial state (v^Y unknown: the statistics are drawn again at the
    # gate), the scenario does
    m_sim = build("mpf", sim, model="lateral", particles=50, config={})
    m_log = build("mpf", log, model="lateral", particles=50, config={})
    assert (m_sim.cfg.x0_given, m_log.cfg.x0_given) == (True, False)
    same = [f.name for f in dataclasses.fields(m_sim.cfg) if f.name not in ("x0_given", "x0_mean", "init_center",
                                                                           "init_reference", "init_distribution",
                                                                           "init_half_width", "sample_period",
                                                                           "sigma", "bias0_std", "bias_rw",
                                                                           "disturbance_rw", "sigma_omega")]
    assert [getattr(m_sim.cfg, k) for k in same] == [getattr(m_log.cfg, k) for k in same]
    # the kf: the scenario's noise figures, the log's estimate
    assert build("kf", sim, model="auto", particles=None, config={}).cfg.sigma_ay == scenario.sensor_spec.sigma_ay
    assert build("kf", log, model="auto", particles=None, config={}).cfg.sigma_ay == log.sensors.sigma[1]
    assert log.sensors.sigma_source[1] == "data" and 0.08 < log.sensors.sigma[1] < 0.12  # the log's 0.1 m/s^2


def test_options_and_their_errors_reach_every_estimator_alike():
    log = for_log(VEHICLE, *_log())
    assert build("combined", log, model="auto", particles=None, config={"mpf": {"forgetting": 0.97}}).mpf.cfg.forgetting == 0.97
    with pytest.raises(ConfigError, match="the kf baseline has the lateral model only"):
        build("kf", log, model="full", particles=None, config={})
    no_vx = for_log(VEHICLE, *(lambda t, s: (t, {k: v for k, v in s.items() if k != "vx"}))(*_log()))
    with pytest.raises(ConfigError, match="the lateral model needs vx"):
        build("ekf", no_vx, model="lateral", particles=None, config={})


def test_a_log_setting_keeps_nothing_of_the_logs_samples():
    """`for_log` reads the samples once: overwritten afterwards (as a replay drops them), they
    change nothing of what the setting builds, which equals `mpf_config_for_log` on them."""
    from tirefilter.estimators import mpf_config_for_log

    t, signals = _log()
    expected = mpf_config_for_log(NO_NOISE_FIGURES, t, signals, model="full", particles=30, overrides={})
    setting = for_log(NO_NOISE_FIGURES, t, signals)
    t[:] = np.nan
    for x in signals.values():
        x[:] = np.nan
    assert build("mpf", setting, model="full", particles=30, config={}).cfg == expected
    assert expected.x0_mean[0] == 20.0 and expected.sample_period == pytest.approx(0.02, rel=1e-12)
