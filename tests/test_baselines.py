"""The paper's baselines (augpf, rls, ekf): exact reductions and convergence on paper-sim
(fixed seeds, stated tolerances)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from figures import within

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.io.results import ESTIMATE_COLUMNS, INPUT_TRUTH_COLUMNS, truth_column
from tirefilter.cosim.run import run_scenario
from tirefilter.estimators import build_estimator
from tirefilter.estimators.augpf import conditional_deviation, inverse_gamma_step
from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.ekf import EKFConfig, SingleTrackEKFModel, StiffnessEKF
from tirefilter.estimators.linear_kf import KFConfig, LinearKF
from tirefilter.estimators.rls import RLSConfig, RLSEstimator, rls_update
from tirefilter.errors import ConfigError
from tirefilter.metrics import stiffness_errors
from tirefilter.scenarios import load_scenario


def _short(duration):
    s = load_scenario("paper-sim")
    return replace(s, duration=duration, surface_changes=tuple(t for t in s.surface_changes if t < duration))


@pytest.fixture(scope="module")
def paper_sim_rows(fmu_paths):
    """3 s of paper-sim sensor data (no estimator), as named columns."""
    _, rows = run_scenario(_short(3.0), seed=4, keep_rows=True)
    with VehicleFMU("2") as fmu:
        names = ESTIMATE_COLUMNS + tuple(map(truth_column, fmu.output_names)) + INPUT_TRUTH_COLUMNS
    return {c: rows[:, j] for j, c in enumerate(names)}


def _samples(r):
    for k in range(len(r["t"])):
        yield (float(r["t"][k]),
               Inputs(delta=r["meas_delta"][k], omega_f=r["meas_omega_f"][k], omega_r=r["meas_omega_r"][k],
                      vx=r["true_vx"][k]),
               Measurement(ax=r["meas_ax"][k], ay=r["meas_ay"][k], yaw_rate=r["meas_yaw_rate"][k]))


# ---- shared maths ---------------------------------------------------------------------------
def test_small_expm_and_discretisation_match_scipy():
    from scipy.linalg import expm

    from tirefilter.estimators import linear_kf
    from tirefilter.estimators.baseline_common import discretize_zoh, expm_small, small_solve

    rng = np.random.default_rng(5)
    for scale in (0.0, 0.01, 0.3, 3.0):
        M = rng.normal(size=(12, 12)) * scale
        np.testing.assert_allclose(expm_small(M), expm(M), rtol=1e-12, atol=1e-13 * max(1.0, np.abs(expm(M)).max()))
    A, b, Q = rng.normal(size=(5, 5)), rng.normal(size=5), np.diag(rng.uniform(0, 1, 5))
    for mine, ref in zip(discretize_zoh(A, b, Q, 0.01), linear_kf.discretize_zoh(A, b, Q, 0.01)):
        np.testing.assert_allclose(mine, ref, rtol=1e-12, atol=1e-16)
    X = rng.normal(size=(3, 3))
    S, B = X @ X.T + np.eye(3), rng.normal(size=(3, 4))
    np.testing.assert_allclose(small_solve(S, B), np.linalg.solve(S, B), rtol=1e-12)


# ---- EKF ------------------------------------------------------------------------------------
@pytest.mark.parametrize("full", [True, False])
@pytest.mark.parametrize("drive", ["front", "rear"])
def test_ekf_jacobians_match_finite_differences(full, drive):
    vehicle = replace(load_scenario("paper-sim").vehicle, drive=drive, roll_gradient=0.004)
    mdl = SingleTrackEKFModel(vehicle, full)
    rng = np.random.default_rng(0)
    for trial in range(20):
        x = [rng.uniform(8, 30), rng.normal(0, 0.5), rng.normal(0, 0.2)][-mdl.nx:]
        c = rng.normal(0, 0.2, mdl.n_w) * mdl.C_nom
        z = np.concatenate([x, c, rng.normal(0, 0.1, mdl.m)])
        vx = x[0] if full else rng.uniform(8, 30)
        # wheel speeds on either side of the body speed: traction and braking slip
        u = np.array([rng.normal(0, 0.05), (vx * (1 + rng.normal(0, 0.03))) / vehicle.wheel_radius,
                      (vx * (1 + rng.normal(0, 0.03))) / vehicle.wheel_radius, vx])
        f, A, _ = mdl.dynamics(z, u)
        h, H = mdl.measurement(z, u)
        A_fd, H_fd = np.zeros_like(A), np.zeros_like(H)
        for i in range(mdl.nz):
            step = 1e-6 * max(1.0, abs(z[i]))
            zp, zm = z.copy(), z.copy()
            zp[i] += step
            zm[i] -= step
            A_fd[:, i] = (mdl.dynamics(zp, u)[0] - mdl.dynamics(zm, u)[0]) / (2 * step)
            H_fd[:, i] = (mdl.measurement(zp, u)[0] - mdl.measurement(zm, u)[0]) / (2 * step)
        np.testing.assert_allclose(A, A_fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(A)), err_msg=f"A, trial {trial}")
        np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(H)), err_msg=f"H, trial {trial}")


def test_ekf_with_frozen_stiffness_equals_the_linear_kalman_filter(paper_sim_rows):
    """Lateral model, stiffness exactly known and no stiffness noise (zero initial
    covariance, zero random walk, no deviation noise), no bias: the augmented EKF is the
    linear KF (the model is affine in x, the local linearisation its exact
    discretisation), to 1e-9 relative."""
    vehicle = load_scenario("paper-sim").vehicle
    x0_std = (0.5, 0.0175)
    kf = LinearKF(vehicle, KFConfig(q_vy=0.25, q_r=0.02, sigma_ay=0.05, sigma_yaw_rate=0.0035, x0_std=x0_std))
    ekf = StiffnessEKF(vehicle, EKFConfig(model="lateral", stiffness_rw=0.0, dev_sigma=0.0, init_std=0.0,
                                          q_state=(0.0, 0.25, 0.02), x0_mean=(0.0, 0.0), x0_std=(1.0, *x0_std),
                                          sigma=(0.05, 0.05, 0.0035)))
    kf.reset()
    ekf.reset()
    for k, (t, u, y) in enumerate(_samples(paper_sim_rows)):
        if k % 7 == 3:
            y = replace(y, ay=np.nan)  # missing samples too
        a, b = kf.step(t, u, y), ekf.step(t, u, y)
        np.testing.assert_allclose([b.vy, b.yaw_rate], [a.vy, a.yaw_rate], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(ekf.P[:2, :2], kf.P, rtol=1e-9, atol=1e-15)
        assert b.Cf_y == vehicle.Cf_y and b.Cr_y == vehicle.Cr_y


# ---- RLS ------------------------------------------------------------------------------------
def test_rls_update_with_forgetting_one_is_batch_least_squares():
    rng = np.random.default_rng(1)
    theta0, P0 = np.array([1.0, -2.0]), np.diag([4.0, 9.0])
    theta, P = theta0.copy(), P0.copy()
    info, rhs = np.linalg.inv(P0), np.linalg.inv(P0) @ theta0
    for _ in range(50):
        m = rng.integers(1, 3)
        Phi, y, w = rng.normal(size=(m, 2)), rng.normal(size=m), rng.uniform(0.5, 2.0, m)
        theta, P, _ = rls_update(theta, P, Phi, y, w, 1.0)
        info += Phi.T @ (w[:, None] * Phi)
        rhs += Phi.T @ (w * y)
    np.testing.assert_allclose(theta, np.linalg.solve(info, rhs), rtol=1e-9)
    np.testing.assert_allclose(P, np.linalg.inv(info), rtol=1e-9)


def test_rls_estimator_with_forgetting_one_is_batch_least_squares_on_its_regressors(paper_sim_rows):
    """The estimator's own regressions (3 s of paper-sim, lambda = 1, projection bounds out
    of reach): theta and P equal the regularised batch solution to 1e-9 relative."""
    vehicle = load_scenario("paper-sim").vehicle
    est = RLSEstimator(vehicle, RLSConfig(forgetting=1.0, bound_low=1e-3, bound_high=1e3, init_center=(
        0.7 * vehicle.Cf_y, 0.7 * vehicle.Cr_y)))
    est.record = True
    est.reset()
    for t, u, y in _samples(paper_sim_rows):
        est.step(t, u, y)
    assert len(est.rows) > 200
    info = np.linalg.inv(est.P0)
    rhs = info @ est.theta0
    for Phi, y, w in est.rows:
        info += Phi.T @ (w[:, None] * Phi)
        rhs += Phi.T @ (w * y)
    np.testing.assert_allclose(est.theta, np.linalg.solve(info, rhs), rtol=1e-9)
    np.testing.assert_allclose(est.P, np.linalg.inv(info), rtol=1e-9)


# ---- AUGPF ----------------------------------------------------------------------------------
def test_inverse_gamma_step_keeps_the_mean_with_the_stated_std():
    rng = np.random.default_rng(2)
    s2 = np.full(200_000, 3.0)
    x = inverse_gamma_step(s2, 0.01, rng)
    se = 0.03 / np.sqrt(len(x))  # standard error of the mean
    assert abs(x.mean() - 3.0) < 4 * se
    assert abs(x.std() / 0.03 - 1.0) < 0.01  # std within 1% of 1% of the mean
    x = inverse_gamma_step(s2[:1000], 0.5, rng)
    assert np.all(x > 0)
    np.testing.assert_array_equal(inverse_gamma_step(s2[:5], 0.0, rng), s2[:5])


def test_conditional_deviation_is_gaussian_conditioning():
    """Weight and draw of the conditional proposal against the joint Gaussian of (w, y)
    conditioned by brute force (numpy inverse), and the marginal by scipy."""
    from scipy.stats import multivariate_normal

    rng = np.random.default_rng(3)
    N, n, m = 4, 3, 2
    mu, s2 = rng.normal(size=(N, n)), rng.uniform(0.5, 2, (N, n))
    D, r = rng.normal(size=(N, m, n)), rng.normal(size=(N, m))
    A = rng.normal(size=(N, m, m))
    noise = A @ np.swapaxes(A, 1, 2) + np.eye(m)
    loglik, mean, cov = conditional_deviation(mu, s2, D, noise, r)
    for i in range(N):
        Sw = np.diag(s2[i])
        S = D[i] @ Sw @ D[i].T + noise[i]
        np.testing.assert_allclose(loglik[i], multivariate_normal(D[i] @ mu[i], S).logpdf(r[i]), rtol=1e-12)
        K = Sw @ D[i].T @ np.linalg.inv(S)
        np.testing.assert_allclose(mean[i], mu[i] + K @ (r[i] - D[i] @ mu[i]), rtol=1e-10)
        np.testing.assert_allclose(cov[i], Sw - K @ D[i] @ Sw, rtol=1e-10, atol=1e-12)


# ---- convergence on paper-sim ---------------------------------------------------------------
# Measured at seed 1 (Cf_y / Cr_y signed mean %, mean abs %, v^Y RMSE m/s) and at seeds 0, 2, 3 for the spread:
#   ekf               -1.67 / -2.43, 2.12 / 2.58, 0.0170  (seeds 0, 2, 3: mean down to -2.76, mean abs up to 2.79)
#   augpf             +0.27 / +0.87, 2.90 / 3.33, 0.0138  (seeds 0, 2: diverged, -54 / -59 % and +17 / +54 %)
#   augpf bootstrap   +0.27 / +0.00, 3.41 / 4.06, 0.0167  (seeds 0, 2, 3: -3.7 / -3.7, +52 / +128, +35 / +80 %)
#   rls (nominal KF)  +0.34 / -0.77, 0.50 / 0.83, 0.0226  (seeds 0, 2, 3: mean -0.77 to +0.34, mean abs up to 0.83)
# Bounds about 3x the larger of the seed-1 figures of Cf_y and Cr_y (the EKF's mean 1.2x of its own -2.4 % bias,
# 1.1x of the seeds' largest);
# the AUGPF's seed 1 is one of its runs that converge (55 of 100 paper-sim trials in an earlier study,
# benchmarks/README.md; the bootstrap proposal fewer).
@pytest.mark.parametrize("name, particles, config, mean_tol, mean_abs_tol, vy_tol", [
    ("ekf", None, {}, 3.0, 6.0, 0.05),
    ("augpf", 300, {}, 2.6, 8.0, 0.042),
    ("augpf", 300, {"augpf": {"proposal": "bootstrap"}}, 0.8, 12.0, 0.05),
    # the KF of the cascade on the nominal (= true, before 30 s) stiffness: with its own
    # estimate (the default) the cascade stays near its start (README, Baselines)
    ("rls", None, {"rls": {"kf_stiffness": "nominal"}}, 2.0, 2.5, 0.05),
])
def test_converges_on_paper_sim(fmu_paths, name, particles, config, mean_tol, mean_abs_tol, vy_tol):
    """paper-sim up to the surface change (29.5 s), initial stiffness 70% +- 30% of truth,
    seed 1: the mean steady-state error of Cf_y and Cr_y below `mean_tol` percent, the mean
    absolute error below `mean_abs_tol`, the v^Y RMSE after 5 s below 0.05 m/s."""
    scenario = _short(29.5)
    est = build_estimator(name, scenario, model="auto", particles=particles, config=config)
    _, rows = run_scenario(scenario, estimator=est, seed=1, keep_rows=True)
    with VehicleFMU("2") as fmu:
        names = ESTIMATE_COLUMNS + tuple(map(truth_column, fmu.output_names)) + INPUT_TRUTH_COLUMNS
    r = {c: rows[:, j] for j, c in enumerate(names)}
    e = [stiffness_errors(r, scenario, param) for param in ("Cf_y", "Cr_y")]
    within("largest abs mean error of Cf_y, Cr_y %", max(abs(x["mean"]) for x in e), mean_tol)
    within("largest mean abs error of Cf_y, Cr_y %", max(x["mean_abs"] for x in e), mean_abs_tol)
    # measured 0.0138-0.0226 m/s (table above); bound 2.2-3x
    within("vy RMSE m/s", np.sqrt(np.mean((r["vy"] - r["true_vy"])[r["t"] > 5] ** 2)), vy_tol)


def test_augpf_borrows_the_numpy_model_by_default_and_numba_gives_the_same(fmu_paths):
    """The AUGPF's default backend ("numpy") keeps numba out of the process (its import
    alone costs ~50 MB, 111 MB with the MPF's kernels: benchmarks/bench_memory.py numba); backend = "numba" borrows the
    MPF's compiled model and gives the same estimates (1 s of paper-sim, seed 1)."""
    import subprocess
    import sys

    code = ("import sys; from dataclasses import replace; from tirefilter.estimators import build_estimator; "
            "from tirefilter.scenarios import load_scenario; from tirefilter.cosim.run import run_scenario; "
            "sc = replace(load_scenario('paper-sim'), duration=1.0); "
            "est = build_estimator('augpf', sc, model='auto', particles=20, config={}); "
            "s, _ = run_scenario(sc, estimator=est, seed=1); print(est.cfg.backend, s.steps, 'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["numpy", "101", "False"]
    scenario = _short(1.0)
    rows = {}
    for backend in ("numpy", "numba"):
        est = build_estimator("augpf", scenario, model="auto", particles=20, config={"augpf": {"backend": backend}})
        _, r = run_scenario(scenario, estimator=est, seed=1, keep_rows=True)
        rows[backend] = r[:, :len(ESTIMATE_COLUMNS)]
    # per column (a std of ~0 is a difference of large numbers); a column that is all NaN (an output the
    # AUGPF does not estimate) has scale 0
    scale = np.max(np.abs(np.nan_to_num(rows["numpy"])), axis=0)
    assert np.all(np.isnan(rows["numba"]) == np.isnan(rows["numpy"]))
    assert np.nanmax(np.abs(rows["numba"] - rows["numpy"]) - 1e-9 * scale) <= 0
    with pytest.raises(ConfigError, match="backend: expected numba or numpy, got 'jax'"):
        build_estimator("augpf", scenario, model="auto", particles=20, config={"augpf": {"backend": "jax"}})


@pytest.mark.parametrize("name", ["ekf", "rls", "augpf"])
def test_a_missing_ay_sample_does_not_open_a_baselines_gate(name):
    """The MPF's rule holds for every estimator's gate (`baseline_common.held_ay`, derivations
    "Linear-region test"): in a steady turn at a^Y = 5 m/s^2, beyond gate_ay_max = 4, with every other a^Y
    sample missing (the guard's held samples), the gate stays closed; at 3 m/s^2 it opens
    after the 1 s warm-up, on the missing samples too (they hold the last a^Y)."""
    from test_stiffness_mpf import _steady_turn  # tests/, on the path as the other test helpers

    from tirefilter.estimators import _baseline
    from tirefilter.estimators.mpf import MPFConfig

    vehicle = load_scenario("paper-sim").vehicle
    cfg = MPFConfig(model="lateral", particles=100, bias0_std=(0.0, 0.0, 0.0), bias_rw=(0.0, 0.0, 0.0),
                    disturbance_rw=(0.0, 0.0, 0.0))
    k = np.arange(300)
    for ay_true, opens in ((5.0, False), (3.0, True)):
        r, delta = _steady_turn(vehicle, ay_true)
        est = _baseline(name, vehicle, cfg, {})
        est.reset(np.random.default_rng(1))
        ay = np.where(k % 2 == 1, np.nan, ay_true)
        active = np.array([est.step(0.01 * j, Inputs(delta, np.nan, np.nan, 20.0), Measurement(np.nan, a, r)).active
                           for j, a in enumerate(ay)])
        if opens:
            assert active[k >= 110].all() and not active[k < 100].any(), (name, ay_true)
        else:
            assert not active.any(), (name, ay_true)
