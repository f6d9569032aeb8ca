"""Replay of recorded logs: the reader and its errors, the replay loop against the
co-simulation it was recorded from, check-log, the CLI, and the real MBDS recording."""

from __future__ import annotations

import gzip
import importlib.util
import json
import math
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from figures import within

from conftest import skip_or_fail_in_ci
from tirefilter.cli import main
from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.io.results import ESTIMATE_COLUMNS, INPUT_TRUTH_COLUMNS, read_results, truth_column
from tirefilter.cosim.run import run_scenario
from tirefilter.errors import ConfigError, LogError, ReplayError
from tirefilter.estimators import build_log_estimator, mpf_config_for_log
from tirefilter.estimators.base import Estimate
from tirefilter.replay import check_log, read_log, replay_log, result_columns, write_log
from tirefilter.scenarios import load_scenario
from tirefilter.vehicle.params import load_vehicle

REPO = Path(__file__).resolve().parents[1]
MBDS = REPO.parent / "shared" / "data" / "mbds-sideslip"
EXAMPLE = REPO / "examples" / "mbds-sideslip"
SEED, PARTICLES, DURATION = 3, 60, 10.0
# Log CSV column <- Result CSV column of a co-simulation (vx: the estimator's input is the true vx)
FROM_COSIM = {"t": "t", "delta": "meas_delta", "ax": "meas_ax", "ay": "meas_ay", "yaw_rate": "meas_yaw_rate",
              "vx": "true_vx", "omega_f": "meas_omega_f", "omega_r": "meas_omega_r"}


def _cosim(model: str):
    """paper-sim for 10 s with the MPF that a replay of its log builds (the same filter; what the
    log tells it, its noise, first samples and step, in place of what the scenario tells):
    (scenario, estimator, Result-CSV columns). The sensors do not depend on the estimator, so a
    first run gives the log the second run's estimator is built from."""
    scenario = load_scenario("paper-sim")
    scenario = replace(scenario, duration=DURATION, surface_changes=())
    with VehicleFMU("2") as fmu:
        names = ESTIMATE_COLUMNS + tuple(map(truth_column, fmu.output_names)) + INPUT_TRUTH_COLUMNS
    _, rows = run_scenario(scenario, seed=SEED, keep_rows=True)
    r = {c: rows[:, j] for j, c in enumerate(names)}
    signals = {name: r[col] for name, col in FROM_COSIM.items() if name != "t"}
    est = build_log_estimator("mpf", load_vehicle(VEHICLE), r["t"], signals, model=model, particles=PARTICLES,
                              config={"mpf": {"x0_std": [0.05, 0.05, 0.002]}})  # a known start: no divergence
    _, rows = run_scenario(scenario, estimator=est, seed=SEED, keep_rows=True)
    return scenario, est, {c: rows[:, j] for j, c in enumerate(names)}


@pytest.fixture(scope="module")
def cosim_full(fmu_paths):
    return _cosim("full")


@pytest.fixture(scope="module")
def cosim_lateral(fmu_paths):
    return _cosim("lateral")


@pytest.fixture(scope="module")
def log_columns(cosim_lateral):
    """The sensor columns of the co-simulation, as a log has them."""
    r = cosim_lateral[2]
    return {name: r[col] for name, col in FROM_COSIM.items()}


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(map(_toml_value, v)) + "]"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(v)


def _config_file(path: Path, cfg) -> Path:
    """An `[mpf]` table that sets every option (`USER_OPTIONS`) to the value in `cfg`."""
    from tirefilter.estimators.mpf.config import USER_OPTIONS

    items = [f"{k} = {_toml_value(getattr(cfg, k))}" for k in USER_OPTIONS]
    path.write_text("[mpf]\n" + "\n".join(items) + "\n")
    return path


VEHICLE = REPO / "src" / "tirefilter" / "scenarios" / "data" / "vehicles" / "midsize-suv.toml"


