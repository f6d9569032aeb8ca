"""The 90 % interval of the coverage figures (DESIGN.md's estimate +- z `*_std`) against the
exact standard normal quantile from scipy and coverages counted by hand, for every place
that scores it: `stiffness_errors`, `run_metrics` and the streamed `RunMetrics`."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import norm

from tirefilter import metrics
from tirefilter.metrics import RunMetrics, run_metrics, stiffness_errors

Z_EXACT = float(norm.ppf(0.95))  # the two-sided 90 % quantile, 1.6448536...
SCHEDULE = SimpleNamespace(excitation=((0.0, 1000.0),), surface_changes=())  # settled from t = 5 s on
TRUTH = 1.0e5  # N/rad
STD = 1.0e3  # N/rad


def _run(errors_in_std) -> dict:
    """A Result-CSV run of Cf_y with the given errors, in units of its constant std, every
    sample inside the settled window."""
    z = np.asarray(errors_in_std, float)
    t = 5.0 + 0.01 * np.arange(z.size)
    return {"t": t, "Cf_y": TRUTH + z * STD, "true_Cf_y_mean": np.full(z.size, TRUTH),
            "Cf_y_std": np.full(z.size, STD)}


def _coverages(r: dict) -> list[float]:
    """coverage90 of `stiffness_errors`, of `run_metrics` (whole run and settled window) and
    of `RunMetrics` fed in chunks of 3 rows (whole run and settled window)."""
    m = run_metrics(r, SCHEDULE)["stiffness"]["Cf_y"]
    s = RunMetrics(list(r), SCHEDULE)
    for k in range(0, r["t"].size, 3):
        s.update({c: v[k:k + 3] for c, v in r.items()})
    ms = s.finalize()["stiffness"]["Cf_y"]
    return [stiffness_errors(r, SCHEDULE, "Cf_y")["coverage90"], m["coverage90"], m["settled_coverage90"],
            ms["coverage90"], ms["settled_coverage90"]]


def test_z90_is_the_exact_normal_quantile():
    assert metrics.Z90 == pytest.approx(Z_EXACT, rel=1e-15)


def test_coverage_of_a_hand_counted_series():
    """Ten errors (in std): |e| <= 1.6449 for 0, 1, -1.6 and 1.64 only: coverage 4/10. (With a
    95 % band, z = 1.96, the four between 1.65 and 1.95 would count too: 8/10.)"""
    r = _run([0.0, 1.0, -1.6, 1.64, -1.65, 1.7, 1.9, -1.95, 2.5, -3.0])
    assert _coverages(r) == [pytest.approx(0.4, abs=1e-15)] * 5


def test_band_edge_is_the_exact_quantile():
    """Errors a hair (1e-7 relative) inside and outside +-z std: the band's edge is the exact
    quantile to that precision, not 1.645 (1.6e-4 further out) nor any other rounding."""
    inside, outside = Z_EXACT * (1 - 1e-7), Z_EXACT * (1 + 1e-7)
    r = _run([inside, -inside, outside, -outside, 1.645, -1.645])
    assert _coverages(r) == [pytest.approx(2 / 6, abs=1e-15)] * 5


def test_calibrated_gaussian_errors_cover_90_percent():
    """Errors at the standard normal quantiles of (i + 1/2) / 1000, i = 0..999 (a calibrated
    posterior, with no sampling noise): |e| <= z90 exactly for the 900 with 0.05 < p < 0.95."""
    p = (np.arange(1000) + 0.5) / 1000
    r = _run(norm.ppf(p))
    assert _coverages(r) == [pytest.approx(0.9, abs=1e-15)] * 5
