"""The model check (`tirefilter.model_check`, run.json `model_check`; docs/derivations.md, "The
model check"): its batch-means error against the direct formula, its false-alarm rate on data
from the model itself (a Kalman filter's exact one-step predictive), its robustness to residuals
correlated in time, the bounded time windows, the MPF's predictive (numpy and compiled equal),
and the check of the MPF on a drive of the linear single-track model (no warning) against the
same drive on saturating Pacejka tyres (the warning names the bins where they saturate)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.io.results import ESTIMATE_COLUMNS
from tirefilter.model_check import (BIN_WIDTH, MAX_WINDOWS, NSUM, ModelCheck, PredictiveCheck, ratio_mean_se,
                                    region_text, summary_line)
from tirefilter.runs import Run, Sample, StepSummary, output_sinks, run
from tirefilter.scenarios import load_scenario
from tirefilter.vehicle import single_track as st


def _kalman_null(M: int, seed: int, n: int = 6000, dt: float = 0.01, phi: float = 0.999, q: float = 0.1,
                 r: float = 0.3):
    """M replications of two channels from the model x_{k+1} = phi x_k + q w, y = x + r v, and the
    Kalman filter's one-step predictive of y (exact): the times (n,), the predicted mean of the
    first channel (the "a^Y", stationary std 2.2) (n, M) and the standardised residuals (n, M, 2)."""
    rng = np.random.default_rng(seed)
    sd = q / math.sqrt(1.0 - phi**2)
    x = rng.standard_normal((M, 2)) * sd
    xh, P = np.zeros((M, 2)), np.full((M, 2), sd**2)
    m0, z = np.empty((n, M)), np.empty((n, M, 2))
    for k in range(n):
        x = phi * x + q * rng.standard_normal((M, 2))
        y = x + r * rng.standard_normal((M, 2))
        m, Pm = phi * xh, phi**2 * P + q**2
        S = Pm + r**2
        m0[k], z[k] = m[:, 0], (y - m) / np.sqrt(S)
        K = Pm / S
        xh, P = m + K * (y - m), (1.0 - K) * Pm
    return np.arange(n) * dt, m0, z


def _fire_rate(t, m0, z, **rule) -> float:
    fires = 0
    for i in range(m0.shape[1]):
        c = PredictiveCheck(**rule)
        c.add(t, m0[:, i], z[:, i])
        fires += c.result()["warning"] is not None
    return fires / m0.shape[1]


def test_batch_means_error_is_the_ratio_estimators_formula():
    """ratio_mean_se from the mergeable sums equals the direct formula over the batch list,
    J/(J-1) sum_j (X_j - theta n_j)^2 / (sum n)^2, for both statistics."""
    rng = np.random.default_rng(0)
    c = PredictiveCheck(batch_s=1.0)
    t = np.arange(2000) * 0.01
    m0, z = np.full(2000, 0.2), rng.standard_normal((2000, 2)) * 1.3 + 0.1
    c.add(t, m0, z)
    c.finish()
    s = c.bins[0, 0]
    n = np.full(20, 100.0)
    for which, g in (("x", z[:, 0]), ("y", z[:, 0] ** 2)):
        X = g.reshape(20, 100).sum(axis=1)
        theta = X.sum() / n.sum()
        se = math.sqrt(20 / 19 * np.sum((X - theta * n) ** 2)) / n.sum()
        got = ratio_mean_se(s, which)
        assert got[0] == pytest.approx(theta, rel=1e-12) and got[1] == pytest.approx(se, rel=1e-9)


def test_false_alarm_rate_on_data_from_the_model_itself():
    """With the exact predictive (a Kalman filter on data from its own model), a rule without
    tolerance at alpha = 0.1 warns on at most about alpha of the runs (Bonferroni over the bins
    and the effective batch count make it conservative); the product's rule (alpha = 0.01 and
    the tolerances) never in 300 runs."""
    t, m0, z = _kalman_null(300, 0)
    rate = _fire_rate(t, m0, z, alpha=0.1, var_tol=0.0, bias_tol=0.0)
    assert 0.01 <= rate <= 0.12, rate  # measured: 0.050 (400 runs of 60 s: 0.040; 200 of 300 s: 0.065)
    assert _fire_rate(t, m0, z) == 0.0  # measured: 0


def test_batch_means_hold_the_rate_when_the_residuals_are_correlated_in_time():
    """Residuals with mean 0 and mean square 1 in every bin but correlated over about a second
    (AR(1), 0.99 per sample): with 5-s batches the rule keeps its rate; taking every sample as
    a tenth of a second as a batch (nearly the iid error) warns on nearly every run."""
    rng = np.random.default_rng(3)
    M, n = 150, 6000
    z = np.empty((n, M, 2))
    z[0] = rng.standard_normal((M, 2))
    for k in range(1, n):
        z[k] = 0.99 * z[k - 1] + math.sqrt(1 - 0.99**2) * rng.standard_normal((M, 2))
    t = np.arange(n) * 0.01
    m0 = np.repeat(3.0 * np.sin(2 * np.pi * t / 7.0)[:, None], M, axis=1)
    rule = dict(alpha=0.1, var_tol=0.0, bias_tol=0.0)
    assert _fire_rate(t, m0, z, **rule) <= 0.12  # measured: 0.040
    assert _fire_rate(t, m0[:, :20], z[:, :20], batch_s=0.1, **rule) >= 0.5  # measured: 0.80


def test_time_windows_stay_bounded_and_cover_every_sample():
    """A 4000-s drive fed in chunks: at most MAX_WINDOWS windows, back to back from the first
    sample, their samples adding up to the drive's; the bins hold the same samples."""
    rng = np.random.default_rng(1)
    c = PredictiveCheck()
    t = 150.02 + np.arange(400_000) * 0.01
    for lo in range(0, len(t), 4096):
        sl = slice(lo, lo + 4096)
        c.add(t[sl], 5.0 * np.sin(t[sl]), rng.standard_normal((len(t[sl]), 2)))
    r = c.result()
    w = r["windows"]
    assert len(w) <= MAX_WINDOWS and w[0]["t_from"] == pytest.approx(150.02)
    assert all(a["t_to"] == pytest.approx(b["t_from"]) for a, b in zip(w, w[1:]))
    assert sum(x["samples"] for x in w) == len(t) == r["samples"] == sum(b["samples"] for b in r["bins"])
    assert r["warning"] is None and c.bins.shape[-1] == NSUM


