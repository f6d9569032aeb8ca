"""The IMU model a new user gets: white noise estimated from the data, bias estimation on
with the MEMS defaults, the vehicle TOML's figures where given, warnings where they
disagree with the data; and the adaptive forgetting of the MPF."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tirefilter.estimators import build_log_estimator
from tirefilter.estimators.sensors import (
    DISTURBANCE_RW, FALLBACK_SIGMA, MEMS_BIAS0_STD, MEMS_BIAS_RW, checked_against, sensors_for_log,
)
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.estimators.mpf.adaptation import DRIFT_TIME, FORGETTING_MAX, FORGETTING_MIN, SURPRISE_TIME
from tirefilter.stats.noise import held_share, white_noise_std
from tirefilter.vehicle.params import VehicleParams, load_vehicle

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = VehicleParams(mass=1500.0, yaw_inertia=2500.0, lf=1.2, lr=1.5, wheel_radius=0.31, cg_height=0.55,
                        Cf_y=80000.0, Cr_y=90000.0, Cx=150000.0)


def _drive(n=6000, dt=0.01, seed=0, sigma=(0.3, 0.2, 0.004)):
    """A vehicle-like signal per IMU channel (sines, steps of a square-wave steer, a slow
    drift) plus white noise of the given std."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    base = {
        "ax": 0.8 * np.sin(2 * np.pi * 0.2 * t) + 0.05 * t / t[-1],
        "ay": 3.0 * np.sin(2 * np.pi * 0.7 * t) + 1.5 * np.sign(np.sin(2 * np.pi * 0.25 * t)),
        "yaw_rate": 0.2 * np.sin(2 * np.pi * 0.7 * t + 0.3),
    }
    return t, {c: base[c] + s * rng.standard_normal(n) for c, s in zip(base, sigma)}


DATA_SHEET = ("mass = 1500.0\nyaw_inertia = 2500.0\nlf = 1.2\nlr = 1.5\nwheel_radius = 0.31\ncg_height = 0.55\n"
              "Cf_y = 80000.0\nCr_y = 90000.0\nCx = 150000.0\n")


def _files(tmp_path, n, seed, extra_vehicle=""):
    """A lateral-model Log CSV of `_drive` and a vehicle TOML of data-sheet values (plus
    `extra_vehicle`)."""
    t, sig = _drive(n=n, seed=seed)
    log = tmp_path / "log.csv"
    cols = {"t": t, "delta": 0.01 * np.sin(t), "vx": np.full_like(t, 20.0), **sig}
    np.savetxt(log, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="")
    veh = tmp_path / "v.toml"
    veh.write_text(DATA_SHEET + extra_vehicle)
    return log, veh


@pytest.mark.parametrize("sigma", [0.02, 0.3, 1.1])
def test_noise_estimate_within_10_percent_of_a_known_level(sigma):
    _, sig = _drive(sigma=(sigma, sigma, sigma))
    for c, y in sig.items():
        assert white_noise_std(y) == pytest.approx(sigma, rel=0.10), c


def test_noise_estimate_ignores_spikes_holds_and_gaps():
    t, sig = _drive(seed=1)
    y = sig["ay"].copy()
    y[::400] += 20.0  # spikes
    held = np.arange(5, len(y), 8)
    y[held] = y[held - 1]  # 12.5% held samples, as a logger repeating the last value
    y[1000:1300] = np.nan  # a gap
    assert white_noise_std(y) == pytest.approx(0.2, rel=0.10)
    assert held_share(y) == pytest.approx(len(held) / np.isfinite(y).sum(), abs=0.01)
    assert math.isnan(white_noise_std(y[:10]))  # too few samples


def test_a_data_sheet_vehicle_gets_noise_from_the_log_and_mems_bias_defaults():
    t, sig = _drive(seed=2)
    sig["vx"] = np.full_like(t, 20.0)
    sig["delta"] = np.zeros_like(t)
    est = build_log_estimator("mpf", VEHICLE, t, sig, model="lateral", particles=20, config={})
    cfg = est.cfg
    assert cfg.sigma == pytest.approx((0.3, 0.2, 0.004), rel=0.10)
    assert cfg.bias0_std == MEMS_BIAS0_STD and cfg.bias_rw == MEMS_BIAS_RW and est.bias_on
    assert cfg.disturbance_rw == DISTURBANCE_RW
    record = est.sensors.to_dict()
    assert record["noise_estimated"] and record["bias_estimated"]
    assert record["sigma_source"] == {"ax": "data", "ay": "data", "yaw_rate": "data"}
    assert record["bias_source"] == "defaults (automotive MEMS)" and not record["warnings"]
    assert "estimated from the log" in est.sensors.describe()[0]


