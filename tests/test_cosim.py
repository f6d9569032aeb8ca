"""The co-simulation run: Result CSV, run summary, reference, partial results, Rerun."""

from __future__ import annotations

import json

import numpy as np
import pytest

from make_reference import COLUMNS, REFERENCE, reference_rows
from tirefilter.cli import main
from tirefilter.io.results import read_results
from tirefilter.errors import FMUError
from tirefilter.cosim.run import run_scenario
from tirefilter.scenarios import load_scenario

REQUIRED = ("t", "active", "vx", "vy", "yaw_rate", "beta", "Cf_y", "Cr_y", "Cx", "Cf_y_std", "Cr_y_std", "Cx_std",
            "Cf_y_sigma", "Cr_y_sigma", "Cx_sigma", "b_ax", "b_ay", "b_yaw_rate", "ess",
            "true_vx", "true_vy", "true_yaw_rate", "true_beta", "true_alpha_f", "true_alpha_r",
            "true_Cf_y", "true_Cr_y", "true_Cx", "true_Cf_y_mean", "true_Cr_y_mean", "true_Cx_mean",
            "true_b_ax", "true_b_ay", "true_b_yaw_rate")


def test_reference_csv_is_reproduced(fmu_paths):
    """The committed reference (tests/make_reference.py) is what the FMU computes today."""
    ref = np.loadtxt(REFERENCE, delimiter=",", skiprows=1)
    with open(REFERENCE) as f:
        assert tuple(f.readline().strip().split(",")) == COLUMNS
    now = reference_rows()
    assert now.shape == ref.shape
    scale = np.maximum(np.max(np.abs(ref), axis=0), 1e-12)
    np.testing.assert_allclose(now / scale, ref / scale, rtol=0, atol=1e-9)


