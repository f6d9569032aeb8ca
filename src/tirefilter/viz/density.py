"""Posterior densities of the stiffness parameters for the recordings, on a fixed grid.

The stiffness MPF's parameter posterior is eq. (26) of the stiffness paper,

    p(theta_k | y_0:k) ~= sum_i q_k^i p(theta_k | x^i_0:k, y_0:k),

a weighted mixture over particles of the NiW posterior (25) of each particle. Its marginal
for the mean of parameter j is a mixture of univariate Student-t densities, one per
particle (docs/derivations.md, "Posterior density"): under mu | Sigma ~ N(mu_hat, gamma Sigma),
Sigma ~ iW(nu, Lambda) of dimension n,

    mu ~ St(mu_hat, gamma Lambda / (nu - n + 1), nu - n + 1)       (scale matrix, dof)
    mu_j ~ t_{nu - n + 1}(loc = C_nom,j + mu_hat_j, scale^2 = gamma Lambda_jj / (nu - n + 1)),

with variance gamma Lambda_jj / (nu - n - 1) = gamma E[Sigma]_jj, the per-particle term of
the Result CSV's `*_std`. This is not a histogram or a kernel smoother of particle points;
as the paper's Fig. 10 shows it is often far from Gaussian.

Estimators without NiW statistics get what their posterior supports (`stiffness_mixture`):
a Gaussian posterior (EKF, RLS) its Gaussian, particles that carry the stiffness as a state
(AUGPF) a weighted Gaussian kernel density estimate, labelled as such (not eq. (26)).

Evaluation is restricted to the grid points where some component exceeds `EPS` times its
own peak; elsewhere every component is below that, so the density is set to 0 there (an
error below EPS times the largest component peak, and a neglected mass below the
Student-t tail beyond that point, < 1e-10 for the settings here).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import gammaln, ndtr, ndtri, stdtr

EPS = 1e-12  # relative component density below which a grid point is skipped
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


@dataclass(frozen=True)
class Mixture:
    """Per-parameter marginals of a stiffness posterior as a weighted mixture of
    location-scale densities: Student-t (df finite) or Gaussian (df = inf).

    `weights` (M,) sum to 1; `loc`, `scale` (M, n) in N/rad (absolute stiffness); `df` (M,).
    `kind` names what the mixture is, for the recording's description.
    """

    params: tuple[str, ...]
    weights: np.ndarray  # (M,)
    loc: np.ndarray  # (M, n)
    scale: np.ndarray  # (M, n)
    df: np.ndarray  # (M,), inf for Gaussian components
    kind: str  # "eq26-student-t" | "gaussian" | "kde"

    def index(self, param: str) -> int:
        return self.params.index(param)

    def pdf(self, param: str, grid: np.ndarray, cache: "ComponentCache | None" = None) -> np.ndarray:
        """The marginal density of `param` on `grid` (G,), per unit of the parameter."""
        return mixture_pdf(grid, self.weights, self.loc[:, self.index(param)], self.scale[:, self.index(param)],
                           self.df, cache)

    def mass(self, param: str, lo: float, hi: float) -> float:
        """The exact probability of lo <= param <= hi (the share of the density a grid
        over [lo, hi] can show), from the components' CDFs."""
        j = self.index(param)
        z = (np.array([[lo], [hi]]) - self.loc[:, j]) / self.scale[:, j]  # (2, M)
        t = np.isfinite(self.df)
        cdf = np.where(t, stdtr(np.where(t, self.df, 1.0), z), ndtr(z))
        ok = (self.scale[:, j] > 0) & np.isfinite(self.loc[:, j])
        return float(self.weights[ok] @ (cdf[1] - cdf[0])[ok])

    def mean(self, param: str) -> float:
        return float(self.weights @ self.loc[:, self.index(param)])

    def std(self, param: str) -> float:
        """The std of the mixture: per component scale^2 df / (df - 2) (scale^2 for a
        Gaussian), plus the spread of the locations. A component with df <= 2 (no finite
        variance) counts as df = 3, so that the value stays a usable width for the
        recording's plots."""
        j = self.index(param)
        df = self.df
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(np.isinf(df), 1.0, np.where(df > 2, df / (df - 2.0), 3.0))
        loc, scale = self.loc[:, j], self.scale[:, j]
        m = self.weights @ loc
        return float(math.sqrt(max(self.weights @ (scale ** 2 * f + (loc - m) ** 2), 0.0)))

    def cdf(self, param: str, x) -> np.ndarray:
        """P(param <= x) for each x (K,), from the components' CDFs."""
        j = self.index(param)
        return _mixture_cdf(np.asarray(x, float), *_unique(self.weights, self.loc[:, j], self.scale[:, j], self.df))

    def quantiles(self, param: str, q, start=None, rtol: float = 1e-9) -> np.ndarray:
        """The q-quantiles (K,) of `param`: the CDF inverted by Newton's method on the
        mixture's density, safeguarded by a bracket that each step narrows (a step that leaves
        it bisects instead), to `rtol` of the std (or the floats' resolution at the mean, for a
        posterior narrower than that). Newton starts from `start` (K,) where given (a guess,
        e.g. from the density on a grid: `grid_quantiles`), else from the normal approximation."""
        j = self.index(param)
        w, loc, scale, df = _unique(self.weights, self.loc[:, j], self.scale[:, j], self.df)
        comps = np.column_stack([loc, scale, df])
        q = np.asarray(q, float)
        m, s = self.mean(param), max(self.std(param), 1e-12 * max(abs(self.mean(param)), 1.0))
        lo, hi = np.full(q.shape, m - 8 * s), np.full(q.shape, m + 8 * s)
        for _ in range(60):  # widen the bracket where a heavy tail holds more than 8 std
            below, above = _mixture_cdf(lo, w, loc, scale, df) > q, _mixture_cdf(hi, w, loc, scale, df) < q
            if not (below.any() or above.any()):
                break
            lo, hi = np.where(below, lo - 8 * s, lo), np.where(above, hi + 8 * s, hi)
        tol = max(rtol * s, 8 * np.spacing(abs(m) + 8 * s))  # not below the floats' resolution at m
        x = m + s * ndtri(np.clip(q, 1e-12, 1 - 1e-12)) if start is None else np.asarray(start, float)
        x = np.clip(np.where(np.isfinite(x), x, m), lo, hi)
        for _ in range(200):
            F = _mixture_cdf(x, w, loc, scale, df) - q
            lo, hi = np.where(F < 0, x, lo), np.where(F < 0, hi, x)
            f = w @ _component_rows(x, comps)
            with np.errstate(divide="ignore", invalid="ignore"):
                newton = x - F / f
            inside = np.isfinite(newton) & (newton > lo) & (newton < hi)
            step = np.where(inside, newton, 0.5 * (lo + hi))  # a step out of the bracket bisects
            done = (np.abs(step - x) <= tol) | (hi - lo <= tol)
            x = step
            if done.all():
                break
        return x