def test_given_figures_win_and_a_3x_disagreement_is_reported():
    t, sig = _drive(seed=3)
    vehicle = replace(VEHICLE, sigma_ax=0.3, sigma_ay=0.01, sigma_yaw_rate=0.004, bias0_std_ax=0.0, bias0_std_ay=0.0,
                      bias0_std_yaw_rate=0.0, bias_rw_ax=0.0, bias_rw_ay=0.0, bias_rw_yaw_rate=0.0)
    model = sensors_for_log(vehicle, sig)
    assert model.sigma == (0.3, 0.01, 0.004) and model.sigma_source == ("vehicle file",) * 3
    assert not model.bias_on and model.bias_source == "vehicle file"
    (warning,) = model.warnings  # ay only: 0.01 against the data's 0.2
    assert "sigma_ay = 0.01" in warning and "0.05 times" in warning
    # a scenario's figures checked against its first seconds: the same rule
    checked = checked_against(replace(model, warnings=()), sig, "the first 10 s")
    assert len(checked.warnings) == 1 and checked.sigma_data[1] == pytest.approx(0.2, rel=0.1)


def test_mpf_overrides_are_reported_as_such_and_short_logs_fall_back():
    t, sig = _drive(n=12, seed=4)
    sig["vx"] = np.full_like(t, 20.0)
    est = build_log_estimator("mpf", VEHICLE, t, sig, model="lateral", particles=10,
                              config={"mpf": {"sigma": [0.5, 0.5, 0.01], "bias_rw": [0, 0, 0], "bias0_std": [0, 0, 0],
                                              "disturbance_rw": [0, 0, 0]}})
    assert not est.bias_on
    record = est.sensors.to_dict()
    assert record["sigma_source"] == {"ax": "--config", "ay": "--config", "yaw_rate": "--config"}
    assert record["bias_source"] == "--config" and not record["bias_estimated"]
    short = sensors_for_log(VEHICLE, sig)
    assert short.sigma == FALLBACK_SIGMA and short.sigma_source == ("default",) * 3
    assert "too few samples" in short.warnings[-1]
    kf = build_log_estimator("kf", VEHICLE, t, sig, model="lateral", particles=None, config={})
    assert kf.sensors.to_dict()["bias_estimated"] is False and "kf" in kf.sensors.bias_source


