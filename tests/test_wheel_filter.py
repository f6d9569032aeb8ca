"""The MPF's wheel-speed pre-filter (estimators/wheel_filter.py, derivations, "Wheel-speed pre-filter") against
closed forms, and how a replay and the MPF turn it on."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.sensors import sensors_for_log, wheel_noise_from_data
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.estimators.wheel_filter import WheelSpeedFilter, steady_state_gain
from tirefilter.scenarios import load_scenario

RW = 0.3
DT = 0.01


def test_steady_state_gain_and_variance_are_the_riccati_fixed_point():
    """After many steps the filter's posterior variance is (1 - K) M with M, K of the closed
    form; the gain solves M = M r / (M + r) + q."""
    f = WheelSpeedFilter(0.03, RW, 0.2, 0.02)
    for k in range(2000):
        f.step(DT, np.array([60.0, 61.0]), 0.0)
    q, r = f.process_variance(DT), (RW * 0.03) ** 2
    assert q == pytest.approx((0.2 * DT) ** 2 + 0.02**2 * DT, rel=1e-15)
    K = steady_state_gain(r, q)
    M = K * r / (1.0 - K)  # K = M / (M + r)
    assert M == pytest.approx(M * r / (M + r) + q, rel=1e-12)
    np.testing.assert_allclose(f.P, (1.0 - K) * M, rtol=1e-12)


def test_no_lag_when_the_drive_explains_the_wheels():
    """Wheel speeds that follow the acceleration it is driven with (a ramp, then a swing) come
    out unchanged: the filter adds no lag where the IMU carries the wheels."""
    f = WheelSpeedFilter(0.03, RW, 0.2, 0.02)
    s, a = 15.0, 0.0
    for k in range(500):
        s += DT * a  # the rolling speed at this sample, from the last sample's acceleration
        out = f.step(DT, np.array([s, s + 0.1]) / RW, a if k else math.nan)
        np.testing.assert_allclose(out * RW, [s, s + 0.1], rtol=0, atol=1e-11)
        a = 1.0 if k < 200 else 2.0 * math.sin(0.05 * k)


def test_white_noise_is_reduced_to_the_closed_form_level():
    """Constant wheel speeds with white noise: the output error has the variance of the
    steady-state filter for a constant, K r / (2 - K) (the error obeys e_k = (1 - K) e_{k-1} +
    K n_k), within 3 % on 200 000 samples; well below r."""
    rng = np.random.default_rng(3)
    sigma = 0.03
    f = WheelSpeedFilter(sigma, RW, 0.2, 0.02)
    n = 200_000
    z = 50.0 + sigma * rng.standard_normal((n, 2))
    out = np.array([f.step(DT, zk, 0.0) for zk in z])[1000:]
    r = (RW * sigma) ** 2
    K = steady_state_gain(r, f.process_variance(DT))
    expected = K * r / (2.0 - K)
    np.testing.assert_allclose(np.var((out - 50.0) * RW, axis=0), expected, rtol=0.03)
    assert expected < 0.2 * r


def test_missing_samples_predict_and_starts_are_the_measurement():
    f = WheelSpeedFilter(0.03, RW, 0.2, 0.02)
    out = f.step(DT, np.array([math.nan, 40.0]), 1.0)
    assert math.isnan(out[0]) and out[1] == 40.0 and f.P[1] == pytest.approx((RW * 0.03) ** 2)
    p_before = f.P[1]
    out = f.step(DT, np.array([41.0, math.nan]), 1.0)  # front starts; rear predicted only
    assert out[0] == 41.0 and math.isnan(out[1])
    assert f.s[1] == pytest.approx(40.0 * RW + DT * 1.0) and f.P[1] == pytest.approx(p_before + f.process_variance(DT))
    f.reset()
    assert np.isnan(f.s).all()


def test_bad_figures_are_refused():
    with pytest.raises(ValueError, match="sigma_omega"):
        WheelSpeedFilter(0.0, RW, 0.2, 0.02)
    for key, value in (("sigma_omega", -0.1), ("sigma_omega", math.inf), ("wheel_slip_rw", -1.0),
                       ("wheel_slip_rw", math.nan)):
        with pytest.raises(ConfigError, match=key):
            MPFConfig(**{key: value}).validated()


def test_wheel_noise_is_estimated_from_the_log():
    """A smooth wheel-speed signal plus white noise of 0.03 rad/s: the estimate within 10 %;
    the replay's sensor model carries it, describes it and turns the MPF's filter on."""
    rng = np.random.default_rng(11)
    t = np.arange(6000) * DT
    clean = 60.0 + 5.0 * np.sin(0.3 * t)
    signals = {"omega_f": clean + 0.03 * rng.standard_normal(t.size),
               "omega_r": clean * 1.01 + 0.03 * rng.standard_normal(t.size),
               "ax": 0.1 * rng.standard_normal(t.size)}
    est = wheel_noise_from_data(signals)
    assert est == pytest.approx(0.03, rel=0.1)
    assert wheel_noise_from_data({"ax": signals["ax"]}) == 0.0
    model = sensors_for_log(None, signals)
    assert model.sigma_omega == est and model.to_dict()["sigma_omega"] == est
    assert any("wheel-speed noise" in line for line in model.describe())
    from tirefilter.estimators import mpf_config_for_log

    vehicle = load_scenario("paper-sim").vehicle
    cfg = mpf_config_for_log(vehicle, t, signals, model="full", particles=10, overrides={}, sensors=model)
    assert cfg.sigma_omega == est
    off = mpf_config_for_log(vehicle, t, signals, model="full", particles=10, overrides={"sigma_omega": 0.0},
                             sensors=model)
    assert off.sigma_omega == 0.0


def test_paper_sim_has_exact_wheels_and_no_filter():
    """The co-simulated scenarios' wheel speeds have no noise: the filter stays off (the
    paper's model), and the lateral model never has one."""
    from tirefilter.estimators import mpf_config_for_scenario

    sc = load_scenario("paper-sim")
    assert sc.sensor_spec.sigma_omega == 0.0
    cfg = mpf_config_for_scenario(sc, model="full", particles=10, overrides={})
    assert cfg.sigma_omega == 0.0
    est = StiffnessMPF(sc.vehicle, cfg)
    est.reset(np.random.default_rng(0))
    assert est.wheels is None
    lateral = StiffnessMPF(sc.vehicle, MPFConfig(model="lateral", sigma_omega=0.03, particles=10))
    lateral.reset(np.random.default_rng(0))
    assert lateral.wheels is None


