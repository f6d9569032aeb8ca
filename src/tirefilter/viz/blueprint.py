"""The one blueprint of a recording: the layout the viewer opens with.

Left: one plot per stiffness parameter (estimate, +-2 posterior std of the mean, +-2
deviation spread, true surface mean, true per-step stiffness). Middle, in tabs: states and
measured vs. estimated yaw rate; bias estimates against true bias; ESS and the gate.
Right, in tabs: the particle clouds, the posterior density of each stiffness parameter
(eq. (26)), the friction curves, the top view of the vehicle.
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


def _series_style(path: str, estimator: str | None):
    """Colour, name and line/marker of a time series, as a view override (styles live in
    the blueprint, so the recorded entities hold data only)."""
    import rerun as rr

    name = path.rsplit("/", 1)[-1]
    if path.startswith("/truth/"):
        if name in paths.STIFFNESS:  # effective stiffness with the per-step deviation
            return rr.SeriesPoints(colors=[TRUTH_STEP], names=[f"true {name}, per step"], marker_sizes=[1.0])
        label = f"true {name[:-5]}, surface mean" if name.endswith("_mean") else f"true {name}"
        return rr.SeriesLines(colors=[TRUTH], names=[label], widths=[2.0 if name.endswith("_mean") else 1.0])
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


def build_blueprint(layout: Layout):
    """The rerun.blueprint.Blueprint for `layout`."""
    import rerun.blueprint as rrb

    e = layout.estimator
    live = rrb.VisibleTimeRange(paths.TIMELINE, start=rrb.TimeRangeBoundary.infinite(),
                                end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0))

    def series(name: str, *entities: str, styles: dict | None = None):
        entities = [p for p in entities if p]
        styles = {**{p: st for p in entities if (st := _series_style(p, e)) is not None}, **(styles or {})}
        return rrb.TimeSeriesView(name=name, origin="/", contents=[f"+ {p}" for p in entities], overrides=styles)

    def est(column: str) -> str | None:
        return paths.entity_path(column, e) if e else None

    stiffness = []
    if e:
        for p in layout.params:
            stiffness.append(series(f"{p} [N/rad]", est(p), f"{paths.estimator_root(e)}/stiffness/{p}/**",
                                    f"/truth/{p}_mean" if layout.truth else None,
                                    f"/truth/{p}" if layout.truth else None, styles=_band_styles(e, p)))
    states = [series(f"{s}", est(s), f"/truth/{s}" if layout.truth else None,
                     "/sensors/vx" if s == "vx" else None) for s in ("vx", "vy", "beta")]
    yaw = series("yaw rate: measured, estimated, true [rad/s]", "/sensors/yaw_rate", est("yaw_rate"),
                 "/truth/yaw_rate" if layout.truth else None)
    middle = [rrb.Vertical(yaw, *states, name="states")]
    if e:
        middle.append(rrb.Vertical(*[series(f"bias {s}", est(f"b_{s}"), f"/truth/b_{s}" if layout.truth else None)
                                     for s in layout.sensors], name="bias"))
        middle.append(rrb.Vertical(series("ESS", est("ess")), series("learning gate (1 = active)", est("active")),
                                   name="ESS, gate"))
    else:
        middle.append(rrb.Vertical(series("sensors", "/sensors/ax", "/sensors/ay"),
                                   series("steer [rad]", "/sensors/delta", "/truth/delta"), name="sensors"))

    right = []
    if e and layout.clouds:
        view = rrb.Spatial2DView if layout.lateral else rrb.Spatial3DView
        right.append(rrb.Vertical(
            view(name="stiffness means per particle (coloured by weight)", origin=paths.particles(e, "stiffness")),
            view(name="state particles", origin=paths.particles(e, "state")), name="particles"))
    if e and layout.densities:
        right.append(rrb.Vertical(*[rrb.BarChartView(name=f"posterior density of {p}, eq. (26)",
                                                     origin=paths.density(e, p)) for p in layout.densities],
                                  name="densities"))
    if e and layout.friction:
        top = rrb.EyeControls3D(position=(0.0, 0.0, 2.0), look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 1.0, 0.0))
        right.append(rrb.Vertical(*[rrb.Spatial3DView(
            name=f"friction {axle}: mu(alpha)", origin="/",
            contents=[f"+ {paths.friction(e, axle)}/**", f"+ {paths.friction(e, axle)}",
                      f"+ {paths.truth_friction(axle)}"], eye_controls=top) for axle in paths.AXLES],
            name="friction"))
    right.append(rrb.Spatial3DView(
        name="top view: path, heading, steer", origin="/vehicle", time_ranges=live,
        eye_controls=rrb.EyeControls3D(position=(0.0, 0.0, 80.0), look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 1.0, 0.0),
                                       tracking_entity=paths.VEHICLE_BODY)))  # from above, following the car
    columns = [rrb.Vertical(*stiffness, name="stiffness")] if stiffness else []
    columns += [rrb.Tabs(*middle), rrb.Tabs(*right)]
    return rrb.Blueprint(rrb.Horizontal(*columns), collapse_panels=False)