def grid_quantiles(mixture: Mixture, param: str, grid: np.ndarray, pdf: np.ndarray, q) -> np.ndarray:
    """Approximate q-quantiles of `param` from its density `pdf` on `grid` (the mass below the
    grid's first point exact, the trapezoid rule across the grid): the start that
    `Mixture.quantiles` polishes, a few Newton steps where the posterior is a lumpy mixture of
    narrow particles (from the normal approximation, tens of steps)."""
    cum = mixture.cdf(param, grid[:1])[0] + np.concatenate([[0.0], np.cumsum(0.5 * (pdf[1:] + pdf[:-1])
                                                                              * np.diff(grid))])
    return np.interp(q, np.maximum.accumulate(cum), grid)


def niw_mean_marginals(log_weights, gamma, mu, Lam, nu, C_nominal, params) -> Mixture:
    """Eq. (26) for the mean: per particle i and parameter j the Student-t marginal of the
    mean, t_{nu_i - n + 1}(C_nom,j + mu_ij, gamma_i Lam_ijj / (nu_i - n + 1)), weighted by q_i.

    log_weights (N,) (normalised or not), gamma (N,), mu (N, n), Lam (N, n, n), nu (N,),
    C_nominal (n,)."""
    mu = np.asarray(mu, float)
    n = mu.shape[-1]
    df = np.asarray(nu, float) - n + 1.0
    if np.any(df <= 0):
        raise ValueError(f"NiW degrees of freedom nu must exceed n - 1 = {n - 1} for a Student-t marginal")
    var = np.asarray(gamma, float)[:, None] * np.diagonal(np.asarray(Lam, float), axis1=1, axis2=2) / df[:, None]
    return Mixture(tuple(params), _weights(log_weights), np.asarray(C_nominal, float) + mu, np.sqrt(var), df,
                   "eq26-student-t")


