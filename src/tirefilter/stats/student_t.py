"""Multivariate Student-t St(mu, Lambda, nu) (scale Lambda, covariance nu/(nu-2) Lambda):
log-density, sampling and the conditional of a jointly Student-t pair. Batch-first:
mu (..., p), Lambda (..., p, p), nu (...)."""

from __future__ import annotations

import numpy as np
from scipy.special import gammaln


def _chol(S):
    """Cholesky of (batches of) symmetric positive-definite matrices, symmetrised first."""
    return np.linalg.cholesky(0.5 * (S + np.swapaxes(S, -1, -2)))


def t_logpdf(x, mu, Lam, nu):
    """log St(x; mu, Lam, nu) = log Gamma((nu+p)/2) - log Gamma(nu/2) - p/2 log(nu pi)
    - 1/2 log|Lam| - (nu+p)/2 log(1 + (x-mu)^T Lam^-1 (x-mu) / nu)."""
    x, mu = np.asarray(x, float), np.asarray(mu, float)
    p = x.shape[-1]
    L = _chol(Lam)
    r = x - mu
    sol = np.linalg.solve(L, r[..., None])[..., 0]
    maha = np.sum(sol * sol, axis=-1)
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    nu = np.asarray(nu, float)
    return (gammaln(0.5 * (nu + p)) - gammaln(0.5 * nu) - 0.5 * p * np.log(nu * np.pi) - 0.5 * logdet
            - 0.5 * (nu + p) * np.log1p(maha / nu))


def t_sample(mu, Lam, nu, rng: np.random.Generator, size=None):
    """Samples mu + L z sqrt(nu / u), z ~ N(0, I), u ~ chi2(nu), L L^T = Lam.

    Without `size`, one sample per batch element; with `size` (an int), that many
    independent samples along a new leading axis.
    """
    mu = np.asarray(mu, float)
    L = _chol(np.asarray(Lam, float))
    nu = np.asarray(nu, float)
    shape = mu.shape if size is None else (size,) + mu.shape
    z = rng.standard_normal(shape)
    u = rng.chisquare(np.broadcast_to(nu, shape[:-1]))
    return mu + np.einsum("...ij,...j->...i", L, z) * np.sqrt(nu / u)[..., None]


def t_conditional(mu1, mu2, L11, L12, L22, nu, x2):
    """Conditional of x1 given x2 when (x1, x2) ~ St([mu1; mu2], [[L11, L12]; [L12^T, L22]], nu):

        nu_1|2  = nu + d2
        mu_1|2  = mu1 + L12 L22^-1 (x2 - mu2)
        Lam_1|2 = (nu + (x2-mu2)^T L22^-1 (x2-mu2)) / (nu + d2) (L11 - L12 L22^-1 L12^T)

    (stiffness paper eq. (41), with the Mahalanobis term as a quadratic form). Returns
    (mu_1|2, Lam_1|2, nu_1|2).
    """
    d2 = np.shape(x2)[-1]
    r = np.asarray(x2, float) - mu2
    G = np.swapaxes(np.linalg.solve(L22, np.swapaxes(L12, -1, -2)), -1, -2)  # L12 L22^-1
    mu_c = mu1 + np.einsum("...ij,...j->...i", G, r)
    maha = np.einsum("...i,...i->...", r, np.linalg.solve(L22, r[..., None])[..., 0])
    nu = np.asarray(nu, float)
    scale = (nu + maha) / (nu + d2)
    Lam_c = scale[..., None, None] * (L11 - G @ np.swapaxes(L12, -1, -2))
    return mu_c, 0.5 * (Lam_c + np.swapaxes(Lam_c, -1, -2)), nu + d2
