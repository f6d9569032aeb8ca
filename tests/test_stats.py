"""Statistical building blocks against exact answers (fixed seeds)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from tirefilter.stats import (NiW, effective_sample_size, normalize_log_weights, systematic_resample, t_conditional,
                              t_logpdf, t_sample)


def _spd(rng, n):
    A = rng.standard_normal((n, n))
    return A @ A.T + n * np.eye(n)


def test_niw_sequential_updates_equal_the_batch_posterior():
    """With forgetting factor 1, eq. (19) applied n times equals the conjugate posterior:
    1/gamma_n = 1/gamma_0 + n, mu_n = (mu_0/gamma_0 + sum x) gamma_n, nu_n = nu_0 + n,
    Lam_n = Lam_0 + S + (n/gamma_0) gamma_n (xbar - mu_0)(xbar - mu_0)^T."""
    rng = np.random.default_rng(0)
    batch, n_obs, dim = 4, 50, 3
    gamma0 = rng.uniform(0.1, 2.0, batch)
    mu0 = rng.standard_normal((batch, dim))
    Lam0 = np.stack([_spd(rng, dim) for _ in range(batch)])
    nu0 = rng.uniform(5, 10, batch)
    s = NiW(gamma0.copy(), mu0.copy(), Lam0.copy(), nu0.copy())
    X = rng.standard_normal((n_obs, batch, dim)) * 2 + 1
    for x in X:
        s.forget(1.0)
        s.update(x)
    xbar = X.mean(0)
    S = np.einsum("kbi,kbj->bij", X - xbar, X - xbar)
    gamma_n = 1 / (1 / gamma0 + n_obs)
    mu_n = (mu0 / gamma0[:, None] + X.sum(0)) * gamma_n[:, None]
    Lam_n = Lam0 + S + ((n_obs / gamma0) * gamma_n)[:, None, None] * np.einsum("bi,bj->bij", xbar - mu0, xbar - mu0)
    np.testing.assert_allclose(s.gamma, gamma_n, rtol=1e-10)
    np.testing.assert_allclose(s.mu, mu_n, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(s.nu, nu0 + n_obs, rtol=1e-12)
    np.testing.assert_allclose(s.Lam, Lam_n, rtol=1e-10)


def test_niw_forgetting_reaches_the_equilibrium_degrees_of_freedom():
    s = NiW(np.ones(1), np.zeros((1, 2)), np.eye(2)[None], np.array([5.0]))
    for _ in range(3000):
        s.forget(0.99)
        s.update(np.zeros((1, 2)))
    assert s.nu[0] == pytest.approx(1 / (1 - 0.99), rel=1e-9)  # Proposition 1 proof


def test_niw_predictive_is_the_marginal_of_the_hierarchical_model():
    """Monte-Carlo check of eq. (21): draw Sigma ~ iW, mu ~ N, w ~ N(mu, Sigma)."""
    rng = np.random.default_rng(1)
    dim, nu, gamma = 2, 9.0, 0.5
    Lam = _spd(rng, dim)
    mu0 = np.array([1.0, -2.0])
    s = NiW(np.array([gamma]), mu0[None], Lam[None], np.array([nu]))
    m, scale, dof = s.predictive()
    n = 200_000
    Sig = sps.invwishart(df=nu, scale=Lam).rvs(n, random_state=rng)
    mu = mu0 + np.einsum("nij,nj->ni", np.linalg.cholesky(gamma * Sig), rng.standard_normal((n, dim)))
    w = mu + np.einsum("nij,nj->ni", np.linalg.cholesky(Sig), rng.standard_normal((n, dim)))
    cov_theory = scale[0] * dof[0] / (dof[0] - 2)
    se = np.sqrt(np.diag(cov_theory) / n)
    assert np.all(np.abs(w.mean(0) - m[0]) < 5 * se)
    np.testing.assert_allclose(np.cov(w.T), cov_theory, rtol=0.05)


def test_t_logpdf_matches_scipy():
    rng = np.random.default_rng(2)
    mu, Lam, nu = rng.standard_normal(3), _spd(rng, 3), 6.5
    x = rng.standard_normal((10, 3))
    ref = sps.multivariate_t(loc=mu, shape=Lam, df=nu).logpdf(x)
    np.testing.assert_allclose(t_logpdf(x, mu, Lam, nu), ref, rtol=1e-12)


def test_t_samples_have_the_theoretical_mean_and_covariance():
    rng = np.random.default_rng(3)
    mu, Lam, nu = np.array([0.5, -1.0, 2.0]), _spd(rng, 3), 8.0
    n = 400_000
    x = t_sample(mu, Lam, nu, rng, size=n)
    cov = Lam * nu / (nu - 2)
    se_mean = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(x.mean(0) - mu) < 4 * se_mean)
    # the variance of a sample variance needs the 4th moment: kurtosis of a t is finite for nu > 4
    kurt = 3 + 6 / (nu - 4)
    se_var = np.diag(cov) * np.sqrt((kurt - 1) / n)
    assert np.all(np.abs(np.var(x, axis=0) - np.diag(cov)) < 5 * se_var)
    np.testing.assert_allclose(np.cov(x.T), cov, rtol=0.03)


@pytest.mark.parametrize("d1,d2", [(1, 1), (1, 2), (2, 1)])
def test_t_conditional_equals_brute_force_conditioning(d1, d2):
    """Conditional density of eq. (41) against the joint density normalised numerically
    on a grid over x1 (x2 fixed)."""
    rng = np.random.default_rng(10 + d1 + d2)
    p = d1 + d2
    mu, Lam, nu = rng.standard_normal(p), _spd(rng, p), 5.0
    x2 = mu[d1:] + rng.standard_normal(d2) * 1.5
    mu_c, Lam_c, nu_c = t_conditional(mu[:d1], mu[d1:], Lam[:d1, :d1], Lam[:d1, d1:], Lam[d1:, d1:], nu, x2)
    axes = [np.linspace(mu_c[i] - 12 * np.sqrt(Lam_c[i, i]), mu_c[i] + 12 * np.sqrt(Lam_c[i, i]), 801 if d1 == 1 else 301)
            for i in range(d1)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, d1)
    joint = np.exp(t_logpdf(np.hstack([grid, np.broadcast_to(x2, (len(grid), d2))]), mu, Lam, nu))
    cell = np.prod([a[1] - a[0] for a in axes])
    brute = joint / (joint.sum() * cell)
    cond = np.exp(t_logpdf(grid, mu_c, Lam_c, nu_c))
    assert np.max(np.abs(brute - cond)) < 1e-3 * np.max(cond)


def test_log_weights_never_underflow_to_nan():
    lw = normalize_log_weights(np.array([-1e6, -1e6 - 1.0, -np.inf]))
    np.testing.assert_allclose(np.exp(lw), [1 / (1 + np.exp(-1)), np.exp(-1) / (1 + np.exp(-1)), 0.0])
    uniform = normalize_log_weights(np.array([-np.inf, np.nan, -np.inf]))
    np.testing.assert_allclose(np.exp(uniform), 1 / 3)
    assert effective_sample_size(normalize_log_weights(np.zeros(10))) == pytest.approx(10)


def test_systematic_resampling_is_unbiased_and_low_variance():
    rng = np.random.default_rng(4)
    w = rng.dirichlet(np.ones(20))
    lw = np.log(w)
    counts = np.zeros(20)
    for _ in range(2000):
        idx = systematic_resample(lw, rng)
        c = np.bincount(idx, minlength=20)
        assert np.all(np.abs(c - 20 * w) < 1 + 1e-9)  # systematic: within one of N w_i
        counts += c
    np.testing.assert_allclose(counts / (2000 * 20), w, atol=2e-3)
    batch = systematic_resample(np.log(np.tile(w, (3, 1))), rng)
    assert batch.shape == (3, 20)


def test_particle_filter_matches_the_kalman_filter():
    """Bootstrap PF with these blocks on a scalar linear-Gaussian model: the filtered
    mean matches the Kalman filter within k Monte-Carlo standard errors."""
    rng = np.random.default_rng(5)
    a, q, r, T, N = 0.9, 0.5, 1.0, 50, 2000
    x, ys = 0.0, []
    for _ in range(T):
        x = a * x + np.sqrt(q) * rng.standard_normal()
        ys.append(x + np.sqrt(r) * rng.standard_normal())
    m, P, kf = 0.0, 1.0, []
    for y in ys:
        m, P = a * m, a * a * P + q
        K = P / (P + r)
        m, P = m + K * (y - m), (1 - K) * P
        kf.append((m, P))
    particles = rng.standard_normal(N)
    for k, y in enumerate(ys):
        particles = a * particles + np.sqrt(q) * rng.standard_normal(N)
        lw = normalize_log_weights(-0.5 * (y - particles) ** 2 / r)
        w = np.exp(lw)
        mean = np.sum(w * particles)
        m_kf, P_kf = kf[k]
        se = np.sqrt(P_kf / effective_sample_size(lw))
        assert abs(mean - m_kf) < 5 * se, (k, mean, m_kf, se)
        particles = particles[systematic_resample(lw, rng)]


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_small_batched_linear_algebra_matches_numpy(n):
    from tirefilter.stats.linalg import chol, chol_solve, logdet_chol, solve_lower, solve_upper_t

    rng = np.random.default_rng(n)
    S = np.stack([_spd(rng, n) for _ in range(50)])
    L = chol(S)
    np.testing.assert_allclose(L, np.linalg.cholesky(S), rtol=1e-12, atol=1e-12)
    b = rng.standard_normal((50, n))
    B = rng.standard_normal((50, n, 2))
    np.testing.assert_allclose(chol_solve(L, b), np.linalg.solve(S, b[..., None])[..., 0], rtol=1e-10)
    np.testing.assert_allclose(chol_solve(L, B), np.linalg.solve(S, B), rtol=1e-10)
    np.testing.assert_allclose(solve_lower(L, b), np.linalg.solve(L, b[..., None])[..., 0], rtol=1e-10)
    np.testing.assert_allclose(solve_upper_t(L, b), np.linalg.solve(np.swapaxes(L, 1, 2), b[..., None])[..., 0],
                               rtol=1e-10)
    np.testing.assert_allclose(logdet_chol(L), np.linalg.slogdet(S)[1], rtol=1e-12, atol=1e-12)


# ---- batch-means sandwich (stats/sandwich.py, derivations, "Batch-means sandwich") ---------------------------
def _ar1(phi: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """A stationary AR(1) sequence with unit innovation variance."""
    from scipy.signal import lfilter

    e = rng.standard_normal(n)
    e[0] /= np.sqrt(1.0 - phi * phi)  # start in the stationary distribution
    return lfilter([1.0], [1.0, -phi], e)


def test_batch_means_sandwich_equals_the_batch_sums_without_forgetting():
    """Fed sample by sample with infinite memory, A, B and B0 are the sums over the closed
    batches, and the ratio is the sandwich's diagonal ratio, exactly."""
    from tirefilter.stats.sandwich import BatchMeansSandwich, sandwich_ratio

    rng = np.random.default_rng(3)
    n, m = 10, 7  # samples per batch, batches
    d = rng.standard_normal((n * m, 2))
    s = d * rng.standard_normal((n * m, 1))
    bm = BatchMeansSandwich(2, batch=n * 0.01, memory=np.inf)
    for k in range(n * m):
        bm.update(s[k], d[k], 0.01)
    S = s.reshape(m, n, 2).sum(axis=1)
    A, B, B0 = d.T @ d, S.T @ S, s.T @ s
    assert bm.batches == m
    np.testing.assert_allclose(bm.A, A, rtol=1e-12)
    np.testing.assert_allclose(bm.B, B, rtol=1e-12)
    np.testing.assert_allclose(bm.B0, B0, rtol=1e-12)
    Ai = np.linalg.inv(A)
    want = np.diag(Ai @ B @ Ai) / np.diag(Ai @ B0 @ Ai)
    np.testing.assert_allclose(bm.ratio, want, rtol=1e-10)
    np.testing.assert_allclose(sandwich_ratio(A, B, B0), want, rtol=1e-10)
    np.testing.assert_allclose(bm.factor, np.sqrt(np.maximum(want, 1.0)), rtol=1e-10)


