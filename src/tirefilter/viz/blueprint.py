"""The blueprint of a recording: the layout the viewer opens with.

Left: one plot per stiffness parameter (estimate, the 90 % band of the mean, the 90 % range
of the per-step stiffness, the true surface mean). Middle, in tabs: the states with the
measured and the true yaw rate; the bias estimates against the true biases (or a note that
the run does not estimate them); ESS with N and the resampling threshold, and the gate.
Right, in tabs: the particle clouds, the posterior density of each stiffness parameter
(eq. (26)), its quantiles over time, the friction curves, the top view of the car.

Every plot has a legend with short series names and a short title with its unit, so
neither is cut off at 1600 x 1000. The recorder sends a first blueprint at the run's first
step (before any data) and the final one at the end, with the y ranges of the settled data,
the notes the run's metrics call for and the camera over the whole path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tirefilter.viz import paths
from tirefilter.viz.units import unit

# colours (RGB); none is the viewer's error red (tests/rerun_web.py tells them apart)
ESTIMATE = (31, 119, 180)
POSTERIOR_BAND = (120, 170, 220)
SPREAD_BAND = (170, 170, 170)
TRUTH = (20, 20, 20)
STEER = (255, 127, 14)
MEASURED = (150, 150, 150)
BODY = (90, 90, 90)

Z90 = 1.6448536269514722  # mean +- Z90 std: the 90 % band of a Gaussian (the dashboard's and metrics' coverage90)
BAND_OF_MEAN = "90 % band of the mean"
PER_STEP = "90 % of per-step stiffness"
QUANTILES = "5 % and 95 % quantiles"
TITLE_MAX = 45  # characters: a title this long is whole in a view a third of a 1600 px wide viewer
CLOUD_EYE = (6.0, -8.5, 4.7)  # the clouds' camera, in std units of the normalised cloud (viz.clouds)
STATE_NAMES = {"vx": "vx", "vy": "vy", "beta": "beta", "yaw_rate": "yaw rate"}


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
    sensors: tuple[str, ...] = ("ax", "ay", "yaw_rate")  # bias channels of the estimator
    references: tuple[str, ...] = ()  # states with a log's reference column (replay), drawn as truth
    bias_estimated: bool = True  # False: the estimator takes the IMU as unbiased (a note, no estimate lines)
    true_bias: tuple[str, ...] = ()  # channels whose true bias is not zero (drawn when bias_estimated is False)
    cx_excited: bool | None = None  # False: the run's metrics say Cx was never excited (a note on its plot)
    path_bounds: tuple[float, float, float, float] | None = None  # x0, x1, y0, y1 [m]: the overview's camera
    ess_lines: bool = False  # N and the resampling threshold are recorded beside the ESS


def layout_json(layout: Layout, y_ranges: dict | None = None) -> str:
    """The layout and the y ranges of a final blueprint as JSON (the recording keeps it as its
    property `tirefilter`, so a tool can rebuild the blueprint with another tab open)."""
    import json
    from dataclasses import asdict

    return json.dumps({"layout": asdict(layout), "y_ranges": {k: list(v) for k, v in (y_ranges or {}).items()}})


def layout_from_json(text: str) -> tuple[Layout, dict]:
    """(Layout, y_ranges) of `layout_json`."""
    import json

    d = json.loads(text)
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in d["layout"].items()}
    return Layout(**fields), {k: tuple(v) for k, v in d["y_ranges"].items()}


def _legend():
    import rerun.blueprint as rrb

    return rrb.PlotLegend(corner=rrb.components.Corner2D.RightTop, visible=True)


def _lines(color, name: str, width: float = 1.0):
    import rerun as rr

    return rr.SeriesLines(colors=[color], names=[name], widths=[width])


def stiffness_title(param: str, cx_excited: bool | None = None) -> str:
    title = f"{param} [{unit(param)}]"
    return title + ": NOT EXCITED, prior only" if param == "Cx" and cx_excited is False else title


def build_blueprint(layout: Layout, *, y_ranges: dict | None = None, active: tuple[int, int] = (0, 0)):
    """The rerun.blueprint.Blueprint for `layout`.

    `y_ranges` (view key -> (low, high)) fixes the y axes of the series views: the recorder
    passes robust ranges of the settled data (`RerunRecorder.y_ranges`), so a start-up
    transient does not squash the rest into a strip; keys are stiffness parameters, states,
    `b_<sensor>`, `ess`, `q_<param>` (quantiles). Without one the view fits all its data.
    `active` picks the open tab of the middle and the right column."""
    import rerun as rr
    import rerun.blueprint as rrb

    e = layout.estimator
    ranges = y_ranges or {}
    live = rrb.VisibleTimeRange(paths.TIMELINE, start=rrb.TimeRangeBoundary.infinite(),
                                end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0))

    def series(name: str, key: str | None, styled: dict):
        """A time series of the entities in `styled` (path -> SeriesLines/SeriesPoints; None: left out)."""
        styled = {p: st for p, st in styled.items() if p}
        rng = ranges.get(key) if key else None
        return rrb.TimeSeriesView(name=name, origin="/", contents=[f"+ {p}" for p in styled], overrides=styled,
                                  plot_legend=_legend(), axis_y=rrb.ScalarAxis(range=rng) if rng is not None else None)

    def est(column: str) -> str | None:
        return paths.entity_path(column, e) if e else None

    def truth(column: str, name: str = "true") -> dict:
        if layout.truth:
            return {f"/truth/{column}": _lines(TRUTH, name, 1.5)}
        if column in layout.references:
            return {f"/truth/{column}": _lines(TRUTH, "reference", 1.5)}
        return {}

    stiffness = []
    if e:
        for p in layout.params:
            note = p == "Cx" and layout.cx_excited is False
            styled = {est(p): _lines(ESTIMATE, "estimate: prior, not excited" if note else "estimate", 2.0)}
            for which, color, label in (("posterior", POSTERIOR_BAND, BAND_OF_MEAN), ("spread", SPREAD_BAND, PER_STEP)):
                for side in ("lower", "upper"):  # one legend entry: the two edges share their name
                    styled[paths.stiffness_band(e, p, f"{which}_{side}")] = _lines(color, label)
            # the per-step truth /truth/<p> stays in the recording, not in the plot (its dots hid the estimate)
            if layout.truth:
                styled[f"/truth/{p}_mean"] = _lines(TRUTH, "true surface mean", 1.5)
            stiffness.append(series(stiffness_title(p, layout.cx_excited), p, styled))

    states = []
    for s in ("yaw_rate", "vx", "vy", "beta"):
        styled = {}
        if s in ("yaw_rate", "vx"):
            styled[f"/sensors/{s}"] = rr.SeriesPoints(colors=[MEASURED], names=["measured"], marker_sizes=[1.0])
        styled[est(s)] = _lines(ESTIMATE, "estimate", 2.0)
        styled.update(truth(s))
        states.append(series(f"{STATE_NAMES[s]} [{unit(s)}]", s, styled))
    middle = [rrb.Vertical(*states, name="states")]
    if e:
        middle.append(rrb.Vertical(*_bias_views(layout, series, est, truth), name="bias"))
        ess = {est("ess"): _lines(ESTIMATE, "ESS", 2.0)}
        if layout.ess_lines:
            ess[paths.ess_line(e, "particles")] = _lines(TRUTH, "N (particles)", 1.5)
            ess[paths.ess_line(e, "threshold")] = _lines(STEER, "resampling threshold", 1.5)
        middle.append(rrb.Vertical(series("ESS [particles]", "ess", ess),
                                   series("learning gate [1 = open]", "active",
                                          {est("active"): _lines(ESTIMATE, "gate")}),
                                   name="ESS, gate"))
    else:
        middle.append(rrb.Vertical(
            series(f"ax, ay [{unit('ax')}]", None, {"/sensors/ax": _lines(ESTIMATE, "measured ax"),
                                                    "/sensors/ay": _lines(STEER, "measured ay")}),
            series(f"steer [{unit('delta')}]", None, {"/sensors/delta": _lines(MEASURED, "measured"),
                                                      **truth("delta")}),
            name="sensors"))

    right = []
    if e and layout.clouds:
        right.append(rrb.Vertical(_cloud_view(layout, "stiffness", "stiffness means per particle"),
                                  _cloud_view(layout, "state", "state particles"), name="particles"))
    if e and layout.densities:
        bars, over_time = [], []
        for p in layout.densities:
            bars.append(rrb.BarChartView(name=f"density of {p} [{unit(p)}]", origin=paths.density(e, p),
                                         contents=["+ $origin", "+ $origin/true_mean"], plot_legend=_legend()))
            q = {paths.density_quantile(e, p, "q05"): _lines(POSTERIOR_BAND, QUANTILES),
                 paths.density_quantile(e, p, "q95"): _lines(POSTERIOR_BAND, QUANTILES),
                 est(p): _lines(ESTIMATE, "mean", 2.0)}
            if layout.truth:
                q[f"/truth/{p}_mean"] = _lines(TRUTH, "true surface mean", 1.5)
            over_time.append(series(f"{p} posterior over time [{unit(p)}]", f"q_{p}", q))
        right.append(rrb.Vertical(*bars, name="densities"))
        right.append(rrb.Vertical(*over_time, name="quantiles"))
    if e and layout.friction:
        top = rrb.EyeControls3D(position=(0.0, 0.0, 2.0), look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 1.0, 0.0))
        right.append(rrb.Vertical(*[rrb.Spatial3DView(
            name=f"friction {axle}: mu(alpha)", origin="/",
            contents=[f"+ {paths.friction(e, axle)}/**", f"+ {paths.friction(e, axle)}",
                      f"+ {paths.truth_friction(axle)}"], eye_controls=top) for axle in paths.AXLES],
            name="friction"))
    right.append(rrb.Vertical(_overview(layout, live), _close_up(), name="top view"))
    columns = [rrb.Vertical(*stiffness, name="stiffness")] if stiffness else []
    columns += [rrb.Tabs(*middle, active_tab=min(active[0], len(middle) - 1)),
                rrb.Tabs(*right, active_tab=min(active[1], len(right) - 1))]
    # the time cursor follows the data as it arrives: at the end of a recording once it is loaded
    stage = "first step" if y_ranges is None else "final"  # which of a recording's two blueprints (tests read it)
    return rrb.Blueprint(rrb.Horizontal(*columns, name=f"tirefilter layout ({stage})"),
                         rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(state="collapsed", timeline=paths.TIMELINE, play_state="following"))


def _bias_views(layout: Layout, series, est, truth) -> list:
    """The bias tab: estimate against truth per channel, with units; when the estimator takes
    the IMU as unbiased, the note (a text view) and the true biases that are not zero."""
    import rerun.blueprint as rrb

    e = layout.estimator
    if layout.bias_estimated:
        return [series(f"bias {STATE_NAMES.get(s, s)} [{unit(s)}]", f"b_{s}",
                       {est(f"b_{s}"): _lines(ESTIMATE, "estimate", 2.0), **truth(f"b_{s}", "true bias")})
                for s in layout.sensors]
    views = [rrb.TextDocumentView(name="bias: not estimated", origin=paths.note(e, "bias"))]
    views += [series(f"true bias {STATE_NAMES.get(s, s)} [{unit(s)}]", f"b_{s}",
                     truth(f"b_{s}", "true bias (not estimated)")) for s in layout.true_bias]
    return views


def _cloud_view(layout: Layout, what: str, name: str):
    """A particle cloud in its normalised frame (`viz.clouds`): the cloud, its axes with
    physical tick labels and the weight colour scale; a fixed camera frames it at every step."""
    import rerun.blueprint as rrb

    e = layout.estimator
    contents = [f"+ {paths.particles(e, what)}", f"+ {paths.particle_axes(e, what)}/**"]
    if layout.lateral:
        return rrb.Spatial2DView(name=name, origin=paths.particles_root(e), contents=contents,
                                 visual_bounds=rrb.VisualBounds2D(x_range=(-4.6, 4.6), y_range=(-4.6, 4.6)))
    return rrb.Spatial3DView(name=name, origin=paths.particles_root(e), contents=contents, line_grid=False,
                             eye_controls=rrb.EyeControls3D(position=CLOUD_EYE, look_target=(0.0, 0.0, 0.0),
                                                            eye_up=(0.0, 0.0, 1.0)))


def overview_eye(bounds, aspect: float = 1.25, fov_y_deg: float = 55.0):
    """(position, look_target, eye_up) of a camera straight above the path's bounding box
    (x0, x1, y0, y1) that holds the whole of it in a view `aspect` times wider than high:
    the longer side of the box runs across the view."""
    import math

    x0, x1, y0, y1 = bounds
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    wx, wy = max(x1 - x0, 1.0), max(y1 - y0, 1.0)
    across, up_down, eye_up = (wx, wy, (0.0, 1.0, 0.0)) if wx >= wy else (wy, wx, (1.0, 0.0, 0.0))
    half = 0.5 * max(across / aspect, up_down) * 1.15  # 15 % margin
    height = half / math.tan(math.radians(0.5 * fov_y_deg))
    return (cx, cy, height), (cx, cy, 0.0), eye_up


def overview_scale(bounds) -> tuple[list, list, str]:
    """The overview's scale bar: (line strips (bar and end ticks), label position, label),
    a round length (1, 2, 5 x 10^k m) near a fifth of the path's longer side, along the
    screen's horizontal below the path's bounding box (`overview_eye`'s orientation)."""
    import math

    x0, x1, y0, y1 = bounds
    wx, wy = max(x1 - x0, 1.0), max(y1 - y0, 1.0)
    raw = max(wx, wy) / 5
    mag = 10.0 ** math.floor(math.log10(raw))
    length = max(m * mag for m in (1, 2, 5, 10) if m * mag <= raw * 1.0001)
    gap, tick = 0.06 * max(wx, wy), 0.015 * max(wx, wy)
    if wx >= wy:  # x across the screen (to the right), y up: the bar below the box, from its left end
        a, b, side = np.array([x0, y0 - gap]), np.array([x0 + length, y0 - gap]), np.array([0.0, 1.0])
    else:  # x up, -y to the right: the bar below the box, from its left end (largest y)
        a, b, side = np.array([x0 - gap, y1]), np.array([x0 - gap, y1 - length]), np.array([1.0, 0.0])

    def p3(v):
        return [float(v[0]), float(v[1]), 0.0]

    strips = [[p3(a), p3(b)], [p3(a - tick * side), p3(a + tick * side)], [p3(b - tick * side), p3(b + tick * side)]]
    return strips, p3(0.5 * (a + b) + 2.5 * tick * side), f"{length:g} m"


def _overview(layout: Layout, live):
    """The whole path from above (grey), the trail up to the time cursor, the car as a dot,
    and a scale bar; the camera holds the path's bounding box (final blueprint)."""
    import rerun.blueprint as rrb

    eye = None
    if layout.path_bounds is not None:
        position, target, up = overview_eye(layout.path_bounds)
        eye = rrb.EyeControls3D(position=position, look_target=target, eye_up=up)
    return rrb.Spatial3DView(name="path of the run [m]", origin="/vehicle", time_ranges=live, line_grid=False,
                             contents=[f"+ {paths.VEHICLE_PATH}", f"+ {paths.VEHICLE_TRAIL}",
                                       f"+ {paths.VEHICLE_MARKER}", f"+ {paths.VEHICLE_SCALE}/**"],
                             eye_controls=eye)


def _close_up():
    """The car from above, the camera following it (a square of 2 CLOSE_UP_HALF_SIZE m):
    outline, heading, steered wheel, the directions of the true and the estimated velocity
    (drawn at rerun_log.BETA_GAIN times the sideslip beta to the heading, labelled), the
    path, a 10 m scale bar."""
    import rerun.blueprint as rrb

    # the data at the time cursor only (a visible time range would draw every past arrow), with the
    # whole path (static) around the car
    return rrb.Spatial3DView(
        name="car: heading vs velocity (beta)", origin="/vehicle", line_grid=False,
        contents=[f"+ {paths.VEHICLE_BODY}/**", f"- {paths.VEHICLE_MARKER}", f"+ {paths.VEHICLE_PATH}",
                  f"+ {paths.VEHICLE_POSITION}/**"],
        # from straight above, x up; the eye follows (and frames) the square around the car
        eye_controls=rrb.EyeControls3D(position=(0.0, -1.0, 100.0), look_target=(0.0, 0.0, 0.0),
                                       eye_up=(1.0, 0.0, 0.0), tracking_entity=paths.VEHICLE_FRAME))


def view_names(layout: Layout, **options) -> list[str]:
    """The titles of every view of `build_blueprint(layout, **options)` (tests: none is cut off)."""
    import rerun.blueprint as rrb

    out = []

    def walk(item):
        if isinstance(item, rrb.View):
            out.append(item.name)
        for child in getattr(item, "contents", ()) if isinstance(item, rrb.Container) else ():
            walk(child)

    walk(build_blueprint(layout, **options).root_container)
    return out


def tab_counts(layout: Layout) -> tuple[int, int]:
    """How many tabs the middle and the right column of `build_blueprint(layout)` have."""
    e = layout.estimator
    right = 1 + bool(e and layout.clouds) + 2 * bool(e and layout.densities) + bool(e and layout.friction)
    return 3 if e else 2, right
