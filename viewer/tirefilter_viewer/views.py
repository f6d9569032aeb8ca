"""What the dashboard draws, as plain arrays: the uPlot charts (series, bands, data from
a History), the particle cloud of the stiffness posterior, the friction curves and their
truth. No viser here; `app` hands these arrays to the page.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tirefilter.estimators.base import FrictionCurve
from tirefilter_viewer.history import History

Z90 = 1.6448536269514722  # the 90% interval of a Gaussian: mean +- Z90 std (docs/usage.md, coverage)
STIFFNESS = ("Cf_y", "Cr_y", "Cx")
UNITS = {"Cf_y": "kN/rad", "Cr_y": "kN/rad", "Cx": "kN/unit slip"}
CLOUD_SCALE = 5.0  # scene units per 100% of the nominal stiffness
ESTIMATE_COLOR = "#1f77b4"  # the estimate line of every chart (the browser test looks for it)
TRUTH_COLOR = "#d62728"
BAND_FILL = "rgba(31, 119, 180, 0.2)"


@dataclass(frozen=True)
class Series:
    """One uPlot series: its legend label, colour and values at the rows `idx`."""

    label: str
    values: Callable[[History, np.ndarray], np.ndarray]
    stroke: str = ESTIMATE_COLOR
    width: float = 2.0
    dash: tuple[float, ...] | None = None
    scale: str = "y"

    def uplot(self) -> dict:
        s = {"label": self.label, "stroke": self.stroke, "width": self.width, "scale": self.scale,
             "points": {"show": False}, "spanGaps": False}
        if self.dash:
            s["dash"] = self.dash
        return s


@dataclass(frozen=True)
class Chart:
    """A uPlot chart over the sample time: `series` after the time axis, `bands` as pairs
    of indices into (time, *series), upper edge first, as uPlot takes them."""

    key: str
    title: str
    series: tuple[Series, ...]
    bands: tuple[tuple[int, int], ...] = ()
    scales: dict | None = None
    min_span: float = 1e-9  # the smallest y range shown (a flat series sits in its middle)
    tab: str = "stiffness"  # the tab of the charts panel it is on
    y_label: str = ""  # the y axis label (the x axis is the time, t [s])

    def data(self, history: History, idx: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        idx = history.decimation() if idx is None else idx
        t = history.column("t")
        return (np.asarray(t[idx], float),) + tuple(np.asarray(s.values(history, idx), float) for s in self.series)

    def y_series(self) -> tuple[int, ...]:
        """Indices into `data` of the series on the "y" scale (the range `app` sets)."""
        return tuple(j + 1 for j, s in enumerate(self.series) if s.scale == "y")

    def uplot_series(self) -> tuple[dict, ...]:
        return ({"label": "t [s]"},) + tuple(s.uplot() for s in self.series)

    def uplot_bands(self) -> tuple[dict, ...]:
        return tuple({"series": b, "fill": BAND_FILL} for b in self.bands)

    def uplot_scales(self) -> dict:
        scales = {"x": {"time": False}}
        scales.update(self.scales or {})
        return scales

    def uplot_axes(self) -> tuple[dict, ...]:
        return axes("t [s]", self.y_label)


AXIS_SIZE = 80  # px left of a chart for the y tick labels: room for a sign and 6 digits


def axes(x_label: str, y_label: str) -> tuple[dict, ...]:
    """uPlot axes: x below with its label, y on the left with its label and room enough
    for tick labels with a minus sign (the default 50 px clipped '-0.0012' to '0.0012')."""
    return ({"label": x_label, "size": 44, "labelSize": 18},
            {"label": y_label, "size": AXIS_SIZE, "labelSize": 18, "gap": 4})


def placeholder(n_series: int) -> tuple[np.ndarray, ...]:
    """Data of a chart before any sample: two points of x, NaN values (uPlot keeps a chart
    created from empty arrays blank even after data arrives)."""
    return (np.array([0.0, 1.0]),) + (np.full(2, math.nan),) * n_series


def y_range(series_data, current: tuple[float, float] | None, min_span: float = 1e-9) -> tuple[float, float]:
    """The y-axis range a chart shows: the current one while the data stays inside it and
    fills at least half of it, otherwise the data's range with 10% margins.

    uPlot loses a whole series' auto-range over a single NaN, so the dashboard sets the
    range itself; the hysteresis keeps the chart from being rebuilt at every update."""
    finite = [x[np.isfinite(x)] for x in series_data]
    finite = [x for x in finite if x.size]
    if not finite:
        return current or (0.0, 1.0)
    lo, hi = min(float(x.min()) for x in finite), max(float(x.max()) for x in finite)
    if current is not None:
        c_lo, c_hi = current
        if c_lo <= lo and hi <= c_hi and (hi - lo) >= 0.5 * (c_hi - c_lo):
            return current
    pad = 0.1 * (hi - lo)
    if hi - lo + 2 * pad < min_span:  # a flat series: at least min_span around it
        pad = (min_span - (hi - lo)) / 2
    return (lo - pad, hi + pad)


def col(name: str, factor: float = 1.0) -> Callable[[History, np.ndarray], np.ndarray]:
    """The values of column `name` (NaN when the rows lack it), times `factor`."""

    def values(h: History, idx: np.ndarray) -> np.ndarray:
        x = h.column(name)
        return np.full(len(idx), math.nan) if x is None else x[idx] * factor

    return values


def edge(name: str, sign: float, factor: float = 1.0) -> Callable[[History, np.ndarray], np.ndarray]:
    """An edge of the 90% interval of the posterior mean: `name` +- Z90 `name`_std."""

    def values(h: History, idx: np.ndarray) -> np.ndarray:
        x, s = h.column(name), h.column(name + "_std")
        if x is None or s is None:
            return np.full(len(idx), math.nan)
        return (x[idx] + sign * Z90 * s[idx]) * factor

    return values


def stiffness_chart(p: str) -> Chart:
    """Estimate of `p` with its 90% band (posterior of the mean, `*_std`) against the true
    surface mean and the true per-step stiffness, in kN."""
    k = 1e-3
    return Chart(
        key=p, title=f"{p} [{UNITS[p]}]: estimate, 90% band, truth", y_label=f"{p} [{UNITS[p]}]",
        series=(Series("true per step", col(f"true_{p}", k), stroke="rgba(214,39,40,0.25)", width=1),
                Series("true surface mean", col(f"true_{p}_mean", k), stroke=TRUTH_COLOR),
                Series("lower 90%", edge(p, -1, k), stroke="rgba(31,119,180,0.5)", width=1),
                Series("upper 90%", edge(p, +1, k), stroke="rgba(31,119,180,0.5)", width=1),
                Series("estimate", col(p, k))),  # drawn last: on top
        bands=((4, 3),), min_span=1.0)


def charts() -> tuple[Chart, ...]:
    """Every time chart of the dashboard (friction curves are separate: `friction_chart`)."""
    return (
        *(stiffness_chart(p) for p in STIFFNESS),
        Chart(key="bias_acc", title="accelerometer bias [m/s^2]: estimate vs truth", min_span=0.02, tab="state, bias",
              y_label="bias [m/s^2]",
              series=(Series("b_ax", col("b_ax")), Series("true b_ax", col("true_b_ax"), stroke=TRUTH_COLOR),
                      Series("b_ay", col("b_ay"), stroke="#2ca02c"),
                      Series("true b_ay", col("true_b_ay"), stroke="#ff7f0e"))),
        Chart(key="bias_yaw", title="yaw-rate bias [rad/s]: estimate vs truth", min_span=2e-3, tab="state, bias",
              y_label="bias [rad/s]",
              series=(Series("b_yaw_rate", col("b_yaw_rate")),
                      Series("true b_yaw_rate", col("true_b_yaw_rate"), stroke=TRUTH_COLOR))),
        Chart(key="vy", title="lateral velocity v^Y [m/s]: estimate vs truth", min_span=0.1, tab="state, bias",
              y_label="v^Y [m/s]",
              series=(Series("vy", col("vy")), Series("true vy", col("true_vy"), stroke=TRUTH_COLOR))),
        Chart(key="ess", title="effective sample size; grey: learning gate (top: active)", min_span=2.0,
              tab="state, bias", y_label="ESS [particles]",
              series=(Series("ESS", col("ess")),
                      Series("learning active", col("active"), stroke="#7f7f7f", width=1, scale="gate")),
              scales={"gate": {"range": (0.0, 1.05)}}),
    )


TABS = ("stiffness", "state, bias", "densities", "particles", "friction")  # the charts panel's tabs, in order
DENSITY_POINTS = 241  # grid points of a density chart


def density_data(mixture, param: str, truth: float = math.nan) -> tuple[np.ndarray, ...] | None:
    """uPlot data of the posterior density of `param` (eq. (26) for the MPF; what
    `viz.density.stiffness_mixture` gives for the others): stiffness [kN/rad] on a grid
    over the mixture's mean +- 6 of its std (the truth, if given, included), the density
    [per kN/rad], and the truth as a vertical line (two points: 0 and the peak). None
    when the mixture lacks `param`."""
    if mixture is None or param not in mixture.params:
        return None
    j = mixture.index(param)
    w, loc, scale = mixture.weights, mixture.loc[:, j], mixture.scale[:, j]
    ok = np.isfinite(loc) & np.isfinite(scale) & (w > 0)
    if not ok.any():
        return None
    mean = float(w[ok] @ loc[ok] / w[ok].sum())
    std = float(np.sqrt(w[ok] @ ((loc[ok] - mean) ** 2 + scale[ok] ** 2) / w[ok].sum()))
    std = max(std, 1e-4 * abs(mean), 1e-9)
    lo, hi = mean - 6 * std, mean + 6 * std
    if math.isfinite(truth):
        lo, hi = min(lo, truth - std), max(hi, truth + std)
    grid = np.linspace(lo, hi, DENSITY_POINTS)
    if math.isfinite(truth):
        grid = np.sort(np.append(grid, truth))
    pdf = mixture.pdf(param, grid) * 1e3  # per kN/rad
    line = np.full(grid.shape, math.nan)
    if math.isfinite(truth):
        k = int(np.searchsorted(grid, truth))
        line[k] = float(np.nanmax(pdf))
    return grid * 1e-3, pdf, line


DENSITY_SERIES = (
    {"label": "stiffness [kN/rad]"},
    {"label": "posterior density", "stroke": ESTIMATE_COLOR, "width": 2, "fill": BAND_FILL, "points": {"show": False}},
    {"label": "true surface mean", "stroke": TRUTH_COLOR, "width": 0, "points": {"show": True, "size": 9,
                                                                                  "fill": TRUTH_COLOR}},
)


def cloud_scatter(cloud, x_param: str, y_param: str, truth: dict | None = None) -> tuple[np.ndarray, ...] | None:
    """uPlot data of the particle cloud projected on (x_param, y_param) [kN/rad]: x sorted
    (uPlot needs increasing x), the particles of the heaviest tenth of the weight, the
    others, and the true surface mean as one point. None without both parameters."""
    if cloud is None:
        return None
    names, values, w, _ = cloud
    if x_param not in names or y_param not in names:
        return None
    x = values[:, list(names).index(x_param)] * 1e-3
    y = values[:, list(names).index(y_param)] * 1e-3
    heavy = w >= np.quantile(w, 0.9) if w.size else np.zeros(0, bool)
    tx = ty = math.nan
    if truth is not None:
        tx, ty = truth.get(x_param, math.nan) * 1e-3, truth.get(y_param, math.nan) * 1e-3
    xs = np.append(x, tx) if math.isfinite(tx) and math.isfinite(ty) else x
    order = np.argsort(xs, kind="stable")
    n = len(x)
    ys_heavy = np.append(np.where(heavy, y, math.nan), math.nan)[:len(xs)]
    ys_light = np.append(np.where(heavy, math.nan, y), math.nan)[:len(xs)]
    ys_truth = np.full(len(xs), math.nan)
    if len(xs) > n:
        ys_truth[n] = ty
    return xs[order], ys_light[order], ys_heavy[order], ys_truth[order]


CLOUD_SERIES = (
    {"label": "x"},
    {"label": "particles", "stroke": "rgba(31,119,180,0.45)", "width": 0,
     "points": {"show": True, "size": 5, "fill": "rgba(31,119,180,0.45)"}},
    {"label": "heaviest 10%", "stroke": "#1f3f8f", "width": 0, "points": {"show": True, "size": 7, "fill": "#1f3f8f"}},
    {"label": "true surface mean", "stroke": TRUTH_COLOR, "width": 0,
     "points": {"show": True, "size": 11, "fill": TRUTH_COLOR}},
)


# -- the particle cloud ---------------------------------------------------------------------
def particle_stiffness(posterior) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray] | None:
    """Per-particle absolute stiffness means from an estimator's `posterior()`:
    (parameter names, values (N, n), normalised weights (N,), nominal (n,)), or None when
    the posterior carries none.

    Read from `stats`: `params` (names as in the Result CSV), `C_nominal` (n,) and either
    `mu` (N, n), the per-particle mean deviation from nominal (the MPF's NiW statistics),
    or `stiffness` (N, n), absolute values.
    """
    stats = getattr(posterior, "stats", None) or {}
    names = stats.get("params")
    nominal = stats.get("C_nominal")
    if names is None or nominal is None:
        return None
    nominal = np.asarray(nominal, float)
    if "stiffness" in stats:
        values = np.asarray(stats["stiffness"], float)
    elif "mu" in stats:
        values = nominal + np.asarray(stats["mu"], float)
    else:
        return None
    if values.ndim != 2 or values.shape[1] != len(names):
        return None
    logw = np.asarray(posterior.log_weights, float)
    w = np.exp(logw - np.max(logw)) if logw.size else logw
    w = w / w.sum() if w.size and w.sum() > 0 else np.full(len(values), 1.0 / max(len(values), 1))
    return tuple(names), values, w, nominal


def cloud_positions(names, values: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """Scene positions (N, 3) of per-particle stiffness: x = Cf_y, y = Cr_y, z = Cx, each
    relative to its nominal value times CLOUD_SCALE (z = 0 without Cx: the lateral model)."""
    out = np.zeros((len(values), 3))
    for axis, p in enumerate(STIFFNESS):
        if p in names:
            j = list(names).index(p)
            out[:, axis] = values[:, j] / nominal[j] * CLOUD_SCALE
    return out


_WEIGHT_MAP = np.array([[190, 205, 225], [90, 130, 200], [30, 60, 160], [150, 30, 120], [215, 25, 28]], float)


def weight_colors(w: np.ndarray) -> np.ndarray:
    """uint8 RGB (N, 3) colouring each particle by its weight relative to the largest:
    pale blue (negligible) through dark blue to red (the heaviest), readable on white."""
    if w.size == 0:
        return np.zeros((0, 3), np.uint8)
    rel = w / np.max(w) if np.max(w) > 0 else np.zeros_like(w)
    pos = rel * (len(_WEIGHT_MAP) - 1)
    lo = np.clip(np.floor(pos).astype(int), 0, len(_WEIGHT_MAP) - 2)
    frac = (pos - lo)[:, None]
    return np.round(_WEIGHT_MAP[lo] * (1 - frac) + _WEIGHT_MAP[lo + 1] * frac).astype(np.uint8)


def truth_position(history: History, nominal: dict[str, float]) -> np.ndarray | None:
    """Scene position (3,) of the newest true surface-mean stiffness (None without truth)."""
    if history.rows == 0 or not history.has_values("true_Cf_y_mean"):
        return None
    pos = np.zeros(3)
    for axis, p in enumerate(STIFFNESS):
        if p in nominal:
            pos[axis] = history.last(f"true_{p}_mean") / nominal[p] * CLOUD_SCALE
    return pos if np.all(np.isfinite(pos)) else None


# -- friction ---------------------------------------------------------------------------------
def friction_truth(scenario, alpha: np.ndarray, surface: float) -> tuple[np.ndarray, np.ndarray]:
    """The true mu(alpha) of both axles at a surface scale, as the friction CSV has it
    (`io.friction.friction_truth`: the pure-lateral Pacejka curve times the surface
    scale; for linear tires C_y alpha / F_z at static axle load times the surface)."""
    from tirefilter.io.friction import friction_truth as truth_of

    mu_f, mu_r = truth_of(scenario)(np.asarray(alpha, float), surface)
    return np.asarray(mu_f, float), np.asarray(mu_r, float)


def friction_from_csv(path) -> tuple[FrictionCurve, tuple[np.ndarray, np.ndarray] | None] | None:
    """The newest snapshot of a friction CSV (`io.friction`) as a FrictionCurve, with
    its truth columns when it has them; None when the file holds no snapshot."""
    from tirefilter.io.friction import read_friction, snapshot_blocks

    blocks = snapshot_blocks(read_friction(path))
    if not blocks:
        return None
    b = blocks[-1]
    curve = FrictionCurve(t=float(b["t"][0]), alpha=b["alpha"], mu_f=b["mu_f"], mu_f_std=b["mu_f_std"],
                          mu_r=b["mu_r"], mu_r_std=b["mu_r_std"])
    truth = (b["true_mu_f"], b["true_mu_r"]) if "true_mu_f" in b and "true_mu_r" in b else None
    return curve, truth


def friction_data(curve, truth: tuple[np.ndarray, np.ndarray] | None, axle: str) -> tuple[np.ndarray, ...]:
    """uPlot data of one axle's friction curve: alpha [deg], posterior mean, the 90% band
    (mean +- Z90 std), and the truth (NaN when unknown)."""
    alpha = np.asarray(curve.alpha, float)
    mu = np.asarray(getattr(curve, f"mu_{axle}"), float)
    std = np.asarray(getattr(curve, f"mu_{axle}_std"), float)
    true = truth[0 if axle == "f" else 1] if truth is not None else np.full(alpha.shape, math.nan)
    return np.degrees(alpha), mu, mu - Z90 * std, mu + Z90 * std, np.asarray(true, float)


FRICTION_SERIES = (
    {"label": "alpha [deg]"},
    {"label": "mu estimate", "stroke": ESTIMATE_COLOR, "width": 2, "points": {"show": False}},
    {"label": "lower 90%", "stroke": "rgba(31,119,180,0.5)", "width": 1, "points": {"show": False}},
    {"label": "upper 90%", "stroke": "rgba(31,119,180,0.5)", "width": 1, "points": {"show": False}},
    {"label": "mu truth", "stroke": TRUTH_COLOR, "width": 2, "points": {"show": False}},
)
FRICTION_BANDS = ({"series": (3, 2), "fill": BAND_FILL},)
