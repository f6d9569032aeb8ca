"""Carrying the learned stiffness posterior from one drive to the next (--save-state /
--init-state)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import replace

import numpy as np
import pytest

from tirefilter.cosim.run import run_scenario
from tirefilter.errors import ConfigError
from tirefilter.estimators import build_estimator
from tirefilter.estimators.state_file import load_state, save_state
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.scenarios import load_scenario


def _uniform_state(n_particles=7, seed=0):
    """A hand-made full-model state with equal weights (no resampling on load)."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n_particles, 3, 3))
    vehicle = load_scenario("paper-sim").vehicle
    est = StiffnessMPF(vehicle, MPFConfig(particles=n_particles, model="full"))
    state = {"format": "tirefilter-stiffness-state", "format_version": 1, "model": "full",
             "params": ["Cx", "Cf_y", "Cr_y"], "C_nominal": est.C_nom.tolist(),
             "log_weights": [0.0] * n_particles, "gamma": rng.uniform(0.01, 0.1, n_particles).tolist(),
             "mu": (1e3 * rng.standard_normal((n_particles, 3))).tolist(),
             "Lam": (1e6 * (A @ np.swapaxes(A, 1, 2) + np.eye(3))).tolist(),
             "nu": rng.uniform(20, 40, n_particles).tolist()}
    return vehicle, est, state


def test_full_state_restores_exactly_and_marginalises_to_lateral():
    vehicle, est, state = _uniform_state()
    est.carry_over(state)
    est.reset(np.random.default_rng(1))
    np.testing.assert_array_equal(est.stats.mu, np.asarray(state["mu"]))
    np.testing.assert_array_equal(est.stats.Lam, np.asarray(state["Lam"]))
    np.testing.assert_array_equal(est.stats.nu, np.asarray(state["nu"]))
    lat = StiffnessMPF(vehicle, MPFConfig(particles=7, model="lateral"))
    lat.carry_over(state)
    lat.reset(np.random.default_rng(1))
    # the lateral block: mu and gamma kept, Lambda's (Cf_y, Cr_y) block, nu - 1
    np.testing.assert_array_equal(lat.stats.mu, np.asarray(state["mu"])[:, 1:])
    np.testing.assert_array_equal(lat.stats.Lam, np.asarray(state["Lam"])[:, 1:, 1:])
    np.testing.assert_array_equal(lat.stats.nu, np.asarray(state["nu"]) - 1.0)
    np.testing.assert_array_equal(lat.stats.gamma, np.asarray(state["gamma"]))


def test_second_drive_starts_where_the_first_ended(fmu_paths, tmp_path):
    """paper-sim, lateral model, 20 s with N = 150: the saved posterior carries the learned
    stiffness; a filter of another N started from it reports it at its first step (within
    the resampling spread), far from the scenario's 70% prior."""
    scenario = load_scenario("paper-sim")
    scenario = replace(scenario, duration=20.0, surface_changes=())
    est = build_estimator("mpf", scenario, model="lateral", particles=150, config={})
    _, rows = run_scenario(scenario, estimator=est, seed=3)
    final = est._estimate(float("nan"))
    path = save_state(est, tmp_path / "drive1.json")
    assert json.loads(path.read_text())["format_version"] == 1
    fresh = build_estimator("mpf", scenario, model="lateral", particles=200, config={})
    load_state(fresh, path)
    fresh.reset(np.random.default_rng(9))
    start = fresh._estimate(float("nan"))
    prior = build_estimator("mpf", scenario, model="lateral", particles=200, config={})
    prior.reset(np.random.default_rng(9))
    for p in ("Cf_y", "Cr_y"):
        learned, carried, cold = getattr(final, p), getattr(start, p), getattr(prior._estimate(float("nan")), p)
        assert abs(carried / learned - 1) < 0.02, (p, carried, learned)
        assert abs(cold / learned - 1) > 0.15, (p, cold, learned)


def test_state_file_errors(tmp_path):
    vehicle, est, state = _uniform_state()
    good = tmp_path / "good.json"
    with pytest.raises(ConfigError, match="nothing learned to save"):
        save_state(est, good)
    est.carry_over(state)
    est.reset(np.random.default_rng(0))
    save_state(est, good)

    other = StiffnessMPF(replace(vehicle, mass=vehicle.mass + 100), MPFConfig(particles=7))
    with pytest.raises(ConfigError, match=r"different vehicle \(mass: saved"):
        load_state(other, good)
    rec = json.loads(good.read_text())
    (tmp_path / "v2.json").write_text(json.dumps(rec | {"format_version": 2}))
    with pytest.raises(ConfigError, match="format version 2"):
        load_state(est, tmp_path / "v2.json")
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(ConfigError, match="not a readable state file"):
        load_state(est, tmp_path / "junk.json")
    with pytest.raises(ConfigError, match="no such state file"):
        load_state(est, tmp_path / "missing.json")
    lateral_rec = rec | {"params": ["Cf_y", "Cr_y"], "mu": np.asarray(rec["mu"])[:, 1:].tolist(),
                         "Lam": np.asarray(rec["Lam"])[:, 1:, 1:].tolist(), "C_nominal": rec["C_nominal"][1:]}
    (tmp_path / "lat.json").write_text(json.dumps(lateral_rec))
    with pytest.raises(ConfigError, match="saved for Cf_y, Cr_y; this filter estimates Cx, Cf_y, Cr_y"):
        load_state(est, tmp_path / "lat.json")
    (tmp_path / "shape.json").write_text(json.dumps(rec | {"nu": rec["nu"][:3]}))
    with pytest.raises(ConfigError, match="shapes do not match"):
        load_state(est, tmp_path / "shape.json")


def test_a_state_saved_before_a_vehicle_key_existed_loads_when_the_key_is_at_its_default(tmp_path):
    """A vehicle key added since the state was saved (relaxation_length, load_sensitivity) counts as its default
    (a vehicle file without them: 0, None)."""
    vehicle = dataclasses.replace(load_scenario("paper-sim").vehicle, relaxation_length=0.0, load_sensitivity=None)
    est = StiffnessMPF(vehicle, MPFConfig(particles=8, backend="numpy"))
    est.reset(np.random.default_rng(0))
    path = save_state(est, tmp_path / "state.json")
    record = json.loads(path.read_text())
    del record["vehicle"]["relaxation_length"], record["vehicle"]["load_sensitivity"]
    path.write_text(json.dumps(record))
    load_state(est, path)