def test_batch_means_sandwich_forgets_per_batch():
    """With memory M each closed batch of length T decays the older ones by exp(-T / M); with
    per-sample factors lambda_k, by their product over the batch."""
    from tirefilter.stats.sandwich import BatchMeansSandwich

    bm = BatchMeansSandwich(1, batch=0.5, memory=2.0)
    for k in range(100):  # 2 batches of 50 samples, score 1 then 2
        v = 1.0 if k < 50 else 2.0
        bm.update(np.array([v]), np.array([1.0]), 0.01)
    keep = np.exp(-0.5 / 2.0)
    np.testing.assert_allclose(bm.B, [[keep * 50.0**2 + 100.0**2]], rtol=1e-12)
    np.testing.assert_allclose(bm.B0, [[keep * 50.0 + 200.0]], rtol=1e-12)
    np.testing.assert_allclose(bm.A, [[keep * 50.0 + 50.0]], rtol=1e-12)

    per_sample = BatchMeansSandwich(1, batch=0.5, memory=np.inf)  # the MPF's way: lambda_k per sample
    for k in range(100):
        per_sample.update(np.array([1.0 if k < 50 else 2.0]), np.array([1.0]), 0.01, 0.99)
    np.testing.assert_allclose(per_sample.B, [[0.99**50 * 50.0**2 + 100.0**2]], rtol=1e-12)
    np.testing.assert_allclose(per_sample.A, [[0.99**50 * 50.0 + 50.0]], rtol=1e-12)


