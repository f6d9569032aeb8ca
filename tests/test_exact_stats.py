"""The statistics' building blocks against exact answers, on the inputs the other tests leave
out: more than one leading (batch) axis, broadcasting, singular and jittered factorisations,
missing and all-impossible weights, and the documented construction of the random draws.
Found by mutation testing (benchmarks/mutation.py): each test here kills mutants that the
other tests let through."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from tirefilter.stats.linalg import chol, chol_solve, gram, logdet_chol, solve_lower, solve_upper_t
from tirefilter.stats.niw import NiW
from tirefilter.stats.noise import held_share, white_noise_std
from tirefilter.stats.particles import effective_sample_size, normalize_log_weights, systematic_resample
from tirefilter.stats.sandwich import BatchMeansSandwich, BatchMeansSandwichPair
from tirefilter.stats.student_t import t_conditional, t_draws, t_logpdf, t_sample


def _spd(rng, n, batch=()):
    A = rng.standard_normal(batch + (n, n))
    return A @ np.swapaxes(A, -1, -2) + n * np.eye(n)


# ---- stats/linalg.py ---------------------------------------------------------------------------

@pytest.mark.parametrize("n", [2, 3])
def test_factor_and_solves_over_two_batch_axes_with_broadcasting(n):
    """(3, 5) batches of n x n matrices, the right-hand sides broadcast along the first axis:
    numpy's cholesky, solve and slogdet to rounding, and an exactly zero upper triangle."""
    rng = np.random.default_rng(20 + n)
    S = _spd(rng, n, (3, 5))
    L = chol(S)
    np.testing.assert_allclose(L, np.linalg.cholesky(S), rtol=1e-12, atol=1e-12)
    assert np.all(np.triu(L, 1) == 0.0)
    b = rng.standard_normal((1, 5, n))  # broadcast over the first batch axis
    B = rng.standard_normal((1, 5, n, 2))  # a matrix right-hand side, broadcast alike
    full_b = np.broadcast_to(b, (3, 5, n))
    np.testing.assert_allclose(solve_lower(L, b), np.linalg.solve(L, full_b[..., None])[..., 0], rtol=1e-10)
    np.testing.assert_allclose(solve_upper_t(L, b), np.linalg.solve(np.swapaxes(L, -1, -2), full_b[..., None])[..., 0],
                               rtol=1e-10)
    np.testing.assert_allclose(chol_solve(L, B), np.linalg.solve(S, np.broadcast_to(B, (3, 5, n, 2))), rtol=1e-10)
    np.testing.assert_allclose(logdet_chol(L), np.linalg.slogdet(S)[1], rtol=1e-12)
    M = rng.standard_normal((3, 5, 4, n))  # four rows: M^T M as a sum of four outer products
    np.testing.assert_allclose(gram(M), np.swapaxes(M, -1, -2) @ M, rtol=1e-12)


def test_jitter_is_added_to_the_diagonal():
    """chol(S, jitter) = cholesky(S + jitter I), every entry (the off-diagonal ones use the
    jittered pivots)."""
    rng = np.random.default_rng(24)
    S = _spd(rng, 3, (4,))
    np.testing.assert_allclose(chol(S, 0.7), np.linalg.cholesky(S + 0.7 * np.eye(3)), rtol=1e-12, atol=1e-12)


def test_a_singular_matrix_gets_a_finite_factor_that_scales_with_it():
    """A rank-one matrix: the zero pivot is floored at a fraction of its diagonal, not left at
    zero (which gives inf / NaN below it): the factor is finite with positive pivots, L L^T is
    the matrix, and the factor of c S is sqrt(c) times the factor of S (the floor is relative
    to the diagonal, so the factorisation keeps the scale equivariance of the exact one)."""
    v = np.array([2.0, 2.0, 1.0])
    S = np.outer(v, v)  # pivots 4, then exactly 0, 0
    L = chol(S)
    assert np.all(np.isfinite(L)) and np.all(np.diagonal(L) > 0)
    np.testing.assert_allclose(L @ L.T, S, rtol=0, atol=1e-6)
    np.testing.assert_allclose(chol(1e6 * S), 1e3 * L, rtol=1e-12, atol=0)
    zero = chol(np.zeros((2, 2)))
    assert np.all(np.isfinite(zero)) and np.all(np.diagonal(zero) > 0) and zero[1, 0] == 0.0


