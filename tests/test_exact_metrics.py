"""The run metrics (metrics.py) against answers worked out by hand, at the edges the other
tests leave out: settled windows that do not start at 0, the bounds of the coverage band,
of the settling tolerance and of the divergence thresholds (which side of each is in), a
surface change at the last sample, reference columns that are all NaN, errors that are never
finite, a divergence from the very first sample; the streamed metrics (`RunMetrics`) must
give the same. Found by mutation testing (benchmarks/mutation.py): each test kills mutants
the other tests let through."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from test_metrics import _same, _streamed
from tirefilter.metrics import Z90, run_metrics, settling_time, steady_state_mask, stiffness_errors

T = np.round(np.arange(0, 2001) * 0.01, 10)  # 0 .. 20 s at 100 Hz


def _band_edge(err: float) -> float:
    """A std whose band Z90 std is `err` exactly (in floating point)."""
    std = err / Z90
    while Z90 * std != err:
        std = np.nextafter(std, np.inf if Z90 * std < err else -np.inf)
    return float(std)


def _both(r, schedule=None, **counters):
    """run_metrics and the streamed metrics (chunks of 7, 1 and 300 rows), checked equal."""
    m = run_metrics(r, schedule, **counters)
    _same(_streamed(r, schedule, [7, 1, 300], **counters), m)
    return m


def test_settled_window_starts_five_seconds_after_each_excitation_start():
    """Excitation 3-12 s and 14-20 s, a surface change at 13 s: settled 8-12 s and 19-20 s."""
    sched = SimpleNamespace(excitation=((3.0, 12.0), (14.0, 20.0)), surface_changes=(13.0,))
    mask = steady_state_mask(T, sched)
    np.testing.assert_array_equal(mask, ((T >= 8.0) & (T <= 12.0)) | (T >= 19.0))
    r = {"t": T, "Cf_y": np.full(T.size, 1.0), "true_Cf_y_mean": np.full(T.size, 1.0)}
    assert _both(r, sched)["settled_windows"] == [[8.0, 12.0], [19.0, 20.0]]


def test_stiffness_errors_by_hand():
    """`stiffness_errors` on four settled samples with errors +10, -20, +5 and 0 %: mean,
    mean |err|, max |err|; the 90 % band +-Z90 std holds an error on its edge; the spread
    sigma in % of the truth."""
    t = np.array([5.0, 6.0, 7.0, 8.0])
    truth = np.array([100.0, 100.0, 200.0, 50.0])
    est = np.array([110.0, 80.0, 210.0, 50.0])
    std = np.array([_band_edge(10.0), 1.0, 1.0, 1.0])  # sample 0 on the edge of its band, 3 inside (error 0)
    r = {"t": t, "true_Cf_y_mean": truth, "Cf_y": est, "Cf_y_std": std, "Cf_y_sigma": np.array([5.0, 5.0, 10.0, 1.0])}
    sched = SimpleNamespace(excitation=((0.0, 10.0),), surface_changes=())
    out = stiffness_errors(r, sched, "Cf_y")
    assert out["mean"] == pytest.approx((10 - 20 + 5 + 0) / 4, rel=1e-12)
    assert out["mean_abs"] == pytest.approx((10 + 20 + 5 + 0) / 4, rel=1e-12)
    assert out["max_abs"] == pytest.approx(20.0, rel=1e-12)
    assert abs(est[0] - truth[0]) == Z90 * std[0]
    assert out["coverage90"] == 0.5
    assert out["sigma_pct"] == pytest.approx((5.0 + 5.0 + 5.0 + 2.0) / 4, rel=1e-12)


def test_coverage_band_includes_its_edge_and_half_coverage_is_no_warning():
    """An error exactly Z90 std away is inside the band; every other sample outside: coverage
    exactly 0.5, which is not below the warning's 50 %."""
    n = 400
    t = np.arange(n) * 0.01
    truth = np.ones(n)
    est = np.where(np.arange(n) % 2 == 0, 3.0, 5.0)
    std = _band_edge(2.0)
    r = {"t": t, "Cf_y": est, "true_Cf_y": truth, "Cf_y_std": np.full(n, std)}
    assert np.all(np.abs(est - truth)[::2] == Z90 * std)
    m = _both(r)
    assert m["stiffness"]["Cf_y"]["coverage90"] == 0.5 and m["warnings"] == []


def _settling_run(after: float, first: float) -> dict:
    """Truth 100 to 10 s, 50 from the change at 10 s; the estimate's relative error is
    `first` at the change's own sample and `after` from the next sample on."""
    truth = np.where(T < 10.0, 100.0, 50.0)
    rel = np.where(T < 10.0, 0.0, after)
    rel[T == 10.0] = first
    return {"t": T, "Cf_y": truth * (1 + rel), "true_Cf_y_mean": truth}


def test_settling_counts_the_change_sample_and_a_band_edge_is_inside():
    """The sample at the change itself counts (outside by 10 %); from the next one the error
    is exactly 5 % (the band's edge, inside): settled 0.01 s after the change. An error of
    5.02 % never settles (the band is 5 %)."""
    sched = SimpleNamespace(excitation=((0.0, 20.0),), surface_changes=(10.0,))
    edge = _settling_run(after=0.05, first=0.10)
    assert np.all(np.abs(edge["Cf_y"] - edge["true_Cf_y_mean"])[T > 10.0] / 50.0 == 0.05)
    assert settling_time(edge, "Cf_y", 10.0) == pytest.approx(0.01)
    assert _both(edge, sched)["stiffness"]["Cf_y"]["settling_s"] == [pytest.approx(0.01)]
    wide = _settling_run(after=0.0502, first=0.0)
    assert settling_time(wide, "Cf_y", 10.0) == float("inf")
    assert _both(wide, sched)["stiffness"]["Cf_y"]["settling_s"] == [float("inf")]
    inside = _settling_run(after=0.0, first=0.0)
    assert _both(inside, sched)["stiffness"]["Cf_y"]["settling_s"] == [0.0]