def test_replay_summary_records_the_sensor_model(tmp_path):
    log, veh = _files(tmp_path, 300, 5)
    assert load_vehicle(veh).sigma_ay is None and load_vehicle(veh).bias_rw_ay is None
    out = tmp_path / "r.csv"
    res = subprocess.run([sys.executable, "-m", "tirefilter.cli", "replay", str(log), "--vehicle", str(veh),
                          "--particles", "20", "--out", str(out)], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    assert "sensor noise (std), estimated from the log" in res.stdout and "IMU bias: estimated" in res.stdout
    sensors = json.loads(out.with_suffix(".json").read_text())["sensors"]
    assert sensors["noise_estimated"] and sensors["bias_estimated"]
    assert sensors["sigma"]["ay"] == pytest.approx(0.2, rel=0.15)


def test_adaptive_forgetting_follows_the_normalised_innovation():
    """z_k is the EWMA of the weighted normalised innovation; lambda_k = 1 - (1 - lambda) z_k,
    clipped (derivations, "Adaptive forgetting"). Checked against the formula on fixed residuals."""
    cfg = MPFConfig(model="lateral", particles=4, forgetting=0.99, bias0_std=(0, 0, 0), bias_rw=(0, 0, 0),
                    disturbance_rw=(0, 0, 0))
    mpf = StiffnessMPF(VEHICLE, cfg)
    mpf.reset(np.random.default_rng(0))
    nu = np.full(4, 12.0)
    fit = np.sqrt(nu / (nu - 2.0))[:, None]  # |v|^2 at its expectation: s_k = 1
    for _ in range(50):
        mpf._adapt_forgetting(fit, nu, 0.01)
    assert mpf.surprise == pytest.approx(1.0) and mpf.lam == pytest.approx(0.99)
    z, a = 1.0, -math.expm1(-0.01 / SURPRISE_TIME)
    for k in range(5):  # residuals 3x their spread: s_k = 9
        mpf._adapt_forgetting(3 * fit, nu, 0.01)
        z += a * (9.0 - z)
        assert mpf.surprise == pytest.approx(z, rel=1e-12)
        assert mpf.lam == pytest.approx(max(1 - 0.01 * z, FORGETTING_MIN), rel=1e-12)
    for _ in range(200):
        mpf._adapt_forgetting(10 * fit, nu, 0.01)
    assert mpf.lam == FORGETTING_MIN
    for _ in range(400):
        mpf._adapt_forgetting(0.1 * fit, nu, 0.01)
    assert mpf.surprise < 0.02 and mpf.lam == FORGETTING_MAX  # 1 - 0.01 z would exceed the cap
    fixed = StiffnessMPF(VEHICLE, replace(cfg, forgetting_mode="fixed"))
    fixed.reset(np.random.default_rng(0))
    fixed._adapt_forgetting(10 * fit, nu, 0.01)
    assert fixed.lam == 0.99


def test_drift_statistic_forgets_fast_when_the_sampled_deviations_lean_one_way():
    """z'_k = |d_k|^2 (2 - a) / (a n_w) of the smoothed whitened w_k - mu (derivations,
    "Adaptive forgetting"): checked against the formula; a persistent lean drives lambda to its minimum,
    zero-mean draws leave it near the configured value."""
    cfg = MPFConfig(model="lateral", particles=3, forgetting=0.99, bias0_std=(0, 0, 0), bias_rw=(0, 0, 0),
                    disturbance_rw=(0, 0, 0))
    mpf = StiffnessMPF(VEHICLE, cfg)
    mpf.reset(np.random.default_rng(0))
    L11 = np.broadcast_to(np.diag([4.0, 9.0]), (3, 2, 2))  # predictive scale: std 2 and 3
    a = -math.expm1(-0.01 / DRIFT_TIME)
    d = np.zeros(2)
    for k in range(3):
        dw = np.tile([2.0 * 0.5, -3.0 * 0.5], (3, 1))  # whitened: (0.5, -0.5) in every particle
        mpf.lam = cfg.forgetting
        mpf._track_drift(dw, L11, 0.01)
        d += a * (np.array([0.5, -0.5]) - d)
        z = d @ d * (2 - a) / (a * 2)
        assert mpf.drift == pytest.approx(d, rel=1e-12)
        assert mpf.lam == pytest.approx(max(min(0.99, 1 - 0.01 * z), FORGETTING_MIN), rel=1e-12)
    for _ in range(100):
        mpf._track_drift(np.tile([2.0, -3.0], (3, 1)), L11, 0.01)
    assert mpf.lam == FORGETTING_MIN
    rng = np.random.default_rng(1)
    mpf.drift[:] = 0.0
    zs = []
    for _ in range(4000):  # zero-mean unit draws: z' averages 1
        mpf.lam = 1.0
        mpf._track_drift(np.tile(rng.standard_normal(2) * [2.0, 3.0], (3, 1)), L11, 0.01)
        zs.append(float(mpf.drift @ mpf.drift) * (2 - a) / (a * 2))
    assert np.mean(zs[200:]) == pytest.approx(1.0, abs=0.15)


def test_check_log_shows_the_noise_and_warns_on_a_3x_disagreement(tmp_path):
    from tirefilter.replay import check_log

    log, veh = _files(tmp_path, 2000, 6, "sigma_ay = 0.05\n")
    summary = check_log(log, veh)
    assert summary.noise["sigma_from_data"]["ay"] == pytest.approx(0.2, rel=0.1)
    assert summary.noise["sigma_from_data"]["yaw_rate"] == pytest.approx(0.004, rel=0.1)
    text = summary.format()
    assert "white noise estimated from the log: ax 0.3" in text and "(vehicle file: 0.05 m/s^2)" in text
    assert any("sigma_ay = 0.05" in w and "0.25 times" in w for w in summary.warnings)
    assert not any("sigma_ax" in w for w in summary.warnings)  # not given: nothing to disagree with
    assert json.loads(json.dumps(summary.to_dict()))["noise"]["sigma_source"]["ay"] == "vehicle file"
