"""The MNIW statistics of the friction GP-SSM (stats/mniw.py), both variants, against exact
answers on what the other tests leave out: masked updates and forgetting (the per-particle
learning gate), two batch axes, the floor on the degrees of freedom, the returned posterior
mean, and the factor of Sigma* the posterior draws use. Found by mutation testing
(benchmarks/mutation.py): each test kills mutants the other tests let through."""

from __future__ import annotations

import numpy as np
import pytest

from tirefilter.stats.mniw import MNIW, MNIWRank1, sample_inverse_wishart

VARIANTS = [MNIW, MNIWRank1]
D, M_FEAT = 2, 5
LAM0 = np.array([[0.5, 0.1], [0.1, 0.4]])


def _sigma_star(st) -> np.ndarray:
    """Sigma* = (Sigma + V)^-1 from the variant's own statistic."""
    return np.linalg.inv(st.K) if isinstance(st, MNIW) else st.P


def _batch_posterior(X, Z, S, nu0):
    """Conjugate posterior of (A, Q) from the rows of X (n, m) and Z (n, d), no forgetting:
    Sigma* = (X^T X + V)^-1, M = Z^T X Sigma*, Lambda = Lambda_0 + (Z - X M^T)^T (Z - X M^T)
    + M V M^T, nu = nu_0 + n (eq. (25)-(26))."""
    V = np.diag(1.0 / S)
    Sig = np.linalg.inv(X.T @ X + V)
    M = Z.T @ X @ Sig
    E = Z - X @ M.T
    return M, LAM0 + E.T @ E + M @ V @ M.T, Sig, nu0 + len(X)


def _learn(cls, rng, batch=(2, 3), T=25, mask_p=None):
    """Statistics over `batch`, each element fed its own data (and mask, when mask_p)."""
    S = rng.uniform(0.5, 2.0, M_FEAT)
    X = rng.standard_normal((T,) + batch + (M_FEAT,))
    Z = np.einsum("...dm,t...m->t...d", rng.standard_normal(batch + (D, M_FEAT)), X)
    Z += 0.3 * rng.standard_normal(Z.shape)
    masks = rng.random((T,) + batch) < mask_p if mask_p is not None else np.ones((T,) + batch, bool)
    st = cls(batch, D, S, LAM0, nu0=5.0)
    for t in range(T):
        st.update(Z[t], X[t], masks[t] if mask_p is not None else None)
    return st, X, Z, S, masks


