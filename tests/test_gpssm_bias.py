"""The friction GP-SSM's IMU bias (docs/derivations.md, "F7. IMU bias") against the exact
answer of its linear-Gaussian part: per particle, given the particle's trajectory, the bias
of each channel is a random walk observed in white noise, whose posterior and marginal
likelihood the batch formulas give."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.gpssm.bias import AY, AY_VAR, R, R_VAR, bias_predict, bias_prior, bias_update
from tirefilter.estimators.gpssm.filter import FrictionGPSSM, GPSSMConfig
from tirefilter.scenarios import load_scenario

VEHICLE = load_scenario("friction-snow").vehicle


def _batch(t, z, p0, q, r):
    """Posterior mean and variance of b(t[-1]) and the log marginal likelihood of the finite z,
    for b(t0) ~ N(0, p0), a random walk of intensity q, z_k = b(t_k) + N(0, r)."""
    t, z = np.asarray(t, float), np.asarray(z, float)
    C = p0 + q * (np.minimum.outer(t, t) - t[0])  # Cov(b_i, b_j)
    seen = np.isfinite(z)
    S = C[np.ix_(seen, seen)] + r * np.eye(seen.sum())
    g = np.linalg.solve(S, C[seen, -1])
    zs = z[seen]
    _, logdet = np.linalg.slogdet(S)
    loglik = -0.5 * (zs @ np.linalg.solve(S, zs) + logdet + zs.size * math.log(2 * math.pi))
    return float(g @ zs), float(C[-1, -1] - g @ C[seen, -1]), loglik


def test_bias_filter_equals_the_batch_posterior():
    """Irregular steps, missing samples, two channels with their own prior, random walk and
    noise: the sequential filter equals the batch posterior to rounding."""
    rng = np.random.default_rng(4)
    n, p0, q, noise = 40, (0.3**2, 0.01**2), (0.002**2, 1e-4**2), (0.05**2, 0.003**2)
    t = np.cumsum(rng.uniform(0.005, 0.05, n))
    z = np.stack([0.2 + 0.05 * rng.standard_normal(n), -0.004 + 0.003 * rng.standard_normal(n)], axis=1)
    z[[3, 17, 18], 0] = np.nan
    z[[9], 1] = np.nan
    b = bias_prior(3, np.sqrt(p0))  # three identical particles: the filter is per row
    for k in range(n):
        if k:
            bias_predict(b, q, t[k] - t[k - 1])
        for ch, j in ((AY, 0), (R, 1)):
            if math.isfinite(z[k, j]):
                bias_update(b, ch, np.full(3, z[k, j]), noise[j])
    for ch, var, j in ((AY, AY_VAR, 0), (R, R_VAR, 1)):
        mean, v, _ = _batch(t, z[:, j], p0[j], q[j], noise[j])
        assert b[:, ch] == pytest.approx(mean, rel=1e-10, abs=1e-14)
        assert b[:, var] == pytest.approx(v, rel=1e-10)


def _drive(est, steps, *, ay_missing=False, b_ay=0.3, b_r=0.01):
    """A slalom at 15 m/s, 25 Hz, from a linear single track, with the IMU offsets b_ay, b_r;
    returns per step the inputs and each particle's trajectory (the r_k its weights saw and the
    a^Y its friction gives, c_k . mu_k) after the step. With the forces linear between samples
    (derivations F4) the weights see the r_k of the held step, r_{k-1} + T_s r'(mu_{k-1}), before
    the remainder is added (no resampling: each row stays one particle)."""
    rng = np.random.default_rng(7)
    est.reset(np.random.default_rng(3))
    rec = []
    v = VEHICLE
    r_held = None
    for k in range(steps):
        t = 0.04 * k
        delta = 0.03 * math.sin(2 * math.pi * 0.5 * t)
        r = 15.0 * delta / 2.8
        ay = math.nan if ay_missing else 15.0 * r + b_ay + 0.05 * rng.standard_normal()
        yr = r + b_r + 0.003 * rng.standard_normal()
        est.step(t, Inputs(delta=delta, vx=15.0), Measurement(ay=ay, yaw_rate=yr))
        c = np.array([est.Fz[0] * math.cos(delta), est.Fz[1]]) / v.mass
        r_seen = est.x[:, 1].copy() if r_held is None else r_held
        rdot = (v.lf * est.Fz[0] * est.mu[:, 0] * math.cos(delta) - v.lr * est.Fz[1] * est.mu[:, 1]) / v.yaw_inertia
        r_held = est.x[:, 1] + 0.04 * rdot  # the next sample's held step
        rec.append((t, ay, yr, r_seen, est.mu @ c, est.logw.copy()))
    return rec


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_each_particles_bias_is_the_batch_posterior_given_its_trajectory(backend):
    """No resampling (threshold 0; no restart either: without resampling the weights
    degenerate and the supervision would start the particles again), so each particle keeps
    its own trajectory: its bias mean and variance of both channels equal the batch posterior
    of the random walk given the residuals y^Y - c . mu_k and y^r - r_k of that trajectory."""
    cfg = GPSSMConfig(particles=6, basis="axle", basis_functions=8, backend=backend, resample_threshold=0.0,
                      supervise=False, bias0_std=(0.3, 0.01), bias_rw=(0.002, 1e-4), sigma=(0.05, 0.003),
                      force_hold="linear")
    est = FrictionGPSSM(VEHICLE, cfg)
    rec = _drive(est, 60)
    assert est.resamples == 0 and est.bias_on
    t = np.array([r[0] for r in rec])
    for i in range(cfg.particles):
        z_ay = np.array([r[1] - r[4][i] for r in rec])
        z_r = np.array([r[2] - r[3][i] for r in rec])
        for ch, var, z, j in ((AY, AY_VAR, z_ay, 0), (R, R_VAR, z_r, 1)):
            mean, v, _ = _batch(t, z, cfg.bias0_std[j] ** 2, cfg.bias_rw[j] ** 2, cfg.sigma[j] ** 2)
            assert est.bias[i, ch] == pytest.approx(mean, rel=1e-9, abs=1e-12)
            assert est.bias[i, var] == pytest.approx(v, rel=1e-9)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_yaw_rate_weights_are_the_marginal_likelihood_with_the_bias_integrated_out(backend):
    """a^Y missing throughout: the only factor of the weights is the yaw rate's, and with no
    resampling the log-weight differences between particles equal those of the batch marginal
    likelihood of each trajectory's residuals y^r - r_k (bias integrated out)."""
    cfg = GPSSMConfig(particles=5, basis="axle", basis_functions=8, backend=backend, resample_threshold=0.0,
                      supervise=False, bias0_std=(0.3, 0.01), bias_rw=(0.002, 1e-4), sigma=(0.05, 0.003),
                      force_hold="linear")
    est = FrictionGPSSM(VEHICLE, cfg)
    rec = _drive(est, 30, ay_missing=True)
    t = np.array([r[0] for r in rec])
    loglik = np.array([_batch(t, np.array([r[2] - r[3][i] for r in rec]), cfg.bias0_std[1] ** 2,
                              cfg.bias_rw[1] ** 2, cfg.sigma[1] ** 2)[2] for i in range(cfg.particles)])
    logw = rec[-1][5]
    assert np.ptp(loglik) > 1.0  # the particles' trajectories differ enough to tell
    np.testing.assert_allclose(logw - logw[0], loglik - loglik[0], rtol=1e-9, atol=1e-9)


def test_no_bias_model_is_the_papers_filter():
    """bias0_std = bias_rw = 0: no bias model; the estimate reports none."""
    est = FrictionGPSSM(VEHICLE, GPSSMConfig(particles=8, basis="axle", bias0_std=(0.0, 0.0), bias_rw=(0.0, 0.0)))
    rec = _drive(est, 5)
    assert not est.bias_on and np.all(est.bias == 0.0) and len(rec) == 5
    e = est.step(0.2, Inputs(delta=0.0, vx=15.0), Measurement(ay=0.1, yaw_rate=0.0))
    assert math.isnan(e.b_ay) and math.isnan(e.b_yaw_rate)
