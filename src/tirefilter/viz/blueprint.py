"""The one blueprint of a recording: the layout the viewer opens with.

Left: one plot per stiffness parameter (estimate, +-2 posterior std of the mean, +-2
deviation spread, true surface mean), its y axis fitted to the data after the start-up.
Middle, in tabs: states and measured vs. estimated yaw rate; bias estimates against true
bias; ESS and the gate. Right, in tabs: the particle clouds, the posterior density of each
stiffness parameter (eq. (26)), the friction curves, the top view of the vehicle. Legends
are off (the view names say what the colours are); the side panels start collapsed.
"""

from __future__ import annotations

from dataclasses import dataclass

from tirefilter.viz import paths

# colours (RGB)
ESTIMATE = (31, 119, 180)
POSTERIOR_BAND = (120, 170, 220)
SPREAD_BAND = (170, 170, 170)
TRUTH = (20, 20, 20)
TRUTH_STEP = (214, 39, 40)
MEASURED = (150, 150, 150)


@dataclass(frozen=True)
class Layout:
    """What the recording holds, as far as the layout cares."""

    estimator: str | None  # None: truth and sensors only
    params: tuple[str, ...] = ("Cf_y", "Cr_y", "Cx")  # estimated stiffness parameters
    lateral: bool = False  # 2-D stiffness cloud (Cf_y, Cr_y) and 2-D state cloud (vy, r)
    clouds: bool = False  # particle clouds are logged
    densities: tuple[str, ...] = ()  # parameters with a density
    friction: bool = False  # the estimator reports friction curves
    truth: bool = True  # co-simulation (truth columns), not a replay
    sensors: tuple[str, ...] = ("ax", "ay", "yaw_rate")  # bias channels to show
    references: tuple[str, ...] = ()  # states with a log's reference column (replay), drawn as truth


def _series_style(path: str, estimator: str | None):
    """Colour, name and line/marker of a time series, as a view override (styles live in
    the blueprint, so the recorded entities hold data only)."""
    import rerun as rr

    name = path.rsplit("/", 1)[-1]
    if path.startswith("/truth/"):
        label = f"true {name[:-5]}, surface mean" if name.endswith("_mean") else f"true {name}"
        return rr.SeriesLines(colors=[TRUTH], names=[label], widths=[1.5 if name.endswith("_mean") else 1.0])
    if path.startswith("/sensors/"):
        return rr.SeriesPoints(colors=[MEASURED], names=[f"measured {name}"], marker_sizes=[1.0])
    if estimator and path.startswith(paths.estimator_root(estimator)):
        return rr.SeriesLines(colors=[ESTIMATE], names=[f"estimated {name}"], widths=[2.0])
    return None


def _band_styles(estimator: str, param: str) -> dict:
    import rerun as rr

    styles = {}
    for which, color, label in (("posterior", POSTERIOR_BAND, "2 std of the mean"),
                                ("spread", SPREAD_BAND, "2 sigma, deviation spread")):
        for side, sign in (("lower", "-"), ("upper", "+")):
            styles[paths.stiffness_band(estimator, param, f"{which}_{side}")] = rr.SeriesLines(
                colors=[color], names=[f"{param} {sign} {label}"], widths=[1.0])
    return styles


# The names of the views say what the colours are: the legends are off (they covered half of
# every plot). Blue: estimate; light blue: +-2 std of the mean; grey: +-2 sigma spread (or a
# measurement); black: truth (co-simulation) or a log's reference.
STIFFNESS_KEY = "blue estimate, light +-2 std, grey +-2 sigma, black true mean"


