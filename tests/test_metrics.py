"""The run summary's metrics (`metrics.run_metrics`) against answers worked out by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tirefilter.metrics import (DIVERGED_VY, Z90, RunMetrics, format_metrics, metrics_line, run_metrics,
                               stiffness_errors)

T = np.round(np.arange(0, 2001) * 0.01, 10)  # 0 .. 20 s at 100 Hz
SCHEDULE = SimpleNamespace(excitation=((0.0, 20.0),), surface_changes=(10.0,))


def _run(**overrides) -> dict:
    """A run whose Cf_y error alternates +-4 % before t = 10 s and +-2 % after (signed mean
    0 in each half), with a surface change at 10 s that halves the truth."""
    n = T.size
    truth = np.where(T < 10.0, 8e4, 4e4)
    sign = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    rel = np.where(T < 10.0, 0.04, 0.02) * sign
    r = {"t": T, "active": (T >= 2.0).astype(float), "Cf_y": truth * (1 + rel), "true_Cf_y_mean": truth,
         "Cf_y_std": np.full(n, 0.03 * 8e4 / Z90),  # band +-2400 N/rad: holds the +-2 % half, not the +-4 % one
         "vy": np.zeros(n), "true_vy": np.full(n, 0.1), "beta": np.zeros(n), "true_beta": np.zeros(n)}
    r.update(overrides)
    return r


def test_errors_are_absolute_and_the_settled_window_follows_the_schedule():
    m = run_metrics(_run(), SCHEDULE, restarts=0, resamples=7)
    s = m["stiffness"]["Cf_y"]
    assert s["reference"] == "true_Cf_y_mean"
    # 1000 samples at 4 %, 1001 at 2 %: the signed mean would be ~0
    assert s["mean_abs_pct"] == pytest.approx((1000 * 4 + 1001 * 2) / 2001, rel=1e-9)
    # settled: 5-10 s (4 %, 500 samples) and 15-20 s (2 %, 501 samples)
    assert m["settled_windows"] == [[5.0, 9.99], [15.0, 20.0]]
    assert s["settled_mean_abs_pct"] == pytest.approx((500 * 4 + 501 * 2) / 1001, rel=1e-9)
    assert s["settled_mean_abs_pct"] == pytest.approx(stiffness_errors(_run(), SCHEDULE, "Cf_y")["mean_abs"])
    assert s["final_pct"] == pytest.approx(2.0)  # sample 2000 is even: +2 %
    # the band holds 2 % errors (1600 < 2400 N/rad at 8e4, 800 at 4e4) but not 4 % (3200 > 2400)
    assert s["coverage90"] == pytest.approx(1001 / 2001)
    assert s["settled_coverage90"] == pytest.approx(501 / 1001)
    assert s["settled_missing"] == 0
    # after 10 s the estimate is within 5 % at once
    assert s["settling_s"] == [0.0]
    assert m["state"]["vy"] == {"reference": "true_vy", "rmse": pytest.approx(0.1), "settled_rmse": pytest.approx(0.1),
                                "max_abs": pytest.approx(0.1), "unit": "m/s"}
    assert m["state_settled"] == "settled windows"
    assert m["restarts"] == 0 and m["resamples"] == 7
    assert m["gate_open_share"] == pytest.approx(1801 / 2001)
    assert m["diverged"]["samples"] == 0 and m["warnings"] == []


def test_log_references_without_a_schedule():
    """A replay: `<name>_true` columns are references, there is no settled window."""
    r = _run()
    r["beta_true"] = r.pop("true_beta") + 0.02
    r["vy_true"] = r.pop("true_vy")
    r["Cf_y_true"] = r.pop("true_Cf_y_mean")
    m = run_metrics(r)
    assert m["settled_windows"] is None and "settled_mean_abs_pct" not in m["stiffness"]["Cf_y"]
    assert m["stiffness"]["Cf_y"]["reference"] == "Cf_y_true"
    assert m["state"]["beta"]["reference"] == "beta_true" and m["state"]["beta"]["rmse"] == pytest.approx(0.02)
    assert m["restarts"] is None and m["resamples"] is None


def test_state_rmse_settled_leaves_out_the_start_up_and_the_changes():
    """vy off by 0.3 m/s before 5 s (start-up) and in 10-15 s (after the surface change),
    by 0.1 m/s elsewhere: the settled RMSE is 0.1 exactly, the whole run's is not; a replay
    (no schedule) leaves out the first STARTUP_S = 5 s."""
    from tirefilter.metrics import STARTUP_S

    off = np.where((T < 5.0) | ((T >= 10.0) & (T < 15.0)), 0.3, 0.1)
    r = _run(vy=np.zeros(T.size), true_vy=off)
    m = run_metrics(r, SCHEDULE)
    n_bad = np.count_nonzero(off == 0.3)
    assert m["state"]["vy"]["rmse"] == pytest.approx(np.sqrt((n_bad * 0.09 + (T.size - n_bad) * 0.01) / T.size))
    assert m["state"]["vy"]["settled_rmse"] == pytest.approx(0.1, rel=1e-12)
    replay = run_metrics(r)
    after = T >= STARTUP_S
    assert replay["state_settled"] == "after 5 s"
    assert replay["state"]["vy"]["settled_rmse"] == pytest.approx(np.sqrt(np.mean(off[after] ** 2)), rel=1e-12)
    assert _streamed(r, None, [300, 901])["state"]["vy"]["settled_rmse"] == pytest.approx(
        replay["state"]["vy"]["settled_rmse"], rel=1e-12)  # the same in chunks


def test_printed_summary_labels_each_window_and_unit():
    """Every column of the printed tables says the window it covers; beta is in degrees;
    the yaw rate's error stands beside the gyro's noise."""
    r = _run(beta=np.full(T.size, 0.01), yaw_rate=np.full(T.size, 0.002), true_yaw_rate=np.zeros(T.size))
    lines = format_metrics(run_metrics(r, SCHEDULE), {"yaw_rate": (0.0035, "gyro")})
    head = lines[:2]
    assert head[0].split() == ["stiffness", "error", "mean", "|err|", "mean", "|err|", "error", "truth", "in", "the",
                               "reference"]
    assert head[1].split() == ["whole", "run", "settled", "at", "end", "90%", "band,", "settled"]
    beta = next(line for line in lines if line.startswith("beta "))
    assert beta.split()[1:3] == [f"{np.degrees(0.01):.3g}", "deg"]  # 0.573 deg, not 0.01 rad
    yaw = next(line for line in lines if line.startswith("yaw_rate "))
    assert "0.002 rad/s" in yaw and "0.0035 rad/s gyro" in yaw
    states = next(k for k, line in enumerate(lines) if line.startswith("state error"))
    assert lines[states + 1].split() == ["whole", "run", "settled", "whole", "run", "(std)"]
    assert any(line.strip().startswith("(settled: from 5 s after each excitation start") for line in lines)
    replay = format_metrics(run_metrics(r))
    states = next(k for k, line in enumerate(replay) if line.startswith("state error"))
    assert replay[states + 1].split() == ["whole", "run", "after", "5", "s", "whole", "run", "(std)"]
    assert "whole run" in replay[1]  # the 90% band's share is over the whole run there


def test_divergence_restarts_and_overconfidence_are_warned():
    vy = np.zeros(T.size)
    bad = (T >= 2.2) & (T < 2.9)
    vy[bad] = -7.2
    std = np.full(T.size, 1.0)  # a band far too narrow
    m = run_metrics(_run(vy=vy, Cf_y_std=std), SCHEDULE, restarts=1)
    d = m["diverged"]
    assert d["signal"] == "vy" and d["threshold"] == DIVERGED_VY
    assert d["samples"] == int(bad.sum()) == 70 and d["windows"] == [[2.2, 2.89]]
    assert d["max_abs"] == pytest.approx(7.3)
    lines = format_metrics(m)
    warnings = [line for line in lines if line.startswith("warning:")]
    assert len(warnings) == 3
    assert any("diverged at 70 samples (2.2-2.89 s)" in w for w in warnings)
    assert any("restarted 1 time" in w for w in warnings)
    assert any("Cf_y: the 90% band" in w and "overconfident" in w for w in warnings)
    assert "restarts 1" in "\n".join(lines) and "DIVERGED" in metrics_line(m) and "1 restart(s)" in metrics_line(m)


@pytest.mark.parametrize("weight, said", [(None, False), (0.0, True), (0.49, True), (0.5, False), (1.0, False)])
def test_a_run_without_excitation_of_cx_says_so(weight, said):
    """The MPF's largest excitation weight of Cx (`cx_weight_max`) below CX_EXCITED = 0.5: one
    line says that Cx was not learned from the drive, in both the table's and the streamed metrics."""
    r = _run()
    for m in (run_metrics(r, SCHEDULE, cx_excitation=weight), _streamed(r, SCHEDULE, [700], cx_excitation=weight)):
        assert m["cx_excitation"] == weight
        lines = [w for w in format_metrics(m) if w.startswith("warning: Cx: no wheel-slip excitation")]
        assert len(lines) == (1 if said else 0)
        if said:
            assert f"at most {weight:.2f} of 1" in lines[0]


