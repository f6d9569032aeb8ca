"""Matrix-normal-inverse-Wishart (MNIW) statistics with exponential forgetting, the
learning part of the friction paper, eq. (24)-(29), (31)-(32); batch-first.

Model (14): zeta = A phi + w, w ~ N(0, Q), A (d, m), phi (m,). Prior (24):
A | Q ~ MN(0, Q, V^-1) (row covariance Q, column covariance V^-1 = diag(S(lambda_j))),
Q ~ iW(nu_0, Lambda_0). The paper writes the column *precision* V, so the posterior
column covariance is Sigma* = (Sigma + V)^-1 (eq. (25b), (32)).

Statistics per batch element (particle, or particle x axle): Phi (..., d, d),
Psi (..., d, m), Sigma (..., m, m), nu (...). Update (27)/(28), with the (28c) typo fixed
(Phi += zeta zeta^T, as (27a)); forgetting (29): Phi, Psi, Sigma, nu times lambda;
posterior M = Psi (Sigma + V)^-1, Lambda = Lambda_0 + Phi - M Psi^T.

Predictive of zeta = A phi + w integrating both A and Q (eq. (31); docs/derivations.md, "Predictive of the next state"):
A phi + w | Q ~ N(M phi, c Q), c = 1 + phi^T Sigma* phi, and with Q ~ iW(nu, Lambda) the
marginal is the multivariate t St(M phi, c Lambda / (nu - d + 1), nu - d + 1).

`MNIWRank1` is the faster variant: it keeps M, P = (Sigma + V)^-1 and Lambda and applies
the forgetting to the prior too (V and Lambda_0 are scaled by lambda with the data), which
makes each update a rank-one (recursive least-squares) step, O(m^2) instead of O(m^3).
With lambda = 1 both are the same posterior. Forgetting the prior lets P grow as
lambda^-k in directions that get no data (RLS wind-up; with the tensor basis most of the
(alpha_f, alpha_r) plane is never visited and P overflows within a run at lambda = 0.99),
so by default the forgetting factor applied to P is raised to keep trace(P) at most the
prior's trace(diag S) (bounded-trace forgetting; Lambda and nu are forgotten with lambda;
`bounded=False`: plain RLS).
"""

from __future__ import annotations

import numpy as np


def _outer(a, b):
    return a[..., :, None] * b[..., None, :]


def _mask(mask, new, old, extra):
    return new if mask is None else np.where(mask.reshape(mask.shape + (1,) * extra), new, old)


def _take(a, idx, nu):
    """a[idx] along the batch's first axis; an unbatched statistic (nu 0-d) is repeated."""
    return (np.asarray(a)[None] if np.ndim(nu) == 0 else a)[idx]


def sample_inverse_wishart(nu, Lam, rng: np.random.Generator) -> np.ndarray:
    """Q ~ iW(nu, Lam) (mean Lam / (nu - d - 1)), batch-first: nu (...), Lam (..., d, d).

    Bartlett: W = C T T^T C^T ~ Wishart(nu, Lam^-1) with C C^T = Lam^-1, T lower
    triangular, T_ii = sqrt(chi2(nu - i)), T_ij ~ N(0, 1) below; Q = W^-1."""
    Lam = np.asarray(Lam, float)
    d = Lam.shape[-1]
    nu = np.broadcast_to(np.asarray(nu, float), Lam.shape[:-2])
    T = np.zeros(Lam.shape)
    for i in range(d):
        T[..., i, i] = np.sqrt(rng.chisquare(nu - i))
        if i:
            T[..., i, :i] = rng.standard_normal(Lam.shape[:-2] + (i,))
    C = np.linalg.cholesky(np.linalg.inv(Lam))
    CT = C @ T
    W = CT @ np.swapaxes(CT, -1, -2)
    Q = np.linalg.inv(W)
    return 0.5 * (Q + np.swapaxes(Q, -1, -2))