def build_blueprint(layout: Layout, *, y_ranges: dict | None = None, density_history: dict | None = None,
                    active: tuple[int, int] = (0, 0)):
    """The rerun.blueprint.Blueprint for `layout`.

    `y_ranges` (parameter -> (low, high)) fixes the y axis of the stiffness plots (the
    recorder passes the range of the data after the start-up, so the converged estimate is
    not a thin strip under the transient); without it the axes fit all the data. `active`
    picks the open tab of the middle and the right column. `density_history` (parameter ->
    (stiffness low, high, t first, t last) of the recorder's density-history image) adds
    that image beside each density snapshot."""
    import rerun.blueprint as rrb

    e = layout.estimator
    live = rrb.VisibleTimeRange(paths.TIMELINE, start=rrb.TimeRangeBoundary.infinite(),
                                end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0))
    no_legend = rrb.PlotLegend(visible=False)

    def series(name: str, *entities: str, styles: dict | None = None, y_range=None):
        entities = [p for p in entities if p]
        styles = {**{p: st for p in entities if (st := _series_style(p, e)) is not None}, **(styles or {})}
        return rrb.TimeSeriesView(name=name, origin="/", contents=[f"+ {p}" for p in entities], overrides=styles,
                                  plot_legend=no_legend,
                                  axis_y=rrb.ScalarAxis(range=y_range) if y_range is not None else None)

    def est(column: str) -> str | None:
        return paths.entity_path(column, e) if e else None

    truth = "black true" if layout.truth else "black reference"
    stiffness = []
    if e:
        for p in layout.params:
            # the per-step truth /truth/<p> stays in the recording, not in the plot: its dots hid the estimate
            stiffness.append(series(f"{p} [N/rad]: {STIFFNESS_KEY}", est(p), f"{paths.estimator_root(e)}/stiffness/{p}/**",
                                    f"/truth/{p}_mean" if layout.truth else None, styles=_band_styles(e, p),
                                    y_range=(y_ranges or {}).get(p)))
    units = {"vx": "m/s", "vy": "m/s", "beta": "rad"}
    states = [series(f"{s} [{units[s]}]: blue estimate, {truth}" + (", grey measured" if s == "vx" else ""),
                     est(s), f"/truth/{s}" if layout.truth or s in layout.references else None,
                     "/sensors/vx" if s == "vx" else None) for s in ("vx", "vy", "beta")]
    yaw = series(f"yaw rate [rad/s]: grey measured, blue estimate, {truth}", "/sensors/yaw_rate", est("yaw_rate"),
                 "/truth/yaw_rate" if layout.truth or "yaw_rate" in layout.references else None)
    middle = [rrb.Vertical(yaw, *states, name="states")]
    if e:
        middle.append(rrb.Vertical(*[series(f"bias {s}: blue estimate, black true", est(f"b_{s}"),
                                            f"/truth/b_{s}" if layout.truth else None)
                                     for s in layout.sensors], name="bias"))
        middle.append(rrb.Vertical(series("effective sample size", est("ess")),
                                   series("learning gate (1 = open)", est("active")), name="ESS, gate"))
    else:
        middle.append(rrb.Vertical(series("sensors ax, ay [m/s^2]", "/sensors/ax", "/sensors/ay"),
                                   series("steer [rad]: grey measured, black true", "/sensors/delta", "/truth/delta"),
                                   name="sensors"))

    right = []
    if e and layout.clouds:
        view = rrb.Spatial2DView if layout.lateral else rrb.Spatial3DView
        right.append(rrb.Vertical(
            view(name="stiffness means per particle (coloured by weight)", origin=paths.particles(e, "stiffness")),
            view(name="state particles", origin=paths.particles(e, "state")), name="particles"))
    if e and layout.densities:
        rows = []
        for p in layout.densities:
            snapshot = rrb.BarChartView(name=f"density of {p} [per N/rad] at the time cursor, eq. (26)",
                                        origin=paths.density(e, p), contents=["+ $origin"], plot_legend=no_legend)
            h = (density_history or {}).get(p)
            if h is None:
                rows.append(snapshot)
                continue
            lo, hi, t0, t1 = h
            rows.append(rrb.Horizontal(snapshot, rrb.Spatial2DView(
                name=f"{p} density over time: {lo:.4g} .. {hi:.4g} N/rad (up), {t0:g} .. {t1:g} s (right)",
                origin=paths.density_history(e, p)), column_shares=[1, 1]))
        right.append(rrb.Vertical(*rows, name="densities"))
    if e and layout.friction:
        top = rrb.EyeControls3D(position=(0.0, 0.0, 2.0), look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 1.0, 0.0))
        right.append(rrb.Vertical(*[rrb.Spatial3DView(
            name=f"friction {axle}: mu(alpha)", origin="/",
            contents=[f"+ {paths.friction(e, axle)}/**", f"+ {paths.friction(e, axle)}",
                      f"+ {paths.truth_friction(axle)}"], eye_controls=top) for axle in paths.AXLES],
            name="friction"))
    right.append(rrb.Spatial3DView(
        name="top view: path, heading, steer", origin="/vehicle", time_ranges=live,
        # from straight above, x up; the eye follows (and frames) the square around the car (it
        # keeps its own distance, set by the size of what it tracks)
        eye_controls=rrb.EyeControls3D(position=(0.0, -1.0, 100.0), look_target=(0.0, 0.0, 0.0),
                                       eye_up=(1.0, 0.0, 0.0), tracking_entity=paths.VEHICLE_FRAME)))
    columns = [rrb.Vertical(*stiffness, name="stiffness")] if stiffness else []
    columns += [rrb.Tabs(*middle, active_tab=min(active[0], len(middle) - 1)),
                rrb.Tabs(*right, active_tab=min(active[1], len(right) - 1))]
    return rrb.Blueprint(rrb.Horizontal(*columns), rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"), rrb.TimePanel(state="collapsed"))


def tab_counts(layout: Layout) -> tuple[int, int]:
    """How many tabs the middle and the right column of `build_blueprint(layout)` have."""
    e = layout.estimator
    right = 1 + bool(e and layout.clouds) + bool(e and layout.densities) + bool(e and layout.friction)
    return 3 if e else 2, right
