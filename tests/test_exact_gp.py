"""The reduced-rank GP basis (stats/gp.py) against exact answers: the eigenfunctions of
eq. (10b) written out, the Dirichlet kernel by its converged eigen-expansion, the spectral
tail, and the odd (mu(-alpha) = -mu(alpha)) layouts by their symmetry. Found by mutation
testing (benchmarks/mutation.py): each test kills mutants the other tests let through."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tirefilter.errors import ConfigError
from tirefilter.stats.gp import AxleBasis, GPBasis1D, TensorBasis, make_basis, spectral_density


def test_eigenfunctions_and_eigenvalues_are_eq_10():
    """phi_j(x) = sin(pi j (x + L) / (2 L)) / sqrt(L) and lambda_j = (pi j / (2 L))^2, at a
    (2, 3) batch of points (phi_1 is positive inside (-L, L)); one function is a basis."""
    L, m = 0.6, 5
    b = GPBasis1D(L, m, 0.1)
    x = np.array([[-0.5, 0.0, 0.2], [0.59, -0.3, 0.45]])
    phi = b.phi(x)
    assert phi.shape == (2, 3, m)
    for j in range(1, m + 1):
        np.testing.assert_allclose(phi[..., j - 1], np.sin(math.pi * j * (x + L) / (2 * L)) / math.sqrt(L), rtol=1e-13,
                                   atol=1e-14)
    assert np.all(phi[..., 0] > 0)
    np.testing.assert_allclose(b.eigenvalues(), (math.pi * np.arange(1, m + 1) / (2 * L)) ** 2, rtol=1e-15)
    assert GPBasis1D(L, 1, 0.1).phi(0.0).shape == (1,)


def test_truncation_bound_is_the_spectral_tail():
    """(1/L) sum_{j > m} S(sqrt(lambda_j)), summed here term by term until the terms vanish;
    raising m by one removes exactly the term j = m + 1."""
    L, ell, s_f = 0.5, 0.08, 2.0
    for m in (4, 9):
        b = GPBasis1D(L, m, ell, s_f)
        tail, j = 0.0, m + 1
        while True:
            term = s_f * math.sqrt(2 * math.pi) * ell * math.exp(-0.5 * ell**2 * (math.pi * j / (2 * L)) ** 2) / L
            tail += term
            if term < 1e-30 * tail:
                break
            j += 1
        assert b.truncation_bound() == pytest.approx(tail, rel=1e-12)
        nxt = GPBasis1D(L, m + 1, ell, s_f)
        S = spectral_density((math.pi * (m + 1) / (2 * L)) ** 2, s_f, ell, 1)
        assert b.truncation_bound() - nxt.truncation_bound() == pytest.approx(S / L, rel=1e-9)


@pytest.mark.parametrize("ell,tol", [(0.25, 1e-12), (1.5, 3e-7)], ids=["short", "three-half-widths"])
def test_dirichlet_kernel_is_the_converged_eigen_expansion(ell, tol):
    """kernel_dirichlet (method of images, 4 images each way) against the eigen-expansion of
    eq. (9) with so many functions that the spectral tail is below 1e-16, on a half-width
    L = 0.5 with points near both boundaries. A lengthscale of three half-widths needs the
    far images: the images beyond |n| = 4 leave 1.06e-7 there (measured; bound 3e-7)."""
    L = 0.5
    exact = GPBasis1D(L, 80, ell)
    assert exact.truncation_bound() < 1e-16
    x = np.array([0.45, 0.15, -0.25, -0.475, 0.0])
    x2 = np.array([-0.45, 0.35, -0.1, 0.475, 0.0])
    ref = exact.kernel_approx(x, x2)
    np.testing.assert_allclose(exact.kernel_dirichlet(x, x2), ref, rtol=0, atol=tol)
    np.testing.assert_allclose(exact.kernel_dirichlet(np.array([L, -L]), np.array([0.1, 0.2])), 0.0, atol=tol)


@pytest.mark.parametrize("m", [4, 6])
def test_odd_tensor_basis_keeps_the_odd_products(m):
    """`odd`: the columns j1 * m + j2 of the full tensor basis with j1 + j2 odd (m^2 / 2 of
    them), their eigenvalue sums and 2-D spectral densities; each kept feature is odd under
    (alpha_f, alpha_r) -> -(alpha_f, alpha_r), at a (2, 3) batch of slips."""
    b = GPBasis1D(0.5, m, 0.1)
    full, odd = TensorBasis(b), TensorBasis(b, odd=True)
    j1, j2 = np.divmod(np.arange(m * m), m)
    want = np.flatnonzero((j1 + j2) % 2 == 1)
    assert odd.size == m * m // 2 and full.size == m * m
    np.testing.assert_array_equal(odd.keep, want)
    rng = np.random.default_rng(50)
    af, ar = rng.uniform(-0.45, 0.45, (2, 3)), rng.uniform(-0.45, 0.45, (2, 3))
    F, Fo = full.features(af, ar), odd.features(af, ar)
    assert F.shape == (2, 3, m * m) and Fo.shape == (2, 3, m * m // 2)
    np.testing.assert_array_equal(Fo, F[..., want])
    np.testing.assert_allclose(odd.features(-af, -ar), -Fo, rtol=1e-12, atol=1e-14)
    lam = b.eigenvalues()
    np.testing.assert_allclose(odd.lam, lam[j1[want]] + lam[j2[want]], rtol=1e-15)
    np.testing.assert_allclose(odd.S, spectral_density(odd.lam, b.s_f, b.lengthscale, 2), rtol=1e-15)
    # the full basis: product of the 1-D functions, index j1 * m + j2
    pf, pr = b.phi(af), b.phi(ar)
    np.testing.assert_allclose(F[1, 2, 2 * m + 3], pf[1, 2, 2] * pr[1, 2, 3], rtol=1e-15)


def test_odd_axle_basis_keeps_the_odd_functions():
    """`odd` per axle: the functions with even j (odd in the slip), m / 2 per axle, front
    row from alpha_f and rear row from alpha_r."""
    b = GPBasis1D(0.5, 6, 0.1)
    odd = AxleBasis(b, odd=True)
    np.testing.assert_array_equal(odd.keep, [1, 3, 5])  # j = 2, 4, 6
    a = np.array([0.1, -0.3, 0.42])
    np.testing.assert_allclose(odd.phi(-a), -odd.phi(a), rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(odd.features(a, -a)[:, 0], b.phi(a)[:, [1, 3, 5]])
    np.testing.assert_array_equal(odd.features(a, -a)[:, 1], b.phi(-a)[:, [1, 3, 5]])
    np.testing.assert_allclose(odd.lam, b.eigenvalues()[[1, 3, 5]], rtol=1e-15)


def test_make_basis_builds_the_layout_asked_for():
    """Each kind, with and without `odd` (default: all functions); the odd per-axle basis
    needs m >= 2 (m = 2 keeps j = 2)."""
    b = GPBasis1D(0.5, 4, 0.1)
    for kind, cls, full_size, odd_size in (("tensor", TensorBasis, 16, 8), ("axle", AxleBasis, 4, 2)):
        plain, odd = make_basis(kind, b), make_basis(kind, b, True)
        assert type(plain) is cls and type(odd) is cls and plain.kind == kind
        assert (plain.odd, plain.size, odd.odd, odd.size) == (False, full_size, True, odd_size)
    assert make_basis("axle", GPBasis1D(0.5, 2, 0.1), True).size == 1
    with pytest.raises(ConfigError, match="m >= 2"):
        make_basis("axle", GPBasis1D(0.5, 1, 0.1), True)