def test_missing_estimates_in_the_settled_window_are_counted():
    est = _run()["Cf_y"].copy()
    est[(T >= 16.0) & (T < 17.0)] = np.nan
    m = run_metrics(_run(Cf_y=est), SCHEDULE)
    assert m["stiffness"]["Cf_y"]["settled_missing"] == 100
    assert any("no estimate at 100 samples" in w for w in m["warnings"])


def test_no_reference_no_figures():
    r = {"t": T, "active": np.ones(T.size), "Cf_y": np.full(T.size, 1e5), "vy": np.zeros(T.size)}
    m = run_metrics(r)
    assert m["stiffness"] == {} and m["state"] == {} and m["diverged"] is None
    assert format_metrics(m) == ["learning gate open 100 % of the time"]


# -- the streamed metrics (metrics.RunMetrics): the same however the rows are cut into chunks ---------
def _same(a, b, path="m"):
    """Equal dicts, lists and numbers, floats to a relative 1e-12 (the order of summation)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), path
        for k in a:
            _same(a[k], b[k], f"{path}[{k!r}]")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-12, abs=0.0) if np.isfinite(a) else a == b, (path, a, b)
    else:
        assert type(a) is type(b) and a == b, (path, a, b)


def _streamed(r: dict, schedule, sizes, **counters) -> dict:
    """RunMetrics fed with `r` in chunks of the given sizes (cycled)."""
    m = RunMetrics(list(r), schedule)
    n, k, i = len(r["t"]), 0, 0
    while k < n:
        step = sizes[i % len(sizes)]
        m.update({c: v[k:k + step] for c, v in r.items()})
        k, i = k + step, i + 1
    return m.finalize(**counters)


def _rough_run(seed: int) -> dict:
    """60 s at 100 Hz with three stiffness parameters, NaN estimates and references, two
    surface changes, settling that ends inside and after a chunk, a divergence in bursts and
    std columns with gaps: every branch of the metrics at once."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(0, 6001) * 0.01, 10)
    n = t.size
    r = {"t": t, "active": (rng.random(n) < 0.7).astype(float)}
    for p, c0 in (("Cf_y", 8e4), ("Cr_y", 9e4), ("Cx", 2e5)):
        mean = np.where(t < 20.0, c0, np.where(t < 40.0, 0.5 * c0, 0.8 * c0))
        tau = rng.uniform(1.0, 4.0)
        since = np.where(t < 40.0, t - 20.0, t - 40.0)  # s since the last surface change
        lag = np.where(t < 20.0, 0.7, np.where(t < 40.0, 1.0, 0.5) * np.exp(-since / tau))
        est = mean * (1 + 0.3 * lag + 0.01 * rng.standard_normal(n))
        est[(t >= 50.0) & (t < 50.5)] = np.nan  # in the settled window: settled 10.5 s after the change at 40 s
        std = np.abs(mean * 0.04 * rng.standard_normal(n))
        std[rng.random(n) < 0.02] = np.nan
        r.update({p: est, f"true_{p}_mean": mean, f"{p}_std": std,
                  f"true_{p}": mean * (1 + 0.05 * rng.standard_normal(n))})
    r["true_Cx_mean"][t > 55.0] = np.nan
    vy_true = 0.3 * np.sin(t)
    vy = vy_true + 0.05 * rng.standard_normal(n)
    vy[(t > 12.0) & (t < 13.0) & (rng.random(n) < 0.5)] += 2.0  # bursts of divergence
    vy[rng.random(n) < 0.01] = np.nan
    r.update(vy=vy, true_vy=vy_true, beta=np.arctan2(vy, 20.0), true_beta=np.arctan2(vy_true, 20.0),
             yaw_rate=0.1 * np.sin(t) + 0.001 * rng.standard_normal(n), true_yaw_rate=0.1 * np.sin(t),
             vx=np.full(n, 20.0) + 0.1 * rng.standard_normal(n), true_vx=np.full(n, np.nan))
    return r