# ---- stats/student_t.py ------------------------------------------------------------------------

def test_t_logpdf_over_two_batch_axes_and_per_element_dof():
    """Points (2, 3, p) against scale matrices (3, p, p) and degrees of freedom as an array:
    scipy's multivariate_t per element; an array of one common dof (the filter's usual
    case) and a one-element array take the scalar special-function path to the same answer."""
    rng = np.random.default_rng(30)
    p = 3
    mu, Lam = rng.standard_normal((3, p)), _spd(rng, p, (3,))
    x = rng.standard_normal((2, 3, p))
    for nu in (np.array([4.5, 7.0, 12.0]), np.full(3, 6.0)):
        ref = np.array([[sps.multivariate_t(mu[j], Lam[j], df=np.broadcast_to(nu, 3)[j]).logpdf(x[i, j])
                         for j in range(3)] for i in range(2)])
        np.testing.assert_allclose(t_logpdf(x, mu, Lam, nu), ref, rtol=1e-12)
    # one point against a (2, 3) batch of scales: the point broadcasts to the scales' batch
    Lam2 = _spd(rng, p, (2, 3))
    ref2 = np.array([[sps.multivariate_t(mu[j], Lam2[i, j], df=6.0).logpdf(x[0, 0]) for j in range(3)]
                     for i in range(2)])
    np.testing.assert_allclose(t_logpdf(x[0, 0], mu, Lam2, 6.0), ref2, rtol=1e-12)
    one = t_logpdf(x[:, :1], mu[:1], Lam[:1], np.array([5.0]))
    np.testing.assert_allclose(one, sps.multivariate_t(mu[0], Lam[0], df=5.0).logpdf(x[:, 0])[:, None], rtol=1e-12)


@pytest.mark.parametrize("nu", [6.0, np.array([5.0, 9.0, 30.0, 4.0])], ids=["common", "per-element"])
def test_t_sample_is_the_documented_construction_from_t_draws(nu):
    """t_sample = mu + L z sqrt(nu / u) with (z, u) = t_draws from the same generator state:
    the construction the compiled samplers reproduce (z standard normal of the samples' shape,
    u chi-square per sample, drawn after z)."""
    rng = np.random.default_rng(31)
    mu, Lam = rng.standard_normal((4, 2)), _spd(rng, 2, (4,))
    x = t_sample(mu, Lam, nu, np.random.default_rng(32))
    z, u = t_draws(nu, (4, 2), np.random.default_rng(32))
    ref = mu + np.einsum("nij,nj->ni", np.linalg.cholesky(Lam), z) * np.sqrt(np.broadcast_to(nu, 4) / u)[:, None]
    np.testing.assert_allclose(x, ref, rtol=1e-12)
    # `size` samples of each: a new leading axis, (5, 4, 2), with its own chi-square per sample
    xs = t_sample(mu, Lam, nu, np.random.default_rng(38), size=5)
    zs, us = t_draws(nu, (5, 4, 2), np.random.default_rng(38))
    assert xs.shape == (5, 4, 2) and us.shape == (5, 4)
    refs = mu + np.einsum("nij,snj->sni", np.linalg.cholesky(Lam), zs) * np.sqrt(np.broadcast_to(nu, 4) / us)[..., None]
    np.testing.assert_allclose(xs, refs, rtol=1e-12)
    # the draws themselves: standard normals, then chi-squares with the element's dof
    check = np.random.default_rng(32)
    z_ref = check.standard_normal((4, 2))
    u_ref = check.chisquare(np.broadcast_to(np.asarray(nu, float), (4,)))
    np.testing.assert_array_equal(z, z_ref)
    np.testing.assert_allclose(u, u_ref, rtol=1e-12)
    assert z.shape == (4, 2) and u.shape == (4,)


