"""Compiled (numba, nopython, cached) kernels of the friction GP-SSM's per-particle work:
the reduced-rank basis (eq. (10b)), the MNIW predictive (eq. (31)-(32)), update
(eq. (27)/(28)) and forgetting (eq. (29)), for the exact statistics (`MNIW`) and the
rank-one ones (`MNIWRank1`).

The numpy classes in `tirefilter.stats.mniw` and `tirefilter.stats.gp` are the readable
reference; `NumbaMNIW` and `NumbaMNIWRank1` subclass them and replace only the hot methods
with one loop over the batch each, so the statistics keep their layout (`take`,
`posterior`, `function_moments`, sampling are inherited). The exact predictive factorises
Sigma + V by Cholesky (the reference uses LU): the two agree to rounding, tested to 1e-12
relative in tests/test_kernels.py.

Kernels are compiled on first use and cached beside this file (`cache=True`), so only the
first process on a machine pays the compilation.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tirefilter.stats.mniw import MNIW, MNIWRank1

_JIT = dict(cache=True, nogil=True, no_cfunc_wrapper=True)  # (no C callback is taken of a kernel)
# a helper only kernels call: no wrapper for Python calls (called from Python it crashes the
# interpreter instead of raising: tests/test_kernel_calls.py)
_JIT_IN = dict(_JIT, no_cpython_wrapper=True)
# Sigma + V up to this size is factorised by the loop below, larger by LAPACK's dpotrf
# (numba's np.linalg.cholesky): measured faster for the 50- and 100-function tensor bases
_LAPACK_FROM = 24


# ---- basis (eq. (10b)) ------------------------------------------------------------------
@njit(**_JIT)
def _phi1(x, L, m, out):
    """out[j - 1] = sin(pi j (x + L) / (2 L)) / sqrt(L), j = 1..m, by angle addition:
    sin((j + 1) a) = sin(j a) cos a + cos(j a) sin a, cos((j + 1) a) = cos(j a) cos a -
    sin(j a) sin a (one sin and one cos for all m; the rounding error grows about linearly
    in j, a few ulp at m = 20, where the three-term form sin((j + 1) a) = 2 cos a sin(j a) -
    sin((j - 1) a) loses up to j^2 ulp near a = 0 and pi)."""
    a = (math.pi / (2.0 * L)) * (x + L)
    r = 1.0 / math.sqrt(L)
    s1, c1 = math.sin(a), math.cos(a)
    s, c = s1, c1
    for j in range(m):
        out[j] = s * r
        s, c = s * c1 + c * s1, c * c1 - s * s1


@njit(**_JIT)
def tensor_features(af, ar, L, m, keep):
    """The paper's 2-D basis at (alpha_f, alpha_r) (N,) -> (N, len(keep)): entries
    j1 * m + j2 of phi_j1(alpha_f) phi_j2(alpha_r) (`TensorBasis.features`)."""
    n = af.shape[0]
    out = np.empty((n, keep.shape[0]))
    pf = np.empty(m)
    pr = np.empty(m)
    for i in range(n):
        _phi1(af[i], L, m, pf)
        _phi1(ar[i], L, m, pr)
        for k in range(keep.shape[0]):
            idx = keep[k]
            out[i, k] = pf[idx // m] * pr[idx % m]
    return out


@njit(**_JIT)
def axle_features(af, ar, L, m, keep):
    """The per-axle basis (N,) -> (N, 2, len(keep)) (`AxleBasis.features`)."""
    n = af.shape[0]
    out = np.empty((n, 2, keep.shape[0]))
    p = np.empty(m)
    for i in range(n):
        _phi1(af[i], L, m, p)
        for k in range(keep.shape[0]):
            out[i, 0, k] = p[keep[k]]
        _phi1(ar[i], L, m, p)
        for k in range(keep.shape[0]):
            out[i, 1, k] = p[keep[k]]
    return out


# ---- exact statistics ---------------------------------------------------------------------
@njit(**_JIT_IN)
def _cholesky(A, C):
    """Lower Cholesky factor of the symmetric positive definite A into C (row-wise dots)."""
    m = A.shape[0]
    for i in range(m):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= C[i, k] * C[j, k]
            if i == j:
                C[i, i] = math.sqrt(s) if s > 0.0 else math.nan
            else:
                C[i, j] = s / C[j, j]


@njit(**_JIT_IN)
def _chol_solve(C, B):
    """B <- A^-1 B for A = C C^T, B (m, r) overwritten."""
    m, r = B.shape
    for i in range(m):  # forward: C Y = B
        for k in range(i):
            c = C[i, k]
            for q in range(r):
                B[i, q] -= c * B[k, q]
        inv = 1.0 / C[i, i]
        for q in range(r):
            B[i, q] *= inv
    for i in range(m - 1, -1, -1):  # back: C^T X = Y
        for k in range(i + 1, m):
            c = C[k, i]
            for q in range(r):
                B[i, q] -= c * B[k, q]
        inv = 1.0 / C[i, i]
        for q in range(r):
            B[i, q] *= inv


@njit(**_JIT)
def exact_predictive(K, Psi, Phi, Lam0, nu, phi):
    """`MNIW.predictive` over a flat batch: K (B, m, m) = Sigma + V, Psi (B, d, m), Phi (B, d, d),
    nu (B,), phi (B, m) -> loc (B, d), scale (B, d, d), dof (B,).
    M = Psi K^-1 (28a), Lambda = Lambda_0 + Phi - M Psi^T (28e), c = 1 + phi^T K^-1 phi,
    St(M phi, c Lambda / (nu - d + 1), nu - d + 1) (eq. (31)-(32))."""
    nb, d, m = Psi.shape
    loc = np.empty((nb, d))
    scale = np.empty((nb, d, d))
    dof = np.empty(nb)
    C = np.empty((m, m))
    X = np.empty((m, d + 1))
    Lam = np.empty((d, d))
    for b in range(nb):
        if m >= _LAPACK_FROM:
            C = np.linalg.cholesky(K[b])
        else:
            _cholesky(K[b], C)
        for j in range(m):
            for i in range(d):
                X[j, i] = Psi[b, i, j]
            X[j, d] = phi[b, j]
        _chol_solve(C, X)
        for i in range(d):  # M = X[:, :d]^T; Lambda
            for k in range(d):
                s = 0.0
                for j in range(m):
                    s += X[j, i] * Psi[b, k, j]
                Lam[i, k] = Lam0[i, k] + Phi[b, i, k] - s
        c = 1.0
        for j in range(m):
            c += phi[b, j] * X[j, d]
        df = nu[b] - d + 1.0
        dof[b] = df
        f = c / df
        for i in range(d):
            s = 0.0
            for j in range(m):
                s += X[j, i] * phi[b, j]
            loc[b, i] = s
            for k in range(d):
                scale[b, i, k] = f * (0.5 * (Lam[i, k] + Lam[k, i]))
    return loc, scale, dof


@njit(**_JIT)
def exact_update(Phi, Psi, K, nu, zeta, phi):
    """In place, eq. (27a)-(27c), (28f): Phi += zeta zeta^T, Psi += zeta phi^T,
    K += phi phi^T, nu += 1."""
    nb, d, m = Psi.shape
    for b in range(nb):
        for i in range(d):
            z = zeta[b, i]
            for k in range(d):
                Phi[b, i, k] += z * zeta[b, k]
            for j in range(m):
                Psi[b, i, j] += z * phi[b, j]
        for i in range(m):
            p = phi[b, i]
            for j in range(m):
                K[b, i, j] += p * phi[b, j]
        nu[b] += 1.0


@njit(**_JIT)
def _factor(lam, nu_min, nu):
    f = lam
    if nu_min > 0.0:
        f = max(f, min(1.0, nu_min / nu))
    return f


@njit(**_JIT)
def exact_forget(Phi, Psi, K, nu, V, lam, nu_min):
    """In place, eq. (29): Phi, Psi, Sigma, nu times f = max(lambda, min(1, nu_min / nu));
    V is kept: K = Sigma + V -> f K + (1 - f) V."""
    nb, d, m = Psi.shape
    for b in range(nb):
        f = _factor(lam, nu_min, nu[b])
        for i in range(d):
            for k in range(d):
                Phi[b, i, k] = Phi[b, i, k] * f
            for j in range(m):
                Psi[b, i, j] = Psi[b, i, j] * f
        for i in range(m):
            for j in range(m):
                K[b, i, j] *= f
            K[b, i, i] += (1.0 - f) * V[i]
        nu[b] = nu[b] * f


# ---- rank-one statistics -----------------------------------------------------------------
@njit(**_JIT)
def rank1_predictive(M, P, Lam, nu, phi):
    """`MNIWRank1.predictive` over a flat batch: c = 1 + phi^T P phi, St(M phi, c Lambda /
    (nu - d + 1), nu - d + 1)."""
    nb, d, m = M.shape
    loc = np.empty((nb, d))
    scale = np.empty((nb, d, d))
    dof = np.empty(nb)
    for b in range(nb):
        c = 0.0
        for i in range(m):
            s = 0.0
            for j in range(m):
                s += P[b, i, j] * phi[b, j]
            c += phi[b, i] * s
        c = 1.0 + c
        df = nu[b] - d + 1.0
        dof[b] = df
        f = c / df
        for i in range(d):
            s = 0.0
            for j in range(m):
                s += M[b, i, j] * phi[b, j]
            loc[b, i] = s
            for k in range(d):
                scale[b, i, k] = f * Lam[b, i, k]
    return loc, scale, dof


@njit(**_JIT)
def rank1_update(M, P, Lam, nu, zeta, phi):
    """In place, recursive least squares: e = zeta - M phi, g = P phi, c = 1 + phi^T g;
    M += e g^T / c, P -= g g^T / c, Lambda += e e^T / c, nu += 1."""
    nb, d, m = M.shape
    g = np.empty(m)
    gs = np.empty(m)
    e = np.empty(d)
    for b in range(nb):
        _rank1_update1(M, P, Lam, nu, b, zeta[b], phi[b], g, gs, e)


@njit(inline="always", **_JIT)
def _rank1_update1(M, P, Lam, nu, b, zeta_b, phi_b, g, gs, e):
    """`rank1_update` of batch entry b with its target zeta_b (d,) and features phi_b (m,)
    (g, gs: (m,), e: (d,) scratch)."""
    d, m = M.shape[1], M.shape[2]
    c = 0.0
    for i in range(m):
        s = 0.0
        for j in range(m):
            s += P[b, i, j] * phi_b[j]
        g[i] = s
        c += phi_b[i] * s
    c = 1.0 + c
    ic = 1.0 / c
    for i in range(d):
        s = 0.0
        for j in range(m):
            s += M[b, i, j] * phi_b[j]
        e[i] = zeta_b[i] - s
    for j in range(m):
        gs[j] = g[j] * ic
    for i in range(d):
        for j in range(m):
            M[b, i, j] += e[i] * gs[j]
        for k in range(d):
            Lam[b, i, k] += e[i] * e[k] * ic
    for i in range(m):
        for j in range(m):
            P[b, i, j] -= g[i] * gs[j]
    nu[b] += 1.0


@njit(inline="always", **_JIT)
def _rank1_forget1(P, Lam, nu, b, lam, nu_min, bounded, trace0):
    """`rank1_forget` of batch entry b."""
    m = P.shape[1]
    d = Lam.shape[1]
    f = _factor(lam, nu_min, nu[b])
    fP = f
    if bounded:
        tr = 0.0
        for i in range(m):
            tr += P[b, i, i]
        fP = min(1.0, max(f, tr / trace0))
    s = 1.0 / fP
    for i in range(m):
        for j in range(m):
            P[b, i, j] *= s
    for i in range(d):
        for k in range(d):
            Lam[b, i, k] = Lam[b, i, k] * f
    nu[b] = nu[b] * f


@njit(**_JIT)
def rank1_forget(P, Lam, nu, lam, nu_min, bounded, trace0):
    """In place: P / f_P, Lambda f, nu f with f = max(lambda, min(1, nu_min / nu)) and, bounded,
    f_P = min(1, max(f, trace(P) / trace0)) (`MNIWRank1.forget`)."""
    for b in range(P.shape[0]):
        _rank1_forget1(P, Lam, nu, b, lam, nu_min, bounded, trace0)


# ---- the statistics classes ----------------------------------------------------------------
def _flat(a, tail: int):
    """A C-contiguous, writable view (or copy) of `a` with the batch axes merged: (B,) + last `tail`
    axes. Writable: numba compiles a read-only array (`np.broadcast_to` of an array of the batch's
    shape is one) as another type, so each kernel would have a second signature to compile."""
    a = np.ascontiguousarray(a)
    if not a.flags.writeable:
        a = a.copy()
    return a.reshape((-1,) + a.shape[a.ndim - tail:])


class _Contiguous:
    """What both compiled statistics share: their arrays (`ARRAYS` and nu) C-contiguous
    float64, as the kernels take them, from construction, from a numpy reference and after
    `take`."""

    ARRAYS: tuple[str, ...] = ()

    @classmethod
    def from_reference(cls, ref):
        new = cls.__new__(cls)
        new.__dict__.update(ref.__dict__)
        new._own()
        return new

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._own()

    def _own(self):
        for name in self.ARRAYS:
            setattr(self, name, np.ascontiguousarray(getattr(self, name), float))
        self.nu = np.ascontiguousarray(np.asarray(self.nu, float))

    def take(self, idx):
        return type(self).from_reference(super().take(idx))


class NumbaMNIW(_Contiguous, MNIW):
    """`MNIW` with the predictive, update and forgetting compiled (same layout, same answers)."""

    ARRAYS = ("Phi", "Psi", "K")

    def predictive(self, phi, return_M: bool = False):
        if return_M or np.ndim(self.nu) == 0:
            return super().predictive(phi, return_M)
        batch, d, m = self.nu.shape, self.d, self.K.shape[-1]
        phi = np.broadcast_to(phi, batch + (m,))
        loc, scale, dof = exact_predictive(_flat(self.K, 2), _flat(self.Psi, 2), _flat(self.Phi, 2),
                                           self.Lam0, _flat(self.nu, 0), _flat(phi, 1))
        return loc.reshape(batch + (d,)), scale.reshape(batch + (d, d)), dof.reshape(batch)

    def update(self, zeta, phi, mask=None) -> None:
        if mask is not None or np.ndim(self.nu) == 0:
            return super().update(zeta, phi, mask)
        batch = self.nu.shape
        exact_update(self.Phi.reshape((-1,) + self.Phi.shape[-2:]), self.Psi.reshape((-1,) + self.Psi.shape[-2:]),
                     self.K.reshape((-1,) + self.K.shape[-2:]), self.nu.reshape(-1),
                     _flat(np.broadcast_to(zeta, batch + (self.d,)), 1),
                     _flat(np.broadcast_to(phi, batch + (self.K.shape[-1],)), 1))

    def forget(self, lam: float, mask=None, nu_min: float = 0.0) -> None:
        if mask is not None or np.ndim(self.nu) == 0:
            return super().forget(lam, mask, nu_min)
        exact_forget(self.Phi.reshape((-1,) + self.Phi.shape[-2:]), self.Psi.reshape((-1,) + self.Psi.shape[-2:]),
                     self.K.reshape((-1,) + self.K.shape[-2:]), self.nu.reshape(-1), self.V, float(lam),
                     float(nu_min))


class NumbaMNIWRank1(_Contiguous, MNIWRank1):
    """`MNIWRank1` with the predictive, update and forgetting compiled."""

    ARRAYS = ("M", "P", "Lam")

    def predictive(self, phi, return_M: bool = False):
        if return_M or np.ndim(self.nu) == 0:
            return super().predictive(phi, return_M)
        batch, d, m = self.nu.shape, self.d, self.P.shape[-1]
        phi = np.broadcast_to(phi, batch + (m,))
        loc, scale, dof = rank1_predictive(_flat(self.M, 2), _flat(self.P, 2), _flat(self.Lam, 2),
                                           _flat(self.nu, 0), _flat(phi, 1))
        return loc.reshape(batch + (d,)), scale.reshape(batch + (d, d)), dof.reshape(batch)

    def update(self, zeta, phi, mask=None) -> None:
        if mask is not None or np.ndim(self.nu) == 0:
            return super().update(zeta, phi, mask)
        batch = self.nu.shape
        rank1_update(self.M.reshape((-1,) + self.M.shape[-2:]), self.P.reshape((-1,) + self.P.shape[-2:]),
                     self.Lam.reshape((-1,) + self.Lam.shape[-2:]), self.nu.reshape(-1),
                     _flat(np.broadcast_to(zeta, batch + (self.d,)), 1),
                     _flat(np.broadcast_to(phi, batch + (self.P.shape[-1],)), 1))

    def forget(self, lam: float, mask=None, nu_min: float = 0.0) -> None:
        if mask is not None or np.ndim(self.nu) == 0:
            return super().forget(lam, mask, nu_min)
        rank1_forget(self.P.reshape((-1,) + self.P.shape[-2:]), self.Lam.reshape((-1,) + self.Lam.shape[-2:]),
                     self.nu.reshape(-1), float(lam), float(nu_min), bool(self.bounded), self.trace0)


def basis_features(basis, alpha_f, alpha_r) -> np.ndarray:
    """`basis.features(alpha_f, alpha_r)` compiled, for (N,) slip angles."""
    af = np.ascontiguousarray(alpha_f, float)
    ar = np.ascontiguousarray(alpha_r, float)
    keep = np.ascontiguousarray(basis.keep, np.int64)
    fn = tensor_features if basis.kind == "tensor" else axle_features
    return fn(af, ar, float(basis.b.L), int(basis.b.m), keep)