# ---- the round trip -----------------------------------------------------------------------
@pytest.mark.parametrize("model", ["lateral", "full"])
def test_replay_reproduces_the_cosimulation(request, tmp_path, capsys, model):
    """A log written from a co-simulation, replayed with the same vehicle, options and seed,
    gives the co-simulation's estimates exactly (the same filter, generator and inputs)."""
    scenario, est, r = request.getfixturevalue(f"cosim_{model}")
    assert scenario.vehicle == load_vehicle(VEHICLE)
    log = write_log(tmp_path / "log.csv", {name: r[col] for name, col in FROM_COSIM.items()})
    config = _config_file(tmp_path / "config.toml", est.cfg)
    out = tmp_path / "replay" / "result.csv"
    argv = ["replay", str(log), "--vehicle", str(VEHICLE), "--model", model, "--particles", str(PARTICLES),
            "--seed", str(SEED), "--config", str(config), "--out", str(out), "--quiet"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert f"{len(r['t'])} rows over 10 s" in printed and "final stiffness" in printed and "Cf_y" in printed

    got = read_results(out)
    assert tuple(got) == ESTIMATE_COLUMNS + tuple(f"meas_{s}" for s in FROM_COSIM if s != "t")
    for col in ESTIMATE_COLUMNS:
        np.testing.assert_array_equal(got[col], r[col], err_msg=col)
    for name, col in FROM_COSIM.items():
        np.testing.assert_array_equal(got["t" if name == "t" else f"meas_{name}"], r[col])
    for col in ("vx", "vy", "yaw_rate", "beta", "Cf_y", "Cr_y", "Cf_y_std", "Cr_y_std", "Cf_y_sigma", "ess"):
        assert np.isfinite(got[col]).all(), col
    assert got["active"].any()

    summary = json.loads(out.with_suffix(".json").read_text())
    for key in ("version", "command", "seed", "estimator", "model", "N", "estimator_config", "steps", "wall_time_s",
                "median_step_us", "status", "error", "log", "vehicle"):
        assert key in summary, key
    assert summary["status"] == "ok" and summary["error"] is None
    assert summary["seed"] == SEED and summary["N"] == PARTICLES and summary["model"] == model
    assert summary["steps"] == len(r["t"]) and summary["estimator"] == "mpf"
    assert summary["log"] == str(log) and summary["vehicle"] == str(VEHICLE)
    assert summary["estimator_config"]["forgetting"] == est.cfg.forgetting
    assert summary["final"]["Cf_y"] == r["Cf_y"][-1]


def test_log_configuration_comes_from_the_vehicle_and_the_log(log_columns):
    """Without overrides: nominal stiffness, the vehicle TOML's noise, the log's median
    step and first samples; the [mpf] table overrides."""
    vehicle = load_vehicle(VEHICLE)
    t = log_columns["t"].copy()
    t[5:] += 0.002  # one longer step: the median stays 0.01
    signals = {k: v for k, v in log_columns.items() if k != "t"}
    signals["yaw_rate"] = signals["yaw_rate"].copy()
    signals["yaw_rate"][0] = np.nan
    full = mpf_config_for_log(vehicle, t, signals, model="full", particles=None, overrides={})
    assert full.model == "full" and full.particles == 500
    assert full.init_center is None and full.init_std == 0.3 and full.init_reference is None
    assert full.sigma == (vehicle.sigma_ax, vehicle.sigma_ay, vehicle.sigma_yaw_rate)
    assert full.sample_period == pytest.approx(0.01, abs=1e-12)
    assert full.x0_mean == (signals["vx"][0], 0.0, signals["yaw_rate"][1])
    no_vx = {k: v for k, v in signals.items() if k != "vx"}
    vx_wheel = mpf_config_for_log(vehicle, t, no_vx, model="full", particles=None, overrides={}).x0_mean[0]
    assert vx_wheel == vehicle.wheel_radius * signals["omega_r"][0]  # front drive: the rear axle is undriven
    lateral = mpf_config_for_log(vehicle, t, signals, model="lateral", particles=40,
                                 overrides={"forgetting": 0.995, "sigma": [0.1, 0.2, 0.01]})
    assert lateral.x0_mean == (0.0, signals["yaw_rate"][1]) and lateral.particles == 40
    assert lateral.forgetting == 0.995 and lateral.sigma == (0.1, 0.2, 0.01)

    est = build_log_estimator("mpf", vehicle, t, signals, model="auto", particles=20, config={}, source="log.csv")
    assert est.cfg.model == "full"
    only_vx = {k: v for k, v in signals.items() if not k.startswith("omega")}
    assert build_log_estimator("mpf", vehicle, t, only_vx, model="auto", particles=20, config={}).cfg.model == "lateral"
    with pytest.raises(ConfigError, match=r"log\.csv: columns: the full model needs omega_f and omega_r"):
        build_log_estimator("mpf", vehicle, t, only_vx, model="full", particles=20, config={}, source="log.csv")
    with pytest.raises(ConfigError, match=r"the lateral model needs vx \(available: delta, ax, ay, yaw_rate, omega_f"):
        build_log_estimator("mpf", vehicle, t, no_vx, model="lateral", particles=20, config={}, source="log.csv")
    with pytest.raises(ConfigError, match="unknown option"):
        build_log_estimator("mpf", vehicle, t, signals, model="full", particles=20, config={"mpf": {"lamda": 1}})
    assert build_log_estimator("none", vehicle, t, signals, model="auto", particles=None, config={}) is None


# ---- bad input ----------------------------------------------------------------------------
GOOD = "t,delta,ax,ay,yaw_rate,vx\n" + "".join(f"{0.01 * k:.2f},0.01,0.1,0.5,0.02,20.0\n" for k in range(6))


def _with_cell(row: int, column: str, value: str, text: str = GOOD) -> str:
    """`text` with the cell of data row `row` (1-based) in `column` replaced."""
    lines = text.splitlines()
    j = lines[0].split(",").index(column)
    cells = lines[row].split(",")
    cells[j] = value
    lines[row] = ",".join(cells)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("text,expected", [
    (GOOD.replace("yaw_rate", "gyro_z"),
     [r"missing required column 'yaw_rate'", r"the file has: t, delta, ax, ay, gyro_z, vx"]),
    (GOOD.replace("delta", "steer").replace(",vx", ",speed"),
     [r"missing required columns 'delta' \(or 'steering_wheel_angle'\), 'vx' and/or 'omega_f', 'omega_r'",
      r"the file has: t, steer, ax, ay, yaw_rate, speed"]),
    (GOOD.replace(",", ";"), [r"missing required columns", r"separated by ';'"]),
    (_with_cell(3, "ay", "abc"), [r"column 'ay', data row 3 \(file line 4\): 'abc' is not a number"]),
    (_with_cell(2, "yaw_rate", "0,02".replace(",", "_x")), [r"column 'yaw_rate', data row 2 \(file line 3\): '0_x02'"]),
    (_with_cell(5, "ax", "inf"), [r"column 'ax', data row 5 \(file line 6\): 'inf' is not a finite number"]),
    (_with_cell(4, "t", "0.02"),
     [r"column 't', data row 4 \(file line 5\): time must increase strictly: t = 0.02 s after t = 0.02 s in data row 3"]),
    (_with_cell(2, "t", "0.0"), [r"column 't', data row 2 \(file line 3\): time must increase strictly: t = 0.0 s"]),
    (_with_cell(3, "t", ""), [r"column 't', data row 3 \(file line 4\): missing time"]),
    (_with_cell(5, "vx", "-3.5"),
     [r"column 'vx', data row 5 \(file line 6\): vx = -3.5 m/s is negative: reverse driving is not supported"]),
    ("", [r"empty file"]),
    ("\n\n", [r"empty file"]),
    ("t,delta,ax,ay,yaw_rate,vx\n", [r"no data rows after the header"]),
    (GOOD.replace("0.03,0.01,0.1,0.5,0.02,20.0", "0.03,0.01,0.1,0.5,20.0"),
     [r"data row 4 \(file line 5\): 5 cells for the header's 6 columns"]),
    ("t,delta,ax,ay,yaw_rate,vx,ay\n0,0,0,0,0,20,0\n", [r"column 'ay', file line 1: the header names column 'ay'"]),
    (GOOD.replace("delta", "steering_wheel_angle"),
     [r"column 'steering_wheel_angle': .*needs steering_ratio in a vehicle TOML \(none given\)"]),
])
def test_bad_logs_get_errors_naming_file_column_row_and_value(tmp_path, text, expected):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(LogError) as info:
        read_log(path)
    message = str(info.value)
    assert message.startswith(str(path)), message
    for pattern in expected:
        assert re.search(pattern, message), (pattern, message)


def test_log_errors_name_the_vehicle_and_reach_the_cli_without_traceback(tmp_path, capsys):
    path = tmp_path / "swa.csv"
    path.write_text(GOOD.replace("delta", "steering_wheel_angle"))
    vehicle = tmp_path / "no-ratio.toml"
    vehicle.write_text("\n".join(line for line in VEHICLE.read_text().splitlines()
                                 if not line.startswith("steering_ratio")))
    with pytest.raises(LogError, match=f"{vehicle} has none"):
        read_log(path, vehicle)
    bad = tmp_path / "bad.csv"
    bad.write_text(_with_cell(3, "ay", "abc"))
    for argv in (["check-log", str(bad)], ["replay", str(bad), "--vehicle", str(VEHICLE), "--out", str(tmp_path / "r.csv")],
                 ["check-log", str(tmp_path / "missing.csv")]):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.startswith("error: ") and "Traceback" not in err, err
    assert "data row 3 (file line 4): 'abc' is not a number" in err or "file not found" in err
    assert not (tmp_path / "r.csv").exists()


def test_low_speed_is_no_error(tmp_path):
    """Below the gate speed the MPF only stops learning; standstill noise in vx is allowed."""
    path = tmp_path / "slow.csv"
    path.write_text(_with_cell(2, "vx", "-0.05", GOOD.replace("20.0", "1.0")))
    summary = check_log(path)
    assert summary.gates["share_speed_below"] == 1.0 and summary.usable


# ---- missing samples, irregular sampling, conversions -------------------------------------
def _damaged(log_columns, seed=0):
    """The co-simulation's log with 20% of the rows dropped, one 0.5 s gap, t jittered by
    up to +-2 ms, and cells emptied in every signal."""
    rng = np.random.default_rng(seed)
    n = len(log_columns["t"])
    keep = rng.random(n) > 0.2
    keep[300:350] = False  # a 0.5 s gap
    keep[:3] = True
    cols = {k: v[keep].copy() for k, v in log_columns.items()}
    cols["t"] = cols["t"] + rng.uniform(-0.002, 0.002, len(cols["t"]))
    for name in ("delta", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r"):
        holes = rng.random(len(cols["t"])) < 0.1
        holes[:2] = False
        cols[name][holes] = np.nan
    cols["ay"][400:420] = np.nan
    return cols


@pytest.mark.parametrize("model", ["lateral", "full"])
def test_missing_samples_and_irregular_sampling_give_finite_estimates(fmu_paths, log_columns, tmp_path, model):
    path = write_log(tmp_path / "damaged.csv", _damaged(log_columns))
    log = read_log(path)
    assert log.rows < 0.8 * len(log_columns["t"]) and np.isnan(log.signals["ay"]).sum() > 20
    est = build_log_estimator("mpf", load_vehicle(VEHICLE), log.t, log.signals, model=model, particles=50,
                              config={"mpf": {"x0_std": [0.05, 0.05, 0.002]}})
    summary, rows = replay_log(log, estimator=est, seed=1, keep_rows=True, results_csv=tmp_path / "r.csv")
    assert summary.status == "ok" and summary.steps == log.rows
    r = {c: rows[:, j] for j, c in enumerate(result_columns(log))}
    for col in ("vx", "vy", "yaw_rate", "beta", "Cf_y", "Cr_y", "Cf_y_std", "Cr_y_sigma", "ess") + (
            ("Cx", "b_ay") if model == "full" else ()):
        assert np.isfinite(r[col]).all(), col
    np.testing.assert_array_equal(r["meas_ay"], log.signals["ay"])  # missing samples stay empty in the output
    assert r["active"].any()

    summary = check_log(path)
    assert summary.gaps["count"] >= 1 and summary.gaps["largest"]["dt"] > 0.45
    assert 2.9 < summary.gaps["largest"]["t"] < 3.0  # where it starts
    assert summary.columns["ay"]["missing"] == int(np.isnan(log.signals["ay"]).sum())


def test_steering_wheel_angle_corner_wheel_speeds_and_gzip(fmu_paths, log_columns, tmp_path):
    vehicle = load_vehicle(VEHICLE)
    cols = {k: v[:200] for k, v in log_columns.items()}
    plain = read_log(write_log(tmp_path / "plain.csv", cols))
    other = dict(cols, steering_wheel_angle=cols["delta"] * vehicle.steering_ratio,
                 omega_fl=cols["omega_f"] + 0.25, omega_fr=cols["omega_f"] - 0.25,
                 omega_rl=cols["omega_r"] * 1.01, omega_rr=cols["omega_r"] * 0.99, comment=np.arange(200.0))
    for name in ("delta", "omega_f", "omega_r"):
        del other[name]
    other["omega_rl"][7] = np.nan  # one corner missing: the axle sample is missing
    path = write_log(tmp_path / "other.csv.gz", other)
    with gzip.open(path, "rt") as f:
        assert f.readline().startswith("t,ax,")
    log = read_log(path, VEHICLE)
    assert log.ignored == ("comment",) and set(log.signals) == set(plain.signals)
    np.testing.assert_allclose(log.signals["delta"], plain.signals["delta"], rtol=1e-15, atol=0)
    np.testing.assert_allclose(log.signals["omega_f"], plain.signals["omega_f"], rtol=1e-14)
    assert np.isnan(log.signals["omega_r"][7])
    np.testing.assert_allclose(np.delete(log.signals["omega_r"], 7), np.delete(plain.signals["omega_r"], 7),
                               rtol=1e-14)
    assert "steering_ratio (16" in log.derived["delta"] and log.derived["omega_f"] == "mean of omega_fl and omega_fr"

    summary = check_log(path, VEHICLE)
    assert summary.models["full"]["supported"] and summary.models["auto"] == "full"
    assert "mean of omega_fl and omega_fr" in summary.models["full"]["reason"]
    assert summary.columns["delta"]["derived"].startswith("steering_wheel_angle / steering_ratio")
    without = check_log(path)  # no vehicle: the steering-wheel angle is reported, not converted
    assert "delta" not in without.columns and "not converted" in without.columns["steering_wheel_angle"]["note"]

    gz = write_log(tmp_path / "plain.csv.gz", cols)
    for name, x in read_log(gz).signals.items():
        np.testing.assert_array_equal(x, plain.signals[name])


# ---- failures -------------------------------------------------------------------------------
class _FailsAt:
    """An estimator that fails at its `k`-th step."""

    name = "failing"

    def __init__(self, k):
        self.k, self.calls = k, 0

    def reset(self, rng):
        self.calls = 0

    def step(self, t, u, y):
        self.calls += 1
        if self.calls > self.k:
            raise FloatingPointError("the filter diverged")
        return Estimate(active=False, vx=u.vx, vy=0.0, yaw_rate=y.yaw_rate, Cf_y=1.0, Cr_y=2.0)

    def posterior(self):
        raise NotImplementedError


def test_failed_replay_keeps_rows_and_says_failed(log_columns, tmp_path, monkeypatch, capsys):
    path = write_log(tmp_path / "log.csv", {k: v[:300] for k, v in log_columns.items()})
    log = read_log(path)
    with pytest.raises(ReplayError, match=r"data row 51 \(file line 52, t = 0\.5 s\): failing failed: "
                                          r"the filter diverged") as info:
        replay_log(log, estimator=_FailsAt(50), results_csv=tmp_path / "a.csv")
    assert info.value.summary.status == "failed" and info.value.summary.steps == 50
    assert len(read_results(tmp_path / "a.csv")["t"]) == 50

    import tirefilter.estimators

    monkeypatch.setattr(tirefilter.estimators, "build", lambda *a, **k: _FailsAt(120))
    out = tmp_path / "cli" / "result.csv"
    assert main(["replay", str(path), "--vehicle", str(VEHICLE), "--out", str(out), "--quiet"]) == 1
    assert "the filter diverged" in capsys.readouterr().err
    r = read_results(out)
    assert len(r["t"]) == 120 and (r["Cf_y"] == 1.0).all()
    summary = json.loads((tmp_path / "cli" / "result.json").read_text())
    assert summary["status"] == "failed" and "data row 121" in summary["error"] and summary["steps"] == 120


# ---- the command line -----------------------------------------------------------------------
def test_replay_without_estimator_and_with_a_recording(log_columns, tmp_path, capsys):
    path = write_log(tmp_path / "log.csv", {k: v[:150] for k, v in log_columns.items()})
    out, rrd = tmp_path / "result.csv", tmp_path / "replay.rrd"
    assert main(["replay", str(path), "--vehicle", str(VEHICLE), "--estimator", "none", "--out", str(out),
                 "--rrd", str(rrd), "--quiet"]) == 0
    assert "recording:" in capsys.readouterr().out
    r = read_results(out)
    assert np.isnan(r["Cf_y"]).all() and len(r["t"]) == 150
    np.testing.assert_array_equal(r["meas_vx"], log_columns["vx"][:150])
    summary = json.loads(out.with_suffix(".json").read_text())
    assert summary["estimator"] == "none" and summary["N"] is None and summary["median_step_us"] is None
    from test_cosim import _rrd_series

    t, ay = _rrd_series(rrd, "/sensors/ay")
    np.testing.assert_array_equal(ay, log_columns["ay"][:150])


def test_check_log_command(log_columns, tmp_path, capsys):
    cols = {k: v[:400] for k, v in log_columns.items()}
    cols["ay"] = cols["ay"] * 2.0  # some samples beyond the linear-region gate
    path = write_log(tmp_path / "log.csv", cols)
    assert main(["check-log", str(path)]) == 0
    printed = capsys.readouterr().out
    for text in ("400 rows", "median 100 Hz", "gaps (dt > 0.02 s): 0", "full model: yes", "lateral model: yes",
                 "--model auto: full", "|ay| > 4 m/s^2"):
        assert text in printed, text
    assert main(["check-log", str(path), "--vehicle", str(VEHICLE), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["rows"] == 400 and record["usable"] and record["models"]["auto"] == "full"
    share = np.mean(np.abs(cols["ay"]) > 4.0)
    assert 0 < share < 1 and record["gates"]["share_ay_above"] == pytest.approx(share)
    assert record["columns"]["omega_f"] == {"missing": 0, "min": cols["omega_f"].min(), "max": cols["omega_f"].max()}

    no_speed = write_log(tmp_path / "no-speed.csv", {k: v for k, v in cols.items() if not k.startswith("omega")}
                         | {"vx": np.full(400, np.nan)})
    assert main(["check-log", str(no_speed)]) == 1
    err = capsys.readouterr().err
    assert "no model can run on this log" in err and "needs vx (the column has no samples)" in err


def test_help_starts_without_numpy():
    """`tirefilter --help` stays fast: the command functions import what they need."""
    code = "import sys, tirefilter.cli; print(sorted(m for m in ('numpy', 'scipy', 'fmpy', 'rerun') if m in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "[]"


# ---- the real recording ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def mbds_log(tmp_path_factory):
    if not MBDS.is_dir():
        skip_or_fail_in_ci(f"the MBDS recording is not at {MBDS} (shared data beside the repository)")
    spec = importlib.util.spec_from_file_location("mbds_convert", EXAMPLE / "convert.py")
    convert = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(convert)
    return convert.convert(convert.DATA, tmp_path_factory.mktemp("mbds") / "log.csv")


def test_real_recording_checks_and_replays(mbds_log, tmp_path):
    summary = check_log(mbds_log, EXAMPLE / "vehicle.toml")
    assert summary.rows == 55001 and summary.median_rate == pytest.approx(100.0, rel=1e-6)
    assert summary.gaps["count"] == 0
    assert all(c["missing"] == 0 for c in summary.columns.values())
    assert summary.ignored == () and summary.references == ("beta_true", "vy_true")
    assert not summary.models["full"]["supported"] and summary.models["auto"] == "lateral"
    assert 0.5 < summary.gates["share_ay_above"] < 0.6 and summary.gates["share_speed_below"] == 0.0

    log = read_log(mbds_log)
    assert set(log.references) == {"true_beta", "true_vy"}
    window = (log.t >= 280.0) & (log.t < 320.0)
    stretch = write_log(tmp_path / "stretch.csv", {**{name: x[window] for name, x in log.columns.items()},
                                                   "beta_true": log.references["true_beta"][window]})
    out = tmp_path / "result.csv"
    assert main(["replay", str(stretch), "--vehicle", str(EXAMPLE / "vehicle.toml"), "--model", "lateral",
                 "--particles", "50", "--out", str(out), "--quiet"]) == 0
    r = read_results(out)
    assert len(r["t"]) == 4000
    for col in ("vy", "yaw_rate", "beta", "Cf_y", "Cr_y", "Cf_y_std", "ess"):
        assert np.isfinite(r[col]).all(), col
    beta_true = read_results(mbds_log)["beta_true"][window]
    np.testing.assert_array_equal(r["true_beta"], beta_true)  # the reference is carried into the results
    rmse = np.sqrt(np.mean((r["beta"] - beta_true) ** 2))
    # measured 0.66 deg (seed 0, N = 50; seeds 1-7: 0.48-0.95 deg; the whole recording, N = 500: about 0.55 deg,
    # README); bound 1.5x. The estimate beta = 0 scores 1.37 deg on this stretch: the bound must be below that.
    # (300-320 s alone, the stretch before, scored 0.93 deg with beta = 0 at 1.20: its large sideslip comes in its
    # last 5 s, before the stiffness is learned, so no bound there told the filter from beta = 0.)
    within("sideslip RMSE deg, 320-360 s", math.degrees(rmse), 1.0)
    assert math.degrees(np.sqrt(np.mean(beta_true**2))) > 1.3
    metrics = json.loads(out.with_suffix(".json").read_text())["metrics"]
    assert metrics["state"]["beta"]["reference"] == "true_beta"
    assert metrics["state"]["beta"]["rmse"] == pytest.approx(rmse, rel=1e-9)  # scored in the summary
    assert metrics["stiffness"] == {} and metrics["diverged"]["signal"] == "beta"


def test_save_state_then_init_state_on_the_next_drive(log_columns, tmp_path, capsys):
    """Drive 1 saves its stiffness posterior, drive 2 (another N) starts from it; a state
    for another vehicle is refused with exit code 1 and the differing key named."""
    path = write_log(tmp_path / "log.csv", {k: v[:400] for k, v in log_columns.items()})
    state = tmp_path / "stiffness.json"
    base = ["replay", str(path), "--vehicle", str(VEHICLE), "--model", "lateral", "--quiet"]
    assert main(base + ["--particles", "60", "--out", str(tmp_path / "d1.csv"), "--save-state", str(state)]) == 0
    assert json.loads(state.read_text())["params"] == ["Cf_y", "Cr_y"]
    assert main(base + ["--particles", "80", "--out", str(tmp_path / "d2.csv"), "--init-state", str(state)]) == 0
    first, second = read_results(tmp_path / "d1.csv"), read_results(tmp_path / "d2.csv")
    # drive 2 starts where drive 1 ended (within the resampling spread): measured 0.0000 / 0.0003 (seed 0; seeds
    # 1-3 up to 0.0009, against drive 1's posterior std of 1.7-2.8 %); bound 3x the seeds' largest
    for p in ("Cf_y", "Cr_y"):
        assert abs(second[p][0] / first[p][-1] - 1) < 0.003, p
    assert json.loads((tmp_path / "d2.json").read_text())["estimator_config"]["init_state"] == str(state)
    capsys.readouterr()
    other = tmp_path / "other.toml"
    other.write_text(VEHICLE.read_text().replace("mass = 2050.0", "mass = 2150.0"))
    assert main(["replay", str(path), "--vehicle", str(other), "--model", "lateral", "--quiet", "--particles", "20",
                 "--out", str(tmp_path / "d3.csv"), "--init-state", str(state)]) == 1
    assert "different vehicle (mass: saved" in capsys.readouterr().err