def test_a_surface_change_at_the_last_sample_has_no_settling_time():
    sched = SimpleNamespace(excitation=((0.0, 20.0),), surface_changes=(10.0, 20.0))
    m = _both(_settling_run(after=0.0, first=0.0), sched)
    assert m["stiffness"]["Cf_y"]["settling_s"] == [0.0]


def test_divergence_thresholds_are_exclusive_and_nan_is_no_divergence():
    """|v^Y error| exactly 1 m/s is not beyond the threshold; without a v^Y reference the
    sideslip's 0.1 rad decides (0.1005 beyond, 0.0995 not), and a missing (NaN) sideslip
    is not a divergence."""
    n = 300
    t = np.arange(n) * 0.01
    vy = np.where(np.arange(n) < 100, 1.0, 0.0)
    m = _both({"t": t, "vy": vy, "true_vy": np.zeros(n)})
    assert m["diverged"]["signal"] == "vy" and m["diverged"]["samples"] == 0
    beta = np.where(np.arange(n) < 100, 0.1005, 0.0995)
    beta[250:] = np.nan
    m = _both({"t": t, "beta": beta, "true_beta": np.zeros(n)})
    d = m["diverged"]
    assert d["signal"] == "beta" and d["samples"] == 100 and d["windows"] == [[0.0, 0.99]]
    assert d["share"] == pytest.approx(100 / n) and d["max_abs"] == pytest.approx(0.1005)


def test_divergence_from_the_first_sample_and_errors_never_finite():
    """A run diverged from its first sample: one window from t = 0 (also when streamed);
    an estimate that is never finite: no largest error (NaN: no samples beyond; infinite:
    every sample beyond)."""
    n = 300
    t = np.arange(n) * 0.01
    vy = np.where(t < 0.5, 3.0, 0.0)
    m = _both({"t": t, "vy": vy, "true_vy": np.zeros(n)})
    assert m["diverged"]["windows"] == [[0.0, 0.49]]
    m = _both({"t": t, "vy": np.full(n, np.nan), "true_vy": np.zeros(n)})
    assert m["diverged"]["samples"] == 0 and m["diverged"]["max_abs"] is None and "vy" not in m["state"]
    m = _both({"t": t, "vy": np.full(n, np.inf), "true_vy": np.zeros(n)})  # beyond, but no finite error
    assert m["diverged"]["samples"] == n and m["diverged"]["max_abs"] is None and "vy" not in m["state"]
    assert m["warnings"] == ["state diverged at 300 samples (0-2.99 s): |vy error| up to inf m/s (threshold 1)"]


def test_an_all_nan_reference_column_gives_way_to_the_next():
    """`true_<p>_mean` / `true_<s>` present but all NaN: the log's `<p>_true` / `<s>_true`
    is the reference."""
    n = 200
    t = np.arange(n) * 0.01
    r = {"t": t, "Cf_y": np.full(n, 110.0), "true_Cf_y_mean": np.full(n, np.nan), "Cf_y_true": np.full(n, 100.0),
         "vy": np.full(n, 0.2), "true_vy": np.full(n, np.nan), "vy_true": np.zeros(n)}
    m = _both(r)
    assert m["stiffness"]["Cf_y"]["reference"] == "Cf_y_true"
    assert m["stiffness"]["Cf_y"]["mean_abs_pct"] == pytest.approx(10.0)
    assert m["state"]["vy"]["reference"] == "vy_true" and m["state"]["vy"]["rmse"] == pytest.approx(0.2)
    assert m["diverged"]["reference"] == "vy_true"


def test_an_estimate_that_is_never_finite_has_no_figures():
    """A stiffness column that is NaN throughout (an estimator without it): no entry."""
    n = 200
    r = {"t": np.arange(n) * 0.01, "Cf_y": np.full(n, np.nan), "true_Cf_y": np.full(n, 100.0),
         "Cr_y": np.full(n, 105.0), "true_Cr_y": np.full(n, 100.0)}
    m = _both(r)
    assert list(m["stiffness"]) == ["Cr_y"]


@pytest.mark.parametrize("bursts", [3, 4])
def test_the_divergence_warning_lists_the_first_three_windows(bursts):
    """The warning names the first three windows of divergence and marks more with '...'."""
    n = 1000
    t = np.arange(n) * 0.01
    vy = np.zeros(n)
    for k in range(bursts):
        vy[100 * (2 * k + 1):100 * (2 * k + 1) + 10] = 5.0
    m = _both({"t": t, "vy": vy, "true_vy": np.zeros(n)})
    spans = "1-1.09 s, 3-3.09 s, 5-5.09 s" + (", ..." if bursts > 3 else "")
    assert [w for w in m["warnings"] if w.startswith("state diverged")] == [
        f"state diverged at {10 * bursts} samples ({spans}): |vy error| up to 5 m/s (threshold 1)"]
