"""Sensor faults (scenarios.faults) and the measurement guard (estimators.guard): the
injector and the guard against exact answers, faults in a scenario TOML, and replays of a
co-simulated drive with faults for every stiffness estimator (finite, no restart on a
spike, recovery within 5 s of a fault's end)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from tirefilter.io.results import read_results
from tirefilter.errors import ConfigError
from tirefilter.estimators import build_log_estimator
from tirefilter.estimators.base import Measurement
from tirefilter.estimators.guard import GuardConfig, MeasurementGuard, guard_from_config
from tirefilter.replay import replay_log, result_columns
from tirefilter.io.log import Log
from tirefilter.scenarios import load_scenario
from tirefilter.scenarios.faults import Fault, fault_log_columns, fault_sets, fault_windows, parse_faults

DURATION, SEED, N = 20.0, 2, 100
# the MPF at its default N: at N = 100 this replay diverges and restarts on about a third of the estimator
# seeds (17 of 48 with main's defaults, 18 of 48 with the interval wheel slip), at N = 500 on none of 24
# (tools/bench_short_replay.py), so a test at N = 100 passes or fails by its seed
MPF_N = 500
RECOVERED_DEG = 0.1  # sideslip RMS error over [end + 5 s, end + 10 s) at most this above the clean replay's


# -- the guard ----------------------------------------------------------------------------------
def _run_guard(guard, ay, t=None):
    t = np.arange(len(ay)) * 0.01 if t is None else t
    return np.array([guard(tk, Measurement(ax=0.1 * math.sin(tk), ay=a, yaw_rate=0.0)).ay for tk, a in zip(t, ay)])


def _smooth(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    return 3 * np.sin(2 * np.pi * 0.5 * t) + 0.05 * rng.standard_normal(n)


def test_guard_removes_exactly_the_spikes_of_a_noisy_signal():
    ay = _smooth()
    spikes = [500, 1200, 1201, 2500]
    ay[spikes] += 20.0
    out = _run_guard(g := MeasurementGuard(), ay)
    assert np.flatnonzero(np.isnan(out)).tolist() == spikes
    assert g.counts()["outliers"] == {"ax": 0, "ay": 4, "yaw_rate": 0} and g.counts()["held"]["ay"] == 0
    np.testing.assert_array_equal(out[~np.isnan(out)], np.delete(ay, spikes))


def test_guard_passes_a_physical_step_and_accepts_a_lasting_level_change():
    ay = np.r_[np.zeros(100), np.full(100, 6.0)] + 0.01 * np.sin(np.arange(200))  # a steer step: passes
    assert not np.isnan(_run_guard(MeasurementGuard(), ay)).any()
    ay = np.r_[np.zeros(100), np.full(100, 12.0)] + 0.01 * np.sin(np.arange(200))  # beyond jump: a new level
    out = _run_guard(MeasurementGuard(), ay)
    rejected = np.flatnonzero(np.isnan(out))
    assert rejected.tolist() == list(range(100, 100 + GuardConfig().window // 2 + 1))  # until the median moves


def test_guard_marks_held_and_stuck_samples_missing():
    ay = _smooth(400)
    ay[101:103] = ay[100]  # held twice
    ay[200:300] = ay[199]  # stuck for 1 s
    out = _run_guard(g := MeasurementGuard(), ay)
    assert np.flatnonzero(np.isnan(out)).tolist() == [101, 102] + list(range(200, 300))
    assert g.counts()["held"]["ay"] == 102 and g.counts()["outliers"]["ay"] == 0


def test_guard_forgets_its_history_after_a_gap_and_can_be_switched_off():
    t = np.r_[np.arange(50) * 0.01, 5.0 + np.arange(50) * 0.01]
    ay = np.r_[np.zeros(50), np.full(50, 14.0)] + 0.01 * np.cos(np.arange(100))
    assert not np.isnan(_run_guard(MeasurementGuard(), ay, t)).any()  # the old level predicts nothing after 5 s
    ay = _smooth(200)
    ay[50] += 30
    ay[60] = ay[59]
    np.testing.assert_array_equal(_run_guard(MeasurementGuard(GuardConfig(enabled=False)), ay), ay)


@pytest.mark.parametrize("table, key", [({"window": 2}, "window"), ({"threshold": -1.0}, "threshold"),
                                        ({"jump": [1.0, 2.0]}, "jump"), ({"enabled": "yes"}, "enabled"),
                                        ({"speed": 1}, "speed"), ({"min_scale": [0, 0, float("nan")]}, "min_scale")])
def test_guard_table_errors_name_the_key(table, key):
    with pytest.raises(ConfigError, match=rf"\[guard\]: {key}"):
        guard_from_config({"guard": table})


# -- the injector ---------------------------------------------------------------------------------
def _inject(faults, n=2000, seed=0):
    t = np.arange(n) * 0.01
    signals = {"ax": np.sin(t), "ay": np.cos(t), "yaw_rate": 0.1 * t, "delta": 0 * t}
    return t, signals, fault_log_columns(t, signals, faults, np.random.default_rng(seed))


def test_injector_faults_against_exact_answers():
    t, s, (t2, out) = _inject([Fault("stuck", "yaw_rate", start=5.0, end=7.0),
                               Fault("spike", "ay", size=20.0, times=(3.0, 3.004, 12.345)),
                               Fault("bias_step", "ax", start=10.0, size=0.3), Fault("gap", start=15.0, end=16.0)])
    keep = (t < 15.0) | (t >= 16.0)
    np.testing.assert_array_equal(t2, t[keep])
    stuck = (t[keep] >= 5.0) & (t[keep] < 7.0)
    assert np.all(out["yaw_rate"][stuck] == s["yaw_rate"][np.argmax(t >= 5.0)])
    np.testing.assert_array_equal(out["yaw_rate"][~stuck], s["yaw_rate"][keep][~stuck])
    dy = out["ay"] - s["ay"][keep]
    assert np.flatnonzero(dy).tolist() == [300, 301, 1235] and np.allclose(dy[[300, 301, 1235]], 20.0)
    dx = out["ax"] - s["ax"][keep]
    np.testing.assert_allclose(dx[t[keep] >= 10.0], 0.3)
    assert not dx[t[keep] < 10.0].any()


def test_dropout_held_and_jitter_rates():
    t, s, (t2, out) = _inject([Fault("dropout", "ay", rate=0.2), Fault("held", "ax", rate=0.12),
                               Fault("jitter", size=0.001)], n=20000)
    share = np.mean(np.isnan(out["ay"]))
    assert abs(share - 0.2) < 3 * math.sqrt(0.2 * 0.8 / 20000)
    held = np.mean(out["ax"][1:] == out["ax"][:-1])
    assert abs(held - 0.12) < 3 * math.sqrt(0.12 * 0.88 / 20000)
    assert np.all(np.diff(t2) > 0)
    assert abs(np.std(t2 - t) - 0.001) < 0.0001


@pytest.mark.parametrize("entry, key", [({"kind": "burst"}, "faults[0].kind"),
                                        ({"kind": "dropout", "signal": "ay"}, "faults[0].rate"),
                                        ({"kind": "dropout", "signal": "ay", "rate": 1.5}, "faults[0].rate"),
                                        ({"kind": "spike", "signal": "speed", "size": 1, "times": [1]},
                                         "faults[0].signal"),
                                        ({"kind": "gap", "start": 5, "end": 4}, "faults[0].end"),
                                        ({"kind": "gap", "size": 1}, "faults[0].size"),
                                        ({"kind": "spike", "signal": "ay", "size": 1, "times": ["a"]},
                                         "faults[0].times")])
def test_fault_errors_name_entry_and_key(entry, key):
    with pytest.raises(ConfigError, match=rf"x.toml: {re.escape(key)}"):
        parse_faults([entry], "x.toml")


# -- a scenario with faults ------------------------------------------------------------------------
def test_scenario_faults_reach_the_estimator_not_the_truth(fmu_paths, tmp_path):
    from tirefilter.cli import main

    base = (load_scenario("paper-sim").file).read_text()
    text = base.replace("duration = 60.0", "duration = 6.0").replace("excitation = [[0.0, 60.0]]",
                                                                     "excitation = [[0.0, 6.0]]")
    text += ('\n[[faults]]\nkind = "spike"\nsignal = "ay"\nsize = 20.0\ntimes = [2.0, 4.0]\n'
             '\n[[faults]]\nkind = "gap"\nstart = 3.0\nend = 3.5\n')
    path = tmp_path / "faulty.toml"
    path.write_text(text)
    assert load_scenario(path).faults[0] == Fault("spike", "ay", size=20.0, times=(2.0, 4.0))
    assert main(["run", "--scenario", str(path), "--estimator", "ekf", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "out" / "run.json").read_text())
    assert summary["guard"]["outliers"]["ay"] == 2 and summary["steps"] == 601 - 50
    r = read_results(tmp_path / "out" / "results.csv")
    assert not np.any((r["t"] >= 3.0) & (r["t"] < 3.5))
    assert np.all(np.isfinite(r["beta"])) and np.max(np.abs(r["meas_ay"])) < 15  # the table keeps the clean sensor


# -- replays with faults, every estimator ---------------------------------------------------------
@pytest.fixture(scope="module")
def drive(fmu_paths):
    """paper-sim for 20 s co-simulated without an estimator, as a Log with the true sideslip."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_faults import paper_sim_drive

    log, vehicle = paper_sim_drive(SEED)
    keep = log.t <= DURATION
    cut = {k: v[keep] for k, v in log.columns.items()}
    log = Log(path=log.path, t=cut["t"], signals={s: cut[s] for s in log.signals}, columns=cut, header=log.header,
              lines=log.lines[keep])
    return log, vehicle