class _Common:
    """What both variants share once M, Lambda and the way to apply Sigma* are known."""

    V: np.ndarray  # (m,) prior precision of the columns, 1 / S(lambda_j)
    Lam0: np.ndarray  # (d, d)
    nu: np.ndarray  # (...)

    @property
    def d(self) -> int:
        return self.Lam0.shape[-1]

    def predictive(self, phi, return_M: bool = False):
        """St of zeta = A phi + w at features phi (..., m): (loc (..., d), scale (..., d, d),
        dof (...)), eq. (31)-(32) with A and Q integrated out; with `return_M` also the
        posterior mean M (..., d, m) it was computed from."""
        M, Lam, Sphi = self._solve(phi)
        c = 1.0 + np.einsum("...j,...j->...", phi, Sphi)
        dof = self.nu - self.d + 1.0
        out = (np.einsum("...ij,...j->...i", M, phi), (c / dof)[..., None, None] * Lam, dof)
        return out + (M,) if return_M else out

    def function_moments(self, phi):
        """Posterior mean and covariance of the function value A phi (no w), per batch
        element: phi (..., G, m) -> mean (..., G, d), cov (..., G, d, d) =
        E[Q] phi^T Sigma* phi with E[Q] = Lambda / (nu - d - 1)."""
        M, Lam = self.posterior()
        Sphi = self._apply_sigma_star(np.swapaxes(phi, -1, -2))  # (..., m, G)
        c = np.einsum("...gj,...jg->...g", phi, Sphi)
        EQ = Lam / (self.nu - self.d - 1.0)[..., None, None]
        return np.einsum("...ij,...gj->...gi", M, phi), c[..., :, None, None] * EQ[..., None, :, :]

    def sample_AQ(self, rng: np.random.Generator):
        """(A, Q) from the posterior: Q ~ iW(nu, Lambda), A | Q ~ MN(M, Q, Sigma*)."""
        M, Lam = self.posterior()
        Q = sample_inverse_wishart(self.nu, Lam, rng)
        Z = rng.standard_normal(M.shape)  # (..., d, m)
        ZS = self._sigma_star_half(Z)  # rows with covariance Sigma*
        return M + np.linalg.cholesky(Q) @ ZS, Q

    def sample_predictive(self, phi, rng: np.random.Generator):
        """zeta = A phi + w by sampling A, Q and w (the long way, for checking `predictive`)."""
        A, Q = self.sample_AQ(rng)
        w = np.einsum("...ij,...j->...i", np.linalg.cholesky(Q), rng.standard_normal(Q.shape[:-1]))
        return np.einsum("...ij,...j->...i", A, phi) + w


class MNIW(_Common):
    """The reference: the paper's statistics (27)-(29), posterior by a factorisation of
    Sigma + V whenever it is needed."""

    def __init__(self, batch: tuple[int, ...], d: int, S, Lam0, nu0: float):
        S = np.asarray(S, float)
        m = S.shape[-1]
        self.V = 1.0 / S
        self.Lam0 = np.asarray(Lam0, float).reshape(d, d)
        self.Phi = np.zeros(batch + (d, d))
        self.Psi = np.zeros(batch + (d, m))
        self.K = np.broadcast_to(np.diag(self.V), batch + (m, m)).copy()  # Sigma + V, kept as such
        self.nu = np.full(batch, float(nu0))

    @property
    def Sigma(self) -> np.ndarray:
        """Sigma of eq. (26c)/(27c) (the statistic is kept as Sigma + V)."""
        return self.K - np.diag(self.V)

    def take(self, idx) -> "MNIW":
        """The statistics of batch elements `idx` along the first axis (resampling)."""
        new = MNIW.__new__(MNIW)
        new.V, new.Lam0 = self.V, self.Lam0
        new.Phi, new.Psi, new.K, new.nu = (_take(a, idx, self.nu) for a in (self.Phi, self.Psi, self.K, self.nu))
        return new

    def update(self, zeta, phi, mask=None) -> None:
        """One observation zeta (..., d) at features phi (..., m), eq. (27a)-(27c) / (28b)-(28d),
        (28f). Where `mask` (...) is False the statistics stay."""
        if mask is None:
            self.Phi += _outer(zeta, zeta)  # (27a); (28c) misprints alpha^T for zeta^T
            self.Psi += _outer(zeta, phi)  # (27b)
            self.K += _outer(phi, phi)  # (27c)
            self.nu = self.nu + 1.0  # (28f)
            return
        self.Phi = _mask(mask, self.Phi + _outer(zeta, zeta), self.Phi, 2)
        self.Psi = _mask(mask, self.Psi + _outer(zeta, phi), self.Psi, 2)
        self.K = _mask(mask, self.K + _outer(phi, phi), self.K, 2)
        self.nu = _mask(mask, self.nu + 1.0, self.nu, 0)

    def forget(self, lam: float, mask=None, nu_min: float = 0.0) -> None:
        """Time update (29a)-(29d): Phi, Psi, Sigma, nu times lambda (only where `mask`);
        V is not forgotten: Sigma + V -> lambda (Sigma + V) + (1 - lambda) V.
        With nu_min the factor is max(lambda, nu_min / nu): a statistic never drops below
        the prior's degrees of freedom (as `NiW.forget`)."""
        f = np.full(np.shape(self.nu), float(lam))
        if nu_min > 0:
            f = np.maximum(f, np.minimum(1.0, nu_min / self.nu))
        if mask is not None:
            f = np.where(mask, f, 1.0)
        self.Phi = self.Phi * f[..., None, None]
        self.Psi = self.Psi * f[..., None, None]
        self.K *= f[..., None, None]
        diag = np.einsum("...ii->...i", self.K)  # a writable view of the diagonals
        diag += (1.0 - f)[..., None] * self.V
        self.nu = self.nu * f

    def _K(self):
        return self.K

    def posterior(self):
        """M = Psi (Sigma + V)^-1 (28a), Lambda = Lambda_0 + Phi - M Psi^T (28e)."""
        MT = np.linalg.solve(self._K(), np.swapaxes(self.Psi, -1, -2))
        M = np.swapaxes(MT, -1, -2)
        Lam = self.Lam0 + self.Phi - M @ np.swapaxes(self.Psi, -1, -2)
        return M, 0.5 * (Lam + np.swapaxes(Lam, -1, -2))

    def _solve(self, phi):
        d = self.d
        rhs = np.concatenate([np.swapaxes(self.Psi, -1, -2), phi[..., :, None]], axis=-1)  # (..., m, d + 1)
        X = np.linalg.solve(self._K(), rhs)
        M = np.swapaxes(X[..., :d], -1, -2)
        Lam = self.Lam0 + self.Phi - M @ np.swapaxes(self.Psi, -1, -2)
        return M, 0.5 * (Lam + np.swapaxes(Lam, -1, -2)), X[..., d]

    def _apply_sigma_star(self, B):
        return np.linalg.solve(self._K(), B)

    def _sigma_star_half(self, Z):
        C = np.linalg.cholesky(self._K())  # Sigma* = C^-T C^-1: rows Z C^-1 have covariance Sigma*
        return np.swapaxes(np.linalg.solve(np.swapaxes(C, -1, -2), np.swapaxes(Z, -1, -2)), -1, -2)