@pytest.mark.parametrize("scales,batch", [((), (4, 5)), ((1,), (4,))], ids=["unbatched", "batch-of-one"])
def test_t_conditional_broadcasts_one_scale_over_a_batch_of_residuals(scales, batch):
    """One joint scale (unbatched, or a batch of one) and a batch of conditioning values:
    each element's conditional equals eq. (41) written with explicit inverses."""
    rng = np.random.default_rng(33)
    d1, d2 = 2, 3
    Lam = _spd(rng, d1 + d2, scales)
    mu = rng.standard_normal(d1 + d2)
    nu = 7.0
    x2 = rng.standard_normal(batch + (d2,))
    L11, L12, L22 = Lam[..., :d1, :d1], Lam[..., :d1, d1:], Lam[..., d1:, d1:]
    mu_c, Lam_c, nu_c = t_conditional(mu[:d1], mu[d1:], L11, L12, L22, nu, x2)
    assert mu_c.shape == batch + (d1,) and Lam_c.shape == batch + (d1, d1)
    c = (0,) if scales else ()
    K = L12[c] @ np.linalg.inv(L22[c])
    for i in np.ndindex(batch):
        r = x2[i] - mu[d1:]
        np.testing.assert_allclose(mu_c[i], mu[:d1] + K @ r, rtol=1e-12)
        q = r @ np.linalg.solve(L22[c], r)
        np.testing.assert_allclose(Lam_c[i], (nu + q) / (nu + d2) * (L11[c] - K @ L12[c].T), rtol=1e-12)
    assert nu_c == nu + d2


@pytest.mark.parametrize("given", ["scale", "factor", "factor-and-whitened"])
def test_t_conditional_of_a_batch_from_its_factor_and_whitened_residual(given):
    """A batch of joint scales (the filter's per-particle case, d1 = 3 deviations given
    d2 = 2 residuals): from L22, from its Cholesky factor, and from the factor with the
    whitened residual, each element equals eq. (41) with explicit inverses."""
    rng = np.random.default_rng(37)
    N, d1, d2 = 6, 3, 2
    Lam = _spd(rng, d1 + d2, (N,))
    mu = rng.standard_normal((N, d1 + d2))
    nu = rng.uniform(4.0, 9.0, N)
    x2 = rng.standard_normal((N, d2))
    L11, L12, L22 = Lam[:, :d1, :d1], Lam[:, :d1, d1:], Lam[:, d1:, d1:]
    kw = {}
    if given != "scale":
        kw["L22_chol"] = np.linalg.cholesky(L22)
    if given == "factor-and-whitened":
        kw["x2_white"] = np.linalg.solve(kw["L22_chol"], (x2 - mu[:, d1:])[..., None])[..., 0]
    mu_c, Lam_c, nu_c = t_conditional(mu[:, :d1], mu[:, d1:], L11, L12, None if kw else L22, nu, x2, **kw)
    for n in range(N):
        K = L12[n] @ np.linalg.inv(L22[n])
        r = x2[n] - mu[n, d1:]
        q = r @ np.linalg.solve(L22[n], r)
        np.testing.assert_allclose(mu_c[n], mu[n, :d1] + K @ r, rtol=1e-12)
        np.testing.assert_allclose(Lam_c[n], (nu[n] + q) / (nu[n] + d2) * (L11[n] - K @ L12[n].T), rtol=1e-11)
    np.testing.assert_allclose(nu_c, nu + d2, rtol=0)


# ---- stats/particles.py ------------------------------------------------------------------------

