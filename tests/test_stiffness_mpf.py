"""The stiffness MPF against ground truth (fixed seeds, stated tolerances)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from figures import within

from tirefilter.io.results import read_results
from tirefilter.cosim.run import run_scenario
from tirefilter.errors import ConfigError
from tirefilter.estimators import build_estimator
from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.estimators.mpf.adaptation import CX_EXCITATION_TIME
from tirefilter.metrics import settling_time, stiffness_errors
from tirefilter.scenarios import load_scenario


def _run(tmp_path, scenario, model, seed, particles=300, duration=None, mpf=None):
    """A run from a known initial state: the truth starts at x0 exactly and the filter
    knows it to 0.05 m/s. (From the paper's P0 = diag([1, 1, pi/180]^2) start-up, the
    filter still locks onto a wrong state in some runs; derivations, "Start-up, plausibility and restart".)"""
    if duration:
        scenario = replace(scenario, duration=duration, surface_changes=tuple(t for t in scenario.surface_changes
                                                                               if t < duration))
    truth = {k: v for k, v in scenario.truth.items() if not k.endswith("_std") or k == "stiffness_dev_std"}
    scenario = replace(scenario, truth=truth | {"vx0_std": 0.0, "vy0_std": 0.0, "yaw_rate0_std": 0.0})
    config = {"mpf": {"x0_std": [0.05, 0.05, 0.002], **(mpf or {})}}
    est = build_estimator("mpf", scenario, model=model, particles=particles, config=config)
    path = tmp_path / f"{model}-{seed}.csv"
    summary, _ = run_scenario(scenario, estimator=est, seed=seed, results_csv=path)
    return read_results(path), summary, scenario


# Bounds of `test_paper_sim_lateral_stiffness_converges`, per model: (|mean error| %, mean |error| % of Cf_y and
# Cr_y, the range of the late sigma %). Measured at its seed 1 and, for the spread, seeds 0, 2, 3 (same run):
#   full:    mean -0.03 / +0.16 % (seeds 0-3 up to 0.23), mean abs 0.30 / 0.35 % (up to 0.53),
#            sigma 5.92 / 5.45 % (4.94-6.07);
#   lateral: mean -0.016 / +0.007 % (up to 0.13), mean abs 1.51 / 0.64 % (up to 1.66 / 0.66),
#            sigma 7.26 / 5.85 % (5.08-7.26).
# Bounds about 3x the seed-1 figure, or about 3x the seeds' largest where the seed-1 figure is near zero by
# chance (the signed means); a steady 2.9 % stiffness bias fails them.
CONVERGED = {
    "full": {"Cf_y": (0.5, 1.0, (4.0, 7.0)), "Cr_y": (0.5, 1.0, (4.0, 7.0))},
    "lateral": {"Cf_y": (0.4, 4.0, (4.0, 8.0)), "Cr_y": (0.4, 2.0, (4.0, 8.0))},
}


@pytest.mark.parametrize("model", ["full", "lateral"])
def test_paper_sim_lateral_stiffness_converges(fmu_paths, tmp_path, model):
    """paper-sim up to the surface change (30 s), N = 300, seed 1: steady-state lateral
    stiffness error (mean and mean absolute) within the measured figures' bounds (`CONVERGED`)
    and the deviation spread near the true 5% once the start-up transient (which inflates
    Lambda; it decays with the forgetting) is over."""
    r, summary, scenario = _run(tmp_path, load_scenario("paper-sim"), model, seed=1, duration=29.5)
    assert np.all(np.isfinite(r["Cf_y"])) and np.all(np.isfinite(r["vy"]))
    for param in ("Cf_y", "Cr_y"):
        mean_tol, mean_abs_tol, (sigma_lo, sigma_hi) = CONVERGED[model][param]
        e = stiffness_errors(r, scenario, param)
        within(f"{param} abs mean error %", abs(e["mean"]), mean_tol,
               wide="the seeds' largest, about 3x: the seed's own mean is near zero by chance")
        within(f"{param} mean abs error %", e["mean_abs"], mean_abs_tol)
        late = r["t"] >= 20.0
        sigma_pct = np.mean(100 * r[f"{param}_sigma"][late] / r[f"true_{param}_mean"][late])
        within(f"{param} deviation spread % (true 5)", sigma_pct, sigma_hi, lower=sigma_lo)
    vy_rmse = np.sqrt(np.mean((r["vy"] - r["true_vy"])[r["t"] > 5] ** 2))
    # measured 0.0042 (full) / 0.0047 (lateral) m/s (seed 1; seeds 0-3: 0.0037-0.0063); bound 3x
    within("vy RMSE m/s", vy_rmse, 0.013)
    if model == "full":
        assert np.isfinite(r["Cx"]).all()
        # weakly observable (docs/design.md): measured -0.24 % (seed 1), +0.83 / +1.14 / +0.51 % (seeds 0, 2, 3);
        # bound 1.3x the seeds' largest (6x the seed-1 figure: Cx spreads more than the lateral stiffness)
        within("Cx abs mean error %", abs(stiffness_errors(r, scenario, "Cx")["mean"]), 1.5,
               wide="1.3x the seeds' largest: Cx is weakly observable")
    else:
        assert np.isnan(r["Cx"]).all()


def test_paper_sim_tracks_the_surface_change(fmu_paths, tmp_path):
    """paper-sim as `tirefilter run --scenario paper-sim --seed 3` runs it (the default C
    backend, N = 500, the paper's start-up from P0), 60 s with the 50% cut of every stiffness
    at 30 s: Cf_y, Cr_y and Cx each settle within 5% of the new surface mean in at most 4 s
    (the settling target of docs/results.md; `metrics.settling_time`: the estimate stays inside the band to the
    end of the run), and the steady-state errors before and after the cut stay small."""
    scenario = load_scenario("paper-sim")
    est = build_estimator("mpf", scenario, model="auto", particles=None, config={})
    assert (est.cfg.backend, est.cfg.particles, est.cfg.model) == ("c", 500, "full")
    run_scenario(scenario, estimator=est, seed=3, results_csv=tmp_path / "r.csv")
    r = read_results(tmp_path / "r.csv")
    # measured 1.29 / 1.30 / 1.69 s (seed 3); seeds 0-7: Cf_y 1.00-4.03, Cr_y 1.04-4.50, Cx 1.25-2.64 s (Cr_y over
    # 4 s in 2 of the 8, and in 16 of the 100 trials of the paper-sim study, docs/results.md): the bound is the 4 s target,
    # 3x this seed's figure
    for param in ("Cf_y", "Cr_y", "Cx"):
        within(f"{param} settling time s", settling_time(r, param, 30.0), 4.0)
    # mean abs error over 5-30 s and 35-60 s: measured 0.34 / 0.51 / 0.80 % (seed 3; seeds 0-7 up to
    # 0.49 / 0.51 / 1.61 %); bound about 3x (lateral 2-3x, Cx 3x)
    for param, tol in (("Cf_y", 1.0), ("Cr_y", 1.0), ("Cx", 2.4)):
        within(f"{param} mean abs error %", stiffness_errors(r, scenario, param)["mean_abs"], tol)


def _synthetic_steps(n=300, seed=0):
    scenario = load_scenario("paper-sim")
    _, rows = run_scenario(replace(scenario, duration=n * 0.01), seed=seed, keep_rows=True)
    from tirefilter.cosim.fmu import VehicleFMU
    from tirefilter.io.results import ESTIMATE_COLUMNS, INPUT_TRUTH_COLUMNS, truth_column

    with VehicleFMU("2") as fmu:
        cols = ESTIMATE_COLUMNS + tuple(map(truth_column, fmu.output_names)) + INPUT_TRUTH_COLUMNS
    return scenario, {c: rows[:, j] for j, c in enumerate(cols)}


def test_missing_measurements_are_skipped_not_propagated(fmu_paths):
    """Missing samples (NaN) on the paper-sim drive, checked sample by sample against a copy of
    the filter stepped otherwise:
    - skipped: where every measurement is missing there is no likelihood, the weights stay
      exactly as they were; where one channel is missing the step is not the one given that
      channel's last sample (a measurement is skipped, not held);
    - a missing input holds the last one: the step equals the step given that value;
    - not propagated: every estimate and every log-weight stays finite, to the end and through a
      final sample with nothing measured."""
    import copy

    scenario, r = _synthetic_steps()
    est = build_estimator("mpf", scenario, model="full", particles=200, config={})
    est.reset(np.random.default_rng(0))
    last_ay = math.nan
    checked = {"none": 0, "ay": 0, "input": 0}
    for k in range(len(r["t"])):
        gone = 200 <= k < 204  # every measurement missing
        y = Measurement(np.nan if k % 3 == 0 or gone else r["meas_ax"][k],
                        np.nan if k % 5 == 0 or gone else r["meas_ay"][k],
                        np.nan if 100 <= k < 120 or gone else r["meas_yaw_rate"][k])
        u = Inputs(r["meas_delta"][k], r["meas_omega_f"][k], np.nan if k == 50 else r["meas_omega_r"][k])
        before = est.posterior().log_weights
        twin = copy.deepcopy(est) if (k == 50 or gone or (k % 5 == 0 and k % 10 == 5)) else None
        e = est.step(r["t"][k], u, y)
        values = [e.vx, e.vy, e.yaw_rate, e.Cf_y, e.Cr_y, e.Cx, e.Cf_y_std, e.Cf_y_sigma, e.ess]
        assert all(math.isfinite(v) for v in values), (k, e)
        assert np.isfinite(est.posterior().log_weights).all(), k
        if k == 50:  # omega_r missing: the one held is the last sample's
            held = twin.step(r["t"][k], Inputs(u.delta, u.omega_f, float(twin.u_prev[2])), y)
            assert repr(held) == repr(e) and np.array_equal(twin.posterior().particles, est.posterior().particles)
            checked["input"] += 1
        elif gone:
            np.testing.assert_array_equal(est.posterior().log_weights, before)
            checked["none"] += 1
        elif twin is not None and math.isfinite(last_ay):  # a^Y missing: not held at its last sample
            with_last = twin.step(r["t"][k], u, replace(y, ay=last_ay))
            assert with_last.vy != e.vy
            checked["ay"] += 1
        if math.isfinite(y.ay):
            last_ay = y.ay
    assert checked == {"none": 4, "ay": 30, "input": 1}
    before = est.posterior().log_weights
    e_all_nan = est.step(r["t"][-1] + 0.01, Inputs(0.01, r["meas_omega_f"][-1], r["meas_omega_r"][-1]), Measurement())
    assert math.isfinite(e_all_nan.Cf_y) and math.isfinite(e_all_nan.vy)
    np.testing.assert_array_equal(est.posterior().log_weights, before)


def test_same_seed_same_estimates(fmu_paths):
    scenario, r = _synthetic_steps(100)
    out = []
    for _ in range(2):
        est = build_estimator("mpf", scenario, model="full", particles=100, config={})
        est.reset(np.random.default_rng(42))
        out.append([est.step(r["t"][k], Inputs(r["meas_delta"][k], r["meas_omega_f"][k], r["meas_omega_r"][k]),
                             Measurement(r["meas_ax"][k], r["meas_ay"][k], r["meas_yaw_rate"][k])).Cf_y
                    for k in range(100)])
    assert out[0] == out[1]


@pytest.mark.parametrize("options,match", [
    ({"particles": 0}, "N must be an integer >= 1"),
    ({"forgetting": 1.5}, r"lambda must be in \(0, 1\]"),
    ({"forgetting": 0.0}, r"lambda must be in \(0, 1\]"),
    ({"sigma": (0.05, -0.1, 0.01)}, "noise values must be >= 0"),
    ({"model": "bicycle"}, "expected full or lateral"),
])
def test_bad_options_are_rejected(options, match):
    vehicle = load_scenario("paper-sim").vehicle
    with pytest.raises(ConfigError, match=match):
        StiffnessMPF(vehicle, MPFConfig(**options))


def test_config_file_overrides_and_unknown_keys(fmu_paths):
    scenario = load_scenario("paper-sim")
    est = build_estimator("mpf", scenario, model="auto", particles=None, config={"mpf": {"forgetting": 0.995}})
    assert est.cfg.forgetting == 0.995 and est.cfg.particles == 500 and est.cfg.model == "full"
    with pytest.raises(ConfigError, match="unknown option"):
        build_estimator("mpf", scenario, model="full", particles=10, config={"mpf": {"lamda": 0.9}})


def test_imu_bias_is_estimated_on_snow_sine(tmp_path):
    """snow-sine has IMU biases (random walk from an initial offset): over the last 10 s
    the bias estimates are within 0.012 m/s^2 RMS of the true accelerometer biases (about
    0.14 and 0.15 m/s^2 with this seed) and within 0.001 rad/s of the yaw-rate bias.
    Measured (seed 2): 0.0044 / 0.0037 m/s^2 (3.2 / 2.4 % of the biases), 0.00033 rad/s;
    seeds 0, 1, 3: up to 0.0059 / 0.0071 m/s^2, 0.00067 rad/s. Bounds about 3x."""
    scenario = load_scenario("snow-sine")
    est = build_estimator("mpf", scenario, model="auto", particles=200, config={})
    run_scenario(scenario, estimator=est, seed=2, results_csv=tmp_path / "r.csv")
    r = read_results(tmp_path / "r.csv")
    last = r["t"] > 30.0
    assert min(abs(r["true_b_ax"][-1]), abs(r["true_b_ay"][-1])) > 0.1  # biases worth estimating
    for channel, tol in (("ax", 0.012), ("ay", 0.012), ("yaw_rate", 1e-3)):
        err = r[f"b_{channel}"][last] - r[f"true_b_{channel}"][last]
        assert np.sqrt(np.mean(err**2)) < tol, channel


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_gap_draws_vx_again_from_the_undriven_wheels(backend):
    """Straight at R_w * 60 rad/s for 1 s, then no sample until the wheels read 64 rad/s
    (the car gained 1.44 m/s in the gap): after a gap longer than `gap_after` the particles'
    v^X is drawn around R_w omega of the undriven (rear) axle at that sample (derivations,
    "After a gap in the data"); a shorter step, a disabled gap_after or a missing wheel speed draws nothing
    and the held inputs keep v^X at the speed before the gap."""
    vehicle = load_scenario("paper-sim").vehicle  # front drive: the rear axle is undriven
    R = vehicle.wheel_radius

    def run(t_after, omega_after=64.0, **options):
        est = StiffnessMPF(vehicle, MPFConfig(particles=200, backend=backend, **options))
        est.reset(np.random.default_rng(3))
        for k in range(101):
            est.step(0.01 * k, Inputs(0.0, 60.0, 60.0), Measurement(0.0, 0.0, 0.0))
        e = est.step(t_after, Inputs(0.0, 64.0, omega_after), Measurement(0.0, 0.0, 0.0))
        return e.vx, est.gap_redraws

    # the two speeds are 1.44 m/s apart; measured (seed 3, both backends) 0.0006 m/s from R_w 64 rad/s after the
    # redraw, 0.0052 / 0.00002 / 0.00001 m/s from R_w 60 rad/s without it (seeds 0, 1: at most 0.0006 / 0.0046);
    # bounds about 3x
    vx, n = run(2.0)
    assert n == 1 and abs(vx - 64.0 * R) < 0.002, vx
    for vx, n in (run(1.4), run(2.0, gap_after=0.0), run(2.0, omega_after=math.nan)):
        assert n == 0 and abs(vx - 60.0 * R) < 0.015, (vx, n)
    with pytest.raises(ConfigError, match="gap_after"):
        StiffnessMPF(vehicle, MPFConfig(gap_after=-1.0))


@pytest.mark.parametrize("options,match", [
    ({"slip_hold": "end"}, "expected interval or start"),
    ({"undriven_stiffness": "surface"}, "expected learned or nominal"),
    ({"restart_at_bound_after": -1.0}, "must be >= 0"),
    ({"x0_vx_wheel_std": -0.1}, "must be >= 0"),
])
def test_bad_slip_and_restart_options_are_rejected(options, match):
    with pytest.raises(ConfigError, match=match):
        StiffnessMPF(load_scenario("paper-sim").vehicle, MPFConfig(**options))


def test_defaults_and_the_papers_variant():
    """The interval slip, a 0.02 m/s v^X start spread, the bound restart and the undriven axle
    scaled by the excitation weight of Cx (nominal until Cx is excited) are the defaults; the
    paper's eq. (9) (slip of t_k held) and its nominal undriven axle are its switches."""
    cfg = MPFConfig()
    assert (cfg.slip_hold, cfg.undriven_stiffness, cfg.x0_vx_wheel_std, cfg.restart_at_bound_after) == (
        "interval", "learned", 0.02, 2.0)
    vehicle = load_scenario("paper-sim").vehicle
    est = StiffnessMPF(vehicle)
    est.reset(np.random.default_rng(0))
    assert est.undriven_share == 0.0 and est.full_share == pytest.approx(vehicle.Cx_undriven / vehicle.Cx)
    nominal = StiffnessMPF(vehicle, MPFConfig(undriven_stiffness="nominal"))
    assert nominal.undriven_share == 0.0 and nominal.full_share == 0.0


def test_cx_excitation_weight_is_the_contraction_of_the_linear_gaussian_posterior():
    """rho = I P_0 / (1 + I P_0) equals 1 - P_N / P_0 of the scalar Kalman filter of
    y_k = b_k w + e_k (prior variance P_0, noise variance R) after the same regressors, and
    the exact values at its ends (derivations, "The undriven axle")."""
    from tirefilter.estimators.mpf import cx_excitation_weight

    rng = np.random.default_rng(2)
    b, R, P0 = rng.normal(0.0, 5e-6, 300), 0.05**2, (0.3 * 2.632e5) ** 2
    P = P0
    for bk in b:  # the covariance form of the Kalman filter
        P = P - P * bk * bk * P / (bk * bk * P + R)
    assert cx_excitation_weight(float(np.sum(b * b) / R), P0) == pytest.approx(1.0 - P / P0, rel=1e-9)
    assert cx_excitation_weight(0.0, P0) == 0.0 and cx_excitation_weight(5.0, 0.0) == 0.0
    assert cx_excitation_weight(1.0 / P0, P0) == pytest.approx(0.5, rel=1e-15)
    assert cx_excitation_weight(9.0 / P0, P0) == pytest.approx(0.9, rel=1e-15)
    assert cx_excitation_weight(math.inf, P0) == 1.0
    with pytest.raises(ValueError, match=">= 0"):
        cx_excitation_weight(-1.0, P0)


def test_cx_excitation_counts_the_changes_of_the_slip_only():
    """`_excite_cx` on a driven slip held at 1% (no information: its level is the bias's), then
    stepped to 2%: the high-passed regressor b_k = (lambda_k - level_k) / m decays as
    (1 - a)^(j + 1) ds / m after the step, a = 1 - exp(-dt / T), so with lambda = 1 the
    information sums to (ds / m)^2 (1 - a)^2 / (1 - (1 - a)^2) / sigma_ax^2; with the gate closed
    it stays frozen, and the undriven axle takes the share rho of the surface scaling."""
    vehicle = load_scenario("paper-sim").vehicle  # front drive
    est = StiffnessMPF(vehicle, MPFConfig(backend="numpy"))
    est.reset(np.random.default_rng(0))
    est.active, est._lam_step, vx, dt = True, 1.0, 20.0, 0.01
    omega = lambda slip: vx / (1 - slip) / vehicle.wheel_radius  # noqa: E731  (slip = 1 - vx / (R_w omega))
    for _ in range(300):
        est._excite_cx(vx, np.array([0.0, omega(0.01), vx / vehicle.wheel_radius, vx]), dt)
    assert est.cx_info == 0.0 and est.cx_weight == 0.0 and est.undriven_share == 0.0
    for _ in range(3000):  # 30 s: (1 - a)^6000 is nothing
        est._excite_cx(vx, np.array([0.0, omega(0.02), vx / vehicle.wheel_radius, vx]), dt)
    q = math.exp(-dt / CX_EXCITATION_TIME)  # 1 - a
    want = (0.01 / vehicle.mass) ** 2 * q * q / (1 - q * q) / est.cfg.sigma[0] ** 2
    assert est.cx_info == pytest.approx(want, rel=1e-9)
    rho = want * est._cx_prior_var() / (1 + want * est._cx_prior_var())
    assert est.cx_weight == pytest.approx(rho, rel=1e-9) and est.cx_weight_max == est.cx_weight
    assert est.undriven_share == pytest.approx(rho * vehicle.Cx_undriven / vehicle.Cx, rel=1e-9)
    est.active = False
    est._excite_cx(vx, np.array([0.0, omega(0.03), vx / vehicle.wheel_radius, vx]), dt)
    assert est.cx_info == pytest.approx(want, rel=1e-9)  # frozen with the gate closed


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("drive", ["front", "rear"])
def test_undriven_axle_at_full_excitation_is_linear_in_w(drive, backend):
    """With Cx fully excited (rho = 1), a + B w of `_model` equals the accelerations of eq. (1)
    computed by hand with the driven axle at C_x,nom + w_x and the undriven one at
    C_u,nom (1 + w_x / C_x,nom)."""
    v = replace(load_scenario("paper-sim").vehicle, drive=drive)
    est = StiffnessMPF(v, MPFConfig(backend=backend))
    est.cx_weight = 1.0
    est._set_undriven_share()
    rng = np.random.default_rng(4)
    n = 7
    x = np.column_stack([20 + rng.normal(0, 1, n), rng.normal(0, 0.3, n), rng.normal(0, 0.1, n)])
    u = np.array([0.03, 20.4 / v.wheel_radius, 19.8 / v.wheel_radius, 20.0])
    w = rng.normal(0, 3e4, (n, 3))
    a, B, af, ar, slip = est._model(x, u)
    got = a + np.einsum("nij,nj->ni", B, w)
    ratio = 1.0 + w[:, 0] / v.Cx
    Cfx, Crx = (v.Cx + w[:, 0], v.Cx_undriven * ratio) if drive == "front" else (v.Cx_undriven * ratio,
                                                                                  v.Cx + w[:, 0])
    Ffx, Frx = Cfx * slip[0], Crx * slip[1]
    Ffy, Fry = (v.Cf_y + w[:, 1]) * af, (v.Cr_y + w[:, 2]) * ar
    cd, sd = math.cos(u[0]), math.sin(u[0])
    want = np.column_stack([(Ffx * cd - Ffy * sd + Frx) / v.mass, (Ffy * cd + Ffx * sd + Fry) / v.mass,
                            (v.lf * (Ffy * cd + Ffx * sd) - v.lr * Fry) / v.yaw_inertia])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


def test_interval_slip_predicts_the_speed_across_a_torque_step(fmu_paths):
    """One propagation step from the true state with the true stiffness of the step, on the
    FMU's paper-sim truth (wheel spin dynamics, torque square wave, 5% deviations redrawn
    every sample): the interval slip predicts v^X at t_k+1 far better than the slip of t_k
    held (derivations, "Wheel slip"), at the torque switches and on average."""
    scenario, r = _synthetic_steps(600)
    v = scenario.vehicle
    errs = {}
    for hold in ("start", "interval"):
        est = StiffnessMPF(v, MPFConfig(slip_hold=hold, backend="numpy"))
        x = np.column_stack([r["true_vx"], r["true_vy"], r["true_yaw_rate"]])[:-1]
        u = np.column_stack([r["true_delta"], r["true_omega_f"], r["true_omega_r"], r["true_vx"]])
        w = np.column_stack([r["true_Cx"] - v.Cx, r["true_Cf_y"] - v.Cf_y, r["true_Cr_y"] - v.Cr_y])[:-1]
        pred = np.empty(len(x))
        for k in range(len(x)):  # one particle per step
            xk, wk = x[k:k + 1], w[k:k + 1]
            first = est._model(xk, u[k])
            if hold == "interval":
                first = est._slip_over_step(xk, u[k], u[k + 1], wk, first, 0.01)
            pred[k] = est._propagate(xk, u[k], wk, 0.01, first)[0, 0]
        errs[hold] = pred - r["true_vx"][1:]
    switch = np.flatnonzero(np.diff(np.sign(r["true_drive_torque"])) != 0)  # steps k whose torque changed at k+1
    switch = switch[switch + 1 < len(x)] + 1
    assert len(switch) >= 2
    start, interval = np.abs(errs["start"][switch]), np.abs(errs["interval"][switch])
    # seed 0: 0.016 / 0.019 m/s held against 0.0004 / 0.0013 m/s; RMS over all steps 1.3e-3 against 7.6e-5
    assert np.all(start > 0.015) and np.all(interval < 0.1 * start), (start, interval)
    rms = {k: float(np.sqrt(np.mean(e**2))) for k, e in errs.items()}
    assert rms["interval"] < 0.1 * rms["start"], rms


def _steady_turn(vehicle, ay, vx=20.0):
    """Yaw rate and road-wheel angle of the linear single-track model in a steady turn at a^Y = ay."""
    r, L = ay / vx, vehicle.lf + vehicle.lr
    alpha_f = vehicle.mass * ay * vehicle.lr / L / vehicle.Cf_y
    alpha_r = vehicle.mass * ay * vehicle.lf / L / vehicle.Cr_y
    vy = vehicle.lr * r - vx * alpha_r
    return r, alpha_f + (vy + vehicle.lf * r) / vx


def _gate_trace(vehicle, backend, ay_samples, r, delta, sigma_ay=0.05, ax_samples=None, **cfg):
    est = StiffnessMPF(vehicle, MPFConfig(model="lateral", particles=200, backend=backend,
                                          sigma=(0.05, sigma_ay, 0.0035), bias0_std=(0.0, 0.0, 0.0),
                                          bias_rw=(0.0, 0.0, 0.0), disturbance_rw=(0.0, 0.0, 0.0), **cfg))
    est.reset(np.random.default_rng(1))
    ax = np.full(len(ay_samples), math.nan) if ax_samples is None else ax_samples
    return np.array([est.step(0.01 * k, Inputs(delta, math.nan, math.nan, 20.0), Measurement(x, ay, r)).active
                     for k, (x, ay) in enumerate(zip(ax, ay_samples))])


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_linear_region_gate_reads_the_lateral_acceleration_only(backend):
    """A steady turn at a^Y = 3 m/s^2 (inside gate_ay_max = 4) with a^X = -3 m/s^2 (braking)
    from sample 150 to 249, one a^X sample missing in it: the linear-region test (the paper's,
    |a^Y| alone) keeps the gate open on every sample after the 1 s warm-up."""
    vehicle = load_scenario("paper-sim").vehicle
    r, delta = _steady_turn(vehicle, 3.0)
    k = np.arange(300)
    ax = np.where((k >= 150) & (k < 250), -3.0, 0.0)
    ax[200] = math.nan
    assert np.array_equal(_gate_trace(vehicle, backend, np.full(300, 3.0), r, delta, ax_samples=ax), k >= 100)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_missing_ay_sample_does_not_open_the_linear_region_gate(backend):
    """A steady turn at a^Y = 5 m/s^2 (beyond gate_ay_max = 4) with every other a^Y sample
    missing (the guard's held samples): the gate stays closed on every sample (a missing
    sample holds the last a^Y, derivations, "Linear-region test")."""
    vehicle = load_scenario("paper-sim").vehicle
    r, delta = _steady_turn(vehicle, 5.0)
    k = np.arange(300)
    ay = np.where(k % 2 == 1, math.nan, 5.0)
    assert not _gate_trace(vehicle, backend, ay, r, delta).any()


def _lateral_drive_with_process_noise(q_true: float, seed: int = 3, T: float = 30.0) -> np.ndarray:
    """The lateral single-track model (paper-sim's vehicle, its nominal stiffness, v^X = 20 m/s,
    0.5 Hz steer of 0.02 rad) with white process noise of std q_true per sqrt(s) on the yaw rate,
    filtered by the MPF with `state_noise_from_data`; returns sqrt(q_state) at the end (v^Y, r)."""
    v = load_scenario("paper-sim").vehicle
    rng = np.random.default_rng(seed)
    dt, vx, sig = 0.01, 20.0, (0.05, 0.05, 0.0035)
    est = StiffnessMPF(v, MPFConfig(model="lateral", particles=200, sigma=sig, bias0_std=(0.0, 0.0, 0.0),
                                    bias_rw=(0.0, 0.0, 0.0), disturbance_rw=(0.0, 0.0, 0.0),
                                    state_noise_from_data=True, state_noise_time=5.0, x0_mean=(0.0, 0.0)))
    est.reset(np.random.default_rng(seed + 1))
    vy = r = 0.0
    for k in range(int(T / dt)):
        t = k * dt
        delta = 0.02 * math.sin(math.pi * t)
        Ff = v.Cf_y * (delta - (vy + v.lf * r) / vx) * math.cos(delta)
        Fr = v.Cr_y * (v.lr * r - vy) / vx
        ay, rdot = (Ff + Fr) / v.mass, (v.lf * Ff - v.lr * Fr) / v.yaw_inertia
        est.step(t, Inputs(delta, math.nan, math.nan, vx),
                 Measurement(math.nan, ay + sig[1] * rng.standard_normal(), r + sig[2] * rng.standard_normal()))
        vy, r = vy + dt * (ay - vx * r), r + dt * rdot + q_true * math.sqrt(dt) * rng.standard_normal()
    q = est.state_noise_estimated()  # what the run summary reports (config_dict, `tirefilter replay`)
    assert est.config_dict()["state_noise_estimated"] == q
    np.testing.assert_array_equal([q["vy"], q["yaw_rate"]], np.sqrt(est.q_state))
    return np.sqrt(est.q_state)


def test_state_noise_is_reported_only_where_it_is_estimated():
    est = StiffnessMPF(load_scenario("paper-sim").vehicle, MPFConfig(model="lateral", particles=20))
    est.reset(np.random.default_rng(0))
    assert est.state_noise_estimated() is None and "state_noise_estimated" not in est.config_dict()


def test_state_noise_from_data_recovers_a_known_process_noise():
    """Covariance matching of the weights' corrections (derivations, "State noise from the data") against a known
    yaw-rate process noise (seeded): 0.1 rad/s per sqrt(s) is recovered within 10% (0.095), 0.03,
    near the gyro's noise floor (0.0035 rad/s per sample), within 30% (0.023: low); without process
    noise the estimate stays below 0.0035. v^Y, which has none, stays below 0.01 m/s per sqrt(s) throughout.
    Measured (seed 3): 0.0954, 0.0230, 0.00115 rad/s; v^Y 0.0042, 0.0048, 0.0038 m/s (seeds 4, 5: 0.0955-0.0975,
    0.0239-0.0247, 0.0025-0.0029; v^Y up to 0.0072). The bounds of the two noises: 2.2x and 1.3x the errors
    (4.6 %, -23 %), the statistic's bias at the noise floor; without noise 3x, v^Y 2.1x."""
    for q_true, lo, hi in ((0.1, 0.09, 0.11), (0.03, 0.021, 0.039), (0.0, 0.0, 0.0035)):
        q = _lateral_drive_with_process_noise(q_true)
        assert lo <= q[1] <= hi, (q_true, q)
        assert q[0] < 0.01, (q_true, q)


@pytest.mark.parametrize("x0_given", [True, False])
def test_without_a_given_initial_state_the_stiffness_statistics_are_drawn_again(x0_given, monkeypatch):
    """A steady turn at a^Y = 3 m/s^2, the gate open from the end of the 1 s warm-up on: the
    stiffness statistics are drawn from the prior at the reset, and without a given initial state
    (`x0_given = False`, a log's) once more, on the sample after the gate's first open one; the
    particles' states are kept."""
    vehicle = load_scenario("paper-sim").vehicle
    r, delta = _steady_turn(vehicle, 3.0)
    est = StiffnessMPF(vehicle, MPFConfig(model="lateral", particles=200, x0_given=x0_given,
                                          bias0_std=(0.0, 0.0, 0.0), bias_rw=(0.0, 0.0, 0.0),
                                          disturbance_rw=(0.0, 0.0, 0.0)))
    draws, k_now = [], [None]
    original = StiffnessMPF._draw_prior_stats

    def recorded(self):
        draws.append(k_now[0])
        x_before = None if self.__dict__.get("x") is None else self.x.copy()
        original(self)
        if x_before is not None:
            np.testing.assert_array_equal(self.x, x_before)

    monkeypatch.setattr(StiffnessMPF, "_draw_prior_stats", recorded)
    est.reset(np.random.default_rng(1))
    active = []
    for k in range(150):
        k_now[0] = k
        active.append(est.step(0.01 * k, Inputs(delta, math.nan, math.nan, 20.0), Measurement(math.nan, 3.0, r)).active)
    first_open = int(np.argmax(active))
    assert 95 <= first_open <= 101 and all(active[first_open:]), first_open
    expected = [None] if x0_given else [None, first_open + 1]
    assert draws == expected, draws


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_std_calibration_scales_the_lateral_std_by_the_sandwich_factor_only(fmu_paths, backend):
    """`std_calibration = "sandwich"` (the default, derivations, "Batch-means sandwich") changes nothing but the
    lateral `*_std`: the same seed gives the same estimates as "off", the paper's posterior of
    the mean, and each lateral std is the paper's times the factor of a batch-means sandwich fed
    independently, while learning, with this sample's predictive a^Y residual, the slips at the
    posterior-mean state and the statistics' forgetting factor."""
    from tirefilter.stats.sandwich import BatchMeansSandwich

    scenario, r = _synthetic_steps(600)
    runs = {}
    for mode in ("off", "sandwich"):
        est = build_estimator("mpf", scenario, model="full", particles=100,
                              config={"mpf": {"std_calibration": mode, "backend": backend}})
        est.reset(np.random.default_rng(5))
        out = []
        for k in range(len(r["t"])):
            e = est.step(r["t"][k], Inputs(r["meas_delta"][k], r["meas_omega_f"][k], r["meas_omega_r"][k]),
                         Measurement(r["meas_ax"][k], r["meas_ay"][k], r["meas_yaw_rate"][k]))
            out.append((e, est.active, est._e_ay, float(est.u_prev[0]), est._lam_step))
        runs[mode] = out
    v = scenario.vehicle
    ref = BatchMeansSandwich(2, MPFConfig().calibration_batch, math.inf)
    grown = 0
    for k, ((e0, *_), (e1, active, e_ay, delta, lam)) in enumerate(zip(runs["off"], runs["sandwich"])):
        assert (e1.Cf_y, e1.Cr_y, e1.Cx, e1.vy, e1.Cx_std, e1.Cf_y_sigma) == (e0.Cf_y, e0.Cr_y, e0.Cx, e0.vy,
                                                                             e0.Cx_std, e0.Cf_y_sigma)
        if active and math.isfinite(e_ay):
            af = delta - (e1.vy + v.lf * e1.yaw_rate) / max(e1.vx, 1.0)
            ar = (v.lr * e1.yaw_rate - e1.vy) / max(e1.vx, 1.0)
            d = np.array([af * math.cos(delta), ar])
            ref.update(d * e_ay, d, 0.01, lam ** (1.0 / MPFConfig().calibration_memory))
        assert e1.Cf_y_std == pytest.approx(e0.Cf_y_std * ref.factor[0], rel=1e-12)
        assert e1.Cr_y_std == pytest.approx(e0.Cr_y_std * ref.factor[1], rel=1e-12)
        grown += e1.Cf_y_std > e0.Cf_y_std
    assert ref.batches >= 3 and grown > 0  # the gate opened and the factor moved off 1


def test_std_calibration_options_are_checked():
    vehicle = load_scenario("paper-sim").vehicle
    assert MPFConfig().std_calibration == "sandwich"
    for options, match in (({"std_calibration": "hac"}, "expected sandwich or off"),
                           ({"calibration_batch": 0.0}, "calibration_batch"),
                           ({"calibration_memory": 0.0}, "calibration_memory")):
        with pytest.raises(ConfigError, match=match):
            StiffnessMPF(vehicle, MPFConfig(**options))


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_load_sensitivity_from_the_vehicle_file(backend):
    """kappa (derivations, "Load transfer") with `load_sensitivity_estimate` on: estimated where the vehicle file
    has no `load_sensitivity` (a spread over the prior that walks), fixed at the file's value where it states one
    (every particle the same, no walk), and a stated 0 or the switch off (the default) is the paper's linear
    axle: the same outputs bit for bit."""
    v = load_scenario("paper-sim").vehicle
    assert v.load_sensitivity == 0.0 and v.relaxation_length == 0.0  # (the single-track truth says so)
    r = 20.0 * 0.2  # a steady turn at 4 m/s^2

    def drive(vehicle, **cfg):
        est = StiffnessMPF(vehicle, MPFConfig(particles=16, backend=backend, gate_warmup=0.05,
                                              **{"load_sensitivity_estimate": True, **cfg}))
        est.reset(np.random.default_rng(5))
        k0 = None if est.k_load is None else est.k_load.copy()
        out = [est.step(0.01 * k, Inputs(delta=0.03, omega_f=20.0 / v.wheel_radius, omega_r=20.0 / v.wheel_radius,
                                         vx=20.0), Measurement(ax=0.0, ay=r, yaw_rate=0.2))
               for k in range(30)]
        return est, k0, np.array([[e.Cf_y, e.Cr_y, e.vy, e.yaw_rate] for e in out])

    est, k0, _ = drive(replace(v, load_sensitivity=None))
    assert est.load_estimated and np.ptp(k0) > 0 and not np.array_equal(est.k_load, k0)
    assert not MPFConfig().load_sensitivity_estimate
    est, k0, _ = drive(replace(v, load_sensitivity=0.01))
    assert not est.load_estimated and np.all(k0 == 0.01) and np.all(est.k_load == 0.01)
    zero, _, a = drive(v)
    off, _, b = drive(replace(v, load_sensitivity=None), load_sensitivity_estimate=False)
    assert zero.k_load is None and off.k_load is None
    np.testing.assert_array_equal(a, b)