@pytest.mark.parametrize("phi", [0.0, 0.6])
def test_batch_means_ratio_is_the_autocorrelation_time_of_an_ar1_score(phi):
    """Scores that are a stationary AR(1) with coefficient phi: the expected ratio of a batch
    of n samples is 1 + 2 sum_{l<n} (1 - l/n) phi^l (-> (1 + phi)/(1 - phi), the integrated
    autocorrelation time); white scores give 1. Two coefficients with independent scores and
    a diagonal A each get their own. K = 2000 batches: the ratio's relative standard error is
    sqrt(2/K) = 3.2%; tolerance 4 of them (fixed seed)."""
    from tirefilter.stats.sandwich import BatchMeansSandwich

    rng = np.random.default_rng(11)
    n, K = 50, 2000
    s = np.stack([_ar1(phi, n * K, rng), _ar1(0.0, n * K, rng)], axis=1)
    bm = BatchMeansSandwich(2, batch=n * 0.01, memory=np.inf)
    one = np.ones(2)
    for k in range(n * K):
        bm.update(s[k], one if k % 2 else np.array([1.0, -1.0]), 0.01)  # A diagonal over each pair
    lags = np.arange(1, n)
    want = 1.0 + 2.0 * np.sum((1.0 - lags / n) * phi**lags)
    tol = 4.0 * np.sqrt(2.0 / K)
    assert abs(bm.ratio[0] / want - 1.0) < tol
    assert abs(bm.ratio[1] - 1.0) < tol
    if phi > 0:
        assert want > 3.5  # (1 + 0.6) / 0.4 = 4 less the finite-batch term: far from white


