"""The friction GP-SSM against the simulated truth (short friction-snow runs, fixed seeds),
its friction CSV in co-simulation and replay, bad settings, slip clipping, low-speed gate,
and the combined pipeline."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from figures import within

from tirefilter.cli import main
from tirefilter.io.friction import FRICTION_COLUMNS, read_friction, snapshot_blocks
from tirefilter.io.results import read_results
from tirefilter.cosim.run import run_scenario
from tirefilter.errors import ConfigError
from tirefilter.estimators import build_estimator
from tirefilter.estimators.base import FrictionCurve, Inputs, Measurement
from tirefilter.estimators.gpssm.filter import DEG, FrictionGPSSM, GPSSMConfig
from tirefilter.scenarios import load_scenario
from tirefilter.vehicle.tires import pure_lateral_friction

SCENARIO = load_scenario("friction-snow")
PEAK = float(np.max(pure_lateral_friction(SCENARIO.model.pacejka, np.linspace(0, 30 * DEG, 301))))


def _visited_rmse(fc: FrictionCurve):
    """RMSE and +-2 std coverage of each axle's curve over the visited slip range."""
    truth = pure_lateral_friction(SCENARIO.model.pacejka, fc.alpha)
    out = []
    for mu, sd, lo, hi in ((fc.mu_f, fc.mu_f_std, *fc.visited[:2]), (fc.mu_r, fc.mu_r_std, *fc.visited[2:])):
        m = (fc.alpha >= lo) & (fc.alpha <= hi)
        err = mu[m] - truth[m]
        out.append((math.sqrt(float(np.mean(err**2))), float(np.mean(np.abs(err) <= 2 * sd[m])), int(m.sum())))
    return out


# RMSE over the visited range in % of the peak friction, mu_f / mu_r: measured (seed 3) axle 0.41 / 0.40, tensor
# 1.34 / 1.12; seeds 0-2: axle up to 0.60 / 0.64, tensor 0.55-1.27 / 0.49-1.00. Bounds 3x the seed-3 figure.
@pytest.mark.parametrize("basis,particles,tol_pct", [("axle", 100, 1.25), ("tensor", 100, 4.0)])
def test_learns_the_snow_curve_over_the_visited_range(fmu_paths, basis, particles, tol_pct):
    """20 s of friction-snow (steering amplitude 0.02 rad, slip up to ~1.5 deg), seed 3: the
    learned mu_f, mu_r within `tol_pct` % of the peak friction (RMSE over the visited range, at
    least 1 deg each side), starting from the 0.05-peak prior that is 80% off there."""
    est = build_estimator("gpssm", SCENARIO, model="auto", particles=particles, config={"gpssm": {"basis": basis}})
    run_scenario(replace(SCENARIO, duration=20.0), estimator=est, seed=3)
    fc = est.friction()
    assert fc.visited[0] < -1 * DEG and fc.visited[1] > 1 * DEG
    visited = _visited_rmse(fc)
    assert all(n >= 8 for _, _, n in visited), visited
    within("larger curve RMSE of mu_f, mu_r over the visited range, % of the peak",
           max(100 * rmse / PEAK for rmse, _, _ in visited), tol_pct)
    # the prior alone is far off there: learning, not the prior, did it
    i = np.argmin(np.abs(fc.alpha - 1 * DEG))
    assert est.prior(fc.alpha[i], fc.alpha[i])[0] < 0.5 * pure_lateral_friction(SCENARIO.model.pacejka, fc.alpha[i])
    assert est.diagnostics()["slip_clipped_samples"] == 0


def _short_scenario_file(tmp_path: Path, duration: float) -> Path:
    text = (Path(SCENARIO.file).read_text().replace("duration = 80.0", f"duration = {duration}")
            .replace("excitation = [[2.0, 80.0]]", f"excitation = [[2.0, {duration}]]"))
    path = tmp_path / "friction-short.toml"
    path.write_text(text)
    return path