def test_log_weights_of_several_trials_are_normalised_per_trial():
    """(trials, particles) log-weights: each row normalised on its own; a NaN weight counts
    as zero; a row with no possible particle becomes uniform over the particles (not over
    the trials); the effective sample size per row is 1 / sum q^2."""
    lw = np.array([[0.0, np.log(3.0), np.nan, -np.inf],
                   [-np.inf, -np.inf, np.nan, -np.inf],
                   [5.0, 5.0, 5.0, 5.0]])
    lq = normalize_log_weights(lw)
    np.testing.assert_allclose(np.exp(lq), [[0.25, 0.75, 0.0, 0.0], [0.25] * 4, [0.25] * 4], rtol=1e-15)
    np.testing.assert_allclose(effective_sample_size(lq), [1 / (0.25**2 + 0.75**2), 4.0, 4.0], rtol=1e-12)
    two = np.exp(normalize_log_weights(np.array([[-np.inf, -np.inf]] * 3)))
    np.testing.assert_allclose(two, 0.5, rtol=1e-15)


def _systematic_by_counting(q, u0, m):
    """Ancestors of the points (u0 + j) / m: for each point the number of cumulative weights
    at or below it (the first particle whose cumulative weight exceeds it)."""
    cdf = np.cumsum(q)
    points = (u0 + np.arange(m)) / m
    return np.minimum(np.sum(cdf[None, :] <= points[:, None], axis=1), len(q) - 1)


@pytest.mark.parametrize("count", [None, 7])
def test_systematic_resampling_equals_counting_the_cumulative_weights(count):
    """The ancestors of every point, one trial and three trials (each with its own uniform,
    drawn as an array of shape (trials, 1) before anything else), against counting."""
    rng = np.random.default_rng(34)
    q = rng.dirichlet(np.full(12, 0.5), size=3)
    lw = normalize_log_weights(np.log(q))
    q = np.exp(lw)
    m = 12 if count is None else count
    idx = systematic_resample(lw[0], np.random.default_rng(35), count)
    u0 = np.random.default_rng(35).random((1,))[0]
    np.testing.assert_array_equal(idx, _systematic_by_counting(q[0], u0, m))
    idx3 = systematic_resample(lw, np.random.default_rng(36), count)
    u3 = np.random.default_rng(36).random((3, 1))[:, 0]
    assert idx3.shape == (3, m)
    for t in range(3):
        np.testing.assert_array_equal(idx3[t], _systematic_by_counting(q[t], u3[t], m))


def test_systematic_resampling_keeps_the_first_particle_over_any_leading_axes():
    """A heavy first particle, one trial and a (2, 3) batch of trials (each with its own
    uniform, drawn as an array of shape (2, 3, 1)): the ancestors start at index 0, as
    counting gives them."""
    q = np.array([0.6, 0.1, 0.1, 0.2])
    idx = systematic_resample(np.log(q), np.random.default_rng(39))
    u0 = np.random.default_rng(39).random((1,))[0]
    np.testing.assert_array_equal(idx, _systematic_by_counting(q, u0, 4))
    assert idx[0] == 0
    qs = np.random.default_rng(40).dirichlet(np.full(4, 0.5), size=(2, 3))
    qs[..., 0] += 2.0
    qs /= qs.sum(axis=-1, keepdims=True)
    idx = systematic_resample(np.log(qs), np.random.default_rng(41))
    u = np.random.default_rng(41).random((2, 3, 1))[..., 0]
    assert idx.shape == (2, 3, 4) and np.all(idx[..., 0] == 0)
    for i in np.ndindex(2, 3):
        np.testing.assert_array_equal(idx[i], _systematic_by_counting(qs[i], u[i], 4))


# ---- stats/niw.py ------------------------------------------------------------------------------

def _niw(batch=(3,), n=2, seed=40):
    rng = np.random.default_rng(seed)
    return NiW(rng.uniform(0.2, 2.0, batch), rng.standard_normal(batch + (n,)), _spd(rng, n, batch),
               rng.uniform(6.0, 12.0, batch))