def widened(mix: Mixture, factor) -> Mixture:
    """The mixture stretched about its mean by `factor` (n,) per parameter: each component's
    location moved to m + f (loc - m) and its scale times f, so that the mean stays and the
    std of the whole mixture is f times its own, exactly (the MPF's calibrated `*_std`,
    derivations, "Batch-means sandwich", is the std of eq. (26) times the sandwich factor)."""
    f = np.asarray(factor, float)
    if f.shape != (len(mix.params),) or not np.all(f >= 1.0):
        raise ValueError(f"std_factor must be {len(mix.params)} values >= 1, got {factor!r}")
    m = mix.weights @ mix.loc
    return replace(mix, loc=m + f * (mix.loc - m), scale=mix.scale * f)


def gaussian_marginals(log_weights, mean, std, params) -> Mixture:
    """A Gaussian (mixture) posterior: mean, std (M, n) absolute stiffness."""
    mean = np.atleast_2d(np.asarray(mean, float))
    return Mixture(tuple(params), _weights(log_weights), mean, np.atleast_2d(np.asarray(std, float)),
                   np.full(len(mean), np.inf), "gaussian")


def weighted_kde(log_weights, samples, params) -> Mixture:
    """Weighted Gaussian kernel density estimate of particle samples (N, n): Silverman's
    bandwidth 1.06 s n_eff^(-1/5) per parameter, s the weighted std and n_eff the
    effective sample size. For particles that carry the stiffness themselves (AUGPF);
    NOT eq. (26), which needs per-particle posteriors."""
    w = _weights(log_weights)
    samples = np.asarray(samples, float)
    m = w @ samples
    s = np.sqrt(np.maximum(w @ (samples - m) ** 2, 0.0))
    n_eff = 1.0 / float(np.sum(w * w))
    h = 1.06 * s * n_eff ** -0.2
    h = np.where(h > 0, h, np.maximum(1e-6 * np.abs(m), 1e-12))  # one distinct sample: a narrow bump
    return Mixture(tuple(params), w, samples, np.broadcast_to(h, samples.shape).copy(), np.full(len(w), np.inf), "kde")


def _weights(log_weights) -> np.ndarray:
    lw = np.asarray(log_weights, float).ravel()
    lw = np.where(np.isnan(lw), -np.inf, lw)
    m = np.max(lw)
    if not np.isfinite(m):
        return np.full(lw.shape, 1.0 / lw.size)
    w = np.exp(lw - m)
    return w / w.sum()


def _unique(weights, loc, scale, df):
    """Distinct usable components (resampled copies merged, their weights summed):
    (weights, loc, scale, df), each (M',)."""
    w, loc, scale, df = (np.asarray(a, float).ravel() for a in (weights, loc, scale, df))
    keep = (w > 0) & (scale > 0) & np.isfinite(loc)
    comps, inverse = np.unique(np.column_stack([loc[keep], scale[keep], df[keep]]), axis=0, return_inverse=True)
    wu = np.bincount(inverse.ravel(), weights=w[keep], minlength=len(comps))
    return wu / wu.sum() if wu.sum() > 0 else wu, comps[:, 0], comps[:, 1], comps[:, 2]


def _mixture_cdf(x, w, loc, scale, df) -> np.ndarray:
    """sum_i w_i F_i(x) for x (K,) over components (M,)."""
    z = (np.asarray(x, float)[:, None] - loc[None, :]) / scale[None, :]  # (K, M)
    t = np.isfinite(df)
    cdf = np.where(t[None, :], stdtr(np.where(t, df, 1.0)[None, :], z), ndtr(z))
    return cdf @ w