ROUGH_SCHEDULE = SimpleNamespace(excitation=((0.0, 30.0), (32.0, 60.0)), surface_changes=(20.0, 40.0, 70.0))


@pytest.mark.parametrize("sizes", [[1], [7, 1, 300], [8192], [999, 2]])
def test_streamed_metrics_equal_run_metrics(sizes):
    cases = [(_run(), SCHEDULE, {"restarts": 0, "resamples": 7}),
             (_run(vy=np.where((T >= 2.2) & (T < 2.9), -7.2, 0.0), Cf_y_std=np.full(T.size, 1.0)), SCHEDULE,
              {"restarts": 1}),
             ({"t": T, "active": np.ones(T.size), "Cf_y": np.full(T.size, 1e5), "vy": np.zeros(T.size)}, None, {}),
             (_rough_run(1), ROUGH_SCHEDULE, {"restarts": 3, "resamples": 40}),
             (_rough_run(2), None, {})]
    est = _run()["Cf_y"].copy()
    est[(T >= 16.0) & (T < 17.0)] = np.nan
    cases.append((_run(Cf_y=est), SCHEDULE, {}))
    log = _run()
    log["beta_true"] = log.pop("true_beta") + 0.02
    log["vy_true"] = log.pop("true_vy")
    log["Cf_y_true"] = log.pop("true_Cf_y_mean")
    cases.append((log, None, {}))
    late = _run(Cf_y=_run()["Cf_y"] * np.where(T > 19.0, 1.5, 1.0))  # never settles: inf
    cases.append((late, SCHEDULE, {}))
    for r, schedule, counters in cases:
        expected = run_metrics(r, schedule, **counters)
        _same(_streamed(r, schedule, sizes, **counters), expected)
    m = run_metrics(_rough_run(1), ROUGH_SCHEDULE)
    # the rough run exercises what it is meant to: finite settling times, divergence windows, NaN references
    assert m["stiffness"]["Cf_y"]["settling_s"] == [pytest.approx(30.5), pytest.approx(10.5)]
    assert m["stiffness"]["Cx"]["settling_s"] == [float("inf")] * 2  # no reference after 55 s: never settled
    assert m["stiffness"]["Cf_y"]["settled_missing"] == 50 and len(m["diverged"]["windows"]) > 5
    assert m["state"].keys() == {"vy", "beta", "yaw_rate"}
    assert run_metrics(late, SCHEDULE)["stiffness"]["Cf_y"]["settling_s"] == [float("inf")]