class MNIWRank1(_Common):
    """The faster variant: M, P = (Sigma + V)^-1, Lambda kept directly, forgetting applied
    to V and Lambda_0 as well, so (P, M, Lambda) follow recursive least squares:
    forget: P / lambda, Lambda lambda, nu lambda; update with e = zeta - M phi,
    g = P phi, c = 1 + phi^T g: M += e g^T / c, P -= g g^T / c, Lambda += e e^T / c."""

    def __init__(self, batch: tuple[int, ...], d: int, S, Lam0, nu0: float, bounded: bool = True):
        S = np.asarray(S, float)
        m = S.shape[-1]
        self.V = 1.0 / S
        self.bounded = bounded
        self.trace0 = float(S.sum())
        self.Lam0 = np.asarray(Lam0, float).reshape(d, d)
        self.M = np.zeros(batch + (d, m))
        self.P = np.broadcast_to(np.diag(S), batch + (m, m)).copy()
        self.Lam = np.broadcast_to(self.Lam0, batch + (d, d)).copy()
        self.nu = np.full(batch, float(nu0))

    def take(self, idx) -> "MNIWRank1":
        new = MNIWRank1.__new__(MNIWRank1)
        new.V, new.Lam0, new.bounded, new.trace0 = self.V, self.Lam0, self.bounded, self.trace0
        new.M, new.P, new.Lam, new.nu = (_take(a, idx, self.nu) for a in (self.M, self.P, self.Lam, self.nu))
        return new

    def update(self, zeta, phi, mask=None) -> None:
        g = np.einsum("...ij,...j->...i", self.P, phi)
        c = 1.0 + np.einsum("...j,...j->...", phi, g)
        e = zeta - np.einsum("...ij,...j->...i", self.M, phi)
        ic = (1.0 / c)[..., None, None]
        if mask is None:
            gs = g * (1.0 / c)[..., None]
            self.M += _outer(e, gs)
            self.P -= _outer(g, gs)
            self.Lam += _outer(e, e) * ic
            self.nu = self.nu + 1.0
            return
        self.M = _mask(mask, self.M + _outer(e, g) * ic, self.M, 2)
        self.P = _mask(mask, self.P - _outer(g, g) * ic, self.P, 2)
        self.Lam = _mask(mask, self.Lam + _outer(e, e) * ic, self.Lam, 2)
        self.nu = _mask(mask, self.nu + 1.0, self.nu, 0)

    def forget(self, lam: float, mask=None, nu_min: float = 0.0) -> None:
        f = np.full(np.shape(self.nu), float(lam))
        if nu_min > 0:
            f = np.maximum(f, np.minimum(1.0, nu_min / self.nu))
        if mask is not None:
            f = np.where(mask, f, 1.0)
        fP = f
        if self.bounded:  # bounded trace: P / lambda never beyond the prior's total variance
            tr = np.einsum("...ii->...", self.P)
            fP = np.minimum(1.0, np.maximum(f, tr / self.trace0))
        self.P *= (1.0 / fP)[..., None, None]
        self.Lam = self.Lam * f[..., None, None]
        self.nu = self.nu * f

    def posterior(self):
        return self.M, self.Lam

    def _solve(self, phi):
        return self.M, self.Lam, np.einsum("...ij,...j->...i", self.P, phi)

    def _apply_sigma_star(self, B):
        return self.P @ B

    def _sigma_star_half(self, Z):
        C = np.linalg.cholesky(self.P)  # rows Z C^T have covariance P
        return Z @ np.swapaxes(C, -1, -2)


def make_mniw(kind: str, batch, d: int, S, Lam0, nu0: float, backend: str = "numpy"):
    """The statistics `kind` ("exact" | "rank1"); backend "numba": the compiled kernels of
    `tirefilter.stats.mniw_numba` (same layout and answers), "numpy": these classes."""
    if backend == "numba":
        from tirefilter.stats.mniw_numba import NumbaMNIW, NumbaMNIWRank1

        cls = NumbaMNIWRank1 if kind == "rank1" else NumbaMNIW
    else:
        cls = MNIWRank1 if kind == "rank1" else MNIW
    return cls(tuple(batch), d, S, Lam0, nu0)