def test_niw_forgetting_with_a_floor_on_the_degrees_of_freedom():
    """Eq. (20) with nu_min: the factor is lambda where lambda nu stays at or above nu_min,
    nu_min / nu where it would not (nu lands on nu_min exactly), and 1 where nu is already
    below nu_min; gamma is divided and Lambda multiplied by the same factor, so gamma nu
    and Lambda / nu are unchanged. Without nu_min the factor is lambda, even for nu < 1."""
    s = NiW(np.ones(4), np.zeros((4, 2)), np.stack([np.eye(2)] * 4), np.array([100.0, 10.0, 9.0, 0.6]))
    before = s.copy()
    s.forget(0.9, nu_min=9.5)
    f = np.array([0.9, 0.95, 1.0, 1.0])
    np.testing.assert_allclose(s.nu, before.nu * f, rtol=1e-15)
    assert s.nu[1] == pytest.approx(9.5, rel=1e-15)
    np.testing.assert_allclose(s.gamma, before.gamma / f, rtol=1e-15)
    np.testing.assert_allclose(s.Lam, before.Lam * f[:, None, None], rtol=1e-15)
    np.testing.assert_array_equal(s.mu, before.mu)
    low = NiW(np.ones(2), np.zeros((2, 2)), np.stack([np.eye(2)] * 2), np.array([0.6, 0.5]))
    low.forget(0.5, nu_min=0.8)  # a floor below 1 still floors: 0.6 -> 0.8 / 0.6 of it, 0.5 -> kept
    np.testing.assert_allclose(low.nu, [0.6, 0.5], rtol=1e-15)
    plain = NiW(np.ones(2), np.zeros((2, 2)), np.stack([np.eye(2)] * 2), np.array([1.5, 40.0]))
    plain.forget(0.5)
    np.testing.assert_allclose(plain.nu, [0.75, 20.0], rtol=1e-15)
    np.testing.assert_allclose(plain.gamma, [2.0, 2.0], rtol=1e-15)


def test_niw_take_selects_the_particles_statistics():
    """Resampling: `take(idx)` holds particle idx[k]'s gamma, mu, Lambda and nu at k."""
    s = _niw(batch=(4,))
    idx = np.array([3, 3, 0, 2])
    t = s.take(idx)
    for a, b in ((t.gamma, s.gamma), (t.mu, s.mu), (t.Lam, s.Lam), (t.nu, s.nu)):
        np.testing.assert_array_equal(a, b[idx])


def test_niw_copy_is_independent_of_the_original():
    s = _niw()
    c = s.copy()
    for a, b in ((c.gamma, s.gamma), (c.mu, s.mu), (c.Lam, s.Lam), (c.nu, s.nu)):
        np.testing.assert_array_equal(a, b)
        assert a is not b and not np.shares_memory(a, b)


def test_niw_moments_are_the_inverse_wishart_and_student_t_moments_over_two_batch_axes():
    """(trials, particles) statistics of dimension 2: E[Sigma] is scipy's inverse-Wishart
    mean, the covariance of mu is gamma E[Sigma], and the predictive is St(mu,
    (1 + gamma) Lambda / (nu - n + 1), nu - n + 1) (eq. (21)) whose covariance is
    (1 + gamma) E[Sigma] (the covariance of mu plus that of w given mu)."""
    s = _niw(batch=(2, 3), n=2, seed=41)
    assert s.dim == 2
    for i in np.ndindex(2, 3):
        ESig = sps.invwishart(df=s.nu[i], scale=s.Lam[i]).mean()
        np.testing.assert_allclose(s.mean_sigma()[i], ESig, rtol=1e-12)
        np.testing.assert_allclose(s.mean_var()[i], s.gamma[i] * ESig, rtol=1e-12)
        mu, scale, dof = (a[i] for a in s.predictive())
        np.testing.assert_allclose(mu, s.mu[i], rtol=0)
        assert dof == pytest.approx(s.nu[i] - 1.0, rel=1e-15)
        np.testing.assert_allclose(scale * dof / (dof - 2.0), (1.0 + s.gamma[i]) * ESig, rtol=1e-12)


