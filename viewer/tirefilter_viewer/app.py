"""The viser dashboard: controls, a background run loop, and the live views.

One worker thread owns the run: the page's controls only queue commands (start, pause,
step, restart, open a Result CSV), and the worker carries them out between samples, so a
run is never touched from two threads. It steps the run at the chosen speed (a multiple of
real time, or as fast as it goes) and publishes the views at most PUBLISH_HZ times per
second: the charts, the particle cloud, the vehicle pose and path, the friction curves,
the status line. Any error (a bad file, an estimator exception) ends up in the page's
error box and the server keeps running.
"""

from __future__ import annotations

import math
import queue
import threading
import time
import traceback
from collections import deque
from pathlib import Path

import numpy as np

from tirefilter_viewer.history import History
from tirefilter_viewer.session import LiveRun, Settings, open_result
from tirefilter_viewer.views import (AXIS_SIZE, FRICTION_BANDS, FRICTION_SERIES, PADDING, PATH_SERIES, STIFFNESS, TABS,
                                     UNITS, Chart, axes, charts, cloud_scatter, cloud_series, density_data,
                                     density_series, equal_axes, friction_data, friction_from_csv, friction_truth,
                                     particle_stiffness, path_data, placeholder, tab_notes, y_range)

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
PUBLISH_HZ = 30.0  # the most view updates per second
POSTERIOR_HZ = 4.0  # the most updates per second of the densities and the 2-D clouds (eq. (26) costs)
SPEEDS = ("0.1x", "0.25x", "0.5x", "1x", "2x", "5x", "10x", "max")
# The page at 1600 x 1000: the charts panel docked left takes all the width the controls
# docked right leave, but for the strip of about 120 px that viser keeps for its 3-D canvas
# (it squeezes the controls to keep it); the dashboard draws nothing there.
CHARTS_WIDTH = 1190  # px
CONTROLS_WIDTH = 280  # px
# px per chart, by tab: each tab fits the page's height without scrolling, with its note
CHART_HEIGHT = {"stiffness": 240, "state": 240, "bias, ESS": 215, "densities": 235, "particles": 370, "path": 800,
                "friction": 370}
# Two fixes of viser 1.1's page, run in the browser. (1) Its text inputs (Log CSV, Vehicle TOML,
# Result CSV) render their label without tying it to the input (the label's `for` names an id the
# input does not have), so a screen reader and `get_by_label` find no name for them: each unnamed
# input gets the label beside it (aria-labelledby), whenever the page changes. (2) A chart that
# mounts before its panel has its width can keep the width it measured then (about 50 px) inside a
# panel 1190 px wide: a chart narrower than its box gets its box resized by a pixel and back, which
# makes it measure again. It runs from an image that fails to load (an empty data: URL), as a viser
# HTML element runs no <script>.
PAGE_FIXES = """<img alt="" src="data:," style="display:none" onerror="(() => {
  const name = () => document.querySelectorAll('label[for]').forEach((label) => {
    const row = label.closest('.mantine-Flex-root');
    const input = row && row.querySelector('input:not([type=hidden]), textarea');
    if (!input || input.labels.length || input.getAttribute('aria-labelledby')) return;
    if (!label.id) label.id = 'label-' + label.htmlFor;
    input.setAttribute('aria-labelledby', label.id);
  });
  name();
  new MutationObserver(name).observe(document.body, {childList: true, subtree: true});
  setInterval(() => document.querySelectorAll('.uplot-container').forEach((box) => {
    const plot = box.querySelector('.uplot');
    if (!plot || box.clientWidth < 100 || box.clientWidth - plot.offsetWidth < 30) return;
    box.style.width = (box.clientWidth - 1) + 'px';
    requestAnimationFrame(() => requestAnimationFrame(() => { box.style.width = ''; }));
  }), 300);
})()">"""


def friction_files(results_csv) -> list[Path]:
    """Where the friction CSV of a Result CSV is: RESULT.friction.csv (`replay`), or
    friction.csv next to results.csv (`run --out DIR`)."""
    from tirefilter.io.friction import friction_csv_path

    path = Path(str(results_csv).strip())
    return [friction_csv_path(path)] + ([path.with_name("friction.csv")] if path.name == "results.csv" else [])


