"""Normal-inverse-Wishart sufficient statistics with exponential forgetting.

mu | Sigma ~ N(mu_hat, gamma Sigma),  Sigma ~ iW(nu, Lambda)  (stiffness paper, Lemma 1),
one set per particle: gamma (N,), mu (N, n), Lam (N, n, n), nu (N,).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class NiW:
    gamma: np.ndarray  # (...,)
    mu: np.ndarray  # (..., n)
    Lam: np.ndarray  # (..., n, n)
    nu: np.ndarray  # (...,)

    @property
    def dim(self) -> int:
        return self.mu.shape[-1]

    def copy(self) -> "NiW":
        return NiW(self.gamma.copy(), self.mu.copy(), self.Lam.copy(), self.nu.copy())

    def take(self, idx) -> "NiW":
        """The statistics of the particles `idx` (resampling)."""
        return NiW(self.gamma[idx], self.mu[idx], self.Lam[idx], self.nu[idx])

    def update(self, w: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Measurement update with one observation w (..., n), eq. (19a)-(19e):
        gamma' = gamma / (1 + gamma), mu' = mu + gamma' z, nu' = nu + 1,
        Lam' = Lam + z z^T / (1 + gamma), z = w - mu. Where `mask` is False, unchanged."""
        z = w - self.mu
        g_new = self.gamma / (1.0 + self.gamma)
        mu = self.mu + g_new[..., None] * z
        Lam = self.Lam + np.einsum("...i,...j->...ij", z, z) / (1.0 + self.gamma)[..., None, None]
        nu = self.nu + 1.0
        if mask is None:
            self.gamma, self.mu, self.Lam, self.nu = g_new, mu, Lam, nu
        else:
            self.gamma = np.where(mask, g_new, self.gamma)
            self.mu = np.where(mask[..., None], mu, self.mu)
            self.Lam = np.where(mask[..., None, None], Lam, self.Lam)
            self.nu = np.where(mask, nu, self.nu)

    def forget(self, lam: float, nu_min: float = 0.0) -> None:
        """Prediction with exponential forgetting, eq. (20): gamma / lambda, nu lambda,
        Lam lambda, mu unchanged.

        With `nu_min`, forgetting stops where it would take nu below nu_min (the factor
        is max(lambda, nu_min / nu) per particle): statistics that receive no data (a
        particle that skips learning) keep the prior's information instead of drifting to
        nu <= n + 1, where the inverse-Wishart mean and the Student-t variance do not exist.
        """
        factor = np.maximum(lam, np.minimum(1.0, nu_min / self.nu)) if nu_min > 0 else np.full_like(self.nu, lam)
        self.gamma = self.gamma / factor
        self.nu = self.nu * factor
        self.Lam = self.Lam * factor[..., None, None]

    def predictive(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Student-t predictive of the next observation, eq. (21) with d = n:
        St(mu, (1 + gamma) / (nu - n + 1) Lam, nu - n + 1)."""
        dof = self.nu - self.dim + 1.0
        scale = ((1.0 + self.gamma) / dof)[..., None, None] * self.Lam
        return self.mu, scale, dof

    def mean_sigma(self) -> np.ndarray:
        """E[Sigma] = Lam / (nu - n - 1), the inverse-Wishart mean (needs nu > n + 1)."""
        return self.Lam / (self.nu - self.dim - 1.0)[..., None, None]

    def mean_var(self) -> np.ndarray:
        """Posterior covariance of mu: gamma E[Sigma] (marginal of mu is Student-t with
        this covariance)."""
        return self.gamma[..., None, None] * self.mean_sigma()