def test_region_names_the_flagged_bins():
    top = list(range(9))
    assert region_text([], top) is None
    assert region_text([6, 7, 8], top) == f"|a^Y| above {6 * BIN_WIDTH:g} m/s^2"
    assert region_text([2, 3], top) == f"|a^Y| {2 * BIN_WIDTH:g}-{4 * BIN_WIDTH:g} m/s^2"
    assert region_text(top, top) == "every |a^Y| visited"


def _sine_drive(model, duration=40.0, seed=2, amp=0.06, vx0=15.0):
    """The truth's single-track model (`model`: its tyres) in a steering sine of growing amplitude
    from vx0, the wheels rolling freely, sampled at 100 Hz with white noise (a^Y 0.05 m/s^2, gyro
    0.0035 rad/s); v^X given as an input."""
    v = model.vehicle
    rng = np.random.default_rng(seed)
    dt = 0.01
    x = np.zeros(9)
    x[st.VX], x[st.WF], x[st.WR] = vx0, vx0 / v.wheel_radius, vx0 / v.wheel_radius
    out = []
    for k in range(int(duration / dt)):
        t = k * dt
        delta = amp * math.sin(2 * math.pi * 0.25 * t) * min(1.0, 1.5 * t / duration)
        u = {"delta": delta, "drive_torque": 0.0, "brake_torque": 0.0, "surface": 1.0, "bank": 0.0}
        _, aux = st.derivatives(x, u, model)
        out.append((t, Inputs(delta=delta, omega_f=x[st.WF], omega_r=x[st.WR], vx=x[st.VX]),
                    Measurement(ax=aux["ax"] + 0.05 * rng.standard_normal(),
                                ay=aux["ay"] + 0.05 * rng.standard_normal(),
                                yaw_rate=x[st.R] + 0.0035 * rng.standard_normal())))
        x = st.rk4_step(x, u, model, dt)
        x[st.WF] = x[st.WR] = x[st.VX] / v.wheel_radius
    return out


def _lateral_mpf(vehicle, backend="numba", particles=100):
    cfg = MPFConfig(particles=particles, model="lateral", backend=backend, bias0_std=(0.0, 0.0, 0.0),
                    bias_rw=(0.0, 0.0, 0.0), disturbance_rw=(0.0, 0.0, 0.0))
    return StiffnessMPF(vehicle, cfg)


