"""What the dashboard draws, as plain arrays: the uPlot charts (series, bands, data from
a History), the particle cloud of the stiffness posterior, the vehicle path, the friction
curves and their truth, and what each tab says when it has nothing to show. No viser
here; `app` hands these arrays and texts to the page.
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
DEG = 180.0 / math.pi  # rad -> deg
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

    def uplot(self, unit: str = "") -> dict:
        """The uPlot series; `unit` is added to the legend's label ("estimate [kN/rad]")."""
        label = f"{self.label} [{unit}]" if unit else self.label
        s = {"label": label, "stroke": self.stroke, "width": self.width, "scale": self.scale,
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
    unit: str = ""  # the unit of the "y" scale's series, shown in the legend beside each label

    def data(self, history: History, idx: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        idx = history.decimation() if idx is None else idx
        t = history.column("t")
        return (np.asarray(t[idx], float),) + tuple(np.asarray(s.values(history, idx), float) for s in self.series)

    def y_series(self) -> tuple[int, ...]:
        """Indices into `data` of the series on the "y" scale (the range `app` sets)."""
        return tuple(j + 1 for j, s in enumerate(self.series) if s.scale == "y")

    def uplot_series(self) -> tuple[dict, ...]:
        return ({"label": "t [s]"},) + tuple(s.uplot(self.unit if s.scale == "y" else "") for s in self.series)

    def uplot_bands(self) -> tuple[dict, ...]:
        return tuple({"series": b, "fill": BAND_FILL} for b in self.bands)

    def uplot_scales(self) -> dict:
        scales = {"x": {"time": False}}
        scales.update(self.scales or {})
        return scales

    def uplot_axes(self) -> tuple[dict, ...]:
        return axes("t [s]", self.y_label)


AXIS_SIZE = 80  # px left of a chart for the y tick labels: room for a sign and 6 digits
# px around the plot (top, right, bottom, left): a tick label centred on the top edge or the
# right end of the x axis needs half its height / width there (uPlot's default clipped the
# top y tick, '0.01' of the bias chart, and the last x tick); the axes take the bottom and left
PADDING = (14, 24, 0, 0)


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
        key=p, title=f"{p} [{UNITS[p]}]: estimate, 90% band, truth", y_label=f"{p} [{UNITS[p]}]", unit=UNITS[p],
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
        Chart(key="vy", title="lateral velocity v^Y [m/s]: estimate vs truth", min_span=0.1, tab="state",
              y_label="v^Y [m/s]", unit="m/s",
              series=(Series("true vy", col("true_vy"), stroke=TRUTH_COLOR), Series("vy", col("vy")))),
        Chart(key="beta", title="sideslip beta [deg]: estimate vs truth", min_span=0.2, tab="state",
              y_label="beta [deg]", unit="deg",
              series=(Series("true beta", col("true_beta", DEG), stroke=TRUTH_COLOR),
                      Series("beta", col("beta", DEG)))),
        Chart(key="yaw_rate", title="yaw rate [rad/s]: estimate vs truth and the gyro", min_span=0.01, tab="state",
              y_label="yaw rate [rad/s]", unit="rad/s",
              series=(Series("gyro (measured)", col("meas_yaw_rate"), stroke="rgba(127,127,127,0.6)", width=1),
                      Series("true yaw rate", col("true_yaw_rate"), stroke=TRUTH_COLOR),
                      Series("yaw rate", col("yaw_rate")))),
        Chart(key="bias_acc", title="accelerometer bias [m/s^2]: estimate vs truth", min_span=0.02, tab="bias, ESS",
              y_label="bias [m/s^2]", unit="m/s^2",
              series=(Series("b_ax", col("b_ax")), Series("true b_ax", col("true_b_ax"), stroke=TRUTH_COLOR),
                      Series("b_ay", col("b_ay"), stroke="#2ca02c"),
                      Series("true b_ay", col("true_b_ay"), stroke="#ff7f0e"))),
        # in mrad/s: uPlot prints ticks with at most 3 decimals ('0.0005' as '0.001', twice on one axis)
        Chart(key="bias_yaw", title="yaw-rate bias [mrad/s]: estimate vs truth", min_span=2.0, tab="bias, ESS",
              y_label="bias [mrad/s]", unit="mrad/s",
              series=(Series("b_yaw_rate", col("b_yaw_rate", 1e3)),
                      Series("true b_yaw_rate", col("true_b_yaw_rate", 1e3), stroke=TRUTH_COLOR))),
        Chart(key="ess", title="effective sample size; grey: learning gate (top: active)", min_span=2.0,
              tab="bias, ESS", y_label="ESS [particles]", unit="particles",
              series=(Series("ESS", col("ess")),
                      Series("learning active [0/1]", col("active"), stroke="#7f7f7f", width=1, scale="gate")),
              scales={"gate": {"range": (0.0, 1.05)}}),
    )


TABS = ("stiffness", "state", "bias, ESS", "densities", "particles", "path", "friction")  # the panel's tabs, in order
DENSITY_POINTS = 241  # grid points of a density chart


def density_data(mixture, param: str, truth: float = math.nan) -> tuple[np.ndarray, ...] | None:
    """uPlot data of the posterior density of `param` (eq. (26) for the MPF; what
    `viz.density.stiffness_mixture` gives for the others): stiffness [kN/rad, Cx kN/unit
    slip] on a grid over the mixture's mean +- 6 of its std (the truth, if given,
    included), the density [per kN/rad], and the truth as a vertical line (two points: 0
    and the peak). None when the mixture lacks `param`."""
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
    pdf = mixture.pdf(param, grid) * 1e3  # per kN/rad (per kN/unit slip)
    line = np.full(grid.shape, math.nan)
    if math.isfinite(truth):
        k = int(np.searchsorted(grid, truth))
        line[k] = float(np.nanmax(pdf))
    return grid * 1e-3, pdf, line


def density_series(param: str) -> tuple[dict, ...]:
    """The uPlot series of the density chart of `param`, each label with its unit."""
    u = UNITS[param]
    return (
        {"label": f"{param} [{u}]"},
        {"label": f"posterior density [1/({u})]", "stroke": ESTIMATE_COLOR, "width": 2, "fill": BAND_FILL,
         "points": {"show": False}},
        {"label": f"true surface mean [1/({u})]", "stroke": TRUTH_COLOR, "width": 0,
         "points": {"show": True, "size": 9, "fill": TRUTH_COLOR}},
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


def cloud_series(x_param: str, y_param: str) -> tuple[dict, ...]:
    """The uPlot series of the particle cloud of `y_param` against `x_param`, each label
    with its unit."""
    uy = UNITS[y_param]
    return (
        {"label": f"{x_param} [{UNITS[x_param]}]"},
        {"label": f"particles: {y_param} [{uy}]", "stroke": "rgba(31,119,180,0.45)", "width": 0,
         "points": {"show": True, "size": 5, "fill": "rgba(31,119,180,0.45)"}},
        {"label": f"heaviest 10%: {y_param} [{uy}]", "stroke": "#1f3f8f", "width": 0,
         "points": {"show": True, "size": 7, "fill": "#1f3f8f"}},
        {"label": f"true surface mean: {y_param} [{uy}]", "stroke": TRUTH_COLOR, "width": 0,
         "points": {"show": True, "size": 11, "fill": TRUTH_COLOR}},
    )


# -- the vehicle path ------------------------------------------------------------------------
def path_data(history: History, idx: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """uPlot data of the vehicle path seen from above (`History.pose`: the truth, else dead
    reckoning), x [m] sorted (uPlot needs increasing x; the path is drawn as points), the
    path's y [m], the start, and the newest position. None without a finite path."""
    x, y, _ = history.pose()
    if len(idx) < 2:
        return None
    px, py = x[idx], y[idx]
    if not (np.isfinite(px).all() and np.isfinite(py).all()):
        return None
    n = len(px)
    xs = np.concatenate([px, px[:1], px[-1:]])
    path = np.concatenate([py, [math.nan, math.nan]])
    start = np.full(n + 2, math.nan)
    start[n] = py[0]
    now = np.full(n + 2, math.nan)
    now[n + 1] = py[-1]
    order = np.argsort(xs, kind="stable")
    return xs[order], path[order], start[order], now[order]


def equal_axes(x: np.ndarray, y: np.ndarray, width_px: float, height_px: float,
               margin: float = 0.08) -> tuple[tuple[float, float], tuple[float, float]]:
    """x and y ranges [m] showing the points (x, y) with as many metres per pixel on both
    axes (a plot area of width_px x height_px), centred, with `margin` of the span around
    them; at least 20 m across."""
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    cx, cy = (x.min() + x.max()) / 2, (y.min() + y.max()) / 2
    per_px = max((x.max() - x.min()) / width_px, (y.max() - y.min()) / height_px, 20.0 / min(width_px, height_px))
    per_px *= 1 + 2 * margin
    hw, hh = per_px * width_px / 2, per_px * height_px / 2
    return (float(cx - hw), float(cx + hw)), (float(cy - hh), float(cy + hh))


PATH_SERIES = (
    {"label": "x [m]"},
    {"label": "path: y [m]", "stroke": ESTIMATE_COLOR, "width": 0,
     "points": {"show": True, "size": 3, "fill": ESTIMATE_COLOR}},
    {"label": "start: y [m]", "stroke": "#2ca02c", "width": 0, "points": {"show": True, "size": 11, "fill": "#2ca02c"}},
    {"label": "now: y [m]", "stroke": TRUTH_COLOR, "width": 0, "points": {"show": True, "size": 13,
                                                                         "fill": TRUTH_COLOR}},
)


# -- what an empty tab says -------------------------------------------------------------------
def tab_notes(source: str, estimator: str | None, *, densities: bool = False, particles: bool = False,
              friction: bool = False, bias: bool = True, cx: bool = True) -> dict[str, str]:
    """Why a tab (or a chart in it) shows nothing, by tab name; tabs with nothing to explain
    are absent.

    `source`: "none" (no run yet), "run" (a live run) or "result" (an opened Result CSV);
    `estimator`: its name (None or "none": no estimator); `densities`, `particles`,
    `friction`: whether those tabs have something to draw; `bias`: the rows hold an IMU
    bias estimate; `cx`: the Cx chart is shown (the lateral model has no Cx).
    """
    if source == "none":
        text = "Nothing to show yet: press **Start** for a run, or open a Result CSV."
        return {tab: text for tab in TABS}
    notes = {}
    name = estimator if estimator not in (None, "none") else None
    posterior = (("densities", densities, "posterior densities"), ("particles", particles, "particle cloud"))
    if source == "result":
        for tab, shown, what in posterior:
            if not shown:
                notes[tab] = (f"**Not in this file:** a Result CSV holds the estimates, not the particles, so it has "
                              f"no {what}. Start a run to see it live.")
        if not friction:
            notes["friction"] = ("**Not in this file:** no friction CSV beside this Result CSV (a friction "
                                 "estimator's run writes RESULT.friction.csv, or friction.csv next to results.csv).")
    else:
        for tab, shown, what in posterior:
            if not shown:
                why = "the run has no estimator" if name is None else f"{name} has no particle posterior of the stiffness"
                notes[tab] = f"**Not for this estimator:** {why}, so there is no {what}."
        if not friction:
            notes["friction"] = ("**Not for this estimator:** " + ("the run has no estimator" if name is None
                                 else f"{name} learns the stiffness, not the friction curve")
                                 + "; the friction GP-SSM (`gpssm`) learns mu(alpha).")
    if not bias:
        notes["bias, ESS"] = ("**IMU bias not estimated** in these rows (the sensors' model has no bias, or the "
                              "estimator does not estimate one): the bias charts show the truth only.")
    if not cx:
        notes["stiffness"] = "**Cx not estimated:** the lateral model has no longitudinal stiffness."
    return notes


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
    {"label": "mu estimate [-]", "stroke": ESTIMATE_COLOR, "width": 2, "points": {"show": False}},
    {"label": "lower 90% [-]", "stroke": "rgba(31,119,180,0.5)", "width": 1, "points": {"show": False}},
    {"label": "upper 90% [-]", "stroke": "rgba(31,119,180,0.5)", "width": 1, "points": {"show": False}},
    {"label": "mu truth [-]", "stroke": TRUTH_COLOR, "width": 2, "points": {"show": False}},
)
FRICTION_BANDS = ({"series": (3, 2), "fill": BAND_FILL},)