def test_the_mpf_takes_the_filtered_wheel_speeds():
    """With sigma_omega > 0 the model sees the filter's wheel speeds: a run fed noisy wheel
    speeds holds (as its last input) exactly what a WheelSpeedFilter fed the same samples and
    the same drive returns; the drive is the last a^X minus the posterior-mean bias plus the
    posterior-mean v^Y r."""
    sc = load_scenario("paper-sim")
    v = sc.vehicle
    est = StiffnessMPF(v, MPFConfig(particles=16, sigma_omega=0.03, bias0_std=(0.1, 0.1, 0.01)))
    est.reset(np.random.default_rng(1))
    ref = WheelSpeedFilter(0.03, v.wheel_radius, est.cfg.sigma[0], est.cfg.wheel_slip_rw)
    rng = np.random.default_rng(2)
    ax_prev, t = math.nan, 0.0
    for k in range(30):
        t += DT
        omega = 20.0 / v.wheel_radius + 0.03 * rng.standard_normal(2)
        ax = 0.3 + 0.05 * rng.standard_normal()
        if k:
            q = np.exp(est.logw)
            drive = ax_prev - q @ est.b[:, 0] + q @ (est.x[:, 1] * est.x[:, 2])
        else:
            drive = math.nan
        expect = ref.step(DT if k else est.cfg.sample_period, omega, drive)
        est.step(t, Inputs(delta=0.01, omega_f=omega[0], omega_r=omega[1], vx=20.0),
                 Measurement(ax=ax, ay=0.5, yaw_rate=0.02))
        np.testing.assert_allclose(est.u_prev[1:3], expect, rtol=1e-14)
        ax_prev = ax


def test_check_log_and_the_replay_summary_show_the_wheel_noise(tmp_path):
    """A full-model log whose wheel speeds carry 0.05 rad/s of white noise: check-log prints
    the estimate (within 10 %), and a replay's run summary records it and the MPF uses it."""
    import json

    from tirefilter.cli import main
    from tirefilter.replay import check_log

    rng = np.random.default_rng(4)
    t = np.arange(1500) * DT
    vx = 20.0 + 0.5 * np.sin(0.5 * t)
    r = 0.05 * np.sin(1.3 * t)
    omega = vx / 0.3
    cols = {"t": t, "delta": 0.02 * np.sin(1.3 * t), "ax": 0.25 * np.cos(0.5 * t) + 0.1 * rng.standard_normal(t.size),
            "ay": vx * r + 0.1 * rng.standard_normal(t.size), "yaw_rate": r + 0.003 * rng.standard_normal(t.size),
            "omega_f": omega + 0.05 * rng.standard_normal(t.size),
            "omega_r": omega * 1.002 + 0.05 * rng.standard_normal(t.size)}
    log = tmp_path / "log.csv"
    np.savetxt(log, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="")
    veh = tmp_path / "v.toml"
    veh.write_text('mass = 1500.0\nyaw_inertia = 2500.0\nlf = 1.2\nlr = 1.4\nwheel_radius = 0.3\ncg_height = 0.55\n'
                   'drive = "rear"\nCf_y = 100000.0\nCr_y = 90000.0\nCx = 150000.0\n')
    summary = check_log(log, veh)
    assert summary.noise["sigma_omega"] == pytest.approx(0.05, rel=0.1)
    assert f"wheel speeds {summary.noise['sigma_omega']:.3g} rad/s" in summary.format()
    out = tmp_path / "res.csv"
    assert main(["replay", str(log), "--vehicle", str(veh), "--out", str(out), "--quiet", "--particles", "50"]) == 0
    run = json.loads(out.with_suffix(".json").read_text())
    assert run["sensors"]["sigma_omega"] == summary.noise["sigma_omega"]
