"""One step of the stiffness MPF against exact answers worked out here, for both backends:
the weight of each particle (eq. (36), the Student-t of the residual, derivations Sec. 3) and
its bias Kalman update (eq. (30), Sec. 4).

The filter takes one sample, then its particles get spread statistics, bias means and
covariances, weights and states, and it takes a second sample: the compiled step
(`_step_compiled`) for the numba backend, the reference for numpy. No resampling
(threshold 0) and the learning gate stays closed (`gate_warmup`), so the statistics are
those that the step used, and the particles reported after the step are the x_k it weighed.
The test computes h, d of eq. (12) from the single-track equations (derivations Sec. 1),
the residual's covariance from the hierarchical model, the Student-t density with
scipy.stats.multivariate_t and the bias posterior in information form (a batch Gaussian
posterior, not the filter's gain form)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.special import logsumexp
from scipy.stats import multivariate_t

from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.scenarios import load_scenario
from tirefilter.stats.niw import NiW

N = 12
DT = 0.01
SIGMA = (0.05, 0.08, 0.004)  # ax, ay, yaw rate white noise
BIAS_RW = (0.02, 0.03, 0.002)  # per sqrt(s)
GRAVITY = 9.80665  # m/s^2, standard gravity (the vehicle model's)
ROLL_GRADIENT = 0.01  # rad per m/s^2: a roll gain 1 + k g of about 1.1 on the a^Y channel


def _vehicle():
    return replace(load_scenario("paper-sim").vehicle, roll_gradient=ROLL_GRADIENT)


def _inputs(vehicle) -> np.ndarray:
    """delta, omega_f, omega_r, vx of both samples: 1.5 % traction slip on the (front) driven axle."""
    return np.array([0.05, 20.3 / vehicle.wheel_radius, 20.0 / vehicle.wheel_radius, 20.0])


def _h_and_d(x: np.ndarray, u: np.ndarray, v, full: bool) -> tuple[np.ndarray, np.ndarray]:
    """h (N, m) and d (N, m, n_w) of eq. (12) at the states x and inputs u, from the single-track
    equations of derivations Sec. 1 (front drive, the undriven axle at its nominal stiffness):
    F = (C_n + w) slip, a^X = (F_fx cos d - F_fy sin d + F_rx) / m, a^Y = (F_fy cos d + F_fx sin d
    + F_ry) / m; the IMU reads [a^X, (1 + k g) a^Y, r]; d = d(reading) / dw, w = [dCx,] dCf, dCr."""
    delta, omega_f, omega_r, vx_in = u
    if full:
        vx, vy, r = x[:, 0], x[:, 1], x[:, 2]
    else:
        vx, vy, r = np.full(len(x), vx_in), x[:, 0], x[:, 1]
    m, g = v.mass, 1.0 + v.roll_gradient * GRAVITY
    af = delta - (vy + v.lf * r) / vx  # eq. (4), small angles
    ar = (v.lr * r - vy) / vx
    c, s = math.cos(delta), math.sin(delta)
    F_fy, F_ry = v.Cf_y * af, v.Cr_y * ar
    n = len(x)
    if not full:
        h = np.column_stack([g * (F_fy * c + F_ry) / m, r])
        D = np.zeros((n, 2, 2))
        D[:, 0, 0], D[:, 0, 1] = g * af * c / m, g * ar / m
        return h, D
    wr_f, wr_r = v.wheel_radius * omega_f, v.wheel_radius * omega_r
    lam_f = (wr_f - vx) / np.maximum(np.abs(vx), abs(wr_f))  # eq. (3), traction positive
    lam_r = (wr_r - vx) / np.maximum(np.abs(vx), abs(wr_r))
    F_fx, F_rx = v.Cx * lam_f, v.Cx_undriven * lam_r
    aX = (F_fx * c - F_fy * s + F_rx) / m
    aY = (F_fy * c + F_fx * s + F_ry) / m
    h = np.column_stack([aX, g * aY, r])
    D = np.zeros((n, 3, 3))
    D[:, 0] = np.column_stack([lam_f * c / m, -af * s / m, np.zeros(n)])
    D[:, 1] = g * np.column_stack([lam_f * s / m, af * c / m, ar / m])
    return h, D


def _second_step(backend: str, model: str, missing: str | None):
    """The filter after its first sample, its particles spread (statistics, bias, weights,
    states), then its second sample (`missing`: that channel of it missing). Returns
    (filter, the particles' arrays before the second sample, the second sample's y and u)."""
    vehicle = _vehicle()
    full = model == "full"
    cfg = MPFConfig(particles=N, model=model, backend=backend, resample_threshold=0.0, gate_warmup=100.0,
                    sigma=SIGMA, bias_rw=BIAS_RW, bias0_std=(0.2, 0.3, 0.01), disturbance_rw=(0.0, 0.0, 0.0),
                    undriven_stiffness="nominal", informed_start=False, std_calibration="off", restart_after=0.0,
                    restart_at_bound_after=0.0)
    est = StiffnessMPF(vehicle, cfg)
    est.reset(np.random.default_rng(0))
    u = _inputs(vehicle)
    est.step(0.0, Inputs(*u), Measurement(ax=0.3, ay=2.0, yaw_rate=0.1))

    rng = np.random.default_rng(7)
    n_w, m = est.n_w, len(est.channels)
    vy, r = rng.uniform(-0.3, 0.3, N), rng.uniform(0.05, 0.3, N)
    est.x = np.column_stack([20.0 + rng.uniform(-0.2, 0.2, N), vy, r] if full else [vy, r])
    # spread statistics: nu~ = nu - n_w + 1 from 3 to 10, so (nu~ - 2) / nu~ from 1/3 to 0.8
    nu = n_w + 2.0 + rng.uniform(0.0, 7.0, N)
    scale = 0.1 * est.C_nom  # deviations of 10 % of nominal
    A = rng.normal(0.0, 1.0, (N, n_w, n_w))
    Lam = (np.einsum("nij,nkj->nik", A, A) + n_w * np.eye(n_w)) * np.outer(scale, scale) * (nu - n_w - 1)[:, None, None]
    est.stats = NiW(rng.uniform(0.05, 1.0, N), rng.normal(0.0, 1.0, (N, n_w)) * scale, Lam, nu)
    B = rng.normal(0.0, 1.0, (N, m, m)) * np.array([0.2, 0.3, 0.01])[list(est.channels)]
    est.P = np.einsum("nij,nkj->nik", B, B) + np.diag(np.square([0.05, 0.05, 0.003])[list(est.channels)])
    est.b = rng.normal(0.0, 0.2, (N, m)) * np.array([1.0, 1.0, 0.05])[list(est.channels)]
    logw = rng.normal(0.0, 0.5, N)
    est.logw = logw - logsumexp(logw)
    est.w_prev = est.stats.mu.copy()
    est._at_x = est._model(est.x, est.u_prev)  # the propagation's first stage at the new states
    before = {"b": est.b.copy(), "P": est.P.copy(), "logw": est.logw.copy(), "stats": est.stats.copy()}

    y = {"ax": 0.4, "ay": 2.6, "yaw_rate": 0.15}
    if missing:
        y[missing] = math.nan
    est.step(DT, Inputs(*u), Measurement(**y))
    assert ("_wk" in est.__dict__) == (backend == "numba")  # the compiled step's arrays: it ran
    ym = np.array([y[c] for c in ("ax", "ay", "yaw_rate")])[list(est.channels)]
    return est, before, ym, u


def _exact(est: StiffnessMPF, before: dict, y: np.ndarray, u: np.ndarray):
    """What the step must give, worked out from its definition: (residuals e (N, |a|), their
    covariance (N, |a|, |a|), nu~ (N,), h, d, the predicted bias covariance, the channels a)."""
    post = est.posterior()
    x = post.particles  # x_k: no resampling, no state noise
    st = before["stats"]
    n_w = st.mu.shape[1]
    h, D = _h_and_d(x, u, est.vehicle, est.full)
    a = np.flatnonzero(np.isfinite(y))
    ch = list(est.channels)
    R = np.diag(np.square(SIGMA)[ch])
    P_pred = before["P"] + np.diag(np.square(BIAS_RW)[ch] * DT)  # eq. (29)
    Da = D[:, a]
    # the predictive of w: w | Sigma ~ N(mu, (1 + gamma) Sigma), Sigma ~ iW(nu, Lam), so
    # Cov(w) = (1 + gamma) E[Sigma] = (1 + gamma) Lam / (nu - n_w - 1)
    cov_w = ((1.0 + st.gamma) / (st.nu - n_w - 1.0))[:, None, None] * st.Lam
    # e = y - h - b - d mu = d (w - mu) + (bias error) + (sensor noise), independent terms
    cov_e = Da @ cov_w @ np.swapaxes(Da, 1, 2) + R[np.ix_(a, a)] + P_pred[:, a][:, :, a]
    e = y[a] - h[:, a] - before["b"][:, a] - np.einsum("nij,nj->ni", Da, st.mu)
    return e, cov_e, st.nu - n_w + 1.0, h, D, P_pred, a, R


CASES = [("full", None), ("full", "ay"), ("lateral", None), ("lateral", "ay")]


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("model, missing", CASES, ids=[f"{m}-{'all' if c is None else 'no-' + c}" for m, c in CASES])
def test_weight_is_the_student_t_density_whose_covariance_is_the_residuals(backend, model, missing):
    """Eq. (36) with derivations Sec. 3: each particle's weight is multiplied by the
    multivariate Student-t density of its residual e = y - h - b - d mu with nu~ = nu - n_w + 1
    degrees of freedom and the scale whose covariance, scale nu~ / (nu~ - 2), is the residual's
    own: d Cov(w) d^T + R + P. So the scale is d Lam_w d^T + (nu~ - 2) / nu~ (R + P), the noise
    scaled by (nu~ - 2) / nu~ as well. Computed here with scipy.stats.multivariate_t, over the
    available channels; the log-weights after the step are log w_prev + log St(...), normalised."""
    est, before, y, u = _second_step(backend, model, missing)
    e, cov_e, dof, *_ = _exact(est, before, y, u)
    ll = np.array([multivariate_t.logpdf(e[i], loc=np.zeros(e.shape[1]), shape=cov_e[i] * (dof[i] - 2.0) / dof[i],
                                         df=dof[i]) for i in range(N)])
    expected = before["logw"] + ll
    expected -= logsumexp(expected)
    got = est.posterior().log_weights
    # the spread of the expected log-weights: a wrong scale moves them by a good part of it
    assert np.ptp(expected) > 1.0
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("model, missing", CASES, ids=[f"{m}-{'all' if c is None else 'no-' + c}" for m, c in CASES])
def test_bias_update_is_the_exact_gaussian_posterior(backend, model, missing):
    """Eq. (30), derivations Sec. 4, per particle: the bias b ~ N(b_prev, P_prev + Q dt)
    (eq. (29)) observed through z = y_a - h_a - d_a mu = b_a + d_a (w - mu) + e_sensor, whose
    noise has covariance N = R + d E[Sigma] d^T with the inverse-Wishart mean
    E[Sigma] = Lam / (nu - n_w - 1) of the predicted statistics. The posterior in information
    form, P_post = (P^-1 + H^T N^-1 H)^-1, b_post = P_post (P^-1 b + H^T N^-1 z) with H the rows
    of the available channels, must be what the filter reports."""
    est, before, y, u = _second_step(backend, model, missing)
    _, _, _, h, D, P_pred, a, R = _exact(est, before, y, u)
    st, n_w = before["stats"], before["stats"].mu.shape[1]
    m = h.shape[1]
    H = np.eye(m)[a]
    sigma_hat = st.Lam / (st.nu - n_w - 1.0)[:, None, None]
    post = est.posterior()
    for i in range(N):
        Da = D[i, a]
        noise = R[np.ix_(a, a)] + Da @ sigma_hat[i] @ Da.T
        z = y[a] - h[i, a] - Da @ st.mu[i]
        info = np.linalg.inv(P_pred[i]) + H.T @ np.linalg.solve(noise, H)
        P_post = np.linalg.inv(info)
        b_post = P_post @ (np.linalg.solve(P_pred[i], before["b"][i]) + H.T @ np.linalg.solve(noise, z))
        np.testing.assert_allclose(post.stats["bias"][i], b_post, rtol=1e-8, atol=1e-12, err_msg=f"b, particle {i}")
        np.testing.assert_allclose(post.stats["bias_cov"][i], P_post, rtol=1e-7, atol=1e-14 * np.abs(P_post).max(),
                                   err_msg=f"P, particle {i}")
    # the update moved the bias: the check is not of an unchanged prior
    assert np.abs(post.stats["bias"] - before["b"]).max() > 1e-3
