"""Rerun recordings of a run: truth, sensors, vehicle pose, estimate series, and the
estimator's posterior (particle clouds, stiffness densities, friction curves).

Result-CSV rows are buffered and sent in bulk with `send_columns` every `chunk` rows and
at close, so the series cost little per step and a run that fails keeps what was sent.
At every `log_every`-th estimator step the posterior is logged as well (`_snapshot`):
per-particle stiffness means and state particles coloured by weight, the posterior
density of each stiffness parameter on a fixed grid (eq. (26), `viz.density`), and the
friction curves of estimators that have `friction()`.

The recording goes to any of: an .rrd file, a viewer spawned here, a viewer or gRPC proxy
at a URL (`RecordingOptions`). The layout (`viz.blueprint`) is decided once the recorder
knows what the estimator provides (its first step) and sent at the end with the y ranges of
the stiffness plots fitted to the data after the start-up (STARTUP_S); a viewer that
watches live also gets it at the first step, without the ranges.

Entity paths: `viz.paths` and the table of docs/rerun.md.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import socket
import sys
import warnings
from pathlib import Path
from urllib.parse import urlparse

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.viz import paths
from tirefilter.viz.blueprint import ESTIMATE, POSTERIOR_BAND, SPREAD_BAND, TRUTH, TRUTH_STEP, Layout, build_blueprint
from tirefilter.viz.density import ComponentCache, stiffness_grid, stiffness_mixture
from tirefilter.viz.options import RecordingContext, RecordingOptions
from tirefilter.viz.paths import TIMELINE, entity_path

LIVE_FLUSH_TIMEOUT = 10.0  # s, the end of a run waits this long for a viewer to take the rest
HISTORY_SHAPE = (120, 240)  # px (stiffness, time) of a density-history image
FRAME_HALF_SIZE = 25.0  # m
STARTUP_S = 5.0  # s: the stiffness plots' y axes fit the data from this long after the first row
_VIRIDIS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
_VIRIDIS_LUT = np.stack([np.interp(np.linspace(0, len(_VIRIDIS) - 1, 256), np.arange(len(_VIRIDIS)), _VIRIDIS[:, c])
                         for c in range(3)], axis=-1).astype(np.uint8)  # (256, 3)


def weight_colors(log_weights) -> np.ndarray:
    """(N, 3) uint8 colours of particles by normalised weight q / max q (viridis-like:
    dark purple = lightest, yellow = heaviest)."""
    lw = np.asarray(log_weights, float)
    lw = np.where(np.isnan(lw), -np.inf, lw)
    m = np.max(lw) if lw.size else 0.0
    s = np.exp(lw - m) if np.isfinite(m) else np.ones_like(lw)
    x = s * (len(_VIRIDIS) - 1)
    anchors = np.arange(len(_VIRIDIS))
    return np.stack([np.interp(x, anchors, _VIRIDIS[:, c]) for c in range(3)], axis=-1).astype(np.uint8)


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
        self._t_index = self.columns.index("t")
        self._truth = "true_x" in self._col and "true_y" in self._col
        self._references = tuple(s for s in paths.STATES if f"true_{s}" in self._col)  # a log's references
        self._t0: float | None = None
        self._settled: dict[str, list[np.ndarray]] = {}  # per parameter: estimate and true mean after start-up
        self._history: dict[str, list[tuple[float, np.ndarray]]] = {}  # per parameter: (t, density) per snapshot
        self._rows: list[np.ndarray] = []
        # rows per bulk send: large for a file, small when a viewer watches live (0.5 s at 100 Hz)
        self._chunk = chunk or (50 if opts.spawn or opts.connect else 1000)
        self._xy: list[np.ndarray] = []
        self._pending = None  # (estimator, Estimate) of the step whose row comes next
        self._steps = 0
        self._layout: Layout | None = None
        self._grids: dict[str, np.ndarray] = {}
        self._caches: dict[str, ComponentCache] = {}  # per parameter: density rows of unchanged components
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
        """Decide the layout; a live viewer gets it now (the file gets it at the end)."""
        self._layout = layout
        self._log_vehicle_drawing()
        if self.options.spawn or self.options.connect:
            self.rec.send_blueprint(build_blueprint(layout), make_active=True, make_default=True)

    def y_ranges(self) -> dict[str, tuple[float, float]]:
        """Per stiffness parameter, the y range of its plot: the 0.5 .. 99.5 % quantiles of
        the estimate and the true surface mean after the start-up, widened by 15 % (at least
        5 % of the mean) on each side; none for a parameter without such data."""
        out = {}
        for p, chunks in self._settled.items():
            x = np.concatenate(chunks)
            x = x[np.isfinite(x)]
            if x.size < 2:
                continue
            lo, hi = np.quantile(x, [0.005, 0.995])
            pad = max(0.15 * (hi - lo), 0.05 * abs(0.5 * (lo + hi)))
            if pad > 0:
                out[p] = (float(lo - pad), float(hi + pad))
        return out

    def _log_vehicle_drawing(self) -> None:
        """The car in its body frame (static): outline, heading arrow, front wheel."""
        rr, log = self._rr, self.rec.log
        v = self.context.vehicle
        lf, lr = (float(v.lf), float(v.lr)) if v is not None else (1.2, 1.6)
        self._lf = lf
        half_w = 0.9
        front, rear = lf + 0.8, -(lr + 0.9)
        outline = [[front, half_w, 0], [rear, half_w, 0], [rear, -half_w, 0], [front, -half_w, 0], [front, half_w, 0]]
        log("/vehicle", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        log(paths.VEHICLE_OUTLINE, rr.LineStrips3D([outline], colors=[ESTIMATE]), static=True)
        log(paths.VEHICLE_HEADING, rr.Arrows3D(vectors=[[front + 1.5, 0, 0]], colors=[TRUTH]), static=True)
        # the top view's camera follows this square, and frames it: the car with 25 m of its path around it
        f = FRAME_HALF_SIZE
        log(paths.VEHICLE_FRAME, rr.LineStrips3D([[[f, f, 0], [-f, f, 0], [-f, -f, 0], [f, -f, 0], [f, f, 0]]],
                                                 colors=[(225, 225, 225)]), static=True)
        log(paths.VEHICLE_STEER, rr.Arrows3D(origins=[[-0.35, 0, 0]], vectors=[[0.7, 0, 0]], colors=[TRUTH_STEP],
                                             radii=[0.08]), static=True)

    def _layout_for(self, estimator, est, mixture, post) -> Layout:
        params = tuple(getattr(estimator, "params", ())) or (mixture.params if mixture is not None else ())
        if not params and est is not None:
            params = tuple(p for p in ("Cx", "Cf_y", "Cr_y") if math.isfinite(getattr(est, p, math.nan)))
        order = tuple(p for p in ("Cx", "Cf_y", "Cr_y") if p in params)
        particles = post is not None and len(post.log_weights) > 1
        return Layout(self.estimator, params=order, lateral="Cx" not in order,
                      clouds=particles, references=self._references,
                      densities=tuple(p for p in order if mixture is not None and p in mixture.params),
                      friction=callable(getattr(estimator, "friction", None)), truth=self._truth,
                      sensors=tuple(s for s in paths.SENSORS if est is None or math.isfinite(getattr(est, f"b_{s}",
                                                                                                     math.nan))))

    # ---- per step -------------------------------------------------------------------------
    def stepped(self, estimator, est) -> None:
        """The estimator has just stepped; its row follows (`write`)."""
        self._pending = (estimator, est)

    def write(self, values) -> None:
        """A Result-CSV row (as a sink of the run loop, `runs.Run`)."""
        row = np.asarray(values, dtype=float)
        self._rows.append(row)
        if self._pending is not None:
            estimator, est = self._pending
            self._pending = None
            if self._steps % self.options.log_every == 0:
                self._snapshot(row, estimator, est)
            self._steps += 1
        if len(self._rows) >= self._chunk:
            self.flush()

    def _snapshot(self, row: np.ndarray, estimator, est) -> None:
        rr = self._rr
        post = _posterior(estimator)
        mixture = stiffness_mixture(post, est, params=getattr(estimator, "params", None),
                                    gaussian=getattr(estimator, "posterior_family", None) == "gaussian")
        if self._layout is None:
            self._send_layout(self._layout_for(estimator, est, mixture, post))
        layout = self._layout
        e = self.estimator
        self.rec.set_time(TIMELINE, duration=float(row[self._t_index]))
        if layout.clouds and mixture is not None:
            cols = [mixture.index(p) for p in layout.params if p in mixture.params]
            with np.errstate(divide="ignore"):
                colors = weight_colors(np.log(mixture.weights))
            pts = mixture.loc[:, cols]
            arch = rr.Points2D if pts.shape[1] == 2 else rr.Points3D
            if pts.shape[1] in (2, 3):
                self.rec.log(paths.particles(e, "stiffness"), arch(pts, colors=colors, radii=rr.Radius.ui_points(2.5)))
        if post is not None and len(post.log_weights) > 1:
            x = np.asarray(post.particles, float)
            stats = post.stats or {}
            if "mu" in stats and "var" in stats and "gamma" not in stats and x.ndim == 2:  # AUGPF: [x, m, s2]
                x = x[:, :x.shape[1] - np.shape(stats["mu"])[-1] - np.shape(stats["var"])[-1]]
            if x.ndim == 2 and x.shape[1] in (2, 3):
                arch = rr.Points2D if x.shape[1] == 2 else rr.Points3D
                self.rec.log(paths.particles(e, "state"),
                             arch(x, colors=weight_colors(post.log_weights), radii=rr.Radius.ui_points(2.5)))
        if mixture is not None:
            grids = {p: self._grid(p, estimator, mixture, post) for p in layout.densities}
            if mixture.kind == "kde" and grids:  # a kernel narrower than the grid spacing would fall between points
                spacing = np.array([grids[p][1] - grids[p][0] if p in grids else 0.0 for p in mixture.params])
                mixture = dataclasses.replace(mixture, scale=np.maximum(mixture.scale, spacing))
            for p, grid in grids.items():
                values = mixture.pdf(p, grid, self._caches.setdefault(p, ComponentCache())).astype(np.float32)
                self._history.setdefault(p, []).append((float(row[self._t_index]), values))
                self.rec.log(paths.density(e, p), rr.BarChart.from_fields(values=values))
                self.rec.log(paths.density_mass(e, p), rr.Scalars(mixture.mass(p, grid[0], grid[-1])))
        if layout.friction:
            self._log_friction(estimator.friction(), row)
        self.snapshots += 1

    def _grid(self, param: str, estimator, mixture, post) -> np.ndarray:
        """The fixed density grid of `param` (chosen at the first snapshot, then kept):
        [0, 1.2 bound_high] x the reference stiffness of the MPF (its means stay inside the
        projection bounds [bound_low, bound_high] x reference; the margin holds the
        densities of particles at a bound); [0, 3.6] x the nominal (or first) value for
        other estimators."""
        if param in self._grids:
            return self._grids[param]
        names = tuple(getattr(estimator, "params", ()))
        cfg = getattr(estimator, "cfg", None)
        ref = None
        if param in names and getattr(estimator, "C_ref", None) is not None:
            ref = float(np.asarray(estimator.C_ref)[names.index(param)])
        stats = getattr(post, "stats", None) or {}
        if ref is None and "C_nominal" in stats and param in tuple(stats.get("params", ())):
            ref = float(np.asarray(stats["C_nominal"])[tuple(stats["params"]).index(param)])
        if ref is None or not ref > 0:
            ref = abs(mixture.mean(param))
        grid = stiffness_grid(ref, 0.0, 1.2 * getattr(cfg, "bound_high", 3.0), self.options.density_points)
        self._grids[param] = grid
        with warnings.catch_warnings():  # rerun-sdk 0.41 warns about the absent `values` of a partial update
            warnings.simplefilter("ignore")
            self.rec.log(paths.density(self.estimator, param),
                         self._rr.BarChart.from_fields(abscissa=grid.astype(np.float32), color=ESTIMATE,
                                                       # bars as wide as the grid step (the default, 1, is 1 N/rad)
                                                       widths=np.full(grid.size, grid[1] - grid[0], np.float32)),
                         static=True)
        return grid

    def density_history(self) -> dict[str, dict]:
        """Per parameter with densities: the image of all snapshots (`image`: (rows, cols, 3)
        uint8, stiffness increasing upwards, one column per snapshot, each column scaled to
        its own peak and coloured viridis-like), cropped to the stiffness range where some
        snapshot exceeds 1 % of its peak (`range`, N/rad), and the time span (`t`, s)."""
        out = {}
        for p, snaps in self._history.items():
            grid = self._grids.get(p)
            if grid is None or not snaps:
                continue
            d = np.stack([v for _, v in snaps]).astype(float)  # (snapshots, grid)
            peak = d.max(axis=1, keepdims=True)
            d = np.divide(d, peak, out=np.zeros_like(d), where=peak > 0)
            used = np.flatnonzero((d > 0.01).any(axis=0))
            if used.size == 0:
                continue
            lo, hi = max(int(used[0]) - 2, 0), min(int(used[-1]) + 3, grid.size)
            img = _VIRIDIS_LUT[np.clip((d[:, lo:hi] * 255).astype(int), 0, 255)]  # (snapshots, rows, 3)
            img = img.transpose(1, 0, 2)[::-1]
            rows = np.linspace(0, img.shape[0] - 1, HISTORY_SHAPE[0]).round().astype(int)  # nearest neighbour
            cols = np.linspace(0, img.shape[1] - 1, HISTORY_SHAPE[1]).round().astype(int)
            out[p] = {"image": np.ascontiguousarray(img[rows][:, cols]),
                      "range": (float(grid[lo]), float(grid[hi - 1])), "t": (snaps[0][0], snaps[-1][0])}
        return out

    def _log_density_history(self) -> dict[str, tuple[float, float]]:
        ranges = {}
        for p, h in self.density_history().items():
            self.rec.log(paths.density_history(self.estimator, p), self._rr.Image(h["image"]), static=True)
            ranges[p] = h["range"] + h["t"]
        return ranges

    def _log_friction(self, curve, row: np.ndarray) -> None:
        """Per axle: the posterior mean mu(alpha), the +-2 std band, the visited slip range,
        and the true curve at the current surface (co-simulation)."""
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
                         rr.LineStrips3D([np.stack([alpha, mu - 2 * std, z], 1), np.stack([alpha, mu + 2 * std, z], 1)],
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
        rr = self._rr
        data = np.vstack(self._rows)
        self._rows.clear()
        t = data[:, self._t_index]
        if self._t0 is None:
            self._t0 = float(t[0])
        after = t >= self._t0 + STARTUP_S
        if after.any():
            for p in paths.STIFFNESS:
                for c in (p, f"true_{p}_mean"):
                    if c in self._col:
                        self._settled.setdefault(p, []).append(data[after, self._col[c]])
        for j, path in enumerate(self._paths):
            if path is not None:
                self._send_scalars(path, t, data[:, j])
        if self.estimator is not None:
            if self._layout is None:  # rows without estimator steps (the estimator FMU): layout from the columns
                params = tuple(p for p in ("Cx", "Cf_y", "Cr_y")
                               if p in self._col and np.isfinite(data[:, self._col[p]]).any())
                self._send_layout(Layout(self.estimator, params=params, lateral="Cx" not in params, truth=self._truth,
                                         references=self._references))
            for p in paths.STIFFNESS:
                if p not in self._col:
                    continue
                c = data[:, self._col[p]]
                for which, col in (("posterior", f"{p}_std"), ("spread", f"{p}_sigma")):
                    if col in self._col:
                        s = data[:, self._col[col]]
                        self._send_scalars(paths.stiffness_band(self.estimator, p, f"{which}_lower"), t, c - 2 * s)
                        self._send_scalars(paths.stiffness_band(self.estimator, p, f"{which}_upper"), t, c + 2 * s)
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
        """Vehicle pose per row (transform of /vehicle/body, steer angle of the front wheel,
        trail point): the true pose in co-simulation, dead reckoning of the estimated (else
        measured) speed and yaw rate in replay."""
        rr = self._rr
        col = self._col
        if self._truth:
            x, y = data[:, col["true_x"]], data[:, col["true_y"]]
            psi = data[:, col["true_psi"]] if "true_psi" in col else np.zeros_like(x)
        else:
            x, y, psi = self._dead_reckon(data, t)
            if x is None:
                return
        self._xy.append(np.stack([x, y], 1))
        steer = next((data[:, col[c]] for c in ("true_delta", "meas_delta") if c in col), np.zeros_like(x))
        steer = np.nan_to_num(steer)
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(psi)
        if not ok.any():
            return
        x, y, psi, steer, tt = x[ok], y[ok], psi[ok], steer[ok], t[ok]
        times = [rr.TimeColumn(TIMELINE, duration=tt)]
        pos = np.stack([x, y, np.zeros_like(x)], 1)
        self.rec.send_columns(paths.VEHICLE_BODY, indexes=times,
                              columns=rr.Transform3D.columns(translation=pos, quaternion=_yaw_quaternion(psi)))
        lf = np.broadcast_to([self._lf or 1.2, 0.0, 0.0], pos.shape)
        self.rec.send_columns(paths.VEHICLE_STEER, indexes=times,
                              columns=rr.Transform3D.columns(translation=lf, quaternion=_yaw_quaternion(steer)))
        self.rec.send_columns(paths.VEHICLE_TRAIL, indexes=times, columns=rr.Points3D.columns(positions=pos))

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

    def close(self) -> None:
        self.flush()
        if self._layout is None:
            self._send_layout(Layout(self.estimator, truth=self._truth, references=self._references))
        if self._xy:
            path = np.vstack(self._xy)
            path = path[np.all(np.isfinite(path), axis=1)]
            path3 = np.column_stack([path, np.zeros(len(path))])  # 3-D: the top view is a 3-D view
            self.rec.log(paths.VEHICLE_PATH, self._rr.LineStrips3D([path3], colors=[SPREAD_BAND]), static=True)
        self.rec.send_blueprint(build_blueprint(self._layout, y_ranges=self.y_ranges(),
                                                density_history=self._log_density_history()),
                                make_active=True, make_default=True)
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
