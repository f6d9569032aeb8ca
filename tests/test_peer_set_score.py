"""peer.score.final_scores (the peer set's scores, benchmarks/bench_peer.py --set) on
arrays with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tirefilter.metrics import Z90
from tirefilter.peer.score import final_scores


def _case():
    t = np.arange(11.0)  # second half: t >= 5, six rows
    truth = {"t": t, "beta_true": np.zeros(11), "ay_true": np.where(t >= 8, 5.0, 1.0),
             "Cf_y_true": np.full(11, 100.0), "Cr_y_true": np.linspace(200.0, 210.0, 11)}
    std = np.full(11, 2.0)
    cf = 100.0 + np.array([9, 9, 9, 9, 9, 0, 1, 2 * Z90 + 0.1, 3, 4, 4.0])  # inside at t = 5, 6, 8, outside 7, 9 ...
    std[9] = 1.0  # ... at t = 9 (3 > Z90), and at t = 10 (4 > 2 Z90 = 3.29)
    cr = truth["Cr_y_true"].copy()
    cr[-1] = math.nan  # the last row has no estimate: the final error is the one before it
    cr[-2] *= 0.97
    beta = np.where(t >= 8, 0.01, 0.0)
    return truth, {"beta": beta, "Cf_y": cf, "Cr_y": cr, "Cf_y_std": std, "Cr_y_std": np.full(11, 3.0)}


def test_final_error_coverage_and_sideslip():
    truth, est = _case()
    s = final_scores(truth, est, ay_min=4.0)
    assert s["Cf_y_final_err"] == pytest.approx(4.0)
    assert s["Cf_y_final_z"] == pytest.approx(2.0)
    assert s["Cf_y_cover"] == pytest.approx(3 / 6)  # t = 5, 6, 8 inside; 7, 9, 10 outside
    assert s["Cr_y_final_err"] == pytest.approx(-3.0)
    assert s["Cr_y_final_z"] == pytest.approx(-0.03 * 209.0 / 3.0)
    assert s["Cr_y_cover"] == pytest.approx(4 / 6)  # t = 5-8 inside; t = 9 (6.27 > 4.93) and the NaN row out
    assert s["beta_rmse_hi_deg"] == pytest.approx(math.degrees(0.01))
    assert s["beta_rmse_deg"] == pytest.approx(math.degrees(0.01 * math.sqrt(3 / 11)))
    assert (s["beta_n"], s["beta_n_hi"]) == (11, 3)


def test_no_high_rows_and_a_failed_estimate():
    truth, est = _case()
    truth["ay_true"][:] = 1.0
    est["beta"][4] = math.nan
    est["Cf_y"][:] = math.nan
    s = final_scores(truth, est)
    assert math.isnan(s["beta_rmse_hi_deg"]) and s["beta_n_hi"] == 0
    assert s["beta_rmse_deg"] == math.inf
    assert s["Cf_y_final_err"] == math.inf and s["Cf_y_cover"] == 0.0