@pytest.mark.parametrize("cls", VARIANTS)
def test_masked_updates_equal_the_batch_posterior_of_the_unmasked_samples(cls):
    """A (2, 3) batch, each element with its own data and its own mask per step (the learning
    gate per particle): each element's posterior is the conjugate posterior of the samples
    its mask let through; for the exact variant Sigma (27c) is their sum of phi phi^T."""
    st, X, Z, S, masks = _learn(cls, np.random.default_rng(70), mask_p=0.6)
    M, Lam = st.posterior()
    for i in np.ndindex(2, 3):
        keep = masks[(slice(None),) + i]
        Mb, Lb, Sb, nub = _batch_posterior(X[(keep,) + i], Z[(keep,) + i], S, 5.0)
        np.testing.assert_allclose(M[i], Mb, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(Lam[i], Lb, rtol=1e-9)
        np.testing.assert_allclose(_sigma_star(st)[i], Sb, rtol=1e-9, atol=1e-12)
        assert st.nu[i] == nub
        if cls is MNIW:
            Xi = X[(keep,) + i]
            np.testing.assert_allclose(st.Sigma[i], Xi.T @ Xi, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("cls", VARIANTS)
def test_posterior_predictive_and_function_moments_over_two_batch_axes(cls):
    """Unmasked updates over a (2, 3) batch: the posterior is the conjugate one per element;
    the predictive (eq. (31)-(32)) is St(M phi, (1 + phi^T Sigma* phi) / (nu - d + 1)
    Lambda, nu - d + 1), with `return_M` also M itself; the function moments at G = 4 points
    are M phi_g and phi_g^T Sigma* phi_g Lambda / (nu - d - 1)."""
    rng = np.random.default_rng(71)
    st, X, Z, S, _ = _learn(cls, rng)
    phi = rng.standard_normal((2, 3, M_FEAT))
    G = rng.standard_normal((2, 3, 4, M_FEAT))
    loc, scale, dof = st.predictive(phi)
    loc2, scale2, dof2, Mret = st.predictive(phi, return_M=True)
    mean, cov = st.function_moments(G)
    for i in np.ndindex(2, 3):
        Mb, Lb, Sb, nub = _batch_posterior(X[(slice(None),) + i], Z[(slice(None),) + i], S, 5.0)
        np.testing.assert_allclose(Mret[i], Mb, rtol=1e-9, atol=1e-12)
        c = 1.0 + phi[i] @ Sb @ phi[i]
        np.testing.assert_allclose(loc[i], Mb @ phi[i], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(scale[i], c / (nub - D + 1.0) * Lb, rtol=1e-9)
        assert dof[i] == nub - D + 1.0
        for g in range(4):
            np.testing.assert_allclose(mean[i][g], Mb @ G[i][g], rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(cov[i][g], G[i][g] @ Sb @ G[i][g] * Lb / (nub - D - 1.0), rtol=1e-9)
    for a, b in ((loc, loc2), (scale, scale2), (dof, dof2)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("cls", VARIANTS)
def test_forgetting_only_where_masked_and_not_below_nu_min(cls):
    """Eq. (29) with a mask and nu_min: factor lambda where lambda nu >= nu_min, nu_min / nu
    where not (nu lands on nu_min), 1 where nu is already below it or the mask is off.
    Exact: Phi, Psi times f and Sigma + V -> f (Sigma + V) + (1 - f) V. Rank one: Lambda
    times f, P / f (below the trace bound), M unchanged. Without nu_min: lambda, even at
    nu < 1."""
    st, *_ = _learn(cls, np.random.default_rng(72), batch=(5,), T=3)
    st.nu = np.array([100.0, 10.0, 9.0, 0.6, 50.0])
    before = {k: np.array(getattr(st, k)) for k in ("Phi", "Psi", "K", "M", "P", "Lam", "nu") if hasattr(st, k)}
    st.forget(0.9, mask=np.array([True, True, True, True, False]), nu_min=9.5)
    f = np.array([0.9, 0.95, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(st.nu, before["nu"] * f, rtol=1e-15)
    F = f[:, None, None]
    if cls is MNIW:
        np.testing.assert_allclose(st.Phi, before["Phi"] * F, rtol=1e-15)
        np.testing.assert_allclose(st.Psi, before["Psi"] * F, rtol=1e-15)
        np.testing.assert_allclose(st.K, F * before["K"] + (1.0 - F) * np.diag(st.V), rtol=1e-14)
    else:
        assert np.all(np.einsum("nii->n", before["P"]) / 0.9 < st.trace0)  # below the bound: plain P / f
        np.testing.assert_allclose(st.P, before["P"] / F, rtol=1e-15)
        np.testing.assert_allclose(st.Lam, before["Lam"] * F, rtol=1e-15)
        np.testing.assert_array_equal(st.M, before["M"])
    st.nu = np.array([1.5, 40.0, 0.6, 2.0, 3.0])
    st.forget(0.5)
    np.testing.assert_allclose(st.nu, [0.75, 20.0, 0.3, 1.0, 1.5], rtol=1e-15)
    st.forget(0.5, nu_min=0.8)  # a floor below 1 floors too: 0.75 and 0.3 stay, 1.0 -> 0.8
    np.testing.assert_allclose(st.nu, [0.75, 10.0, 0.3, 0.8, 0.8], rtol=1e-15)


@pytest.mark.parametrize("cls", VARIANTS)
def test_the_factor_of_sigma_star_gives_rows_with_covariance_sigma_star(cls):
    """The posterior draws of A take rows Z H with H from `_sigma_star_half`: H^T H is Sigma*
    exactly (to rounding), per element of a batch."""
    st, *_ = _learn(cls, np.random.default_rng(73), batch=(4,), T=12)
    H = st._sigma_star_half(np.broadcast_to(np.eye(M_FEAT), (4, M_FEAT, M_FEAT)))
    np.testing.assert_allclose(np.swapaxes(H, -1, -2) @ H, _sigma_star(st), rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize("batch", [(4000,), (40, 100)])
def test_inverse_wishart_draws_are_symmetric_with_the_inverse_wishart_mean(batch):
    """Draws over one or two batch axes: each exactly symmetric, their mean Lambda / (nu -
    d - 1) within 5 standard errors (fixed seed)."""
    rng = np.random.default_rng(74)
    Lam = np.array([[2.0, 0.3, -0.2], [0.3, 1.0, 0.1], [-0.2, 0.1, 1.5]])
    nu = 11.0
    Q = sample_inverse_wishart(np.full(batch, nu), np.broadcast_to(Lam, batch + (3, 3)), rng)
    assert Q.shape == batch + (3, 3)
    np.testing.assert_array_equal(Q, np.swapaxes(Q, -1, -2))
    q = Q.reshape(-1, 3, 3)
    se = q.std(0) / np.sqrt(len(q))
    assert np.all(np.abs(q.mean(0) - Lam / (nu - 3 - 1)) < 5 * se)


@pytest.mark.parametrize("kind", ["exact", "rank1"])
def test_make_mniw_picks_the_variant_and_the_backend(kind):
    """`make_mniw`: the variant of `kind`, as the numpy class or its compiled twin, with the
    prior precision of the columns V = 1 / S."""
    from tirefilter.stats.mniw import make_mniw
    from tirefilter.stats.mniw_numba import NumbaMNIW, NumbaMNIWRank1

    S = np.array([0.5, 2.0, 4.0])
    args = ((4,), 2, S, LAM0, 5.0)
    assert type(make_mniw(kind, *args)) is (MNIWRank1 if kind == "rank1" else MNIW)
    assert type(make_mniw(kind, *args, backend="numba")) is (NumbaMNIWRank1 if kind == "rank1" else NumbaMNIW)
    assert make_mniw(kind, *args).V.tolist() == (1.0 / S).tolist()
