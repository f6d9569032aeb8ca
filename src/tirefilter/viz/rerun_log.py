"""Rerun recordings of a run: truth, sensors, vehicle pose, estimate series, and the
estimator's posterior (particle clouds, stiffness densities and their quantiles, friction
curves).

Result-CSV rows are buffered and sent in bulk with `send_columns` every `chunk` rows and
at close, so the series cost little per step and a run that fails keeps what was sent.
Values are recorded in the units of `viz.units` (stiffness in kN, beta in degrees). At
every `log_every`-th estimator step the posterior is logged as well (`_snapshot`): the
particle clouds in their normalised frame with axes and a weight colour scale
(`viz.clouds`), the posterior density of each stiffness parameter over its mean -+
DENSITY_REACH std (eq. (26), `viz.density`) with the true mean as a bar, its 5 % and 95 %
quantiles, and the friction curves of estimators that have `friction()`.

The recording goes to any of: an .rrd file, a viewer spawned here, a viewer or gRPC proxy
at a URL (`RecordingOptions`). The layout (`viz.blueprint`) is decided once the recorder
knows what the estimator provides (its first step) and sent to every sink at once, before
any data, so a viewer shows it from the start; the final blueprint follows at the end,
with the y ranges fitted to the data after the start-up (STARTUP_S), the notes the run's
metrics call for (Cx not excited) and the overview's camera over the whole path.

Entity paths: `viz.paths` and the table of docs/rerun.md.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import socket
import sys
from pathlib import Path
from urllib.parse import urlparse

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.viz import clouds, paths
from tirefilter.viz.blueprint import (BODY, ESTIMATE, POSTERIOR_BAND, SPREAD_BAND, STATE_NAMES, STEER, TRUTH, Z90,
                                      Layout, build_blueprint, layout_json, overview_scale)
from tirefilter.viz.density import ComponentCache, grid_quantiles, stiffness_mixture, window_grid
from tirefilter.viz.options import RecordingContext, RecordingOptions
from tirefilter.viz.paths import TIMELINE, entity_path
from tirefilter.viz.units import DEG, scale, unit

LIVE_FLUSH_TIMEOUT = 10.0  # s, the end of a run waits this long for a viewer to take the rest
CLOSE_UP_HALF_SIZE = 15.0  # m: the close-up's camera frames a square of twice this around the car
ARROW_LENGTH = 12.0  # m: heading and velocity arrows
BETA_GAIN = 10.0  # the velocity arrows are drawn at this many times beta to the heading (a few degrees: else unseen)
STARTUP_S = 5.0  # s: the y ranges fit the data from this long after the first row
DENSITY_REACH = 4.0  # the density snapshot shows the posterior over its mean -+ this many std
MIN_WINDOW = 1e-4  # ... and at least -+ this share of the mean
QUANTILES = (0.05, 0.95)  # the density views' and the quantiles tab's band
SETTLED_LIMIT = 100_000  # values kept per view for its y range (thinned by 2 beyond)
BIAS_NOTE = ("**Bias not estimated.** This estimator takes the IMU as unbiased: its bias prior "
             "(`bias0_std`) and random walk (`bias_rw`) are zero, as in the stiffness paper's Sec. VI. "
             "Its `b_ax`, `b_ay`, `b_yaw_rate` columns are that zero, not an estimate; the true "
             "biases are `/truth/b_<sensor>` (drawn here when they are not zero).")
CX_NOTE = ("**Cx not excited on this drive.** The largest excitation weight of Cx was {w:.2f} of 1 "
           "(below {limit:g}: `metrics.CX_EXCITED`; derivations, \"The undriven axle\"). The wheel "
           "slip never carried information about Cx, so its estimate is the prior, not learned; "
           "its narrow band is the prior's, and its error says nothing about the filter.")


class _Samples:
    """Values of one view after the start-up, thinned by 2 (every other one kept from then
    on) whenever more than SETTLED_LIMIT are held: the quantiles of a long run from about
    SETTLED_LIMIT evenly spread values."""

    def __init__(self):
        self.parts: list[np.ndarray] = []
        self.n, self.stride, self.phase = 0, 1, 0

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x, float).ravel()
        if self.stride > 1:
            keep = np.arange(self.phase, len(x), self.stride)
            self.phase = (self.phase - len(x)) % self.stride
            x = x[keep]
        x = x[np.isfinite(x)]
        self.parts.append(x)
        self.n += len(x)
        if self.n > SETTLED_LIMIT:
            v = np.concatenate(self.parts)[::2]
            self.parts, self.n, self.stride = [v], len(v), 2 * self.stride

    def values(self) -> np.ndarray:
        return np.concatenate(self.parts) if self.parts else np.zeros(0)


def robust_range(x: np.ndarray) -> tuple[float, float] | None:
    """The y range of a view from its settled data: the 0.5 .. 99.5 % quantiles widened by 15 %
    of their span (at least 5 % of their mid value) on each side, then out to multiples of the
    power of ten P below that span where this at most doubles it (`snap_range`); None without
    a span."""
    x = x[np.isfinite(x)]
    if x.size < 2:
        return None
    lo, hi = np.quantile(x, [0.005, 0.995])
    pad = max(0.15 * (hi - lo), 0.05 * abs(0.5 * (lo + hi)))
    return snap_range(float(lo - pad), float(hi + pad)) if pad > 0 else None


def snap_range(lo: float, hi: float) -> tuple[float, float]:
    """(lo, hi) widened out to multiples of P = 10^floor(log10(hi - lo)), unless that more than
    doubles it. Rerun's plots label their y axis at powers of ten only: a range of 105 .. 290
    showed the single label 200, -0.55 .. 0.5 only 0; 100 .. 300 and -1 .. 1 show three."""
    p = 10.0 ** math.floor(math.log10(hi - lo))
    a, b = math.floor(lo / p) * p, math.ceil(hi / p) * p
    return (a, b) if b - a <= 2 * (hi - lo) else (lo, hi)


def _view_columns(columns) -> dict[str, tuple[str, ...]]:
    """Per view key of `build_blueprint`, the Result-CSV columns its y range fits."""
    out = {p: (p, f"true_{p}_mean") for p in paths.STIFFNESS}
    out.update({"vx": ("vx", "true_vx", "meas_vx"), "vy": ("vy", "true_vy"), "beta": ("beta", "true_beta"),
                "yaw_rate": ("yaw_rate", "true_yaw_rate", "meas_yaw_rate")})
    out.update({f"b_{s}": (f"b_{s}", f"true_b_{s}") for s in paths.SENSORS})
    return {k: tuple(c for c in cols if c in columns) for k, cols in out.items() if any(c in columns for c in cols)}


class RerunRecorder:
    """Records one run. `target` is a RecordingOptions, or the path of an .rrd file. A sink of
    the run loop (`runs.Run`): `stepped(estimator, est)`, then `write(row)`, per sample; `close()`."""

    def __init__(self, target, columns: tuple[str, ...], estimator: str | None, *,
                 application_id: str = "tirefilter", recording_id: str | None = None, chunk: int | None = None,
                 context: RecordingContext | None = None):
        import rerun as rr

        self._rr = rr
        opts = target if isinstance(target, RecordingOptions) else RecordingOptions(rrd=target)
        self.options = opts.validated()
        self.path = Path(opts.rrd) if opts.rrd else None
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        self._open_sinks()
        self.estimator = estimator
        self.context = context or RecordingContext()
        self.columns = tuple(columns)
        self._col = {c: j for j, c in enumerate(self.columns)}
        self._paths = [entity_path(c, estimator) for c in self.columns]
        self._scales = np.array([scale(c) for c in self.columns])
        self._t_index = self.columns.index("t")
        self._truth = "true_x" in self._col and "true_y" in self._col
        self._references = tuple(s for s in paths.STATES if f"true_{s}" in self._col)  # a log's references
        self._t0: float | None = None
        self._views = _view_columns(self._col)
        self._settled: dict[str, _Samples] = {}  # per view key: its values after the start-up
        self._rows: list[np.ndarray] = []
        # rows per bulk send: large for a file, small when a viewer watches live (0.5 s at 100 Hz)
        self._chunk = chunk or (50 if opts.spawn or opts.connect else 1000)
        self._bounds = [math.inf, -math.inf, math.inf, -math.inf]  # x0, x1, y0, y1 of the path
        self._path_parts: list[np.ndarray] = []
        self._biased: set[str] = set()  # channels whose true bias is not zero somewhere
        self._pending = None  # (estimator, Estimate) of the step whose row comes next
        self._last_estimator = None
        self._steps = 0
        self._layout: Layout | None = None
        self._ess_lines: tuple[float, float | None] | None = None  # N, resampling threshold
        self._caches: dict[str, ComponentCache] = {}  # per parameter: density rows of unchanged components
        self._scale_logged: set[str] = set()  # clouds whose weight colour scale is drawn
        self._dead_reckoning = (0.0, 0.0, 0.0, None)  # x, y, psi, t of the last row (replay)
        self._lf = None
        self.snapshots = 0
        if estimator is None:
            self._send_layout(Layout(None, truth=self._truth, references=self._references))

    # ---- sinks and layout ---------------------------------------------------------------
    def _open_sinks(self) -> None:
        rr, opts = self._rr, self.options
        sinks = []
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.path)))
        if opts.spawn:
            _spawn_viewer(opts.spawn_port)
            sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{opts.spawn_port}/proxy"))
        if opts.connect and not (opts.spawn and opts.connect.rstrip("/") == f"rerun+http://127.0.0.1:{opts.spawn_port}"
                                                                              "/proxy"):
            _check_listening(str(opts.connect))
            sinks.append(rr.GrpcSink(str(opts.connect)))
        self.rec.set_sinks(*sinks)

    def _send_layout(self, layout: Layout) -> None:
        """Decide the layout and send it to every sink now, before the data (a viewer that
        opens the file or watches the stream shows it from the first row on)."""
        self._layout = layout
        self._log_vehicle_drawing()
        if layout.estimator and not layout.bias_estimated:
            self.rec.log(paths.note(layout.estimator, "bias"),
                         self._rr.TextDocument(BIAS_NOTE, media_type=self._rr.MediaType.MARKDOWN), static=True)
        self.rec.send_blueprint(build_blueprint(layout), make_active=True, make_default=True)

    def y_ranges(self) -> dict[str, tuple[float, float]]:
        """Per view key (stiffness parameters, states, `b_<sensor>`, `q_<param>`), the y range
        of its plot from the data after the start-up (`robust_range`); `ess` from 0 to 1.05 N,
        `active` (the gate) -0.05 .. 1.05. None for a view without such data."""
        out = {k: r for k, v in self._settled.items() if (r := robust_range(v.values())) is not None}
        if self._ess_lines is not None:
            out["ess"] = (0.0, 1.05 * self._ess_lines[0])
        out["active"] = (-0.05, 1.05)
        return out

    def _log_vehicle_drawing(self) -> None:
        """The car in its body frame (static): outline and filled shape, heading arrow, front wheel, a dot for
        the overview; the close-up's frame and scale bar around its position."""
        rr, log = self._rr, self.rec.log
        v = self.context.vehicle
        lf, lr = (float(v.lf), float(v.lr)) if v is not None else (1.2, 1.6)
        self._lf = lf
        half_w = 0.9
        front, rear = lf + 0.8, -(lr + 0.9)
        outline = [[front, half_w, 0], [rear, half_w, 0], [rear, -half_w, 0], [front, -half_w, 0], [front, half_w, 0]]
        log("/vehicle", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        log(paths.VEHICLE_OUTLINE, rr.LineStrips3D([outline], colors=[BODY], radii=rr.Radius.ui_points(1.5)),
            static=True)
        log(paths.VEHICLE_SHAPE, rr.Boxes3D(mins=[[rear, -half_w, -0.01]], sizes=[[front - rear, 2 * half_w, 0.01]],
                                            colors=[(*POSTERIOR_BAND, 160)], fill_mode="solid"), static=True)
        log(paths.VEHICLE_HEADING, rr.Arrows3D(vectors=[[ARROW_LENGTH, 0, 0]], colors=[SPREAD_BAND],
                                               radii=rr.Radius.ui_points(1.5)), static=True)
        log(paths.VEHICLE_STEER, rr.Arrows3D(origins=[[-0.35, 0, 0]], vectors=[[0.7, 0, 0]], colors=[STEER],
                                             radii=[0.08]), static=True)
        log(paths.VEHICLE_MARKER, rr.Points3D([[0, 0, 0]], colors=[ESTIMATE], radii=rr.Radius.ui_points(5.0)),
            static=True)
        for path, color in ((paths.VEHICLE_VELOCITY, TRUTH), (paths.VEHICLE_VELOCITY_ESTIMATE, ESTIMATE)):
            log(path, rr.Arrows3D.from_fields(colors=[color], radii=rr.Radius.ui_points(1.5)), static=True)
        log(paths.VEHICLE_TRAIL, rr.Points3D.from_fields(colors=[POSTERIOR_BAND], radii=rr.Radius.ui_points(1.5)),
            static=True)
        # the close-up's camera follows this square (it does not turn with the car), and frames it
        f = CLOSE_UP_HALF_SIZE
        log(paths.VEHICLE_FRAME, rr.LineStrips3D([[[f, f, 0], [-f, f, 0], [-f, -f, 0], [f, -f, 0], [f, f, 0]]],
                                                 colors=[(225, 225, 225)]), static=True)
        # 10 m along the screen's right (-y, the camera looks down with x up) at its lower left
        x0, y0 = -0.85 * f, 0.85 * f
        log(paths.VEHICLE_CLOSE_SCALE, rr.LineStrips3D(
            [[[x0, y0, 0], [x0, y0 - 10.0, 0]], [[x0 - 0.6, y0, 0], [x0 + 0.6, y0, 0]],
             [[x0 - 0.6, y0 - 10.0, 0], [x0 + 0.6, y0 - 10.0, 0]]], colors=[TRUTH], radii=rr.Radius.ui_points(1.5)),
            static=True)
        log(f"{paths.VEHICLE_CLOSE_SCALE}/label", rr.Points3D([[x0 + 1.6, y0 - 5.0, 0]], labels=["10 m"],
                                                              colors=[TRUTH], radii=[0.01], show_labels=True),
            static=True)

    def _layout_for(self, estimator, est, mixture, post) -> Layout:
        params = tuple(getattr(estimator, "params", ())) or (mixture.params if mixture is not None else ())
        if not params and est is not None:
            params = tuple(p for p in ("Cx", "Cf_y", "Cr_y") if math.isfinite(getattr(est, p, math.nan)))
        order = tuple(p for p in ("Cx", "Cf_y", "Cr_y") if p in params)
        particles = post is not None and len(post.log_weights) > 1
        cfg = getattr(estimator, "cfg", None)
        if particles:
            n = float(len(post.log_weights))
            threshold = getattr(cfg, "resample_threshold", None)
            self._ess_lines = (n, None if threshold is None else float(threshold) * n)
        return Layout(self.estimator, params=order, lateral="Cx" not in order,
                      clouds=particles, references=self._references,
                      densities=tuple(p for p in order if mixture is not None and p in mixture.params),
                      friction=callable(getattr(estimator, "friction", None)), truth=self._truth,
                      sensors=tuple(s for s in paths.SENSORS if est is None or math.isfinite(getattr(est, f"b_{s}",
                                                                                                     math.nan))),
                      bias_estimated=bool(getattr(estimator, "bias_on", True)), ess_lines=particles)

    # ---- per step -------------------------------------------------------------------------
    def stepped(self, estimator, est) -> None:
        """The estimator has just stepped; its row follows (`write`)."""
        self._pending = (estimator, est)

    def write(self, values) -> None:
        """A Result-CSV row (as a sink of the run loop, `runs.Run`)."""
        row = np.asarray(values, dtype=float)
        self._rows.append(row)
        if self._t0 is None:
            self._t0 = float(row[self._t_index])
        if self._pending is not None:
            estimator, est = self._pending
            self._pending = None
            self._last_estimator = estimator
            if self._steps % self.options.log_every == 0:
                self._snapshot(row, estimator, est)
            self._steps += 1
        if len(self._rows) >= self._chunk:
            self.flush()

    def _snapshot(self, row: np.ndarray, estimator, est) -> None:
        post = _posterior(estimator)
        mixture = stiffness_mixture(post, est, params=getattr(estimator, "params", None),
                                    gaussian=getattr(estimator, "posterior_family", None) == "gaussian")
        if self._layout is None:
            self._send_layout(self._layout_for(estimator, est, mixture, post))
        layout = self._layout
        t = float(row[self._t_index])
        self.rec.set_time(TIMELINE, duration=t)
        if layout.clouds and mixture is not None:
            names = [p for p in layout.params if p in mixture.params]
            if len(names) in (2, 3):
                pts = mixture.loc[:, [mixture.index(p) for p in names]] * np.array([scale(p) for p in names])
                with np.errstate(divide="ignore"):
                    self._log_cloud("stiffness", pts, [f"{p} [{unit(p)}]" for p in names], np.log(mixture.weights))
        if post is not None and len(post.log_weights) > 1:
            x = np.asarray(post.particles, float)
            stats = post.stats or {}
            if "mu" in stats and "var" in stats and "gamma" not in stats and x.ndim == 2:  # AUGPF: [x, m, s2]
                x = x[:, :x.shape[1] - np.shape(stats["mu"])[-1] - np.shape(stats["var"])[-1]]
            if x.ndim == 2 and x.shape[1] in (2, 3):
                states = ("vx", "vy", "yaw_rate")[3 - x.shape[1]:]
                self._log_cloud("state", x, [f"{STATE_NAMES[s]} [{unit(s)}]" for s in states], post.log_weights)
        if mixture is not None:
            for p in layout.densities:
                self._log_density(p, mixture, row, t)
        if layout.friction:
            self._log_friction(estimator.friction(), row)
        self.snapshots += 1

    def _log_cloud(self, what: str, pts: np.ndarray, names: list[str], log_weights) -> None:
        """A cloud in physical units with the transform to its normalised frame, and its
        axes, tick labels and weight colour scale in that frame (`viz.clouds`)."""
        rr, e = self._rr, self.estimator
        d = pts.shape[1]
        frame = clouds.normalising(pts)
        translation, scale3 = clouds.transform(frame)
        points, strips = (rr.Points2D, rr.LineStrips2D) if d == 2 else (rr.Points3D, rr.LineStrips3D)
        self.rec.log(paths.particles(e, what),
                     points(pts, colors=clouds.weight_colors(log_weights), radii=rr.Radius.ui_points(2.5)),
                     rr.Transform3D(translation=translation, scale=scale3))
        ax = clouds.axes(frame, tuple(names))
        base = paths.particle_axes(e, what)
        self.rec.log(base, strips(ax.strips, colors=[clouds.AXIS_COLOR], radii=rr.Radius.ui_points(0.75)))
        self.rec.log(f"{base}/labels", points(ax.label_positions, labels=ax.labels, colors=[clouds.AXIS_COLOR],
                                              radii=rr.Radius.ui_points(0.5), show_labels=True))
        if what not in self._scale_logged:
            self._scale_logged.add(what)
            pos, colors, label_pos, labels = clouds.weight_scale(d)
            self.rec.log(f"{base}/weight_scale", points(pos, colors=colors, radii=rr.Radius.ui_points(4.0)),
                         static=True)
            self.rec.log(f"{base}/weight_scale/labels", points(label_pos, labels=labels, colors=[clouds.AXIS_COLOR],
                                                               radii=rr.Radius.ui_points(0.5), show_labels=True),
                         static=True)

    def _log_density(self, p: str, mixture, row: np.ndarray, t: float) -> None:
        """The density of `p` over its mean -+ DENSITY_REACH std (at least -+ MIN_WINDOW of the
        mean; per recorded unit: kN/rad,
        kN/unit slip), the exact mass of that window, the true mean as a bar as high as the
        density's peak, and the 5 % and 95 % quantiles."""
        rr, e = self._rr, self.estimator
        m, s = mixture.mean(p), mixture.std(p)
        if not (s > 0 and math.isfinite(s) and math.isfinite(m)):
            return
        # a collapsed posterior (one distinct particle) still gets a window that float32 resolves
        grid = window_grid(m, max(s, MIN_WINDOW * abs(m) / DENSITY_REACH), DENSITY_REACH, self.options.density_points)
        if mixture.kind == "kde":  # a kernel narrower than the grid spacing would fall between its points
            j = mixture.index(p)
            widths = mixture.scale.copy()
            widths[:, j] = np.maximum(widths[:, j], grid[1] - grid[0])
            mixture = dataclasses.replace(mixture, scale=widths)
        k = scale(p)
        values = mixture.pdf(p, grid, self._caches.setdefault(p, ComponentCache())) / k
        step = (grid[1] - grid[0]) * k
        self.rec.log(paths.density(e, p), rr.BarChart(values.astype(np.float32), abscissa=grid * k,
                                                      widths=np.full(grid.size, step, np.float32), color=ESTIMATE))
        self.rec.log(paths.density_mass(e, p), rr.Scalars(mixture.mass(p, grid[0], grid[-1])))
        j = self._col.get(f"true_{p}_mean")
        truth = float(row[j]) * k if j is not None else math.nan
        if math.isfinite(truth):
            self.rec.log(paths.density_truth(e, p), rr.BarChart(np.array([values.max()], np.float32),
                                                                abscissa=np.array([truth]),
                                                                widths=np.array([2 * step], np.float32), color=TRUTH))
        # to 1e-6 of the std: below what the recording's float32 resolves at the mean (6e-8 of it)
        q = mixture.quantiles(p, QUANTILES, start=grid_quantiles(mixture, p, grid, values * k, QUANTILES),
                              rtol=1e-6) * k
        for which, v in zip(("q05", "q95"), q):
            self.rec.log(paths.density_quantile(e, p, which), rr.Scalars(float(v)))
        if self._t0 is not None and t >= self._t0 + STARTUP_S:
            self._settled.setdefault(f"q_{p}", _Samples()).add(np.append(q, truth))

    def _log_friction(self, curve, row: np.ndarray) -> None:
        """Per axle: the posterior mean mu(alpha), its 90 % band, the visited slip range, and
        the true curve at the current surface (co-simulation)."""
        if curve is None:
            return
        rr, e = self._rr, self.estimator
        alpha = np.asarray(curve.alpha, float)
        visited = np.asarray(curve.visited, float).reshape(2, 2)
        z = np.zeros_like(alpha)
        axles = (("front", curve.mu_f, curve.mu_f_std), ("rear", curve.mu_r, curve.mu_r_std))
        for k, (axle, mu, std) in enumerate(axles):
            mu, std = np.asarray(mu, float), np.asarray(std, float)
            self.rec.log(paths.friction(e, axle), rr.LineStrips3D([np.stack([alpha, mu, z], 1)], colors=[ESTIMATE],
                                                                  radii=rr.Radius.ui_points(1.5)))
            self.rec.log(paths.friction(e, axle, "band"),
                         rr.LineStrips3D([np.stack([alpha, mu - Z90 * std, z], 1),
                                          np.stack([alpha, mu + Z90 * std, z], 1)],
                                         colors=[POSTERIOR_BAND], radii=rr.Radius.ui_points(1.0)))
            lo, hi = visited[k]
            if math.isfinite(lo) and math.isfinite(hi):
                finite = np.isfinite(mu)
                top = float(np.max(np.abs(mu[finite]) + 2 * np.nan_to_num(std[finite]))) if finite.any() else 1.0
                self.rec.log(paths.friction(e, axle, "visited"),
                             rr.LineStrips3D([[[lo, -top, 0], [lo, top, 0]], [[hi, -top, 0], [hi, top, 0]]],
                                             colors=[SPREAD_BAND], radii=rr.Radius.ui_points(1.0)))
            if self.context.friction_truth is not None:
                j = self._col.get("true_surface")
                surface = float(row[j]) if j is not None and math.isfinite(row[j]) else 1.0
                true_mu = np.asarray(self.context.friction_truth(alpha, surface)[k], float)
                self.rec.log(paths.truth_friction(axle), rr.LineStrips3D(
                    [np.stack([alpha, true_mu, z], 1)], colors=[TRUTH], radii=rr.Radius.ui_points(1.5)))

    # ---- bulk series ---------------------------------------------------------------------
    def flush(self) -> None:
        if not self._rows:
            return
        data = np.vstack(self._rows)
        self._rows.clear()
        t = data[:, self._t_index]
        after = t >= self._t0 + STARTUP_S
        if after.any():
            for key, cols in self._views.items():
                self._settled.setdefault(key, _Samples()).add(
                    np.concatenate([data[after, self._col[c]] * scale(c) for c in cols]))
        for s in paths.SENSORS:
            j = self._col.get(f"true_b_{s}")
            if j is not None and np.any(np.abs(np.nan_to_num(data[:, j])) > 0):
                self._biased.add(s)
        for j, path in enumerate(self._paths):
            if path is not None:
                self._send_scalars(path, t, data[:, j] * self._scales[j])
        if self.estimator is not None:
            if self._layout is None:  # rows without estimator steps (the estimator FMU): layout from the columns
                params = tuple(p for p in ("Cx", "Cf_y", "Cr_y")
                               if p in self._col and np.isfinite(data[:, self._col[p]]).any())
                self._send_layout(Layout(self.estimator, params=params, lateral="Cx" not in params, truth=self._truth,
                                         references=self._references))
            for p in paths.STIFFNESS:
                if p not in self._col:
                    continue
                c = data[:, self._col[p]] * scale(p)
                for which, col in (("posterior", f"{p}_std"), ("spread", f"{p}_sigma")):
                    if col in self._col:
                        s = data[:, self._col[col]] * scale(p)
                        self._send_scalars(paths.stiffness_band(self.estimator, p, f"{which}_lower"), t, c - Z90 * s)
                        self._send_scalars(paths.stiffness_band(self.estimator, p, f"{which}_upper"), t, c + Z90 * s)
            if self._ess_lines is not None and "ess" in self._col:
                n, threshold = self._ess_lines
                self._send_scalars(paths.ess_line(self.estimator, "particles"), t, np.full(t.shape, n))
                if threshold is not None:
                    self._send_scalars(paths.ess_line(self.estimator, "threshold"), t, np.full(t.shape, threshold))
        self._send_pose(data, t)

    def _send_scalars(self, path: str, t: np.ndarray, column: np.ndarray) -> None:
        rr = self._rr
        keep = ~np.isnan(column)
        if not keep.any():
            return
        if not keep.all():
            t, column = t[keep], column[keep]
        self.rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                              columns=rr.Scalars.columns(scalars=column))

    def _send_pose(self, data: np.ndarray, t: np.ndarray) -> None:
        """Vehicle pose per row (transform of /vehicle/body, of /vehicle/position without the
        heading, steer angle of the front wheel, trail point) and the velocity directions:
        the true pose and velocity in co-simulation; in replay, dead reckoning of the
        estimated (else measured) speed and yaw rate, and the estimated velocity."""
        rr = self._rr
        col = self._col
        if self._truth:
            x, y = data[:, col["true_x"]], data[:, col["true_y"]]
            psi = data[:, col["true_psi"]] if "true_psi" in col else np.zeros_like(x)
        else:
            x, y, psi = self._dead_reckon(data, t)
            if x is None:
                return
        steer = next((data[:, col[c]] for c in ("true_delta", "meas_delta") if c in col), np.zeros_like(x))
        steer = np.nan_to_num(steer)
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(psi)
        if not ok.any():
            return
        self._path_parts.append(np.stack([x[ok], y[ok]], 1))
        self._bounds = [min(self._bounds[0], float(x[ok].min())), max(self._bounds[1], float(x[ok].max())),
                        min(self._bounds[2], float(y[ok].min())), max(self._bounds[3], float(y[ok].max()))]
        rows = data[ok]
        x, y, psi, steer, tt = x[ok], y[ok], psi[ok], steer[ok], t[ok]
        times = [rr.TimeColumn(TIMELINE, duration=tt)]
        pos = np.stack([x, y, np.zeros_like(x)], 1)
        self.rec.send_columns(paths.VEHICLE_BODY, indexes=times,
                              columns=rr.Transform3D.columns(translation=pos, quaternion=_yaw_quaternion(psi)))
        self.rec.send_columns(paths.VEHICLE_POSITION, indexes=times, columns=rr.Transform3D.columns(translation=pos))
        lf = np.broadcast_to([self._lf or 1.2, 0.0, 0.0], pos.shape)
        self.rec.send_columns(paths.VEHICLE_STEER, indexes=times,
                              columns=rr.Transform3D.columns(translation=lf, quaternion=_yaw_quaternion(steer)))
        self.rec.send_columns(paths.VEHICLE_TRAIL, indexes=times, columns=rr.Points3D.columns(positions=pos))
        self._send_velocities(rows, tt)

    def _send_velocities(self, rows: np.ndarray, t: np.ndarray) -> None:
        """Per row, the direction of the true (black) and the estimated (blue) velocity in the
        body frame, ARROW_LENGTH long from the centre of gravity like the heading arrow, at
        BETA_GAIN times the sideslip beta = atan2(vy, vx) to it (beta is a few degrees: drawn as
        it is, the arrows would lie on the heading). One label per row says so and gives both
        angles in degrees (on the true arrow; on the estimated one in replay)."""
        rr, col = self._rr, self._col
        nan = np.full(len(rows), np.nan)

        def angle(vx: str, vy: str) -> np.ndarray:
            return np.arctan2(rows[:, col[vy]], rows[:, col[vx]]) if vx in col and vy in col else nan

        true_beta, est_beta = angle("true_vx", "true_vy"), angle("vx", "vy")
        labels = [", ".join(([f"{b:+.1f}° true (black)"] if math.isfinite(b) else []) +
                            ([f"{c:+.1f}° est. (blue)"] if math.isfinite(c) else []))
                  for b, c in zip(true_beta * DEG, est_beta * DEG)]
        labels = np.array([f"beta, drawn x{BETA_GAIN:g}: " + x if x else "" for x in labels], dtype=object)
        labelled = paths.VEHICLE_VELOCITY if np.isfinite(true_beta).any() else paths.VEHICLE_VELOCITY_ESTIMATE
        for path, beta in ((paths.VEHICLE_VELOCITY, true_beta), (paths.VEHICLE_VELOCITY_ESTIMATE, est_beta)):
            keep = np.isfinite(beta)
            if not keep.any():
                continue
            drawn = BETA_GAIN * beta
            vectors = ARROW_LENGTH * np.stack([np.cos(drawn), np.sin(drawn), np.zeros_like(beta)], 1)[keep]
            self.rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t[keep])],
                                  columns=rr.Arrows3D.columns(vectors=vectors,
                                                              labels=list(labels[keep]) if path == labelled else None))

    def _dead_reckon(self, data: np.ndarray, t: np.ndarray):
        col = self._col

        def first(*names):
            for n in names:
                if n in col and np.isfinite(data[:, col[n]]).any():
                    return np.nan_to_num(data[:, col[n]])
            return None

        vx, r = first("vx", "meas_vx"), first("yaw_rate", "meas_yaw_rate")
        if vx is None or r is None:
            return None, None, None
        vy = first("vy")
        vy = np.zeros_like(vx) if vy is None else vy
        x0, y0, psi0, t0 = self._dead_reckoning
        dt = np.diff(np.concatenate([[t[0] if t0 is None else t0], t]))
        psi = psi0 + np.cumsum(r * dt)  # Euler, rate held over the interval before each sample
        x = x0 + np.cumsum((vx * np.cos(psi) - vy * np.sin(psi)) * dt)
        y = y0 + np.cumsum((vx * np.sin(psi) + vy * np.cos(psi)) * dt)
        self._dead_reckoning = (float(x[-1]), float(y[-1]), float(psi[-1]), float(t[-1]))
        return x, y, psi

    def final_layout(self) -> Layout:
        """The layout with what the end of the run knows: the channels with a true bias, whether
        Cx was excited (the estimator's `cx_weight_max` against `metrics.CX_EXCITED`), the
        bounding box of the path."""
        from tirefilter.metrics import CX_EXCITED

        layout = self._layout
        w = getattr(self._last_estimator, "cx_weight_max", None)
        excited = None if w is None or "Cx" not in layout.params else bool(w >= CX_EXCITED)
        bounds = tuple(self._bounds) if math.isfinite(self._bounds[0]) else None
        return dataclasses.replace(layout, true_bias=tuple(s for s in paths.SENSORS if s in self._biased),
                                   cx_excited=excited, path_bounds=bounds)

    def close(self) -> None:
        self.flush()
        if self._layout is None:
            self._send_layout(Layout(self.estimator, truth=self._truth, references=self._references))
        final = self.final_layout()
        rr = self._rr
        if self._path_parts:
            path = np.vstack(self._path_parts)
            path3 = np.column_stack([path, np.zeros(len(path))])  # 3-D: the top view is a 3-D view
            self.rec.log(paths.VEHICLE_PATH, rr.LineStrips3D([path3], colors=[SPREAD_BAND],
                                                              radii=rr.Radius.ui_points(1.0)), static=True)
        if final.path_bounds is not None:
            strips, label_at, label = overview_scale(final.path_bounds)
            self.rec.log(paths.VEHICLE_SCALE, rr.LineStrips3D(strips, colors=[TRUTH], radii=rr.Radius.ui_points(1.5)),
                         static=True)
            self.rec.log(f"{paths.VEHICLE_SCALE}/label", rr.Points3D([label_at], labels=[label], colors=[TRUTH],
                                                                     radii=[0.01], show_labels=True), static=True)
        if final.cx_excited is False:
            from tirefilter.metrics import CX_EXCITED

            text = CX_NOTE.format(w=float(self._last_estimator.cx_weight_max), limit=CX_EXCITED)
            self.rec.log(paths.note(self.estimator, "Cx"), rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN),
                         static=True)
        self._layout = final
        ranges = self.y_ranges()
        self.rec.send_property("tirefilter", rr.AnyValues(layout=layout_json(final, ranges)))
        self.rec.send_blueprint(build_blueprint(final, y_ranges=ranges), make_active=True, make_default=True)
        live = self.options.spawn or self.options.connect
        try:
            # a viewer that went away must not hang the end of the run (the file sink is flushed too)
            self.rec.flush(timeout_sec=LIVE_FLUSH_TIMEOUT) if live else self.rec.flush()
        except RuntimeError as exc:
            print(f"warning: the Rerun stream did not complete: {exc}", file=sys.stderr)
        self.rec.disconnect()


