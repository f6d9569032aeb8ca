"""Reduced-rank Gaussian-process basis on [-L, L] (Solin & Saerkkae 2014), as the friction
paper uses it, eq. (9)-(12): Laplace-operator eigenfunctions with Dirichlet boundary
conditions, their eigenvalues and the spectral density of the squared-exponential kernel.

    phi_j(x)   = sin(pi j (x + L) / (2 L)) / sqrt(L)          eq. (10b), j = 1..m
    lambda_j   = (pi j / (2 L))^2                              eq. (10a)
    S(omega)   = s_f (2 pi l^2)^(d/2) exp(-l^2 omega^2 / 2)    SE kernel, angular frequency
    kappa(x, x') ~= sum_j S(sqrt(lambda_j)) phi_j(x) phi_j(x')  eq. (9)

`s_f` is the kernel's variance, kappa(r) = s_f exp(-r^2 / (2 l^2)) as the paper writes
the kernel (Sec. 4); the paper prints S for ordinary frequency, with the Laplacian
eigenvalues the angular-frequency form above is the right one (docs/derivations.md, "Reduced-rank basis").

Two layouts over the axle slip angles alpha = (alpha_f, alpha_r):
- `TensorBasis`: the paper's 2-D basis, products phi_j1(alpha_f) phi_j2(alpha_r) with
  lambda = lambda_j1 + lambda_j2 (m^2 functions, 100 for m = 10);
- `AxleBasis`: one 1-D basis per axle (mu_f of alpha_f, mu_r of alpha_r), m + m functions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tirefilter.errors import ConfigError

SOURCE = "gp basis"


@dataclass(frozen=True)
class GPBasis1D:
    """The 1-D reduced-rank basis of a squared-exponential GP on [-L, L]."""

    L: float  # half-width of the domain (rad for slip angles)
    m: int  # number of basis functions
    lengthscale: float  # l, same unit as L
    s_f: float = 1.0  # kernel variance

    def __post_init__(self):
        def bad(key, problem):
            raise ConfigError(SOURCE, key, problem)

        def positive(v) -> bool:
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0

        if not positive(self.L):
            bad("L", f"the domain half-width must be a finite number > 0, got {self.L!r}")
        if not positive(self.lengthscale):
            bad("lengthscale", f"must be a finite number > 0, got {self.lengthscale!r}")
        if not (isinstance(self.m, (int, np.integer)) and not isinstance(self.m, bool) and self.m >= 1):
            bad("basis_functions", f"need an integer number of basis functions >= 1, got {self.m!r}")
        if not positive(self.s_f):
            bad("s_f", f"the kernel variance must be a finite number > 0, got {self.s_f!r}")

    @property
    def j(self) -> np.ndarray:
        return np.arange(1, self.m + 1)

    def eigenvalues(self) -> np.ndarray:
        """lambda_j = (pi j / (2 L))^2, eq. (10a); (m,)."""
        return (math.pi * self.j / (2.0 * self.L)) ** 2

    def phi(self, x) -> np.ndarray:
        """Eigenfunctions at x (...,) -> (..., m), eq. (10b). x is not clipped here."""
        x = np.asarray(x, float)
        return np.sin((math.pi / (2.0 * self.L)) * (x[..., None] + self.L) * self.j) / math.sqrt(self.L)

    def spectral_density(self) -> np.ndarray:
        """S(sqrt(lambda_j)) = s_f sqrt(2 pi) l exp(-l^2 lambda_j / 2); (m,)."""
        return spectral_density(self.eigenvalues(), self.s_f, self.lengthscale, 1)

    def kernel(self, x, x2) -> np.ndarray:
        """The exact SE kernel s_f exp(-(x - x')^2 / (2 l^2)) (broadcasting)."""
        d = np.asarray(x, float) - np.asarray(x2, float)
        return self.s_f * np.exp(-0.5 * d * d / self.lengthscale**2)

    def kernel_approx(self, x, x2) -> np.ndarray:
        """The reduced-rank kernel of eq. (9): sum_j S_j phi_j(x) phi_j(x')."""
        return np.einsum("...j,...j,j->...", self.phi(x), self.phi(x2), self.spectral_density())

    def truncation_bound(self, terms: int = 100000) -> float:
        """sup |kappa_Dirichlet - kappa_m| <= (1/L) sum_{j>m} S_j: the spectral mass left out
        (|phi_j| <= 1/sqrt(L)). kappa_Dirichlet is `kernel_dirichlet`, the m -> infinity limit."""
        j = np.arange(self.m + 1, self.m + 1 + terms)
        lam = (math.pi * j / (2.0 * self.L)) ** 2
        return float(np.sum(spectral_density(lam, self.s_f, self.lengthscale, 1)) / self.L)

    def kernel_dirichlet(self, x, x2, images: int = 4) -> np.ndarray:
        """The m -> infinity limit of eq. (9): the SE kernel with Dirichlet boundaries at
        +-L, by the method of images (period 4 L):
        sum_n [kappa(x - x' + 4 n L) - kappa(x + x' + 2 L + 4 n L)]."""
        x = np.asarray(x, float)
        x2 = np.asarray(x2, float)
        out = 0.0
        for n in range(-images, images + 1):
            shift = 4 * n * self.L
            out = out + self.kernel(x - x2 + shift, 0.0) - self.kernel(x + x2 + 2 * self.L + shift, 0.0)
        return out


def spectral_density(lam, s_f: float, lengthscale: float, dim: int) -> np.ndarray:
    """SE spectral density in angular frequency at omega^2 = lam:
    s_f (2 pi l^2)^(dim/2) exp(-l^2 lam / 2)."""
    return s_f * (2.0 * math.pi * lengthscale**2) ** (dim / 2.0) * np.exp(-0.5 * lengthscale**2 * np.asarray(lam))


class TensorBasis:
    """The paper's 2-D basis over (alpha_f, alpha_r): phi_{j1 j2} = phi_j1(alpha_f) phi_j2(alpha_r),
    lambda = lambda_j1 + lambda_j2, S from the 2-D SE density (eq. (9)-(10), d = 2).
    Both axles share one feature vector of m^2 entries (index j1 * m + j2).

    `odd`: only the products that are odd under (alpha_f, alpha_r) -> -(alpha_f, alpha_r),
    i.e. j1 + j2 odd (phi_j is odd in x for even j, even for odd j): a friction function
    with mu(-alpha) = -mu(alpha), m^2 / 2 functions (m even)."""

    kind = "tensor"

    def __init__(self, b: GPBasis1D, odd: bool = False):
        self.b, self.odd = b, odd
        lam = b.eigenvalues()
        j = b.j
        keep = ((j[:, None] + j[None, :]) % 2 == 1).ravel() if odd else np.ones(b.m * b.m, bool)
        self.keep = np.flatnonzero(keep)
        self.lam = (lam[:, None] + lam[None, :]).ravel()[self.keep]
        self.S = spectral_density(self.lam, b.s_f, b.lengthscale, 2)
        self.size = self.keep.size

    def features(self, alpha_f, alpha_r) -> np.ndarray:
        """(...,) slip angles -> (..., size)."""
        pf, pr = self.b.phi(alpha_f), self.b.phi(alpha_r)
        full = (pf[..., :, None] * pr[..., None, :]).reshape(pf.shape[:-1] + (self.b.m * self.b.m,))
        return full if not self.odd else full[..., self.keep]


class AxleBasis:
    """One 1-D basis per axle: mu_f depends on alpha_f alone, mu_r on alpha_r (m each;
    `odd`: only the odd functions, even j, m / 2 per axle)."""

    kind = "axle"

    def __init__(self, b: GPBasis1D, odd: bool = False):
        self.b, self.odd = b, odd
        self.keep = np.flatnonzero(b.j % 2 == 0) if odd else np.arange(b.m)
        self.lam = b.eigenvalues()[self.keep]
        self.S = b.spectral_density()[self.keep]
        self.size = self.keep.size

    def phi(self, x) -> np.ndarray:
        """The kept 1-D functions at x (...,) -> (..., size)."""
        return self.b.phi(x)[..., self.keep]

    def features(self, alpha_f, alpha_r) -> np.ndarray:
        """(...,) slip angles -> (..., 2, size): row 0 front, row 1 rear."""
        return np.stack([self.phi(alpha_f), self.phi(alpha_r)], axis=-2)


def make_basis(kind: str, b: GPBasis1D, odd: bool = False):
    if kind == "tensor":
        return TensorBasis(b, odd)
    if kind == "axle":
        if odd and b.m < 2:
            raise ConfigError(SOURCE, "basis_functions", "the odd per-axle basis needs m >= 2 (it keeps even j)")
        return AxleBasis(b, odd)
    raise ConfigError(SOURCE, "basis", f"expected tensor or axle, got {kind!r}")
