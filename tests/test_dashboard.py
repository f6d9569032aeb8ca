"""The dashboard (`viewer/`, `tirefilter dashboard`): its data (history, charts, cloud,
pose) against exact answers, its runs against `run_scenario` / `replay_log` row for row,
the server's address, its errors, and the page in a real browser (Debian's chromium,
driven headless by Playwright)."""

from __future__ import annotations

import dataclasses
import math
import re
import socket
import tempfile
import time
import urllib.request
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tirefilter.cli import build_parser, import_viewer, main
from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.io.results import ESTIMATE_COLUMNS, read_results, result_columns
from tirefilter.cosim.run import cosim_samples, run_scenario
from tirefilter.errors import ConfigError, ReplayError
from tirefilter.estimators import build_estimator
from tirefilter.estimators.base import FrictionCurve
from tirefilter.replay import read_log, replay_log, write_log
from tirefilter.runs import spawn_seeds
from tirefilter.scenarios import DATA_DIR, load_scenario

import_viewer()  # installed with the project, or found in viewer/ of this checkout

from tirefilter_viewer import app as app_module  # noqa: E402
from tirefilter_viewer import session as session_module  # noqa: E402
from tirefilter_viewer.app import Dashboard  # noqa: E402
from tirefilter_viewer.history import MAX_POINTS, History  # noqa: E402
from tirefilter_viewer.session import (EstimatorFailure, LiveRun, Settings, build_with_forgetting,  # noqa: E402
                                       open_result)
from tirefilter_viewer.views import (Z90, charts, friction_data, friction_from_csv, friction_truth,  # noqa: E402
                                     particle_stiffness, y_range)

VEHICLE = DATA_DIR / "vehicles" / "midsize-suv.toml"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
SEED, N_SMALL = 3, 50


@pytest.fixture(scope="module", autouse=True)
def compiled_kernels(fmu_paths):
    """The compiled kernels of the MPF and the GP-SSM loaded (or, in a fresh clone, compiled:
    about a minute, more on a loaded machine) before any run of the dashboard, so that the
    waits below bound the runs and not a first compile: a few samples of a straight drive
    through a small default MPF, full and lateral model, and 0.2 s of friction-snow through
    a small GP-SSM."""
    from tirefilter.estimators.base import Inputs, Measurement
    from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF

    vehicle = load_scenario("paper-sim").vehicle
    omega = 20.0 / vehicle.wheel_radius
    for model in ("full", "lateral"):
        est = StiffnessMPF(vehicle, MPFConfig(particles=8, model=model))
        est.reset(np.random.default_rng(0))
        for k in range(5):
            est.step(0.01 * k, Inputs(delta=0.01, omega_f=omega, omega_r=omega, vx=20.0),
                     Measurement(ax=0.0, ay=0.5, yaw_rate=0.03))
    scenario = replace(load_scenario("friction-snow"), duration=0.2)
    run_scenario(scenario, estimator=build_estimator("gpssm", scenario, model="auto", particles=8, config={}))


def wait_for(predicate, timeout: float = 60.0, what: str = "condition"):  # generous: a loaded CI machine
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


# ---- history, charts, cloud: plain numpy -------------------------------------------------------
def test_history_grows_and_decimates_with_stable_points():
    h = History(("t", "x"), capacity=4)
    for k in range(5000):
        h.append((0.01 * k, float(k)))
    np.testing.assert_array_equal(h.column("x"), np.arange(5000.0))
    assert h.column("nope") is None and h.last("x") == 4999.0
    idx = h.decimation()
    assert idx[-1] == 4999 and len(idx) <= MAX_POINTS + 1
    stride = idx[1] - idx[0]
    assert stride & (stride - 1) == 0 and np.all(np.diff(idx[:-1]) == stride)  # every 2^j-th sample
    small = History(("t",))
    for k in range(10):
        small.append((k,))
    np.testing.assert_array_equal(small.decimation(), np.arange(10))  # short: every sample
    assert History(("t",)).decimation().size == 0


def test_pose_prefers_truth_and_dead_reckons_a_circle():
    n, dt, vx, r = 2001, 0.001, 10.0, 0.5
    t = np.arange(n) * dt
    h = History.from_columns({"t": t, "vx": np.full(n, vx), "vy": np.zeros(n), "yaw_rate": np.full(n, r)})
    x, y, psi = h.pose()
    R = vx / r  # a circle of radius 20 m, counter-clockwise
    np.testing.assert_allclose(psi, r * t, atol=1e-12)
    np.testing.assert_allclose(x, R * np.sin(psi), atol=vx * dt * 1.0)  # forward Euler: O(dt) error
    np.testing.assert_allclose(y, R * (1 - np.cos(psi)), atol=vx * dt * 1.0)
    truth = History.from_columns({"t": t, "true_x": t * 2, "true_y": -t, "true_psi": np.ones(n), "vx": np.full(n, vx)})
    x, y, psi = truth.pose()
    np.testing.assert_array_equal(x, t * 2) and np.testing.assert_array_equal(psi, np.ones(n))


def test_y_range_keeps_its_range_until_the_data_leave_it():
    first = y_range([np.array([0.0, 10.0]), np.array([np.nan, 5.0])], None)
    assert first == pytest.approx((-1.0, 11.0))  # 10% margins, NaN ignored
    assert y_range([np.array([1.0, 9.0])], first) == first  # inside and fills > half: kept
    assert y_range([np.array([0.0, 12.0])], first) == pytest.approx((-1.2, 13.2))  # left it: new range
    assert y_range([np.array([4.0, 4.5])], first) == pytest.approx((3.95, 4.55))  # shrank below half
    assert y_range([np.array([2.0, 2.0])], None, min_span=1.0) == pytest.approx((1.5, 2.5))
    assert y_range([np.full(3, np.nan)], None) == (0.0, 1.0)


