"""Multivariate Student-t St(mu, Lambda, nu) (scale Lambda, covariance nu/(nu-2) Lambda):
log-density, sampling and the conditional of a jointly Student-t pair. Batch-first:
mu (..., p), Lambda (..., p, p), nu (...)."""

from __future__ import annotations

import numpy as np

from tirefilter.stats.linalg import chol, gram, logdet_chol, solve_lower


def t_logpdf_whitened(v, logdet, nu):
    """log St from the whitened residual v = L^-1 (x - mu) (L L^T = Lam) and log|Lam|:
    log Gamma((nu+p)/2) - log Gamma(nu/2) - p/2 log(nu pi) - 1/2 log|Lam|
    - (nu+p)/2 log(1 + |v|^2 / nu). Lets a caller reuse a factorisation it needs anyway."""
    from scipy.special import gammaln  # (here: scipy.special maps some 28 MB, which a compiled MPF never needs)

    p = v.shape[-1]
    nu = _common(nu)
    const = gammaln(0.5 * (nu + p)) - gammaln(0.5 * nu) - 0.5 * p * np.log(nu * np.pi)
    return const - 0.5 * logdet - 0.5 * (nu + p) * np.log1p(np.einsum("...i,...i->...", v, v) / nu)


def _common(nu):
    """nu as a float when every batch element has the same degrees of freedom (the usual
    case in a filter: the special functions and the chi-square draw then run once)."""
    nu = np.asarray(nu, float)
    if nu.ndim and nu.size and nu.flat[0] == nu.min() == nu.max():
        return float(nu.flat[0])
    return nu


def t_logpdf(x, mu, Lam, nu):
    """log St(x; mu, Lam, nu)."""
    r = np.asarray(x, float) - mu
    L = chol(np.asarray(Lam, float))
    L = np.broadcast_to(L, np.broadcast_shapes(r.shape[:-1], L.shape[:-2]) + L.shape[-2:])
    v = solve_lower(L, np.broadcast_to(r, L.shape[:-1]))
    return t_logpdf_whitened(v, logdet_chol(L), nu)


def t_sample(mu, Lam, nu, rng: np.random.Generator, size=None):
    """Samples mu + L z sqrt(nu / u), z ~ N(0, I), u ~ chi2(nu), L L^T = Lam.

    Without `size`, one sample per batch element; with `size` (an int), that many
    independent samples along a new leading axis.
    """
    mu = np.asarray(mu, float)
    L = chol(np.asarray(Lam, float))
    shape = mu.shape if size is None else (size,) + mu.shape
    z, u = t_draws(nu, shape, rng)
    return mu + np.einsum("...ij,...j->...i", L, z) * np.sqrt(_common(nu) / u)[..., None]


def t_draws(nu, shape, rng: np.random.Generator):
    """The random numbers of `t_sample` for samples of `shape` (..., p): z ~ N(0, I) (shape)
    and u ~ chi2(nu) (shape[:-1]), batched (one chi-square call for a common nu), drawn by
    the same generator calls in the same order, so a compiled sampler fed (z, u) follows the
    reference exactly."""
    nu = _common(nu)
    z = rng.standard_normal(shape)
    u = rng.chisquare(nu, shape[:-1]) if np.ndim(nu) == 0 else rng.chisquare(np.broadcast_to(nu, shape[:-1]))
    return z, u


def t_conditional(mu1, mu2, L11, L12, L22, nu, x2, *, L22_chol=None, x2_white=None):
    """Conditional of x1 given x2 when (x1, x2) ~ St([mu1; mu2], [[L11, L12]; [L12^T, L22]], nu):

        nu_1|2  = nu + d2
        mu_1|2  = mu1 + L12 L22^-1 (x2 - mu2)
        Lam_1|2 = (nu + (x2-mu2)^T L22^-1 (x2-mu2)) / (nu + d2) (L11 - L12 L22^-1 L12^T)

    (stiffness paper eq. (41), with the Mahalanobis term as a quadratic form). A caller
    that already has the Cholesky factor of L22 passes it as `L22_chol` (L22 is then not
    read); one that also has the whitened residual L22_chol^-1 (x2 - mu2) passes it as
    `x2_white`. Returns (mu_1|2, Lam_1|2, nu_1|2).
    """
    d2 = np.shape(x2)[-1]
    Lc = chol(np.asarray(L22, float)) if L22_chol is None else L22_chol
    if x2_white is None:
        r = np.asarray(x2, float) - mu2
        if r.shape[:-1] != Lc.shape[:-2]:
            Lc = np.broadcast_to(Lc, np.broadcast_shapes(r.shape[:-1], Lc.shape[:-2]) + Lc.shape[-2:])
            r = np.broadcast_to(r, Lc.shape[:-1])
        v = solve_lower(Lc, r)  # whitened residual
    else:
        v = x2_white
    M = solve_lower(Lc, np.swapaxes(L12, -1, -2))  # Lc^-1 L21, so L12 L22^-1 L21 = M^T M
    mu_c = mu1 + np.einsum("...ki,...k->...i", M, v)
    nu = np.asarray(nu, float)
    scale = (nu + np.einsum("...i,...i->...", v, v)) / (nu + d2)
    Lam_c = scale[..., None, None] * (L11 - gram(M))
    return mu_c, Lam_c, nu + d2
