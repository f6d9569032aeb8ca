"""The master drives any object following the Estimator protocol (docs/design.md)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.io.results import read_results
from tirefilter.cosim.run import run_scenario
from tirefilter.estimators.base import Estimate, Estimator, Inputs, Measurement, Posterior
from tirefilter.scenarios import load_scenario
from test_cosim import _rrd_series


class EchoEstimator:
    """Reports what it was given: the state from the measured signals, and one draw
    from its generator as the stiffness (to show the generator is seeded per run)."""

    name = "echo"

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.calls: list[tuple[float, Inputs, Measurement]] = []

    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        self.calls.append((t, u, y))
        return Estimate(active=t >= 1.0, vx=u.vx, vy=0.0, yaw_rate=y.yaw_rate, Cf_y=1e5 + self.rng.standard_normal(),
                        Cr_y=1e5, b_ax=y.ax, ess=float(len(self.calls)))

    def posterior(self) -> Posterior:
        return Posterior(np.zeros((1, 3)), np.zeros(1))


def test_echo_follows_the_protocol():
    assert isinstance(EchoEstimator(), Estimator)


def test_master_feeds_sensors_and_writes_estimates(fmu_paths, tmp_path):
    # friction-snow samples at 25 Hz with a 10 ms communication step
    scenario = replace(load_scenario("friction-snow"), duration=2.0,
                       sensors=("ay", "yaw_rate", "vx", "delta"))  # no ax, no wheel speeds
    est = EchoEstimator()
    summary, _ = run_scenario(scenario, estimator=est, seed=5, results_csv=tmp_path / "r.csv", rrd=tmp_path / "r.rrd")
    r = read_results(tmp_path / "r.csv")
    assert summary.steps == len(est.calls) == 51 and summary.median_step_us > 0
    times = np.array([c[0] for c in est.calls])
    np.testing.assert_allclose(times, r["t"])
    np.testing.assert_allclose(np.diff(times), 0.04, atol=1e-9)
    # measurements and inputs are the FMU's sensor outputs at the sample instants
    np.testing.assert_allclose([c[2].yaw_rate for c in est.calls], r["meas_yaw_rate"], rtol=1e-15)
    np.testing.assert_allclose([c[2].ay for c in est.calls], r["meas_ay"], rtol=1e-15)
    np.testing.assert_allclose([c[1].delta for c in est.calls], r["meas_delta"], rtol=1e-15)
    np.testing.assert_allclose([c[1].vx for c in est.calls], r["true_vx"], rtol=1e-15)
    # sensors the scenario does not have arrive as NaN
    assert all(math.isnan(c[2].ax) and math.isnan(c[1].omega_f) and math.isnan(c[1].omega_r) for c in est.calls)
    # the estimate columns hold what the estimator returned
    np.testing.assert_allclose(r["vx"], r["true_vx"], rtol=1e-15)
    np.testing.assert_allclose(r["beta"], 0.0)
    np.testing.assert_array_equal(r["active"], (r["t"] >= 1.0).astype(float))
    np.testing.assert_array_equal(r["ess"], np.arange(1, 52))
    assert np.isnan(r["b_ax"]).all() and np.isnan(r["Cx"]).all()
    # and the recording has the estimator's series under /estimator/echo/...
    t_rrd, cf = _rrd_series(tmp_path / "r.rrd", "/estimator/echo/stiffness/Cf_y")
    np.testing.assert_allclose(cf, r["Cf_y"] * 1e-3, rtol=1e-15)  # recorded in kN/rad
    _, yaw = _rrd_series(tmp_path / "r.rrd", "/estimator/echo/state/yaw_rate")
    np.testing.assert_allclose(yaw, r["yaw_rate"], rtol=1e-15)


def test_one_fmu_reset_between_trials(fmu_paths):
    """Monte-Carlo use: one FMU instance, reset per trial, seeds reproduce exactly."""
    scenario = replace(load_scenario("paper-sim"), duration=5.0)
    with VehicleFMU("2") as fmu:
        runs = [run_scenario(scenario, estimator=EchoEstimator(), seed=s, fmu=fmu, keep_rows=True)[1]
                for s in (1, 2, 1)]
    np.testing.assert_array_equal(np.nan_to_num(runs[0]), np.nan_to_num(runs[2]))
    assert not np.array_equal(np.nan_to_num(runs[0]), np.nan_to_num(runs[1]))
    _, fresh = run_scenario(scenario, estimator=EchoEstimator(), seed=2, keep_rows=True)
    np.testing.assert_array_equal(np.nan_to_num(runs[1]), np.nan_to_num(fresh))