def test_stiffness_chart_band_is_the_90_percent_interval():
    from scipy.stats import norm

    assert Z90 == pytest.approx(norm.ppf(0.95), rel=1e-15)
    chart = next(c for c in charts() if c.key == "Cf_y")
    h = History.from_columns({"t": np.array([0.0, 1.0]), "Cf_y": np.array([1e5, 2e5]),
                              "Cf_y_std": np.array([1e3, 2e3]), "true_Cf_y_mean": np.array([9e4, 9e4])})
    t, true_step, true_mean, lo, hi, est = chart.data(h)
    np.testing.assert_allclose(est, [100.0, 200.0])  # kN/rad
    np.testing.assert_allclose(lo, [100.0 - Z90, 200.0 - 2 * Z90])
    np.testing.assert_allclose(hi, [100.0 + Z90, 200.0 + 2 * Z90])
    np.testing.assert_allclose(true_mean, [90.0, 90.0])
    assert np.isnan(true_step).all()  # no such column: NaN, no error
    assert chart.bands == ((4, 3),) and chart.y_series() == (1, 2, 3, 4, 5)  # upper, lower edge


def test_particle_cloud_is_the_posterior_whose_weighted_mean_is_the_estimate(fmu_paths):
    run = LiveRun.open(Settings(particles=N_SMALL, seed=SEED))
    try:
        for _ in range(150):
            row = run.step()
        names, values, w, nominal = particle_stiffness(run.estimator.posterior())
    finally:
        run.close()
    assert names == ("Cx", "Cf_y", "Cr_y") and values.shape == (N_SMALL, 3)
    assert w.sum() == pytest.approx(1.0)
    est = dict(zip(ESTIMATE_COLUMNS, row))
    for j, p in enumerate(names):  # eq. (27a): the weighted mean of the particles' means
        assert w @ values[:, j] == pytest.approx(est[p], rel=1e-9)
    assert nominal.shape == (3,) and np.all(nominal > 0)


def test_path_chart_is_the_pose_sorted_by_x_with_start_and_now_on_equal_axes():
    from tirefilter_viewer.views import equal_axes, path_data

    t = np.linspace(0.0, 2 * np.pi, 101)
    h = History.from_columns({"t": t, "true_x": 30 * np.sin(t), "true_y": 10 * (1 - np.cos(t)), "true_psi": t})
    x, path, start, now = path_data(h, h.decimation())
    assert len(x) == 103 and np.all(np.diff(x) >= 0)  # 101 points, the start and now
    pairs = sorted(zip(x[np.isfinite(path)], path[np.isfinite(path)]))
    np.testing.assert_allclose(pairs, sorted(zip(30 * np.sin(t), 10 * (1 - np.cos(t)))), atol=1e-12)
    assert np.count_nonzero(np.isfinite(start)) == 1 and np.count_nonzero(np.isfinite(now)) == 1
    assert start[np.isfinite(start)][0] == 0.0 and now[np.isfinite(now)][0] == pytest.approx(0.0, abs=1e-12)
    (x0, x1), (y0, y1) = equal_axes(x, np.concatenate([path, start, now]), 1000.0, 500.0)
    assert (x1 - x0) / 1000.0 == pytest.approx((y1 - y0) / 500.0)  # as many metres per pixel both ways
    assert x0 < -30 and x1 > 30 and y0 < 0 and y1 > 20  # the whole path inside
    assert (x0 + x1) / 2 == pytest.approx(0.0) and (y0 + y1) / 2 == pytest.approx(10.0)  # centred
    assert path_data(History.from_columns({"t": t[:1], "vx": t[:1]}), np.zeros(1, int)) is None


def test_every_empty_tab_says_why():
    from tirefilter_viewer.views import TABS, tab_notes

    idle = tab_notes("none", None)
    assert set(idle) == set(TABS) and all("press **Start**" in n for n in idle.values())
    result = tab_notes("result", None)  # an opened Result CSV: no particles, no friction CSV
    assert set(result) == {"densities", "particles", "friction"}
    assert all(n.startswith("**Not in this file:**") for n in result.values())
    assert "friction" not in tab_notes("result", None, friction=True)
    mpf = tab_notes("run", "mpf", densities=True, particles=True)
    assert set(mpf) == {"friction"} and "mpf learns the stiffness, not the friction curve" in mpf["friction"]
    kf = tab_notes("run", "kf", densities=True, particles=False, friction=False, bias=False, cx=False)
    assert kf["particles"].startswith("**Not for this estimator:** kf has no particle posterior")
    assert set(kf) == {"particles", "friction", "bias, ESS", "stiffness"}
    assert "the run has no estimator" in tab_notes("run", "none")["densities"]
    assert tab_notes("run", "gpssm", densities=True, particles=True, friction=True) == {}


def test_legends_and_axes_carry_each_parameters_unit():
    from tirefilter_viewer.views import cloud_series, density_series

    for chart in charts():
        for s in chart.uplot_series()[1:]:
            assert re.search(r"\[[^\]]+\]$", s["label"]), (chart.key, s["label"])  # every legend entry has a unit
    assert next(c for c in charts() if c.key == "Cx").uplot_series()[-1]["label"] == "estimate [kN/unit slip]"
    cx = [s["label"] for s in density_series("Cx")]
    assert cx[0] == "Cx [kN/unit slip]" and all("kN/rad" not in label for label in cx)
    assert density_series("Cf_y")[0]["label"] == "Cf_y [kN/rad]"
    assert [s["label"] for s in cloud_series("Cf_y", "Cx")][:2] == ["Cf_y [kN/rad]", "particles: Cx [kN/unit slip]"]


def test_friction_curve_and_its_truth():
    scenario = load_scenario("friction-snow")
    alpha = np.linspace(-0.3, 0.3, 61)
    mu_f, mu_r = friction_truth(scenario, alpha, 0.5)
    p = scenario.model.pacejka
    Ba = p.B_y * alpha
    expected = 0.5 * p.mu_y * np.sin(p.C_y * np.arctan(Ba - p.E_y * (Ba - np.arctan(Ba))))  # Magic Formula / F_z
    np.testing.assert_allclose(mu_f, expected, rtol=1e-12) and np.testing.assert_allclose(mu_r, expected, rtol=1e-12)
    linear = load_scenario("paper-sim")
    lf, lr = friction_truth(linear, alpha, 1.0)
    Fz_f, _ = linear.vehicle.static_axle_loads()
    np.testing.assert_allclose(lf, linear.vehicle.Cf_y * alpha / Fz_f)
    curve = FrictionCurve(t=1.0, alpha=alpha, mu_f=np.tanh(alpha), mu_f_std=np.full(61, 0.1), mu_r=alpha,
                          mu_r_std=np.zeros(61))
    a, mu, lo, hi, true = friction_data(curve, (mu_f, mu_r), "f")
    np.testing.assert_allclose(a, np.degrees(alpha))
    np.testing.assert_allclose(hi - lo, 2 * Z90 * 0.1)
    np.testing.assert_array_equal(true, mu_f)
    assert np.isnan(friction_data(curve, None, "r")[4]).all()