# ---- stats/noise.py ----------------------------------------------------------------------------

def _from_second_differences(d: np.ndarray) -> np.ndarray:
    """The samples y (len(d) + 2,) whose second differences y_{k+1} - 2 y_k + y_{k-1} are d."""
    y = [0.0, 0.37]
    for dk in d:
        y.append(dk + 2.0 * y[-1] - y[-2])
    return np.array(y)


def test_noise_level_is_the_scaled_mad_of_the_second_differences():
    """Samples built from chosen second differences d (median far from 0): the estimate is
    MAD(d) / Phi^-1(3/4) / sqrt(1 + 4 + 1), with MAD about the median of d (derivations
    Sec. 15); a missing sample in between is skipped, not a break."""
    d = np.random.default_rng(42).standard_normal(60) + 3.0
    y = _from_second_differences(d)
    assert np.all(np.diff(y) != 0.0)  # no held samples to drop
    mad = np.median(np.abs(d - np.median(d)))
    expected = mad / sps.norm.ppf(0.75) / np.sqrt(np.sum(np.square([1.0, -2.0, 1.0])))
    assert white_noise_std(y) == pytest.approx(expected, rel=1e-14)
    gap = np.insert(y, 30, np.nan)
    assert white_noise_std(gap) == pytest.approx(expected, rel=1e-14)


def test_noise_level_needs_twenty_fresh_samples():
    """The module's contract: at least 20 usable samples (the first one included; a held
    sample does not count), else NaN."""
    y = _from_second_differences(np.random.default_rng(43).standard_normal(40))
    assert np.isfinite(white_noise_std(y[:20]))
    assert np.isnan(white_noise_std(y[:19]))
    held = np.insert(y[:20], 5, y[4])  # 21 samples, one repeats the one before: 20 remain
    assert white_noise_std(held) == white_noise_std(y[:20])
    assert np.isnan(white_noise_std(np.insert(y[:19], 5, y[4])))


def test_held_share_counts_repeats_of_the_previous_finite_sample():
    assert held_share(np.array([1.0, 1.0])) == 1.0
    assert held_share(np.array([1.0, 2.0])) == 0.0
    assert held_share(np.array([1.0, np.nan, 1.0, 3.0, 3.0])) == pytest.approx(2.0 / 3.0, rel=1e-15)
    assert np.isnan(held_share(np.array([1.0, np.nan])))


# ---- stats/sandwich.py -------------------------------------------------------------------------

def test_sandwich_accepts_short_batches_and_memories():
    """Any batch length and memory > 0 is a setting (here both below 1 s): the first batch of
    0.3 s closes after its third 0.1 s sample."""
    bm = BatchMeansSandwich(1, batch=0.3, memory=0.5)
    for k in range(3):
        bm.update(np.array([1.0]), np.array([1.0]), 0.1)
    assert bm.batches == 1
    np.testing.assert_allclose(bm.B, [[9.0]], rtol=1e-15)