@pytest.fixture(scope="module")
def clean(drive):
    """clean(name): `_replay(drive, name, ())`, the fault-free replay the fault tests compare
    with, made once per module and estimator (seeded: every call gave the same arrays; the
    tests only read them)."""
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = _replay(drive, name, ())
        return cache[name]

    return get


def _replay(drive, name, faults):
    from bench_faults import faulty_log

    log, vehicle = drive
    flog = faulty_log(log, faults, SEED)[0] if faults else log
    est = build_log_estimator(name, vehicle, flog.t, {s: flog.signals[s] for s in flog.available}, model="auto",
                              particles={"gpssm": 20, "mpf": MPF_N}.get(name, N), config={}, source="test")  # gpssm: cost
    summary, rows = replay_log(flog, estimator=est, seed=SEED, keep_rows=True)
    r = dict(zip(result_columns(flog), rows.T))
    err = np.degrees(r["beta"] - flog.columns["beta_true"])
    return r, err, getattr(est, "restarts", 0), summary.guard, flog


@pytest.mark.parametrize("name", ["mpf", "augpf", "rls", "ekf", "kf", "gpssm"])
def test_estimators_stay_finite_and_do_not_restart_on_spikes(drive, clean, name):
    sets = fault_sets(DURATION)
    _, err0, restarts0, _, _ = clean(name)
    r, err, restarts, guard, _ = _replay(drive, name, sets["spike"])
    assert guard["outliers"]["ay"] == 5 and restarts == restarts0
    assert np.sqrt(np.mean(err ** 2)) <= 1.5 * np.sqrt(np.mean(err0 ** 2)) + 0.02
    r, err, restarts, guard, _ = _replay(drive, name, sets["combined"])
    assert all(np.isfinite(r[c]).all() for c in ("vx", "vy", "yaw_rate", "beta"))
    if name != "gpssm":
        assert np.isfinite(r["Cf_y"]).all() and np.isfinite(r["Cr_y"]).all()


@pytest.mark.parametrize("name, fault", [("mpf", "stuck"), ("mpf", "gap"), ("ekf", "stuck"), ("ekf", "gap")])
def test_sideslip_recovers_within_5_s_of_the_fault_end(drive, clean, name, fault):
    faults = fault_sets(DURATION)[fault]
    _, err0, _, _, _ = clean(name)
    r, err, _, _, flog = _replay(drive, name, faults)
    (start, end), = fault_windows(faults)
    w, w0 = (flog.t >= end + 5.0) & (flog.t < end + 10.0), (drive[0].t >= end + 5.0) & (drive[0].t < end + 10.0)
    assert w.sum() > 100
    assert np.sqrt(np.mean(err[w] ** 2)) <= np.sqrt(np.mean(err0[w0] ** 2)) + RECOVERED_DEG