def window_grid(mean: float, std: float, k: float, points: int) -> np.ndarray:
    """`points` values over mean -+ k std: the recording's density snapshot shows the
    posterior there (a physical axis zoomed on it, not a fixed range of the run)."""
    if points < 2 or not (std > 0 and math.isfinite(std) and math.isfinite(mean)):
        raise ValueError(f"bad density window: {points} points over {mean} +- {k} x {std}")
    return np.linspace(mean - k * std, mean + k * std, int(points))


def _half_width(df: np.ndarray) -> np.ndarray:
    """z where a component's density falls to EPS times its peak: Student-t
    (1 + z^2/df)^(-(df+1)/2) = EPS, Gaussian exp(-z^2/2) = EPS."""
    gauss = math.sqrt(-2.0 * math.log(EPS))
    with np.errstate(over="ignore", invalid="ignore"):
        z = np.sqrt(df * np.expm1(-2.0 * math.log(EPS) / (df + 1.0)))
    return np.where(np.isfinite(df), z, gauss)


def mixture_pdf(grid, weights, loc, scale, df, cache: "ComponentCache | None" = None) -> np.ndarray:
    """sum_i w_i f_i(x) on `grid` (G,) for location-scale Student-t (df_i finite) or
    Gaussian (df_i = inf) components, vectorised over components; only the window of grid
    points inside some component's EPS-support is evaluated (module docstring).

    Identical components (resampled copies) are evaluated once, with their weights summed.
    With a `cache`, the rows of components seen at the previous call on the same grid are
    reused: while the stiffness MPF's gate is closed its statistics do not change, and a
    wide prior would otherwise cost a full-grid evaluation per snapshot."""
    grid = np.asarray(grid, float)
    w, loc, scale, df = (np.asarray(a, float).ravel() for a in (weights, loc, scale, df))
    out = np.zeros(grid.shape)
    keep = (w > 0) & (scale > 0) & np.isfinite(loc)
    if not keep.any():
        return out
    comps, inverse = np.unique(np.column_stack([loc[keep], scale[keep], df[keep]]), axis=0, return_inverse=True)
    wu = np.bincount(inverse.ravel(), weights=w[keep], minlength=len(comps))
    reach = _half_width(comps[:, 2]) * comps[:, 1]
    lo, hi = np.searchsorted(grid, [np.min(comps[:, 0] - reach), np.max(comps[:, 0] + reach)], side="left")
    hi = min(hi + 1, grid.size)
    if hi <= lo:
        return out
    if cache is None:
        out[lo:hi] = wu @ _component_rows(grid[lo:hi], comps)
        return out
    lo, hi, rows = cache.rows(grid, lo, hi, comps)
    out[lo:hi] = wu @ rows
    return out


def _component_rows(x: np.ndarray, comps: np.ndarray) -> np.ndarray:
    """(M, W) densities of the components (loc, scale, df) rows of `comps` at `x`."""
    loc, scale, df = comps[:, 0], comps[:, 1], comps[:, 2]
    z = (x[None, :] - loc[:, None]) / scale[:, None]
    t = np.isfinite(df)
    logf = np.empty_like(z)
    if t.any():
        d = df[t]
        const = gammaln(0.5 * (d + 1.0)) - gammaln(0.5 * d) - 0.5 * np.log(d * math.pi) - np.log(scale[t])
        logf[t] = const[:, None] - (0.5 * (d + 1.0))[:, None] * np.log1p(z[t] ** 2 / d[:, None])
    if (~t).any():
        logf[~t] = (-_LOG_SQRT_2PI - np.log(scale[~t]))[:, None] - 0.5 * z[~t] ** 2
    return np.exp(logf)


