"""The friction learner's statistics against exact answers: the reduced-rank basis against
the kernel it approximates, MNIW recursions against the batch posterior, the predictive
against its theoretical moments."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tirefilter.errors import ConfigError
from tirefilter.stats.gp import AxleBasis, GPBasis1D, TensorBasis, make_basis
from tirefilter.stats.mniw import MNIW, MNIWRank1, sample_inverse_wishart
from tirefilter.stats.student_t import t_sample

VARIANTS = (MNIW, MNIWRank1)


# ---- basis ---------------------------------------------------------------------------
@pytest.mark.parametrize("m", [20, 40, 80])
def test_basis_reproduces_dirichlet_kernel_within_truncation_bound(m):
    """eq. (9): sum_j S_j phi_j phi_j' is the SE kernel with Dirichlet boundaries minus
    the left-out spectral mass, so |error| <= (1/L) sum_{j>m} S_j everywhere."""
    b = GPBasis1D(L=1.0, m=m, lengthscale=0.1, s_f=2.0)
    x = np.linspace(-1, 1, 161)
    X, X2 = np.meshgrid(x, x)
    err = np.max(np.abs(b.kernel_approx(X, X2) - b.kernel_dirichlet(X, X2)))
    bound = b.truncation_bound()
    assert err <= bound + 1e-12
    if m >= 40:
        assert bound < 1e-6  # converged: S(pi m / 2L) = exp(-(0.1 * 63)^2 / 2) is tiny
    else:
        assert err > 0.05 * bound  # the bound is not vacuous where truncation matters


def test_basis_equals_se_kernel_away_from_the_boundary():
    """Inside [-L + 5 l, L - 5 l] the boundary images are below 1e-5: the expansion is the
    plain SE kernel there (60 functions: truncation bound < 1e-9)."""
    b = GPBasis1D(L=1.0, m=60, lengthscale=0.1)
    x = np.linspace(-0.5, 0.5, 101)
    X, X2 = np.meshgrid(x, x)
    assert b.truncation_bound() < 1e-9
    assert np.max(np.abs(b.kernel_approx(X, X2) - b.kernel(X, X2))) < 1e-5


def test_eigen_and_spectral_density():
    b = GPBasis1D(L=0.5, m=5, lengthscale=0.2, s_f=3.0)
    j = np.arange(1, 6)
    assert np.allclose(b.eigenvalues(), (np.pi * j / 1.0) ** 2)
    assert np.allclose(b.spectral_density(), 3.0 * math.sqrt(2 * math.pi) * 0.2 * np.exp(-0.02 * b.eigenvalues()))
    # orthonormal on [-L, L] (trapezoid rule on a fine grid), zero at the boundary
    x = np.linspace(-0.5, 0.5, 20001)
    P = b.phi(x)
    G = np.trapezoid(P[:, :, None] * P[:, None, :], x, axis=0)
    assert np.allclose(G, np.eye(5), atol=1e-6)
    assert np.allclose(b.phi(np.array([-0.5, 0.5])), 0.0, atol=1e-12)


def test_tensor_and_axle_layouts():
    b = GPBasis1D(L=0.5, m=4, lengthscale=0.1)
    t, a = TensorBasis(b), AxleBasis(b)
    af, ar = np.array([0.1, -0.2]), np.array([0.05, 0.3])
    F = t.features(af, ar)
    assert F.shape == (2, 16) and t.S.shape == (16,)
    assert np.allclose(F[1, 2 * 4 + 3], b.phi(af[1])[2] * b.phi(ar[1])[3])
    lam = b.eigenvalues()
    assert np.isclose(t.lam[2 * 4 + 3], lam[2] + lam[3])
    assert np.isclose(t.S[0], 2 * math.pi * 0.01 * math.exp(-0.005 * (lam[0] * 2)))
    A = a.features(af, ar)
    assert A.shape == (2, 2, 4) and np.allclose(A[:, 1], b.phi(ar))


@pytest.mark.parametrize("kw,key", [(dict(L=0.0), "L"), (dict(L=-1.0), "L"), (dict(lengthscale=0.0), "lengthscale"),
                                    (dict(lengthscale=-0.1), "lengthscale"), (dict(m=0), "basis_functions"),
                                    (dict(m=2.5), "basis_functions"), (dict(s_f=0.0), "s_f"),
                                    (dict(L=float("nan")), "L")])
def test_bad_basis_settings_are_rejected(kw, key):
    args = dict(L=0.5, m=10, lengthscale=0.035, s_f=500.0) | kw
    with pytest.raises(ConfigError, match=key):
        GPBasis1D(**args)


def test_unknown_layout_is_rejected():
    with pytest.raises(ConfigError, match="tensor or axle"):
        make_basis("grid", GPBasis1D(L=0.5, m=3, lengthscale=0.1))


# ---- MNIW statistics -----------------------------------------------------------------
def _data(rng, T=60, d=2, m=6):
    X = rng.standard_normal((T, m))
    A = rng.standard_normal((d, m))
    Z = X @ A.T + 0.3 * rng.standard_normal((T, d))
    S = rng.uniform(0.5, 2.0, m)
    Lam0 = np.array([[0.5, 0.1], [0.1, 0.4]])[:d, :d]
    return X, Z, S, Lam0


def _batch_posterior(X, Z, S, Lam0, nu0, w=None, prior_scale=1.0):
    """Weighted least squares in closed form: M = Z^T W X (X^T W X + s V)^-1,
    Lambda = s Lambda_0 + (Z - X M^T)^T W (Z - X M^T) + s M V M^T, nu = s nu_0 + sum w
    (eq. (25)-(26); w = 1, s = 1 without forgetting)."""
    w = np.ones(len(X)) if w is None else w
    V = np.diag(1.0 / S) * prior_scale
    M = np.linalg.solve(X.T @ (w[:, None] * X) + V, X.T @ (w[:, None] * Z)).T
    E = Z - X @ M.T
    Lam = prior_scale * Lam0 + E.T @ (w[:, None] * E) + M @ V @ M.T
    return M, Lam


@pytest.mark.parametrize("cls", VARIANTS)
def test_sequential_updates_equal_batch_posterior(cls):
    rng = np.random.default_rng(1)
    X, Z, S, Lam0 = _data(rng)
    st = cls((3,), 2, S, Lam0, nu0=5.0)  # three identical batch elements
    for x, z in zip(X, Z):
        st.forget(1.0)
        st.update(np.broadcast_to(z, (3, 2)), np.broadcast_to(x, (3, 6)))
    M, Lam = st.posterior()
    Mb, Lb = _batch_posterior(X, Z, S, Lam0, 5.0)
    assert np.allclose(M, Mb, rtol=0, atol=1e-10 * np.abs(Mb).max())
    assert np.allclose(Lam, Lb, rtol=0, atol=1e-10 * np.abs(Lb).max())
    assert np.allclose(st.nu, 5.0 + len(X))


def test_forgetting_equals_weighted_batch_posterior():
    """Exact variant with lambda < 1: data weighted lambda^(T-k), the prior (V, Lambda_0) not
    forgotten, nu = lambda^T nu_0 + sum lambda^(T-k) (eq. (29))."""
    rng = np.random.default_rng(2)
    X, Z, S, Lam0 = _data(rng, T=40)
    lam = 0.95
    st = MNIW((), 2, S, Lam0, nu0=6.0)
    for x, z in zip(X, Z):
        st.forget(lam)
        st.update(z, x)
    w = lam ** np.arange(len(X) - 1, -1, -1)
    Mb, Lb = _batch_posterior(X, Z, S, Lam0, 6.0, w=w)
    M, Lam = st.posterior()
    assert np.allclose(M, Mb, atol=1e-10) and np.allclose(Lam, Lb, atol=1e-10)
    assert np.isclose(st.nu, 6.0 * lam ** len(X) + w.sum())


def test_rank1_forgetting_equals_batch_with_forgotten_prior():
    """Fast variant with lambda < 1: the same weighted batch posterior with V and Lambda_0
    scaled by lambda^T too (what it trades for the rank-one update)."""
    rng = np.random.default_rng(3)
    X, Z, S, Lam0 = _data(rng, T=40)
    lam = 0.95
    st = MNIWRank1((), 2, S, Lam0, nu0=6.0, bounded=False)
    for x, z in zip(X, Z):
        st.forget(lam)
        st.update(z, x)
    w = lam ** np.arange(len(X) - 1, -1, -1)
    Mb, Lb = _batch_posterior(X, Z, S, Lam0, 6.0, w=w, prior_scale=lam ** len(X))
    M, Lam = st.posterior()
    assert np.allclose(M, Mb, atol=1e-10) and np.allclose(Lam, Lb, atol=1e-10)


def test_rank1_bounded_trace_stops_windup():
    """Data in one direction only, lambda = 0.9, 200 steps: plain RLS lets P grow as
    0.9^-200 in the other directions; bounded, trace(P) stays <= trace(diag S) and the
    data direction is still learned; while the trace is below the bound both agree."""
    rng = np.random.default_rng(8)
    S = np.array([1.0, 2.0, 0.5])
    plain = MNIWRank1((), 1, S, np.eye(1), nu0=4.0, bounded=False)
    bounded = MNIWRank1((), 1, S, np.eye(1), nu0=4.0)
    x = np.array([1.0, 0.0, 0.0])
    for k in range(200):
        z = np.array([0.7 + 0.1 * rng.standard_normal()])
        for st in (plain, bounded):
            st.forget(0.9)
            st.update(z, x)
    assert np.trace(plain.P) > 1e8
    assert np.trace(bounded.P) <= S.sum() * (1 + 1e-12)
    assert abs(bounded.M[0, 0] - 0.7) < 0.05
    # below the bound the forgetting is plain: P / lambda
    st = MNIWRank1((), 1, S, np.eye(1), nu0=4.0)
    for x in np.eye(3):
        st.update(np.array([0.1]), x)
    P = st.P.copy()
    st.forget(0.9)
    assert np.allclose(st.P, P / 0.9) and np.trace(st.P) < S.sum()


@pytest.mark.parametrize("cls", VARIANTS)
def test_mask_take_and_nu_floor(cls):
    rng = np.random.default_rng(4)
    st = cls((4,), 1, np.ones(3), np.eye(1), nu0=5.0)
    mask = np.array([True, False, True, False])
    st.update(rng.standard_normal((4, 1)), rng.standard_normal((4, 3)), mask)
    assert np.allclose(st.nu, [6, 5, 6, 5])
    M, _ = st.posterior()
    assert np.all(M[1] == 0) and np.any(M[0] != 0)
    st.forget(0.5, nu_min=5.0)
    assert np.allclose(st.nu, [5, 5, 5, 5])  # forgetting stops at the prior's dof
    M = st.posterior()[0]  # (the exact variant's M moves with forgetting: V is not forgotten)
    sub = st.take(np.array([2, 2, 0]))
    assert np.allclose(sub.posterior()[0], M[[2, 2, 0]])


# ---- predictive ----------------------------------------------------------------------
def _learned(cls, rng):
    X, Z, S, Lam0 = _data(rng, T=15)
    st = cls((), 2, S, Lam0, nu0=8.0)
    for x, z in zip(X, Z):
        st.update(z, x)
    return st, rng.standard_normal(6)


@pytest.mark.parametrize("cls", VARIANTS)
@pytest.mark.parametrize("path", ["marginal_t", "sample_A_and_Q"])
def test_predictive_samples_match_theoretical_moments(cls, path):
    """zeta = A phi + w: mean M phi, covariance c Lambda / (nu - d - 1), c = 1 + phi^T Sigma* phi,
    whether drawn from the multivariate t of eq. (31) or by sampling Q, A and w; within
    5 Monte-Carlo standard errors (fixed seed, 200k draws)."""
    rng = np.random.default_rng(5)
    st, phi = _learned(cls, rng)
    M, Lam = st.posterior()
    K = st.K if cls is MNIW else np.linalg.inv(st.P)
    c = 1.0 + phi @ np.linalg.solve(K, phi)
    mean_th = M @ phi
    cov_th = c * Lam / (st.nu - 2 - 1)
    n = 200_000
    if path == "marginal_t":
        loc, scale, dof = st.predictive(phi)
        assert np.allclose(loc, mean_th) and np.isclose(dof, st.nu - 1)
        z = t_sample(loc, scale, dof, rng, size=n)
    else:
        big = st.take(np.zeros(n, dtype=int))
        z = big.sample_predictive(np.broadcast_to(phi, (n, 6)), rng)
    se_mean = np.sqrt(np.diag(cov_th) / n)
    assert np.all(np.abs(z.mean(0) - mean_th) < 5 * se_mean)
    dz = z - mean_th
    prods = dz[:, :, None] * dz[:, None, :]
    se_cov = prods.std(0) / math.sqrt(n)
    assert np.all(np.abs(prods.mean(0) - cov_th) < 5 * se_cov)


def test_inverse_wishart_sampler_mean():
    rng = np.random.default_rng(6)
    Lam = np.array([[2.0, 0.3], [0.3, 1.0]])
    nu = 12.0
    Q = sample_inverse_wishart(np.full(100_000, nu), np.broadcast_to(Lam, (100_000, 2, 2)), rng)
    mean = Lam / (nu - 3)
    se = Q.std(0) / math.sqrt(len(Q))
    assert np.all(np.abs(Q.mean(0) - mean) < 5 * se)


@pytest.mark.parametrize("cls", VARIANTS)
def test_function_moments(cls):
    """Mean M phi and covariance E[Q] phi^T Sigma* phi of A phi at a batch of points."""
    rng = np.random.default_rng(7)
    st, phi = _learned(cls, rng)
    G = rng.standard_normal((3, 6))
    mean, cov = st.function_moments(G)
    M, Lam = st.posterior()
    K = st.K if cls is MNIW else np.linalg.inv(st.P)
    for g in range(3):
        assert np.allclose(mean[g], M @ G[g])
        assert np.allclose(cov[g], G[g] @ np.linalg.solve(K, G[g]) * Lam / (st.nu - 3))