def test_streamed_metrics_need_the_time_column():
    with pytest.raises(ValueError, match="column t"):
        RunMetrics(["Cf_y"])


def test_a_replay_longer_than_a_chunk_states_the_metrics_of_its_results(tmp_path):
    """A replay's summary (`runs.Metrics`, 8192 rows a chunk) on 12 001 rows: the
    metrics of `run_metrics` on the Result CSV written, to 1e-12."""
    import json
    from pathlib import Path

    from tirefilter.cli import main
    from tirefilter.io.results import read_results

    rng = np.random.default_rng(0)
    t = np.arange(12001) * 0.01
    delta = 0.02 * np.sin(2 * np.pi * 0.2 * t)
    vx = np.full(t.size, 20.0)
    yaw = vx * delta / 2.9
    cols = {"t": t, "delta": delta, "ax": 0.05 * rng.standard_normal(t.size),
            "ay": vx * yaw + 0.05 * rng.standard_normal(t.size), "yaw_rate": yaw + 0.003 * rng.standard_normal(t.size),
            "vx": vx, "vy_true": 0.01 * np.sin(t), "beta_true": np.arctan2(0.01 * np.sin(t), vx),
            "Cf_y_true": np.full(t.size, 1.1e5)}
    log = tmp_path / "drive.csv"
    with open(log, "w") as f:
        f.write(",".join(cols) + "\n")
        for row in zip(*(c.tolist() for c in cols.values())):
            f.write(",".join(repr(x) for x in row) + "\n")
    vehicle = Path(__file__).resolve().parents[1] / "src/tirefilter/scenarios/data/vehicles/midsize-suv.toml"
    out = tmp_path / "out.csv"
    assert main(["replay", str(log), "--vehicle", str(vehicle), "--estimator", "kf", "--out", str(out), "--quiet"]) == 0
    m = json.loads(out.with_suffix(".json").read_text())["metrics"]
    assert m["samples"] == 12001 and {"vy", "beta"} <= set(m["state"])
    _same(m, json.loads(json.dumps(run_metrics(read_results(out), restarts=m["restarts"],
                                               resamples=m["resamples"]))))