def speed_factor(label: str) -> float:
    """'2x' -> 2.0 (times real time); 'max' -> inf."""
    return math.inf if label == "max" else float(label.rstrip("x"))


class Dashboard:
    """The dashboard server; `Dashboard(port=0)` picks a free port (see `url`).

    Binds to 127.0.0.1 unless another `host` is given explicitly.
    """

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, *, settings: Settings | None = None,
                 speed: str = "1x", publish_hz: float = PUBLISH_HZ, verbose: bool = False, data_dir=None):
        import viser

        from tirefilter_viewer.dataroot import DataRoot

        self.data_root = DataRoot(data_dir)  # paths typed in the page stay inside it (default: the working dir)

        if speed not in SPEEDS:
            raise ValueError(f"speed {speed!r} is not one of {', '.join(SPEEDS)}")
        self.server = viser.ViserServer(host=host, port=port, verbose=verbose)
        self.host = host
        self.publish_interval = 1.0 / publish_hz
        self.settings = settings or Settings()
        self._commands: queue.Queue = queue.Queue()
        self._run: LiveRun | None = None
        self._history: History | None = None
        self._source_label = ""
        self._playing = False
        self._state = "idle"
        self._publish_times: deque[float] = deque(maxlen=64)
        self.updates = 0  # views published so far
        self._pace = (time.perf_counter(), 0.0)  # (wall, sim time) the speed is measured from
        self._finished_unshown = False
        self._result_friction = None  # (FrictionCurve, truth) of an opened Result CSV
        self._posterior_shown = -math.inf  # perf_counter of the last density / 2-D cloud update
        self._metrics = ""  # metrics.metrics_line of a finished run or an opened Result CSV
        self._build_gui(speed)
        self._quit = threading.Event()
        self._worker = threading.Thread(target=self._work, name="tirefilter-dashboard", daemon=True)
        self._worker.start()

    # -- public ----------------------------------------------------------------------------------
    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        host = self.host if ":" not in self.host else f"[{self.host}]"
        return f"http://{host}:{self.port}"

    def command(self, name: str, *args) -> None:
        """Queue a command for the worker: start, pause, step, restart, open_result PATH."""
        self._commands.put((name, *args))

    def status(self) -> dict:
        """What the page shows in its status line, as numbers (for tests and benchmarks)."""
        h = self._history
        return {"state": self._state, "rows": h.rows if h is not None else 0, "updates": self.updates,
                "update_rate": self.update_rate(), "t": h.last("t") if h is not None else math.nan,
                "error": self._error.content if self._error.visible else None}

    def update_rate(self) -> float:
        """View updates per second over the last (up to) 64 updates."""
        ts = self._publish_times
        if len(ts) < 2 or ts[-1] <= ts[0]:
            return 0.0
        return (len(ts) - 1) / (ts[-1] - ts[0])

    def stop(self) -> None:
        self._quit.set()
        self._commands.put(("quit",))
        self._worker.join(timeout=5)
        if self._run is not None:
            self._run.close()
        self.server.stop()

    # -- the page --------------------------------------------------------------------------------
    def _build_gui(self, speed: str) -> None:
        from tirefilter.estimators import ESTIMATORS
        from tirefilter.scenarios import DATA_DIR, scenario_files

        gui = self.server.gui
        gui.configure_theme(control_width="small", show_share_button=False)
        gui.main_panel.dock_right()
        gui.main_panel.set_width(CONTROLS_WIDTH)
        s = self.settings
        gui.add_markdown("**tirefilter** — tire stiffness and friction estimation, live")
        gui.add_html(PAGE_FIXES)
        with gui.add_folder("Run"):
            self._start = gui.add_button("Start", hint="start a new run, or resume a paused one")
            self._pause = gui.add_button("Pause")
            self._step = gui.add_button("Step", hint="advance one sample")
            self._restart = gui.add_button("Restart", hint="a new run with the settings below")
            self._speed = gui.add_dropdown("Speed", SPEEDS, initial_value=speed, hint="times real time")
        self._status = gui.add_markdown("**idle**: press Start")
        self._error = gui.add_markdown("", visible=False)
        with gui.add_folder("Source"):
            self._source = gui.add_dropdown("Source", ("scenario", "log"), initial_value=s.source,
                                            hint="co-simulate a scenario against the vehicle FMU, or replay a Log CSV")
            names = tuple(scenario_files())
            self._scenario = gui.add_dropdown("Scenario", names, initial_value=s.scenario if s.scenario in names
                                              else names[0])
            self._log = gui.add_text("Log CSV", s.log, hint="path of the Log CSV to replay (source: log)")
            self._vehicle = gui.add_text("Vehicle TOML", s.vehicle or str(DATA_DIR / "vehicles" / "midsize-suv.toml"),
                                         hint="vehicle TOML of the log (source: log)")
        with gui.add_folder("Estimator"):
            self._estimator = gui.add_dropdown("Estimator", ESTIMATORS, initial_value=s.estimator)
            self._model = gui.add_dropdown("Model", ("auto", "full", "lateral"), initial_value=s.model)
            self._particles = gui.add_number("Particles N", int(s.particles), min=1, max=100000, step=1)
            self._forgetting = gui.add_number("Forgetting factor", float(s.forgetting), min=0.5, max=1.0, step=0.001)
            self._seed = gui.add_number("Seed", int(s.seed), min=0, step=1)
        with gui.add_folder("Result CSV"):
            self._result_path = gui.add_text("Result CSV", "", hint="a Result CSV written by `tirefilter run` or "
                                             "`tirefilter replay`, shown without re-running")
            self._open = gui.add_button("Open Result CSV")

        self._start.on_click(lambda _: self.command("start"))
        self._pause.on_click(lambda _: self.command("pause"))
        self._step.on_click(lambda _: self.command("step"))
        self._restart.on_click(lambda _: self.command("restart"))
        self._open.on_click(lambda _: self.command("open_result", self._result_path.value))
        self._speed.on_update(lambda _: self.command("speed"))

        self._build_charts()

    def _build_charts(self) -> None:
        """The charts panel, docked left: one tab per group of charts (views.TABS), each tab
        headed by a note that says why it shows nothing, when it does not (`views.tab_notes`)."""
        gui = self.server.gui
        self._panel = gui.add_panel()
        self._panel.dock_left()  # placed and sized before its charts: a chart sizes itself to the panel
        self._panel.set_width(CHARTS_WIDTH)  # when it mounts (one that mounted first could stay 50 px wide)
        tabs = {name: self._panel.add_tab(name) for name in TABS}
        self._notes = {}
        for name, tab in tabs.items():
            with tab:
                self._notes[name] = gui.add_markdown("", visible=False)
        self._charts: list[tuple[Chart, object]] = []
        self._ranges: dict[int, tuple[float, float]] = {}  # id(handle) -> the y range it shows
        for chart in charts():
            with tabs[chart.tab]:
                handle = gui.add_uplot(placeholder(len(chart.series)), chart.uplot_series(), title=chart.title,
                                       bands=chart.uplot_bands() or None, scales=self._scales(chart.uplot_scales()),
                                       axes=chart.uplot_axes(), height=CHART_HEIGHT[chart.tab], padding=PADDING)
            self._charts.append((chart, handle))
        self._densities = {}
        self._clouds = {}
        with tabs["densities"]:
            for p in STIFFNESS:
                self._densities[p] = gui.add_uplot(
                    placeholder(2), density_series(p), axes=axes(f"{p} [{UNITS[p]}]", f"density [1/({UNITS[p]})]"),
                    title=f"posterior density of {p} (eq. (26)), true surface mean", height=CHART_HEIGHT["densities"],
                    scales=self._scales({"x": {"time": False}}), padding=PADDING, visible=False)
        with tabs["particles"]:
            for x, y in (("Cf_y", "Cr_y"), ("Cf_y", "Cx")):
                self._clouds[(x, y)] = gui.add_uplot(
                    placeholder(3), cloud_series(x, y), axes=axes(f"{x} [{UNITS[x]}]", f"{y} [{UNITS[y]}]"),
                    title=f"particle cloud: stiffness mean per particle, {y} against {x}",
                    height=CHART_HEIGHT["particles"], scales=self._scales({"x": {"time": False}}), padding=PADDING,
                    visible=False)
        with tabs["path"]:
            self._path = gui.add_uplot(placeholder(len(PATH_SERIES) - 1), PATH_SERIES, axes=axes("x [m]", "y [m]"),
                                       title="vehicle path seen from above (truth, else dead-reckoned), equal scales",
                                       height=CHART_HEIGHT["path"], scales=self._scales({"x": {"time": False}}),
                                       padding=PADDING, visible=False)
        self._friction = {}
        with tabs["friction"]:
            for axle, name in (("f", "front"), ("r", "rear")):
                self._friction[axle] = gui.add_uplot(placeholder(len(FRICTION_SERIES) - 1), FRICTION_SERIES,
                                                     title=f"friction mu(alpha), {name} axle: estimate, 90% band, truth",
                                                     bands=FRICTION_BANDS, scales=self._scales({"x": {"time": False}}),
                                                     axes=axes("alpha [deg]", "mu [-]"), padding=PADDING,
                                                     height=CHART_HEIGHT["friction"], visible=False)
        self._posterior_shown_in = {"densities": False, "particles": False}  # what the run's posterior gave
        self._publish_notes()

    @staticmethod
    def _scales(base: dict, y: tuple[float, float] = (0.0, 1.0), x: tuple[float, float] = (0.0, 1.0)) -> dict:
        """uPlot scales with fixed ranges: uPlot neither re-ranges x on new data nor ranges
        y over a NaN, so the dashboard sets both (x: the run's time span)."""
        scales = {**base, "y": {"auto": False, "range": (float(y[0]), float(y[1]))}}
        scales["x"] = {**base.get("x", {}), "auto": False, "range": (float(x[0]), float(x[1]))}
        return scales

    def _set_data(self, handle, data: tuple[np.ndarray, ...], y_series, base_scales: dict, x_range,
                  min_span: float = 1e-9) -> None:
        """New data for a chart, and new ranges when x changes or the data leave the y range."""
        current = self._ranges.get(id(handle))
        rng = (tuple(x_range), y_range([data[j] for j in y_series], current[1] if current else None, min_span))
        if rng != current:
            self._ranges[id(handle)] = rng
            handle.scales = self._scales(base_scales, rng[1], rng[0])
        handle.data = data

    def _settings(self) -> Settings:
        return Settings(source=self._source.value, scenario=self._scenario.value, log=self._log.value.strip(),
                        vehicle=self._vehicle.value.strip(), estimator=self._estimator.value, model=self._model.value,
                        particles=int(self._particles.value), forgetting=float(self._forgetting.value),
                        seed=int(self._seed.value))

    # -- the worker ------------------------------------------------------------------------------
    def _work(self) -> None:
        next_publish = time.perf_counter()
        while not self._quit.is_set():
            try:
                cmd = self._commands.get(timeout=0.0 if self._playing else 0.05)
            except queue.Empty:
                cmd = None
            try:
                if cmd is not None:
                    if cmd[0] == "quit":
                        return
                    self._handle(cmd)
                    next_publish = time.perf_counter()
                if self._playing:
                    self._advance(next_publish)
                now = time.perf_counter()
                if now >= next_publish and (self._playing or cmd is not None or self._finished_unshown):
                    self._publish()
                    # the cadence counts from the start of a publication, so stepping yields to it
                    next_publish = max(next_publish + self.publish_interval, now)
            except Exception as exc:  # everything reaches the page; the server keeps running
                self._fail(exc)

    def _handle(self, cmd: tuple) -> None:
        name = cmd[0]
        if name == "start":
            if self._run is None or self._run.finished:
                self._new_run()
            self._set_playing(True)
        elif name == "restart":
            self._new_run()
            self._set_playing(True)
        elif name == "pause":
            self._set_playing(False)
        elif name == "step":
            if self._run is None or self._run.finished:
                self._new_run()
            self._set_playing(False)
            self._step_once()
        elif name == "speed":
            self._reset_pace()
        elif name == "open_result":
            self._open_result(cmd[1])

    def _set_playing(self, playing: bool) -> None:
        self._playing = playing and self._run is not None and not self._run.finished
        self._state = "running" if self._playing else ("paused" if self._run is not None and not self._run.finished
                                                        else self._state)
        self._reset_pace()

    def _reset_pace(self) -> None:
        t = self._history.last("t") if self._history is not None and self._history.rows else None
        self._pace = (time.perf_counter(), t)  # t None: from the first sample on

    def _new_run(self) -> None:
        self._close_run()
        self._clear_error()
        self._clear_views()
        self._state = "starting"
        self._run = LiveRun.open(self.data_root.settings(self._settings()))
        self._history = History(self._run.columns)
        n = getattr(getattr(self._run.estimator, "cfg", None), "particles", None)
        self._source_label = f"{self._run.label}, estimator {self._run.name}" + (f" (N = {n})" if n else "")
        self._state = "paused"
        self._publish_times.clear()

    def _close_run(self) -> None:
        self._playing = False
        if self._run is not None:
            self._run.close()
            self._run = None

    def _step_once(self) -> bool:
        """One sample; False when the run is over."""
        row = self._run.step()
        if row is None:
            self._finish()
            return False
        self._history.append(row)
        return True

    def _finish(self) -> None:
        self._playing = False
        self._state = "finished"
        self._finished_unshown = True  # the last samples and the state still go to the page
        if self._run is not None:
            self._run.close()
            self._metrics = self._metrics_line(self._run.scenario, self._run.estimator)

    def _advance(self, until: float) -> None:
        """Step until the next publication is due, no faster than the chosen speed."""
        speed = speed_factor(self._speed.value)
        if not math.isfinite(speed) and self._playing:  # at least one sample per publication
            if not self._step_once():
                return
        while time.perf_counter() < until and self._playing:
            if math.isfinite(speed) and self._history.rows:
                wall0, sim0 = self._pace
                if sim0 is None:
                    wall0, sim0 = self._pace = (time.perf_counter(), self._history.last("t"))
                target = sim0 + speed * (time.perf_counter() - wall0)
                if self._history.last("t") >= target:
                    time.sleep(min(0.002, max(0.0, until - time.perf_counter())))
                    continue
            if not self._step_once():
                return
            if not self._commands.empty():
                return

    def _open_result(self, path: str) -> None:
        path = str(self.data_root.resolve(path, "Result CSV"))
        data = open_result(path)
        friction = None
        for candidate in friction_files(path):
            if candidate.is_file() and self.data_root.inside(candidate):
                friction = friction_from_csv(candidate)
                break
        self._close_run()
        self._clear_error()
        self._clear_views()
        self._history = History.from_columns(data)
        self._result_friction = friction
        self._source_label = f"Result CSV {Path(str(path).strip()).name}" + (", friction CSV" if friction else "")
        self._metrics = self._metrics_line(None, None)
        self._state = "result"
        self._publish_times.clear()

    def _metrics_line(self, scenario, estimator) -> str:
        """`metrics.metrics_line` of the rows so far (the windows of the scenario, if any;
        the estimator's restart and resample counters)."""
        from tirefilter.metrics import metrics_line, run_metrics

        h = self._history
        if h is None or not h.rows:
            return ""
        m = run_metrics({c: h.column(c) for c in h.columns}, scenario,
                        restarts=getattr(estimator, "restarts", None), resamples=getattr(estimator, "resamples", None))
        return metrics_line(m)

    def _fail(self, exc: Exception) -> None:
        from tirefilter.errors import TirefilterError

        self._playing = False
        if self._run is not None:
            self._run.close()
        self._state = "failed"
        text = str(exc) if isinstance(exc, TirefilterError) else f"{type(exc).__name__}: {exc}"
        if not isinstance(exc, TirefilterError):
            traceback.print_exc()
        self._error.content = f"**Error:** {text}"
        self._error.visible = True
        try:
            self._publish()
        except Exception:  # the views may be what failed: the message is out already
            traceback.print_exc()

    def _clear_error(self) -> None:
        if self._error.visible:
            self._error.visible = False
            self._error.content = ""

    # -- the views -------------------------------------------------------------------------------
    def _clear_views(self) -> None:
        """Empty charts: what a new run (or a run that could not start) begins from."""
        self._history = None
        self._result_friction = None
        self._source_label = ""
        self._posterior_shown_in = {"densities": False, "particles": False}
        with self.server.atomic():
            for chart, handle in self._charts:
                if self._ranges.pop(id(handle), None) is not None:
                    handle.scales = self._scales(chart.uplot_scales())
                    handle.data = placeholder(len(chart.series))
            for handle in (*self._friction.values(), *self._densities.values(), *self._clouds.values(), self._path):
                handle.visible = False
                if self._ranges.pop(id(handle), None) is not None:
                    handle.data = placeholder(len(handle.series) - 1)
            self._metrics = ""
            self._publish_notes()

    def _publish(self) -> None:
        now = time.perf_counter()
        h = self._history
        with self.server.atomic():
            if h is not None and h.rows:
                idx = h.decimation()
                t = h.column("t")
                t_end = t[0] + self._run.duration if self._run is not None else t[-1]
                x_range = (float(t[0]), float(max(t_end, t[-1], t[0] + 1e-3)))
                for chart, handle in self._charts:
                    visible = chart.key != "Cx" or h.has_values("Cx") or h.has_values("true_Cx_mean")
                    if handle.visible != visible:
                        handle.visible = visible
                    if visible:
                        self._set_data(handle, chart.data(h, idx), chart.y_series(), chart.uplot_scales(), x_range,
                                       chart.min_span)
                self._publish_path(h, idx)
            self._publish_cloud(h)
            self._publish_friction(h)
            self._publish_notes()
            self._publish_times.append(now)
            self.updates += 1
            self._finished_unshown = False
            self._status.content = self._status_text()

    def _publish_notes(self) -> None:
        """Each tab's note: why it shows nothing (`views.tab_notes`), hidden where it shows
        what it should."""
        h = self._history
        if h is None or not h.rows:
            source = "none" if self._run is None and h is None else "run"
            notes = tab_notes(source, None) if source == "none" else {}
        else:
            source = "run" if self._run is not None else "result"
            est = self._run.estimator if self._run is not None else None
            notes = tab_notes(source, self._run.name if self._run is not None else None,
                              densities=self._posterior_shown_in["densities"],
                              particles=self._posterior_shown_in["particles"],
                              friction=callable(getattr(est, "friction", None)) or self._result_friction is not None,
                              bias=_bias_estimated(est, h), cx=h.has_values("Cx"))
            if source == "run" and est is not None and h.rows < 2:  # the posterior is not drawn yet: no verdict
                notes.pop("densities", None), notes.pop("particles", None)
        for tab, handle in self._notes.items():
            text = notes.get(tab, "")
            if handle.content != text:
                handle.content = text
            if handle.visible != bool(text):
                handle.visible = bool(text)

    def _publish_cloud(self, h: History | None) -> None:
        """The posterior tabs (at most POSTERIOR_HZ times a second): the densities and the
        particle clouds of the run's estimator; their charts hidden while it gives none."""
        cloud = None
        if self._run is not None and self._run.estimator is not None and h is not None and h.rows:
            now = time.perf_counter()
            if not (now - self._posterior_shown >= 1.0 / POSTERIOR_HZ or self._finished_unshown or not self._playing):
                return
            self._posterior_shown = now
            cloud = particle_stiffness(self._run.estimator.posterior())
            self._publish_posterior(h, cloud)
            return
        for handle in (*self._densities.values(), *self._clouds.values()):
            if handle.visible:
                handle.visible = False

    def _publish_posterior(self, h: History, cloud) -> None:
        """The posterior tabs: the density of each stiffness parameter (eq. (26) for the MPF)
        and the particle cloud in two projections, each framed on what it shows (ticks in
        kN/rad), with the true surface mean where the run has one."""
        from tirefilter.viz.density import stiffness_mixture

        est = self._run.estimator
        truth = {p: h.last(f"true_{p}_mean") for p in STIFFNESS if h.has_values(f"true_{p}_mean")}
        mixture = stiffness_mixture(est.posterior(), None, params=getattr(est, "params", None))
        shown = {"densities": False, "particles": False}
        for p, handle in self._densities.items():
            data = density_data(mixture, p, truth.get(p, math.nan))
            if data is not None:
                self._set_data(handle, data, (1, 2), {"x": {"time": False}}, (data[0][0], data[0][-1]))
                shown["densities"] = True
            if handle.visible != (data is not None):
                handle.visible = data is not None
        for (x, y), handle in self._clouds.items():
            data = cloud_scatter(cloud, x, y, truth)
            if data is not None:
                self._set_data(handle, data, (1, 2, 3), {"x": {"time": False}}, _padded(data[0]))
                shown["particles"] = True
            if handle.visible != (data is not None):
                handle.visible = data is not None
        self._posterior_shown_in = shown

    def _publish_path(self, h: History, idx: np.ndarray) -> None:
        """The path tab: the vehicle path from above, on axes with as many metres per pixel
        both ways (the plot area: the chart less its axes and padding)."""
        data = path_data(h, idx)
        if data is None:
            return
        x_range, y_range_m = equal_axes(data[0], np.concatenate([d[np.isfinite(d)] for d in data[1:]]),
                                        CHARTS_WIDTH - 40 - AXIS_SIZE - PADDING[1],
                                        CHART_HEIGHT["path"] - 44 - PADDING[0] - 60)
        rng = (x_range, y_range_m)
        if self._ranges.get(id(self._path)) != rng:
            self._ranges[id(self._path)] = rng
            self._path.scales = self._scales({"x": {"time": False}}, y_range_m, x_range)
        self._path.data = data
        if not self._path.visible:
            self._path.visible = True

    def _publish_friction(self, h: History | None) -> None:
        est = self._run.estimator if self._run is not None else None
        friction = getattr(est, "friction", None)
        curve, truth = None, None
        if callable(friction) and h is not None and h.rows:
            curve = friction()
            if self._run.scenario is not None and h.has_values("true_surface"):
                truth = friction_truth(self._run.scenario, np.asarray(curve.alpha, float), h.last("true_surface"))
        elif self._run is None and self._result_friction is not None:  # an opened Result CSV's friction CSV
            curve, truth = self._result_friction
        for axle, handle in self._friction.items():
            if curve is None:
                if handle.visible:
                    handle.visible = False
                continue
            data = friction_data(curve, truth, axle)
            self._set_data(handle, data, (1, 2, 3, 4), {"x": {"time": False}}, (data[0][0], data[0][-1]), 0.1)
            if not handle.visible:
                handle.visible = True

    def _status_text(self) -> str:
        h = self._history
        if h is None:
            hint = {"idle": ": press Start", "failed": ": see the error below"}.get(self._state, "")
            return f"**{self._state}**{hint}"
        parts = [f"**{self._state}**", self._source_label]
        t = h.last("t")
        duration = f" of {self._run.duration:g}" if self._run is not None else ""
        parts.append(f"t = {t:.2f}{duration} s" if math.isfinite(t) else "t = -")
        parts.append(f"{h.rows} samples")
        if self._state == "running" and not h.rows:  # the first step loads the compiled kernels
            parts.append("first step (a machine's first run compiles the kernels: about a minute)")
        if self._state == "running":
            parts.append(f"{self.update_rate():.0f} updates/s")
        if self._run is not None and self._run.median_step_us():
            parts.append(f"step {self._run.median_step_us():.0f} us (median)")
        if self._metrics:
            parts.append(self._metrics)
        return " · ".join(parts)