def _listening(host: str, port: int, timeout: float = 0.5) -> bool:
    try:
        socket.create_connection((host, port), timeout=timeout).close()
        return True
    except OSError:
        return False


def _spawn_viewer(port: int, wait: float = 20.0) -> None:
    """Start the Rerun viewer of rerun-sdk listening on 127.0.0.1:`port` (detached: it
    outlives the run), unless one already listens there; wait until it accepts
    connections. (rerun.spawn would let its gRPC server listen on every interface.)"""
    import subprocess
    import time

    if _listening("127.0.0.1", port):
        return
    exe = _bundled_viewer() or shutil.which("rerun")
    if exe is None:
        raise ConfigError("--spawn", "", "no Rerun viewer found (rerun-sdk's rerun_cli, or `rerun` on PATH)")
    viewer = subprocess.Popen([exe, "--bind", "127.0.0.1", "--port", str(port), "--expect-data-soon"],
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    deadline = time.monotonic() + wait
    while not _listening("127.0.0.1", port):
        if viewer.poll() is not None:
            raise ConfigError("--spawn", "", f"the Rerun viewer ({exe}) exited with status {viewer.returncode} "
                              "before it listened (no display? use --rrd and open the file later)")
        if time.monotonic() > deadline:
            raise ConfigError("--spawn", "", f"the Rerun viewer ({exe}) did not listen on 127.0.0.1:{port} "
                              f"within {wait:g} s")
        time.sleep(0.1)


def _check_listening(url: str, timeout: float = 2.0) -> None:
    """A clear error before the run when nothing listens at a --connect URL (rerun-sdk
    would buffer the recording in memory and retry in the background)."""
    parsed = urlparse(url.replace("rerun+", "", 1).replace("rerun://", "https://", 1))
    if parsed.hostname is None or parsed.port is None:
        return
    try:
        socket.create_connection((parsed.hostname, parsed.port), timeout=timeout).close()
    except OSError as exc:
        raise ConfigError("--connect", url, f"nothing accepts connections at {parsed.hostname}:{parsed.port} "
                          f"({exc.strerror or exc}); start a viewer first (`.venv/bin/rerun`) or use --spawn") from None


def _yaw_quaternion(angle: np.ndarray) -> np.ndarray:
    """(n, 4) quaternions xyzw of rotations by `angle` about +z."""
    q = np.zeros((len(angle), 4))
    q[:, 2], q[:, 3] = np.sin(0.5 * angle), np.cos(0.5 * angle)
    return q


def _posterior(estimator):
    """estimator.posterior(), or None where the estimator has none (or no particles)."""
    get = getattr(estimator, "posterior", None)
    if not callable(get):
        return None
    try:
        post = get()
    except NotImplementedError:
        return None
    if post is None or getattr(post, "log_weights", None) is None or len(post.log_weights) == 0:
        return None
    return post


def _bundled_viewer() -> str | None:
    """The viewer binary shipped with rerun-sdk (rerun_cli), so --spawn works without the
    venv's bin/ on PATH."""
    try:
        import rerun_cli
    except ImportError:
        return None
    exe = Path(rerun_cli.__file__).with_name("rerun")
    return str(exe) if exe.is_file() else None