@pytest.mark.parametrize("cls", [BatchMeansSandwich, BatchMeansSandwichPair])
def test_sandwich_default_is_no_forgetting(cls):
    """Without the per-sample factor (default 1, and 1 given explicitly) every sample
    counts: two closed batches of the scores (1, -1) and (2, 0.5) with d = (1, 1), infinite
    memory, give A, B and B0 as their sums."""
    bm = cls(2, batch=0.02, memory=np.inf) if cls is BatchMeansSandwich else cls(batch=0.02, memory=np.inf)
    explicit = cls(2, batch=0.02, memory=np.inf) if cls is BatchMeansSandwich else cls(batch=0.02, memory=np.inf)
    scores = [np.array([1.0, -1.0]), np.array([2.0, 0.5])] * 2
    for s in scores:
        bm.update(s, np.array([1.0, 1.0]), 0.01)
        explicit.update(s, np.array([1.0, 1.0]), 0.01, 1.0)
    S = np.array([3.0, -0.5])
    for b in (bm, explicit):
        assert b.batches == 2
        np.testing.assert_allclose(b.A, 4.0 * np.ones((2, 2)), rtol=1e-15)
        np.testing.assert_allclose(b.B, 2.0 * np.outer(S, S), rtol=1e-15)
        np.testing.assert_allclose(b.B0, 2.0 * sum(np.outer(s, s) for s in scores[:2]), rtol=1e-15)
    if cls is BatchMeansSandwichPair:
        fresh = cls(batch=0.02, memory=np.inf)
        for s in scores:
            fresh.update_pair(*s.tolist(), 1.0, 1.0, 0.01)
        assert fresh.B.tobytes() == bm.B.tobytes() and fresh.batches == 2


def test_sandwich_with_zero_scores_keeps_its_factor():
    """All scores zero (a residual that is exactly zero), and one regressor component zero:
    the samples count (the batches close), the lag-0 sandwich has no positive diagonal, the
    ratio is undefined and the factor stays 1 (not NaN)."""
    for bm in (BatchMeansSandwich(2, batch=0.02, memory=np.inf), BatchMeansSandwichPair(batch=0.02, memory=np.inf)):
        rng = np.random.default_rng(44)
        for k in range(6):  # every other regressor has its first component zero (A stays regular)
            bm.update(np.zeros(2), rng.standard_normal(2) * [k % 2, 1.0], 0.01)
        assert bm.batches == 3
        np.testing.assert_array_equal(bm.factor, [1.0, 1.0])
        np.testing.assert_array_equal(bm.ratio, [1.0, 1.0])


def test_sandwich_closes_a_batch_whose_steps_sum_short_by_round_off():
    """Ten 0.1 s samples sum to 0.9999999999999999 s: they close a 1 s batch."""
    assert sum([0.1] * 10) < 1.0
    for bm in (BatchMeansSandwich(2, batch=1.0, memory=np.inf), BatchMeansSandwichPair(batch=1.0, memory=np.inf)):
        for _ in range(10):
            bm.update(np.ones(2), np.ones(2), 0.1)
        assert bm.batches == 1


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # (the squares of 1e200)
@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e200], ids=["nan", "inf", "overflowing"])
def test_sandwich_skips_a_sample_with_any_component_not_finite_or_overflowing(bad):
    """A sample whose score or regressor has one component NaN, infinite, or so large that
    its square overflows (1e200) is skipped, whichever of the four components it is, by the
    array sandwich and the pair alike: the statistics equal those of the run without it."""
    rng = np.random.default_rng(45)
    s, d = rng.standard_normal((8, 2)), rng.standard_normal((8, 2))
    for j in range(4):
        runs = []
        for cls in (BatchMeansSandwich, BatchMeansSandwichPair):
            with_bad = cls(2, 0.04, np.inf) if cls is BatchMeansSandwich else cls(0.04, np.inf)
            without = cls(2, 0.04, np.inf) if cls is BatchMeansSandwich else cls(0.04, np.inf)
            for k in range(8):
                if k == 3:
                    sb, db = s[k].copy(), d[k].copy()
                    (sb if j < 2 else db)[j % 2] = bad
                    with_bad.update(sb, db, 0.01)
                with_bad.update(s[k], d[k], 0.01)
                without.update(s[k], d[k], 0.01)
            assert with_bad.batches == without.batches == 2
            for key in ("A", "B", "B0"):
                assert getattr(with_bad, key).tobytes() == getattr(without, key).tobytes(), (j, key)
            runs.append(with_bad)
        assert runs[0].B.tobytes() == runs[1].B.tobytes()