# ---- runs: the same rows as the command line ----------------------------------------------------
def test_live_cosimulation_gives_the_rows_of_run_scenario(fmu_paths):
    scenario = load_scenario("paper-sim")
    short = replace(scenario, duration=1.0)
    est = build_estimator("mpf", short, model="auto", particles=N_SMALL, config={})
    _, rows = run_scenario(short, estimator=est, seed=SEED, keep_rows=True)
    run = LiveRun.open(Settings(scenario="paper-sim", estimator="mpf", particles=N_SMALL, seed=SEED))
    try:
        live = np.vstack([run.step() for _ in range(len(rows))])
        assert run.duration == scenario.duration and run.median_step_us() > 0
    finally:
        run.close()
    np.testing.assert_array_equal(live, rows)  # bit for bit: the same loop, seed and estimator


def test_cosim_samples_feed_the_estimator_what_run_scenario_writes(fmu_paths):
    scenario = replace(load_scenario("snow-sine"), duration=0.5)
    _, rows = run_scenario(scenario, seed=SEED, keep_rows=True)
    with VehicleFMU("2") as fmu:
        steps = []
        samples = list((s.t, s.inputs, s.meas, np.concatenate([s.y, s.u]))
                       for s in cosim_samples(scenario, fmu, scenario.fmu_parameters(spawn_seeds(SEED)[0]),
                                              on_step=steps.append))
        k_ay = result_columns(fmu.output_names).index("meas_ay")
    assert len(samples) == len(rows) and steps == list(range(int(round(0.5 / scenario.communication_step))))
    for (t, u, y, values), row in zip(samples, rows):
        assert t == row[0]
        np.testing.assert_array_equal(values, row[len(ESTIMATE_COLUMNS):])
        assert y.ay == row[k_ay]  # the measurement handed over is the FMU's sensor output


def _log_from_cosim(tmp_path: Path) -> Path:
    scenario = replace(load_scenario("paper-sim"), duration=1.0)
    _, rows = run_scenario(scenario, seed=SEED, keep_rows=True)
    with VehicleFMU("2") as fmu:
        r = {c: rows[:, j] for j, c in enumerate(result_columns(fmu.output_names))}
    return write_log(tmp_path / "drive.csv", {"t": r["t"], "delta": r["meas_delta"], "ax": r["meas_ax"],
                                              "ay": r["meas_ay"], "yaw_rate": r["meas_yaw_rate"], "vx": r["true_vx"],
                                              "omega_f": r["meas_omega_f"], "omega_r": r["meas_omega_r"]})


def test_live_replay_gives_the_rows_of_replay_log(fmu_paths, tmp_path):
    path = _log_from_cosim(tmp_path)
    settings = Settings(source="log", log=str(path), vehicle=str(VEHICLE), estimator="mpf", particles=N_SMALL,
                        seed=SEED, forgetting=0.995)
    run = LiveRun.open(settings)
    live = []
    while (row := run.step()) is not None:
        live.append(row)
    assert run.finished and run.estimator.cfg.forgetting == 0.995 and run.duration == pytest.approx(1.0)
    from tirefilter.estimators import build_log_estimator
    from tirefilter.vehicle.params import load_vehicle

    vehicle = load_vehicle(VEHICLE)
    log = read_log(path, vehicle)
    est = build_log_estimator("mpf", vehicle, log.t, {n: log.signals[n] for n in log.available}, model="auto",
                              particles=N_SMALL, config={"mpf": {"forgetting": 0.995}})
    _, rows = replay_log(log, estimator=est, seed=SEED, keep_rows=True)
    np.testing.assert_array_equal(np.vstack(live), rows)


def test_settings_reach_the_estimator_and_bad_settings_are_named(fmu_paths):
    run = LiveRun.open(Settings(particles=7, forgetting=0.95, seed=1))
    assert run.estimator.cfg.particles == 7 and run.estimator.cfg.forgetting == 0.95
    run.close()
    kf = LiveRun.open(Settings(estimator="kf", model="lateral", forgetting=0.9))  # no forgetting option: unchanged
    assert kf.name == "kf" and not hasattr(kf.estimator.cfg, "forgetting")
    assert np.isfinite(kf.step()[ESTIMATE_COLUMNS.index("Cf_y")])
    kf.close()
    for bad, key in ((Settings(particles=0), "N"), (Settings(forgetting=1.5), "forgetting"),
                     (Settings(source="log"), "Log CSV"), (Settings(estimator="nope"), "estimator")):
        with pytest.raises(ConfigError, match=key):
            LiveRun.open(bad)
    with pytest.raises(ConfigError, match="no such Result CSV"):
        open_result("/nonexistent/results.csv")


def test_forgetting_goes_through_the_estimators_own_table():
    @dataclasses.dataclass(frozen=True)
    class Cfg:
        forgetting: float = 0.99

    class Est:
        def __init__(self, cfg):
            self.cfg = cfg

    calls = []

    def build(config, table="demo"):
        calls.append(config)
        return Est(Cfg(**config.get(table, {})))

    assert build_with_forgetting(build, "demo", 0.97).cfg.forgetting == 0.97
    assert calls == [{}, {"demo": {"forgetting": 0.97}}]
    calls.clear()
    assert build_with_forgetting(build, "demo", 0.99).cfg.forgetting == 0.99 and calls == [{}]  # the default: once
    with pytest.raises(ConfigError, match=r"did not take the forgetting factor from a \[demo\] table"):
        build_with_forgetting(lambda config: build(config, table="other"), "demo", 0.97)