def _bias_estimated(estimator, h: History) -> bool:
    """Whether the rows hold an IMU bias estimate: the estimator's sensor model says so
    (`sensors.bias_on`); without one (a Result CSV, an estimator without it), a bias column
    with a finite value other than 0 (a filter that does not estimate it writes 0 or nothing)."""
    sensors = getattr(estimator, "sensors", None)
    if sensors is not None and hasattr(sensors, "bias_on"):
        return bool(sensors.bias_on)
    for c in ("b_ax", "b_ay", "b_yaw_rate"):
        x = h.column(c)
        if x is not None and np.any(np.isfinite(x) & (x != 0)):
            return True
    return False


def _padded(x: np.ndarray) -> tuple[float, float]:
    """The range of x with 10% margins (at least 1e-6 wide)."""
    lo, hi = float(np.nanmin(x)), float(np.nanmax(x))
    pad = max(0.1 * (hi - lo), 1e-6)
    return lo - pad, hi + pad


def serve(host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, *, verbose: bool = True, data_dir=None) -> None:
    """`tirefilter dashboard`: serve until interrupted (Ctrl-C or SIGTERM), then stop cleanly."""
    import signal

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # started in the background: Ctrl-C still stops it
        signal.signal(signal.SIGINT, interrupt)
    dashboard = Dashboard(host=host, port=port, verbose=verbose, data_dir=data_dir)
    print(f"tirefilter dashboard: {dashboard.url}" + ("" if host in ("127.0.0.1", "localhost", "::1") else
          f"  (bound to {host}: reachable from other machines)"), flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        dashboard.stop()