def _checked_run(est, samples) -> dict:
    """The drive through the run loop with the model-check sink: the summary's check."""
    sink = ModelCheck(est)
    stepper = Run(est, ESTIMATE_COLUMNS, [sink])
    summary = run((Sample(k, t, u, y) for k, (t, u, y) in enumerate(samples)), stepper,
                  StepSummary(seed=0, estimator=est.name), rng=np.random.default_rng(1))
    json.dumps(summary.model_check)  # (run.json)
    return summary.model_check


def test_mpf_predictive_backends_equal():
    """The one-step predictive (mean, variance, measured value of a^Y and the yaw rate) of the
    compiled step equals the numpy reference's at every sample; the C backend's equals numba's bit for bit."""
    sc = load_scenario("snow-sine")
    samples = _sine_drive(sc.model, duration=4.0)
    got = {}
    for backend in ("numpy", "numba", "c"):
        est = _lateral_mpf(sc.model.vehicle, backend, particles=40)
        est.predictive_wanted = True
        est.reset(np.random.default_rng(1))
        rows = []
        for t, u, y in samples:
            est.step(t, u, y)
            p = est.one_step_predictive()
            rows.append(np.full(6, np.nan) if p is None else np.concatenate(p[1:]))
        got[backend] = np.array(rows)
    a, b = got["numpy"], got["numba"]
    assert np.array_equal(got["c"], b, equal_nan=True)
    assert np.array_equal(np.isnan(a), np.isnan(b)) and np.isnan(a[0]).all() and not np.isnan(a[1:]).any()
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12)


def test_mpf_check_names_the_saturating_bins_and_passes_the_linear_model():
    """The same 40-s drive on snow, the truth's tyres linear (the filter's own model) or Pacejka
    (saturating near |a^Y| 2.5 m/s^2): no warning on the first; on the second the a^Y residuals
    fall short of the prediction in the upper bins and the warning names them."""
    sc = load_scenario("snow-sine")
    linear = _checked_run(_lateral_mpf(sc.model.vehicle),
                          _sine_drive(dataclasses.replace(sc.model, tire_model="linear")))
    assert linear["warning"] is None and linear["ay_abs_max"] > 2.5
    assert "explains the data" in summary_line(linear)
    sat = _checked_run(_lateral_mpf(sc.model.vehicle), _sine_drive(sc.model))
    assert sat["warning"] is not None and sat["region"].startswith("|a^Y| above")
    low = float(sat["region"].split()[2])
    assert 1.5 <= low <= 2.5  # measured: 2 m/s^2
    flagged = [b for b in sat["bins"] if b["ay"].get("flagged") or b["yaw_rate"].get("flagged")]
    assert flagged and all(b["ay_abs_from"] >= low for b in flagged)
    assert min(b["ay"]["bias"] for b in flagged) < -0.5  # measured: -0.99 std (the tyre gives less than predicted)
    assert summary_line(sat).startswith("warning: model check:")


def test_output_sinks_check_an_estimator_with_a_predictive():
    est = _lateral_mpf(load_scenario("snow-sine").model.vehicle, particles=8)
    sinks = output_sinks(ESTIMATE_COLUMNS, est)
    assert any(isinstance(s, ModelCheck) for s in sinks) and est.predictive_wanted
    assert not any(isinstance(s, ModelCheck) for s in output_sinks(ESTIMATE_COLUMNS, est, metrics=False))


def test_ekf_check_on_its_own_model_and_on_saturating_tyres():
    """The EKF's Gaussian predictive (h and S of its linearisation) in the same check: no warning
    on the drive of its own model (its predictive wider than the data: the process noise and the
    per-step stiffness deviations it assumes); on the Pacejka drive its stiffness, a random walk,
    follows the tyres down and its stated uncertainty covers the misfit: no warning either,
    where the MPF's flags |a^Y| above 2 m/s^2."""
    from tirefilter.estimators.ekf import EKFConfig, StiffnessEKF

    sc = load_scenario("snow-sine")
    cfg = EKFConfig(model="lateral")
    for model in (dataclasses.replace(sc.model, tire_model="linear"), sc.model):
        check = _checked_run(StiffnessEKF(sc.model.vehicle, cfg), _sine_drive(model))
        assert check["warning"] is None and check["samples"] == 3999
        ratios = [b[c]["var_ratio"] for b in check["bins"] if b["tested"] for c in ("ay", "yaw_rate")]
        assert max(ratios) < 1.5  # measured: 0.62 (linear), 0.59 (Pacejka; the a^Y bias at most -0.17 std)