def test_estimator_failure_names_the_time(fmu_paths, tmp_path, monkeypatch):
    run = LiveRun.open(Settings(particles=N_SMALL))
    original = run.estimator.step
    monkeypatch.setattr(run.estimator, "step", lambda t, u, y: original(t, u, y) if t < 0.05 else 1 / 0)
    with pytest.raises(EstimatorFailure, match=r"mpf failed at t = 0.05 s: ZeroDivisionError"):
        while run.step() is not None:
            pass
    assert run.finished and run.step() is None
    run.close()
    log_run = LiveRun.open(Settings(source="log", log=str(_log_from_cosim(tmp_path)), vehicle=str(VEHICLE),
                                    particles=N_SMALL))
    monkeypatch.setattr(log_run.estimator, "step", lambda t, u, y: 1 / 0)
    with pytest.raises(ReplayError, match=r"drive.csv: data row 1 \(file line 2, t = 0.0 s\): mpf failed"):
        log_run.step()


# ---- the server -----------------------------------------------------------------------------------
def _non_loopback_address() -> str | None:
    """An IPv4 address of this machine other than 127.x (None if it has none). The UDP
    connect sends nothing; it only picks the interface of the default route."""
    found = set()
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))
            found.add(s.getsockname()[0])
    except OSError:
        pass
    try:
        found |= {ai[4][0] for ai in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET)}
    except OSError:
        pass
    return next((a for a in sorted(found) if not a.startswith("127.") and a != "0.0.0.0"), None)


def _reachable(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=2):
            return True
    except OSError:
        return False


@pytest.fixture
def dashboard(fmu_paths):
    d = Dashboard(port=0, speed="max", settings=Settings(particles=N_SMALL, seed=SEED), data_dir="/")  # tmp files
    yield d
    d.stop()


def test_server_is_not_reachable_on_a_non_loopback_address_by_default(dashboard):
    address = _non_loopback_address()
    if address is None:
        pytest.skip("this machine has no non-loopback IPv4 address to try")
    assert dashboard.host == "127.0.0.1"
    assert _reachable("127.0.0.1", dashboard.port)
    assert not _reachable(address, dashboard.port), f"the dashboard answers on {address}"
    exposed = Dashboard(host="0.0.0.0", port=0)  # the control: asked explicitly, it is reachable there
    try:
        assert _reachable(address, exposed.port)
    finally:
        exposed.stop()


def test_cli_dashboard_binds_loopback_unless_told(monkeypatch):
    args = build_parser().parse_args(["dashboard"])
    assert (args.host, args.port) == ("127.0.0.1", 8080)
    calls = []
    monkeypatch.setattr(import_viewer(), "serve", lambda **kw: calls.append(kw))
    assert main(["dashboard", "--port", "9123"]) == 0
    assert main(["dashboard", "--host", "0.0.0.0"]) == 0
    assert calls == [{"host": "127.0.0.1", "port": 9123}, {"host": "0.0.0.0", "port": 8080}]


def test_the_command_serves_on_loopback_and_stops_on_sigterm(fmu_paths):
    import os
    import signal
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "tirefilter.cli", "dashboard", "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=os.environ.copy())
    try:
        url = None
        for line in proc.stdout:
            if m := re.match(r"tirefilter dashboard: (http://\S+)", line):
                url = m.group(1)
                break
        assert url is not None and url.startswith("http://127.0.0.1:")
        assert urllib.request.urlopen(url, timeout=5).status == 200
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_run_pause_step_restart_and_errors_keep_the_server(dashboard, monkeypatch, tmp_path):
    d = dashboard
    d._speed.value = "1x"  # real time: the run is still going when paused
    d.command("start")
    wait_for(lambda: d.status()["rows"] > 20, what="samples")
    for _ in range(10):  # never ahead of real time (one sample at most) since the pace started
        wall_p, sim_p = d._pace
        t = d.status()["t"]
        assert t <= sim_p + (time.perf_counter() - wall_p) + 0.0101
        time.sleep(0.05)
    d.command("pause")
    wait_for(lambda: d.status()["state"] == "paused", what="pause")
    rows = d.status()["rows"]
    time.sleep(0.2)
    assert d.status()["rows"] == rows  # paused
    d.command("step")
    wait_for(lambda: d.status()["rows"] == rows + 1, what="one step")
    d._particles.value = 9
    d.command("restart")
    wait_for(lambda: "(N = 9)" in d._status.content and d.status()["state"] == "running", what="restart")
    assert d._run.estimator.cfg.particles == 9
    # an estimator exception: a message in the page, the server goes on
    real_open = session_module.LiveRun.open

    def failing_open(settings):
        run = real_open(settings)
        monkeypatch.setattr(run.estimator, "step", lambda t, u, y: (_ for _ in ()).throw(RuntimeError("boom")))
        return run

    monkeypatch.setattr(app_module.LiveRun, "open", staticmethod(failing_open))
    d.command("restart")
    error = wait_for(lambda: d.status()["error"], what="the error message")
    assert "mpf failed at t = 0 s: RuntimeError: boom" in error and d.status()["state"] == "failed"
    assert urllib.request.urlopen(d.url, timeout=5).status == 200
    monkeypatch.setattr(app_module.LiveRun, "open", staticmethod(real_open))
    # a bad log file
    bad = tmp_path / "bad.csv"
    bad.write_text("t,delta,ax,ay,yaw_rate,vx\n0.0,0.0,0.1,0.2,0.0,20\n0.01,abc,0.1,0.2,0.0,20\n")
    d._source.value, d._log.value = "log", str(bad)
    d.command("restart")
    error = wait_for(lambda: (d.status()["error"] or "").find("bad.csv") >= 0 and d.status()["error"], what="log error")
    assert "column 'delta'" in error and "'abc'" in error
    # a good log replays; with no truth in it, the path is dead-reckoned from the estimates
    d._log.value = str(_log_from_cosim(tmp_path))
    d.command("restart")
    wait_for(lambda: "log drive.csv" in d._status.content and d.status()["rows"] > 20 and d._path.visible,
             what="the replay")
    assert d.status()["error"] is None and "true_x" not in d._history.columns
    # a Result CSV opens without running; the error goes away
    results = tmp_path / "results.csv"
    scenario = replace(load_scenario("paper-sim"), duration=2.0)
    run_scenario(scenario, estimator=build_estimator("mpf", scenario, model="auto", particles=N_SMALL, config={}),
                 seed=SEED, results_csv=results)
    d.command("open_result", str(results))
    wait_for(lambda: d._status.content.startswith("**result**"), what="the Result CSV")
    assert d.status()["error"] is None and d.status()["rows"] == 201 and d._run is None
    cf = next(h for c, h in d._charts if c.key == "Cf_y")
    np.testing.assert_allclose(cf.data[5], read_results(results)["Cf_y"] * 1e-3)  # published before the status
    d.command("open_result", str(bad))
    assert "not a Result CSV" in wait_for(lambda: d.status()["error"], what="bad Result CSV")
    # a run to its end: the page hears that it finished, with every sample
    import tirefilter.scenarios

    real_load = tirefilter.scenarios.load_scenario
    monkeypatch.setattr(tirefilter.scenarios, "load_scenario", lambda name: replace(real_load(name), duration=0.5))
    d._source.value, d._speed.value = "scenario", "max"
    d.command("start")
    # (the state turns "finished" at once, the status line at the next publication: wait for both)
    wait_for(lambda: d.status()["state"] == "finished" and d._status.content.startswith("**finished**")
             and "51 samples" in d._status.content, what="the end")
    assert d.status()["error"] is None