class ComponentCache:
    """The component rows of the last `mixture_pdf` call of one parameter: components
    are keyed by their exact (loc, scale, df); a row is reused when the new window lies
    inside the cached one and the cached one is at most about twice as wide; the cache holds
    only the last call's components."""

    def __init__(self):
        self.grid_id, self.lo, self.hi, self.keys = None, 0, 0, {}
        self.table = np.empty((0, 0))
        self.hits = self.misses = 0

    def rows(self, grid, lo, hi, comps):
        gid = (grid.size, float(grid[0]), float(grid[-1]))
        # the cached window is kept while it holds the new one and is not much wider (once the
        # posterior narrows, new components must not be evaluated over the prior's window)
        if gid != self.grid_id or lo < self.lo or hi > self.hi or (self.hi - self.lo) > 2 * (hi - lo) + 16:
            self.grid_id, self.lo, self.hi, self.keys, self.table = gid, lo, hi, {}, np.empty((0, hi - lo))
        keys = [c.tobytes() for c in comps]
        have = np.array([self.keys.get(k, -1) for k in keys], dtype=np.intp)
        rows = np.empty((len(comps), self.hi - self.lo))
        hit = have >= 0
        rows[hit] = self.table[have[hit]]
        if (~hit).any():
            rows[~hit] = _component_rows(grid[self.lo:self.hi], comps[~hit])
        self.hits += int(hit.sum())
        self.misses += int((~hit).sum())
        self.keys, self.table = {k: i for i, k in enumerate(keys)}, rows
        return self.lo, self.hi, rows


def stiffness_grid(reference, low: float = 0.0, high: float = 3.6, points: int = 1601) -> np.ndarray:
    """The fixed grid of one parameter for a whole run: `points` values from low to high
    times the reference stiffness."""
    if points < 2 or not 0 <= low < high or not reference > 0:
        raise ValueError(f"bad density grid: {points} points over [{low}, {high}] x {reference}")
    return np.linspace(low * reference, high * reference, int(points))


def stiffness_mixture(posterior, estimate=None, *, params=None, gaussian: bool = False) -> Mixture | None:
    """The stiffness posterior an estimator's snapshot supports, or None.

    - NiW statistics (`gamma, mu, Lam, nu` and `C_nominal` in `posterior.stats`): eq. (26).
    - `stiffness_mean`, `stiffness_std` (M, n) in the stats: a Gaussian mixture with the
      posterior's log-weights (M = 1: one Gaussian).
    - `stiffness` (N, n) in the stats (particles carrying the stiffness), or `mu` (N, n)
      deviations with `C_nominal` and no NiW statistics (AUGPF): weighted KDE.
    - `gaussian=True` (the estimator declares `posterior_family = "gaussian"`), or a
      posterior of one 'particle' (the Gaussian filters KF, RLS, EKF), and an Estimate
      with finite `<param>` and `<param>_std` > 0: that Gaussian per parameter.
    `params` names the columns where the stats do not (`stats["params"]`).
    """
    stats = getattr(posterior, "stats", None) or {}
    names = tuple(stats.get("params", params or ()))
    logw = getattr(posterior, "log_weights", None)
    if names and all(k in stats for k in ("gamma", "mu", "Lam", "nu", "C_nominal")):
        mix = niw_mean_marginals(logw, stats["gamma"], stats["mu"], stats["Lam"], stats["nu"], stats["C_nominal"],
                                 names)
        return mix if "std_factor" not in stats else widened(mix, stats["std_factor"])
    if names and "stiffness_mean" in stats and "stiffness_std" in stats:
        mean = np.atleast_2d(stats["stiffness_mean"])
        return gaussian_marginals(logw if logw is not None and len(logw) == len(mean) else np.zeros(len(mean)),
                                  mean, stats["stiffness_std"], names)
    if names and "stiffness" in stats and logw is not None:
        return weighted_kde(logw, stats["stiffness"], names)
    if (names and logw is not None and len(logw) > 1 and "mu" in stats and "C_nominal" in stats
            and np.shape(stats["mu"]) == (len(logw), len(names))):  # AUGPF: sampled means, no statistics
        return weighted_kde(logw, np.asarray(stats["C_nominal"], float) + np.asarray(stats["mu"], float), names)
    single = logw is not None and len(logw) == 1  # a Gaussian filter's posterior as one 'particle' (KF, RLS, EKF)
    if (gaussian or single) and estimate is not None:
        names = tuple(p for p in (params or ("Cx", "Cf_y", "Cr_y"))
                      if math.isfinite(getattr(estimate, p, math.nan)) and getattr(estimate, p + "_std", math.nan) > 0)
        if names:
            mean = [[getattr(estimate, p) for p in names]]
            std = [[getattr(estimate, p + "_std") for p in names]]
            return gaussian_marginals(np.zeros(1), mean, std, names)
    return None