def test_pair_sandwich_equals_the_array_sandwich_bit_for_bit():
    """`BatchMeansSandwichPair` (n = 2, the open batch in Python floats: the MPF's fused step) gives
    the parent's statistics exactly, bit for bit, through closed batches, per-sample forgetting,
    samples it must skip (non-finite, dt <= 0, forget outside (0, 1]), a reset, and fed either by
    floats (`update_pair`) or by arrays (`update`)."""
    from tirefilter.stats.sandwich import BatchMeansSandwich, BatchMeansSandwichPair

    rng = np.random.default_rng(17)
    n = 400
    k = np.arange(n)
    d = np.stack([0.03 * (1.5 + np.sin(k / 20.0)), 0.02 * np.cos(k / 15.0)], axis=1)
    d += 0.003 * rng.standard_normal((n, 2))
    s = d * (rng.standard_normal((n, 1)) * 0.3 + np.sin(k / 9.0)[:, None])  # correlated scores
    forget = 1.0 - 0.02 * rng.random(n)
    dt = np.full(n, 0.01)
    s[37, 1], d[91, 0], dt[120], forget[150], forget[151] = np.nan, np.inf, 0.0, 0.0, 1.5  # skipped samples
    ref, pair, by_arrays = (BatchMeansSandwich(2, 0.25, 3.0), BatchMeansSandwichPair(0.25, 3.0),
                            BatchMeansSandwichPair(0.25, 3.0))
    for k in range(n):
        if k == 300:  # (the MPF resets it at a restart)
            for bm in (ref, pair, by_arrays):
                bm.reset()
        ref.update(s[k], d[k], dt[k], forget[k])
        pair.update_pair(*s[k].tolist(), *d[k].tolist(), float(dt[k]), float(forget[k]))
        by_arrays.update(s[k], d[k], dt[k], forget[k])
        for bm in (pair, by_arrays):
            assert bm.batches == ref.batches and bm.factor.tolist() == ref.factor.tolist()
            assert bm.factor_pair == tuple(ref.factor.tolist())
    assert ref.batches == 4 and ref.factor.max() > 1.0  # batches closed after the reset, the factor moved
    for bm in (pair, by_arrays):
        for key in ("A", "B", "B0", "ratio"):
            assert getattr(bm, key).tobytes() == getattr(ref, key).tobytes(), key
        assert (bm._T, bm._log_keep) == (ref._T, ref._log_keep)


def test_batch_means_sandwich_rejects_bad_settings():
    from tirefilter.stats.sandwich import BatchMeansSandwich

    with pytest.raises(ValueError, match="batch"):
        BatchMeansSandwich(2, batch=0.0, memory=1.0)
    with pytest.raises(ValueError, match="memory"):
        BatchMeansSandwich(2, batch=1.0, memory=0.0)