def test_real_time_pace_starts_at_the_first_sample_of_a_log(dashboard, tmp_path):
    d = dashboard
    log = read_log(_log_from_cosim(tmp_path))
    late = {n: log.columns[n] for n in ("t", "delta", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r")}
    late["t"] = late["t"] + 1000.0  # a log from the middle of a drive
    d._source.value, d._log.value, d._speed.value = "log", str(write_log(tmp_path / "late.csv", late)), "1x"
    d.command("start")
    wait_for(lambda: d.status()["rows"] > 20, what="samples of a log starting at t = 1000 s")
    assert d.status()["state"] == "running"  # paced: the 1 s log takes 1 s, not rushed to its end


class FrictionFake:
    """An estimator with a friction() of a known curve, wrapping a real one (the friction
    estimators' interface: FrictionCurve)."""

    def __init__(self, inner):
        self.inner, self.name, self.cfg, self.t = inner, "fake-friction", inner.cfg, math.nan

    def reset(self, rng):
        self.inner.reset(rng)

    def step(self, t, u, y):
        self.t = t
        return self.inner.step(t, u, y)

    def posterior(self):
        return self.inner.posterior()

    def friction(self) -> FrictionCurve:
        alpha = np.linspace(-0.2, 0.2, 41)
        return FrictionCurve(t=self.t, alpha=alpha, mu_f=0.3 * np.tanh(10 * alpha), mu_f_std=np.full(41, 0.05),
                             mu_r=0.25 * np.tanh(12 * alpha), mu_r_std=np.full(41, 0.02))


def test_friction_estimators_get_their_curve_against_truth(dashboard, monkeypatch):
    d = dashboard
    real = session_module.build_with_forgetting
    monkeypatch.setattr(session_module, "build_with_forgetting", lambda *a: FrictionFake(real(*a)))
    d._scenario.value = "friction-snow"
    d.command("step")
    wait_for(lambda: d.status()["rows"] == 1 and d._friction["f"].visible, what="the friction charts")
    run = d._run
    curve = run.estimator.friction()
    truth = friction_truth(run.scenario, curve.alpha, d._history.last("true_surface"))
    for axle in ("f", "r"):
        expected = friction_data(curve, truth, axle)
        for got, want in zip(d._friction[axle].data, expected):
            np.testing.assert_allclose(got, want)
    assert not np.isnan(d._friction["f"].data[4]).any()  # the truth is known in a co-simulation
    monkeypatch.setattr(session_module, "build_with_forgetting", real)
    d.command("restart")
    wait_for(lambda: not d._friction["f"].visible, what="the friction charts to go")


def test_the_friction_gpssm_live_and_from_its_friction_csv(dashboard, tmp_path):
    d = dashboard
    d._scenario.value, d._estimator.value, d._particles.value = "friction-snow", "gpssm", 20
    published = d.updates
    for _ in range(3):
        d.command("step")
    # every step command ends in a publication: after the third the worker waits for commands, and
    # the estimator can be read from this thread (its statistics' lazy update is not for two threads)
    wait_for(lambda: d.status()["rows"] == 3 and d.updates >= published + 3 and d._friction["r"].visible,
             what="the GP-SSM's curves")
    curve = d._run.estimator.friction()
    truth = friction_truth(d._run.scenario, curve.alpha, d._history.last("true_surface"))
    want = friction_data(curve, truth, "f")

    def drawn_is_current() -> bool:  # the page may still show the curve of an earlier row
        return all(np.allclose(g, w, rtol=1e-7, atol=0, equal_nan=True) for g, w in zip(d._friction["f"].data, want))

    wait_for(drawn_is_current, what="the curve of the third row")
    for got, w in zip(d._friction["f"].data, want):
        np.testing.assert_allclose(got, w)
    # the same estimator's run on the command line: its Result CSV opens with the friction CSV beside it
    scenario = replace(load_scenario("friction-snow"), duration=2.0)
    est = build_estimator("gpssm", scenario, model="auto", particles=20, config={})
    run_scenario(scenario, estimator=est, seed=SEED, results_csv=tmp_path / "results.csv",
                 friction_csv=tmp_path / "friction.csv")
    d.command("open_result", str(tmp_path / "results.csv"))
    wait_for(lambda: d._status.content.startswith("**result**") and d._friction["f"].visible, what="the friction CSV")
    last = friction_from_csv(tmp_path / "friction.csv")
    assert last[0].t == pytest.approx(2.0) and last[1] is not None  # the end snapshot, with truth
    for got, want in zip(d._friction["r"].data, friction_data(*last, "r")):
        np.testing.assert_allclose(got, want)
    np.testing.assert_allclose(d._friction["r"].data[1], est.friction().mu_r)  # the curve at the run's end


# ---- the page in a real browser -------------------------------------------------------------------
def _shot(page, path: Path) -> None:
    """The page as a PNG at `path` (DevTools' Page.captureScreenshot, as tests/rerun_web.py
    takes them: Playwright's `page.screenshot` makes the page draw again, which costs CPU
    seconds under software GL)."""
    from rerun_web import screenshot_png

    path.write_bytes(screenshot_png(page))


def _not_blank(path: Path) -> float:
    from PIL import Image

    pixels = np.asarray(Image.open(path).convert("L"), float)
    return float(pixels.std())


# Records the texts of each canvas's latest drawing (tick values, axis labels: uPlot clears
# the whole canvas before it draws) with their position, alignment, width and the height of
# their glyphs above and below their y (device px), so the tests can read what the charts
# say and whether it fits.
RECORD_CANVAS_TEXT = """
(() => {
  const texts = new WeakMap();
  window.__canvasTexts = (canvas) => texts.get(canvas) || [];
  const clear = CanvasRenderingContext2D.prototype.clearRect;
  CanvasRenderingContext2D.prototype.clearRect = function (x, y, w, h) {
    if (x <= 0 && y <= 0 && w >= this.canvas.width && h >= this.canvas.height) texts.set(this.canvas, []);
    return clear.apply(this, arguments);
  };
  const orig = CanvasRenderingContext2D.prototype.fillText;
  CanvasRenderingContext2D.prototype.fillText = function (text, x, y, maxWidth) {
    const t = this.getTransform();
    const list = texts.get(this.canvas) || [];
    const m = this.measureText(String(text));
    list.push({text: String(text), x: t.a * x + t.c * y + t.e, y: t.b * x + t.d * y + t.f, align: this.textAlign,
               width: m.width * Math.abs(t.a || 1), ascent: m.actualBoundingBoxAscent * Math.abs(t.d || 1),
               descent: m.actualBoundingBoxDescent * Math.abs(t.d || 1), rotated: t.b !== 0});
    if (list.length > 400) list.splice(0, list.length - 400);
    texts.set(this.canvas, list);
    return orig.apply(this, arguments);
  };
})();
"""


def _charts_on_page(page) -> list[dict]:
    """Every visible uPlot chart: its title, box on the page (CSS px), the canvas width in
    device px, and the texts drawn on its canvas since the last redraw began."""
    return page.evaluate("""() => [...document.querySelectorAll('.uplot')].filter(u => u.offsetParent !== null)
        .map(u => {
            const c = u.querySelector('canvas'); const r = u.getBoundingClientRect();
            return {title: (u.querySelector('.u-title') || {}).textContent || '', x: r.x, y: r.y, width: r.width,
                    height: r.height, canvas_width: c ? c.width : 0, canvas_height: c ? c.height : 0,
                    texts: c ? window.__canvasTexts(c) : [],
                    legend: [...u.querySelectorAll('.u-legend .u-series .u-label')].map(l => l.textContent)};
        })""")


def _tick_labels(chart: dict) -> list[dict]:
    """The numeric tick labels drawn on a chart's canvas (its latest drawing of each)."""
    out = {}
    for t in chart["texts"]:
        try:
            float(t["text"].replace("\u2212", "-").replace(",", ""))
        except ValueError:
            continue
        out[(t["text"], t["align"], t["rotated"])] = t
    return list(out.values())


def _chart_has_line(page, index: int = 0) -> bool:
    """Whether chart `index` shows the estimate's line: pixels of its colour (#1f77b4)."""
    return page.evaluate("""(i) => {
        const c = document.querySelectorAll('.uplot canvas')[i];
        if (!c || !c.width) return false;
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0;
        for (let k = 0; k < d.length; k += 4)
            if (Math.abs(d[k] - 31) < 12 && Math.abs(d[k + 1] - 119) < 12 && Math.abs(d[k + 2] - 180) < 12
                && d[k + 3] > 200) n++;
        return n > 30;
    }""", index)


def _click_tab(page, tab: str) -> None:
    page.get_by_role("tab", name=tab, exact=True).click()


def _note(page) -> str:
    """The visible note at the head of the charts panel's shown tab ('' without one): the
    text of the visible paragraphs left of the controls."""
    from tirefilter_viewer.app import CHARTS_WIDTH

    return page.evaluate("""(w) => [...document.querySelectorAll('p')].filter(e => e.offsetParent !== null
        && e.getBoundingClientRect().right <= w).map(e => e.textContent).join(' ')""", CHARTS_WIDTH)


def _check_layout(page, tmp_path) -> None:
    """At 1600 x 1000 the charts are the page: each tab of the charts panel shows its charts
    whole (no scrolling), at least 1150 px wide (the width the old 3-D strip had is theirs:
    the canvas keeps about 120 px and draws nothing, no 3-D labels); the controls take at
    most 300 px; the axes are labelled, tick labels keep their signs and fit in the canvas,
    across and up and down (the top tick of the bias chart, '0.01', was cut in half); every
    legend entry has its unit, the densities' and the clouds' their parameter's (Cx is
    kN per unit slip); the sideslip has its chart; the particle cloud has numeric ticks on
    both axes; a tab that shows nothing says why (paper-sim's bias is not estimated)."""
    from tirefilter_viewer.app import CONTROLS_WIDTH
    from tirefilter_viewer.views import TABS, UNITS, charts

    expected = {tab: [c.title for c in charts() if c.tab == tab] for tab in TABS}
    expected["densities"] = [f"posterior density of {p} (eq. (26)), true surface mean" for p in ("Cf_y", "Cr_y", "Cx")]
    expected["particles"] = [f"particle cloud: stiffness mean per particle, {y} against Cf_y" for y in ("Cr_y", "Cx")]
    expected["path"] = ["vehicle path seen from above (truth, else dead-reckoned), equal scales"]
    assert "sideslip beta [deg]: estimate vs truth" in expected["state"]
    for tab in ("stiffness", "state", "bias, ESS", "densities", "particles", "path"):
        _click_tab(page, tab)
        wait_for(lambda: [c["title"] for c in _charts_on_page(page)] == expected[tab], timeout=60,
                 what=f"the charts of the {tab} tab")
        # a redraw with data (the texts of this drawing are the newest ones)
        wait_for(lambda: all(len(_tick_labels(c)) >= 4 for c in _charts_on_page(page)), timeout=60,
                 what=f"tick labels in the {tab} tab")
        _shot(page, tmp_path / f"tab-{tab.replace(', ', '-')}.png")
        for c in _charts_on_page(page):
            assert c["width"] >= 1150 and c["height"] >= 150, c["title"]
            assert c["x"] >= 0 and c["y"] >= 0 and c["y"] + c["height"] <= 1000, f"{c['title']} needs scrolling"
            labels = [t for t in c["texts"] if not _tick_labels({"texts": [t]})]
            assert any(t["rotated"] for t in labels) and any(not t["rotated"] for t in labels), \
                f"{c['title']}: axis labels {[t['text'] for t in labels]}"
            ticks = [(t["text"], t["align"]) for t in c["texts"] if not t["rotated"] and _tick_labels({"texts": [t]})]
            assert len(ticks) == len(set(ticks)), (c["title"], ticks)  # no two ticks of an axis read the same
            for t in _tick_labels(c):  # every tick label lies inside the canvas: nothing clipped
                left = t["x"] - (t["width"] if t["align"] == "right" else t["width"] / 2 if t["align"] == "center"
                                 else 0)
                assert left >= -0.5 and left + t["width"] <= c["canvas_width"] + 0.5, (c["title"], t)
                if not t["rotated"]:
                    assert t["y"] - t["ascent"] >= -0.5 and t["y"] + t["descent"] <= c["canvas_height"] + 0.5, \
                        (c["title"], t)
            assert len(c["legend"]) >= 2 and all(re.search(r"\[[^\]]+\]$", label) for label in c["legend"]), \
                (c["title"], c["legend"])  # every entry with its unit
            param = next((p for p in ("Cf_y", "Cr_y", "Cx") if f"density of {p} " in c["title"]
                          or c["title"].endswith(f"{p} against Cf_y")), None)
            if param is not None:  # the densities' and clouds' legends in that parameter's unit
                assert all(UNITS[param] in label for label in c["legend"][1:]), (c["title"], c["legend"])
                if param == "Cx":
                    assert "kN/rad" not in " ".join(c["legend"][1:]), c["legend"]
        if tab == "bias, ESS":
            bias = next(c for c in _charts_on_page(page) if c["title"].startswith("accelerometer bias"))
            ticks = [t["text"] for t in _tick_labels(bias) if not t["rotated"]]
            assert any(x.startswith(("-", "\u2212")) for x in ticks), ticks  # the signs are drawn
            assert "0.01" in ticks, ticks  # the top tick, whole (above)
            assert "bias [m/s^2]" in [t["text"] for t in bias["texts"]]
            assert "IMU bias not estimated" in _note(page)
        if tab == "particles":
            for c in _charts_on_page(page):
                values = {t["text"] for t in _tick_labels(c)}
                assert len(values) >= 6, (c["title"], values)  # numeric ticks on both axes
    _click_tab(page, "friction")
    wait_for(lambda: "Not for this estimator: mpf learns the stiffness, not the friction curve" in _note(page),
             what="the friction tab's note")
    assert not _charts_on_page(page)
    scene = page.evaluate("""() => [...document.querySelectorAll('canvas')].filter(c => !c.closest('.uplot'))
        .map(c => c.getBoundingClientRect().width)""")
    assert scene and max(scene) <= 130, scene  # the 3-D canvas: the strip viser keeps, nothing in it
    assert page.get_by_text(re.compile("/ nominal")).count() == 0  # no 3-D labels ('Cf_y / nominal')
    controls = page.evaluate("""() => Math.max(...[...document.querySelectorAll('button')]
        .filter(b => b.textContent.trim() === 'Start').map(b => b.getBoundingClientRect().width))""")
    assert controls <= CONTROLS_WIDTH, controls
    _click_tab(page, "stiffness")


def _check_inputs_are_named(page) -> None:
    """Every visible input of the page has an accessible name (a label tied to it, or
    aria-labelledby / aria-label naming it): viser's text inputs had none."""
    unnamed = page.evaluate("""() => [...document.querySelectorAll('input:not([type=hidden]), textarea')]
        .filter(e => e.offsetParent !== null)
        .filter(e => !(e.labels && e.labels.length) && !e.getAttribute('aria-label')
                     && !(e.getAttribute('aria-labelledby') || '').split(' ').some(id => {
                         const l = document.getElementById(id); return l && l.textContent.trim(); }))
        .map(e => e.outerHTML.slice(0, 120))""")
    assert not unnamed, unnamed
    for name in ("Log CSV", "Vehicle TOML", "Result CSV", "Particles N", "Seed"):
        assert page.get_by_label(name, exact=True).count() == 1, name


def _close_notices(page) -> None:
    """Close viser's notices (headless chromium's 'software WebGL' one sits over the controls
    at 1600 px)."""
    try:
        page.locator(".mantine-Notification-closeButton").first.wait_for(timeout=5000)
    except Exception:  # none came
        return
    close = page.locator(".mantine-Notification-closeButton")
    for k in range(close.count()):
        close.nth(k).click()


@pytest.mark.xdist_group("browser")  # one browser at a time (make test runs two workers)
def test_the_page_in_a_real_browser(fmu_paths, tmp_path, chromium):
    from playwright import sync_api  # the test extra (pip); its browser download is never used
    bad = tmp_path / "bad_log.csv"
    bad.write_text("t,ax,ay,yaw_rate,vx\n0.0,0.1,0.2,0.0,20.0\n")  # no steering column
    d = Dashboard(port=0, speed="2x", settings=Settings(particles=200, seed=SEED),  # still running when paused
                  data_dir="/")  # tmp files
    shots = []
    try:
        with sync_api.sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
            browser = pw.chromium.launch_persistent_context(
                profile, executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_FLAGS,
                viewport={"width": 1600, "height": 1000})
            try:
                page = browser.new_page()
                page.add_init_script(RECORD_CANVAS_TEXT)
                requests = []
                page.on("request", lambda r: requests.append(r.url))
                page.goto(d.url)
                status = page.locator("p", has_text=re.compile(r"^(idle|running|paused|finished|failed|result)"))
                _close_notices(page)
                wait_for(lambda: _note(page) == "Nothing to show yet: press Start for a run, or open a Result CSV.",
                         what="the empty tab's note")  # before a run, the tabs say why they are empty
                _check_inputs_are_named(page)
                page.get_by_role("button", name="Start", exact=True).click()
                page.get_by_text(re.compile(r"running · scenario paper-sim")).wait_for(timeout=60000)
                page.wait_for_function("() => document.querySelectorAll('.uplot canvas').length >= 3", timeout=60000)
                wait_for(lambda: _chart_has_line(page, 0), what="a line in the Cf_y chart")
                shots.append(tmp_path / "running.png")
                _shot(page, shots[-1])

                # paused before the slow layout checks, so that a slow machine cannot let the run finish first
                page.get_by_role("button", name="Pause", exact=True).click()
                page.get_by_text(re.compile(r"^paused · ")).wait_for(timeout=30000)
                t_paused = d.status()["t"]
                time.sleep(0.3)
                assert d.status()["t"] == t_paused
                _check_layout(page, tmp_path)

                n_input = page.get_by_label("Particles N", exact=True)
                n_input.fill("100")
                n_input.press("Enter")
                wait_for(lambda: d._particles.value == 100, what="N to reach the server")
                page.get_by_role("button", name="Restart", exact=True).click()
                page.get_by_text(re.compile(r"estimator mpf \(N = 100\)")).wait_for(timeout=60000)
                assert d._run.estimator.cfg.particles == 100
                wait_for(lambda: d.status()["rows"] > 50 and _chart_has_line(page, 0), what="the restarted run")
                shots.append(tmp_path / "restarted.png")
                _shot(page, shots[-1])

                # a Result CSV (typed into its named input): the tabs it cannot fill say why
                results = tmp_path / "results.csv"
                short = replace(load_scenario("paper-sim"), duration=2.0)
                run_scenario(short, estimator=build_estimator("mpf", short, model="auto", particles=N_SMALL, config={}),
                             seed=SEED, results_csv=results)
                page.get_by_label("Result CSV", exact=True).fill(str(results))
                wait_for(lambda: d._result_path.value == str(results), what="the Result CSV's path")
                page.get_by_role("button", name="Open Result CSV", exact=True).click()
                page.get_by_text(re.compile(r"^result · Result CSV results\.csv")).wait_for(timeout=60000)
                for tab in ("densities", "particles", "friction"):
                    _click_tab(page, tab)
                    wait_for(lambda: _note(page).startswith("Not in this file:"), what=f"the {tab} tab's note")
                    assert not _charts_on_page(page), tab  # nothing but the note
                shots.append(tmp_path / "result-densities.png")
                _shot(page, shots[-1])
                _click_tab(page, "stiffness")

                page.get_by_label("Source", exact=True).click()
                page.get_by_role("option", name="log", exact=True).click()
                page.get_by_label("Log CSV", exact=True).fill(str(bad))
                wait_for(lambda: d._log.value == str(bad) and d._source.value == "log", what="the log settings")
                page.get_by_role("button", name="Restart", exact=True).click()
                message = page.get_by_text(re.compile(r"^Error: .*bad_log\.csv"))
                message.wait_for(timeout=60000)
                assert "steering" in message.inner_text()
                shots.append(tmp_path / "error.png")
                _shot(page, shots[-1])
                assert urllib.request.urlopen(d.url, timeout=5).status == 200  # still serving
                assert status.count() >= 1
                local = (d.url, d.url.replace("http://", "ws://"), "data:", "blob:")
                assert requests and all(u.startswith(local) for u in requests), \
                    f"the page asked for {[u for u in requests if not u.startswith(local)]}"  # nothing from the network
            finally:
                browser.close()
    finally:
        d.stop()
    for shot in shots:
        assert shot.is_file() and _not_blank(shot) > 5.0, f"{shot} looks blank"


def test_density_chart_is_the_mixture_on_a_grid_around_it_with_the_truth():
    from scipy import stats

    from tirefilter.viz.density import gaussian_marginals
    from tirefilter_viewer.views import DENSITY_POINTS, density_data

    mix = gaussian_marginals(np.log([0.25, 0.75]), [[1.0e5], [1.1e5]], [[2e3], [4e3]], ("Cf_y",))
    x, pdf, truth = density_data(mix, "Cf_y", truth=1.5e5)  # beyond mean + 6 std
    mean = 0.25 * 1.0e5 + 0.75 * 1.1e5
    std = math.sqrt(0.25 * ((1e5 - mean) ** 2 + 2e3 ** 2) + 0.75 * ((1.1e5 - mean) ** 2 + 4e3 ** 2))
    assert len(x) == DENSITY_POINTS + 1 and np.all(np.diff(x) >= 0)
    assert x[0] == pytest.approx((mean - 6 * std) * 1e-3) and x[-1] == pytest.approx((1.5e5 + std) * 1e-3)
    exact = (0.25 * stats.norm.pdf(x * 1e3, 1e5, 2e3) + 0.75 * stats.norm.pdf(x * 1e3, 1.1e5, 4e3)) * 1e3
    # per kN/rad; viz.density leaves points below 1e-12 of a component's peak at 0
    np.testing.assert_allclose(pdf, exact, rtol=1e-9, atol=1e-11 * exact.max())
    k = np.flatnonzero(np.isfinite(truth))
    assert len(k) == 1 and x[k[0]] == pytest.approx(150.0) and truth[k[0]] == pytest.approx(pdf.max())
    assert density_data(mix, "Cx") is None and density_data(None, "Cf_y") is None


def test_cloud_scatter_sorts_x_splits_the_heaviest_tenth_and_adds_the_truth():
    from tirefilter_viewer.views import cloud_scatter

    rng = np.random.default_rng(0)
    values = np.column_stack([rng.normal(1e5, 1e3, 50), rng.normal(1.2e5, 1e3, 50)])
    w = rng.random(50)
    w /= w.sum()
    x, light, heavy, truth = cloud_scatter((("Cf_y", "Cr_y"), values, w, np.array([1e5, 1.2e5])), "Cf_y", "Cr_y",
                                           {"Cf_y": 1.01e5, "Cr_y": 1.19e5})
    assert len(x) == 51 and np.all(np.diff(x) >= 0)
    assert np.count_nonzero(np.isfinite(heavy)) == np.count_nonzero(w >= np.quantile(w, 0.9)) == 5
    assert np.count_nonzero(np.isfinite(light)) == 45
    k = np.flatnonzero(np.isfinite(truth))
    assert len(k) == 1 and (x[k[0]], truth[k[0]]) == (pytest.approx(101.0), pytest.approx(119.0))
    pairs = sorted(zip(x[np.isfinite(light) | np.isfinite(heavy)], np.fmax(light, heavy)[np.isfinite(light)
                                                                                      | np.isfinite(heavy)]))
    np.testing.assert_allclose(pairs, sorted(zip(values[:, 0] * 1e-3, values[:, 1] * 1e-3)))