def test_run_writes_friction_csv_blocks_with_truth(fmu_paths, tmp_path, capsys):
    cfg = tmp_path / "g.toml"
    cfg.write_text('[gpssm]\nbasis = "axle"\nparticles = 50\n')
    out = tmp_path / "run"
    assert main(["run", "--scenario", str(_short_scenario_file(tmp_path, 12.0)), "--estimator", "gpssm",
                 "--config", str(cfg), "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "friction curves:" in printed and "clipped): 0 of" in printed
    with open(out / "friction.csv") as f:
        assert tuple(f.readline().strip().split(",")) == FRICTION_COLUMNS + ("true_mu_f", "true_mu_r")
    blocks = snapshot_blocks(read_friction(out / "friction.csv"))
    assert [b["t"][0] for b in blocks] == [10.0, 12.0]  # every 10 s and at the end
    for b in blocks:
        a = b["alpha"]
        assert a[0] == pytest.approx(-30 * DEG) and a[-1] == pytest.approx(30 * DEG)
        assert np.max(np.diff(a)) <= 0.25 * DEG + 1e-12
        assert np.allclose(b["true_mu_f"], pure_lateral_friction(SCENARIO.model.pacejka, a))
        assert np.all(np.isfinite(b["mu_f"])) and np.all(b["mu_r_std"] >= 0)
    import json

    summary = json.loads((out / "run.json").read_text())
    assert summary["estimator"] == "gpssm" and summary["estimator_config"]["basis"] == "axle"
    assert summary["estimator_config"]["diagnostics"]["slip_clipped_samples"] == 0


def test_replay_writes_result_friction_csv(fmu_paths, tmp_path):
    """A co-simulation's signals as a Log CSV, replayed: RESULT.friction.csv, no truth."""
    summary, rows = run_scenario(replace(SCENARIO, duration=6.0), seed=0, keep_rows=True)
    from tirefilter.cosim.fmu import VehicleFMU
    from tirefilter.io.results import result_columns
    from tirefilter.replay import write_log

    cols = dict(zip(result_columns(VehicleFMU().output_names), rows.T))
    log = write_log(tmp_path / "log.csv", {"t": cols["t"], "delta": cols["meas_delta"], "ax": cols["meas_ax"],
                                           "ay": cols["meas_ay"], "yaw_rate": cols["meas_yaw_rate"],
                                           "vx": cols["true_vx"]})
    cfg = tmp_path / "g.toml"
    cfg.write_text('[gpssm]\nbasis = "axle"\nparticles = 40\nsnapshot_every = 2.0\n')
    result = tmp_path / "res.csv"
    assert main(["replay", str(log), "--vehicle", str(SCENARIO.vehicle_file), "--estimator", "gpssm", "--config",
                 str(cfg), "--out", str(result), "--quiet"]) == 0
    with open(tmp_path / "res.friction.csv") as f:
        assert tuple(f.readline().strip().split(",")) == FRICTION_COLUMNS
    blocks = snapshot_blocks(read_friction(tmp_path / "res.friction.csv"))
    assert [b["t"][0] for b in blocks] == pytest.approx([2.0, 4.0, 6.0])
    assert len(read_results(result)["t"]) == len(cols["t"])


def test_failed_run_keeps_snapshots(fmu_paths, tmp_path):
    class Failing(FrictionGPSSM):
        def step(self, t, u, y):
            if t > 11.0:
                raise ConfigError("test", "", "injected failure")
            return super().step(t, u, y)

    base = build_estimator("gpssm", SCENARIO, model="auto", particles=30, config={"gpssm": {"basis": "axle"}})
    est = Failing(SCENARIO.vehicle, base.cfg)
    with pytest.raises(ConfigError, match="injected"):
        run_scenario(replace(SCENARIO, duration=20.0), estimator=est, seed=0, friction_csv=tmp_path / "f.csv")
    blocks = snapshot_blocks(read_friction(tmp_path / "f.csv"))
    assert [b["t"][0] for b in blocks] == [10.0]


@pytest.mark.parametrize("key,value,match", [
    ("L", 0.0, "L"), ("L", -0.1, "L"), ("lengthscale", 0.0, "lengthscale"), ("lengthscale", -1.0, "lengthscale"),
    ("basis_functions", 0, "basis_functions"), ("slip_range", 0.6, "wider than the basis domain"),
    ("grid_step", 0.01, "0.25 deg"), ("basis", "grid", "tensor or axle"), ("forgetting", 1.5, "forgetting"),
    ("stats", "fast", "exact or rank1"), ("nonsense", 1, "unknown option"), ("s_f", -1.0, "s_f"),
])
def test_bad_settings_rejected_before_the_run(tmp_path, key, value, match):
    with pytest.raises(ConfigError, match=match):
        build_estimator("gpssm", SCENARIO, model="auto", particles=None, config={"gpssm": {key: value}})


def test_bad_settings_write_nothing(tmp_path, capsys):
    cfg = tmp_path / "g.toml"
    cfg.write_text("[gpssm]\nlengthscale = -0.01\n")
    out = tmp_path / "run"
    assert main(["run", "--scenario", "friction-snow", "--estimator", "gpssm", "--config", str(cfg), "--out",
                 str(out), "--quiet"]) == 1
    assert "lengthscale" in capsys.readouterr().err
    assert not (out / "results.csv").exists()
    with pytest.raises(ConfigError, match="lateral model only"):
        build_estimator("gpssm", SCENARIO, model="full", particles=None, config={})


@pytest.mark.parametrize("basis", ["tensor", "axle"])
def test_slip_outside_domain_is_clipped_and_counted(basis):
    """L = 0.1 rad, a steer of 0.3 rad: every particle's front slip is outside and clipped
    (N counted at that step); straight driving after: nothing more."""
    N = 20
    est = FrictionGPSSM(SCENARIO.vehicle, GPSSMConfig(particles=N, basis=basis, L=0.1, x0_std=(0.01, 0.001)))
    est.reset(np.random.default_rng(0))
    est.step(0.0, Inputs(delta=0.3, vx=10.0), Measurement(ay=0.0, yaw_rate=0.0))
    d = est.diagnostics()
    assert d["slip_clipped_samples"] == N and d["slip_clipped_steps"] == 1 and d["particle_slip_evaluations"] == N
    est.step(0.04, Inputs(delta=0.0, vx=10.0), Measurement(ay=0.0, yaw_rate=0.0))
    d = est.diagnostics()
    assert d["slip_clipped_samples"] == N and d["slip_clipped_steps"] == 1 and d["particle_slip_evaluations"] == 2 * N
    fc = est.friction()
    assert np.all(np.isfinite(fc.mu_f)) and fc.alpha[-1] == pytest.approx(0.1)


@pytest.mark.parametrize("stats", ["exact", "rank1"])
def test_low_speed_freezes_learning(stats):
    est = FrictionGPSSM(SCENARIO.vehicle, GPSSMConfig(particles=20, basis="axle", stats=stats))
    est.reset(np.random.default_rng(1))
    nu0 = np.array(est.stats.nu).copy()
    for k in range(5):
        e = est.step(0.04 * k, Inputs(delta=0.05, vx=2.0), Measurement(ay=0.5, yaw_rate=0.1))
        assert not e.active and math.isfinite(e.vy) and math.isfinite(e.Cf_y)
    assert np.array_equal(np.array(est.stats.nu), nu0)
    e = est.step(0.2, Inputs(delta=0.05, vx=10.0), Measurement(ay=0.5, yaw_rate=0.1))
    assert e.active and np.all(np.array(est.stats.nu) > nu0)


def test_missing_vx_is_an_error():
    est = FrictionGPSSM(SCENARIO.vehicle, GPSSMConfig(particles=5, basis="axle"))
    est.reset(np.random.default_rng(0))
    with pytest.raises(ConfigError, match="needs vx"):
        est.step(0.0, Inputs(delta=0.0), Measurement(ay=0.0, yaw_rate=0.0))


def test_combined_hands_over_the_mpf_slope(fmu_paths):
    """Combined: the MPF's cornering stiffness becomes the prior's slope (within 15% of the
    true snow slope B C mu at the handover), then the GP learns; seed 0, 20 s."""
    est = build_estimator("combined", SCENARIO, model="auto", particles=100, config={"gpssm": {"basis": "axle"}})
    assert est.name == "combined"
    run_scenario(replace(SCENARIO, duration=20.0), estimator=est, seed=0)
    d = est.diagnostics()
    assert d["handover_time"] is not None and d["handover_time"] < 20.0
    p = SCENARIO.model.pacejka
    true_slope = p.B_y * p.C_y * p.mu_y
    sf, sr = est.prior.slope()
    # measured +4.7 / +5.4 % (seed 0); seeds 1-3: +1.8 to +6.1 %; bound 2.8x
    assert sf == pytest.approx(true_slope, rel=0.15) and sr == pytest.approx(true_slope, rel=0.15)
    assert est.prior0.slope()[0] < 0.2 * true_slope  # the paper's prior (peak 0.05) is far below


def _slip_stretch(force_hold: str, seeds=(0, 1, 3)) -> float:
    """The posterior-mean slip angles against the truth's over 4-20 s of friction-snow (tensor
    basis, N = 200): the least-squares factor e = s a_true, averaged over both axles and the seeds."""
    from tirefilter.cosim.fmu import VehicleFMU
    from tirefilter.io.results import result_columns

    factors = []
    for seed in seeds:
        est = build_estimator("gpssm", SCENARIO, model="auto", particles=200,
                              config={"gpssm": {"force_hold": force_hold}})
        slips, step = [], est.step

        def record(t, u, y, step=step, est=est):
            e = step(t, u, y)
            slips.append(est.mean_slip)
            return e

        est.step = record
        _, rows = run_scenario(replace(SCENARIO, duration=20.0), estimator=est, seed=seed, keep_rows=True)
        cols = dict(zip(result_columns(VehicleFMU().output_names), rows.T))
        m = cols["t"] >= 4.0
        for axle, est_slip in zip("fr", np.array(slips)[m].T):
            true = cols[f"true_alpha_{axle}"][m]
            factors.append(float(true @ est_slip / (true @ true)))
    return float(np.mean(factors))


# measured: linear 0.9905 (the seeds' single factors 0.97-1.01), zero (the paper's held forces) 1.062; bound 3x
def test_the_slip_angles_are_not_stretched(fmu_paths):
    """The forces growing linearly over the step (`force_hold = "linear"`, derivations F4): the
    filter's slip angles follow the truth's without the stretch of the held forces (the held a^Y
    lags the sampled one by half a step, and v^Y integrates the lag into a v^Y error in phase
    with v^Y, 6 % of the slip on this drive)."""
    assert abs(_slip_stretch("linear") - 1.0) < 0.03
    assert _slip_stretch("zero") - 1.0 > 0.04


def test_lag_shift_is_the_forgotten_mean_of_the_slip_errors_smoothed():
    """`lag_shift` against its definition written out: the learning samples' signed held-force
    slip errors, forgotten with the statistics' factor, per grid bin of the mean slip, smoothed with
    the kernel's length-scale and divided by the smoothed forgotten count."""
    est = FrictionGPSSM(SCENARIO.vehicle, GPSSMConfig(particles=4, basis="axle"))
    est.reset(np.random.default_rng(0))
    rng = np.random.default_rng(1)
    G = len(est.grid)
    W, S = np.zeros((2, G)), np.zeros((2, G))
    for _ in range(30):
        lam, jf, jr, e = float(rng.uniform(0.9, 1.0)), int(rng.integers(G)), int(rng.integers(G)), float(rng.normal())
        est._slip_spread(lam, jf, jr, 0.0, 0.0, e)
        W *= lam
        S *= lam
        W[0, jf] += 1.0
        W[1, jr] += 1.0
        S[0, jf] += e
        S[1, jr] += e
    k = np.exp(-0.5 * ((est.grid[:, None] - est.grid[None, :]) / est.cfg.lengthscale) ** 2)
    want = (S @ k.T) / (W @ k.T)
    np.testing.assert_allclose(est.lag_shift(), want, rtol=1e-12, atol=1e-15)


def test_friction_reads_the_learned_curve_at_the_shifted_slip():
    """With the held forces' slip error recorded, the calibrated curve and its std are the
    uncorrected ones read at alpha + lag_shift (linear interpolation on the grid); the paper's
    band (`band = "posterior"`) records none and reads the curve as learned."""
    for band in ("calibrated", "posterior"):
        est = FrictionGPSSM(SCENARIO.vehicle, GPSSMConfig(particles=20, basis="axle", band=band))
        est.reset(np.random.default_rng(2))
        for k in range(60):
            d = 0.03 * math.sin(2 * math.pi * 0.5 * 0.04 * k)
            est.step(0.04 * k, Inputs(delta=d, vx=12.0), Measurement(ay=12.0 * 12.0 * d / 2.8, yaw_rate=12.0 * d / 2.8))
        fc = est.friction()
        if band == "posterior":
            assert not np.any(est.slips.lag)
            continue
        shift = est.lag_shift()
        assert np.max(np.abs(shift)) > 0.01 * DEG
        lag = est.slips.lag.copy()
        est.slips.lag[:] = 0.0
        raw = est.friction()
        est.slips.lag[:] = lag
        for mu, sd, raw_mu, raw_sd, sh in ((fc.mu_f, fc.mu_f_std, raw.mu_f, raw.mu_f_std, shift[0]),
                                           (fc.mu_r, fc.mu_r_std, raw.mu_r, raw.mu_r_std, shift[1])):
            np.testing.assert_allclose(mu, np.interp(fc.alpha + sh, fc.alpha, raw_mu), rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(sd, np.interp(fc.alpha + sh, fc.alpha, raw_sd), rtol=1e-12, atol=1e-15)