def test_run_command_writes_results_summary_and_recording(fmu_paths, tmp_path, capsys):
    out = tmp_path / "run"
    rrd = tmp_path / "run.rrd"
    assert main(["run", "--scenario", "snow-sine", "--estimator", "none", "--seed", "2", "--out", str(out), "--rrd",
                 str(rrd), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "4001 samples" in printed and "results:" in printed

    r = read_results(out / "results.csv")
    for col in REQUIRED:
        assert col in r, col
    assert len(r["t"]) == 4001
    np.testing.assert_allclose(np.diff(r["t"]), 0.01, atol=1e-9)
    assert np.isnan(r["Cf_y"]).all() and np.isnan(r["vy"]).all()  # no estimator: empty estimate columns
    np.testing.assert_allclose(r["true_beta"], np.arctan2(r["true_vy"], r["true_vx"]), atol=1e-12)
    assert np.ptp(r["true_b_yaw_rate"]) > 0  # bias random walk is on in snow-sine

    summary = json.loads((out / "run.json").read_text())
    for key in ("version", "command", "seed", "estimator", "model", "N", "estimator_config", "steps",
                "wall_time_s", "median_step_us"):
        assert key in summary, key
    assert summary["seed"] == 2 and summary["steps"] == 4001 and summary["estimator"] == "none"
    assert summary["status"] == "ok"

    series = _rrd_series(rrd, "/truth/vx")
    np.testing.assert_allclose(series[0], r["t"], atol=1e-9)
    np.testing.assert_allclose(series[1], r["true_vx"], rtol=1e-12)
    sensors = _rrd_series(rrd, "/sensors/yaw_rate")
    np.testing.assert_allclose(sensors[1], r["meas_yaw_rate"], rtol=1e-12)


def _rrd_series(path, entity):
    """(times [s], values) of a scalar entity in a recording."""
    from rerun.chunk import RrdReader

    times, values = [], []
    for chunk in RrdReader(path).store().stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        t = batch.column(names.index("sim_time")).cast("int64").to_numpy() * 1e-9
        v = np.concatenate(batch.column(names.index("Scalars:scalars")).to_pylist())
        times.append(t)
        values.append(v)
    assert times, f"{entity} not in {path}"
    t, v = np.concatenate(times), np.concatenate(values)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


def test_failed_run_keeps_rows_before_the_failure(fmu_paths, tmp_path):
    scenario_file = tmp_path / "stop.toml"
    scenario_file.write_text("""
name = "stop"
duration = 30.0
estimator_rate = 100.0
[tires]
model = "linear"
[truth]
vx0 = 8.0
[[inputs.brake_torque]]
type = "steps"
times = [0.0, 2.0]
values = [0.0, 3000.0]
""")
    out = tmp_path / "out"
    rc = main(["run", "--scenario", str(scenario_file), "--out", str(out), "--quiet"])
    assert rc == 1
    r = read_results(out / "results.csv")
    assert 200 < len(r["t"]) < 3001  # rows up to the failure, not the whole run
    assert r["true_vx"][-1] < 1.5
    summary = json.loads((out / "run.json").read_text())
    assert summary["status"] == "failed" and "v_min" in summary["error"]
    with pytest.raises(FMUError, match=r"t = \d+\.\d+ s"):
        run_scenario(load_scenario(scenario_file), seed=0)


def test_scenarios_json_lists_schedules(capsys):
    assert main(["scenarios", "--json"]) == 0
    records = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert set(records) == {"paper-sim", "snow-sine", "asphalt-normal", "friction-snow"}
    assert records["paper-sim"]["surface_changes"] == [30.0]
    assert records["paper-sim"]["estimator_rate"] == 100.0
    assert records["friction-snow"]["estimator_rate"] == 25.0
    assert records["asphalt-normal"]["excitation"] == [[67.0, 400.0]]
    for r in records.values():
        assert {"name", "duration", "estimator_rate", "excitation", "surface_changes"} <= set(r)


def test_samples_at_a_slower_estimator_rate(fmu_paths):
    scenario = load_scenario("friction-snow")  # 25 Hz estimator, 10 ms communication step
    from dataclasses import replace

    summary, rows = run_scenario(replace(scenario, duration=4.0), seed=1, keep_rows=True)
    assert summary.steps == 101 and summary.communication_steps == 400
    np.testing.assert_allclose(np.diff(rows[:, 0]), 0.04, atol=1e-9)


def test_run_summary_states_the_metrics_of_its_results(fmu_paths, tmp_path, capsys):
    """run.json `metrics` is `metrics.run_metrics` of the Result CSV written (with the
    scenario's windows and the estimator's counters), and the printed summary states it."""
    from tirefilter.metrics import run_metrics
    from tirefilter.scenarios import load_scenario

    short = tmp_path / "paper-sim-short.toml"
    short.write_text(load_scenario("paper-sim").file.read_text().replace("duration = 60.0", "duration = 8.0")
                     .replace("excitation = [[0.0, 60.0]]", "excitation = [[0.0, 8.0]]"))
    out = tmp_path / "run"
    assert main(["run", "--scenario", str(short), "--particles", "40", "--seed", "1", "--out", str(out),
                 "--quiet"]) == 0
    printed = capsys.readouterr().out
    m = json.loads((out / "run.json").read_text())["metrics"]
    expected = run_metrics(read_results(out / "results.csv"), load_scenario(short), restarts=m["restarts"],
                           resamples=m["resamples"], cx_excitation=m["cx_excitation"])
    assert json.loads(json.dumps(expected)) == m
    assert m["cx_excitation"] > 0.5  # paper-sim's torque steps excite Cx (derivations, "The undriven axle")
    assert m["settled_windows"] == [[5.0, 8.0]] and set(m["stiffness"]) == {"Cf_y", "Cr_y", "Cx"}
    assert m["resamples"] > 0 and m["restarts"] >= 0 and 0 < m["gate_open_share"] <= 1
    assert "mean |err|" in printed and "settled" in printed and "90% band, settled" in printed
    assert f"restarts {m['restarts']}, resamples {m['resamples']}" in printed
    vy = next(line for line in printed.splitlines() if line.startswith("vy "))
    assert vy.split()[1:5] == [f"{m['state']['vy']['rmse']:.3g}", "m/s", f"{m['state']['vy']['settled_rmse']:.3g}",
                               "m/s"]
