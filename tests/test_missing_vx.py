"""A replayed log with empty vx cells (docs/usage.md: an empty cell is a missing sample; the
estimator holds the last input): the lateral-model baselines run through it and give
exactly what they give on the same log with each empty cell filled with the previous
row's value; a vx missing before the first finite one is the same error for all of them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tirefilter.io.results import ESTIMATE_COLUMNS
from tirefilter.errors import ReplayError
from tirefilter.estimators import build_log_estimator
from tirefilter.replay import read_log, replay_log
from tirefilter.vehicle.params import load_vehicle

REPO = Path(__file__).resolve().parents[1]
VEHICLE = REPO / "src" / "tirefilter" / "scenarios" / "data" / "vehicles" / "midsize-suv.toml"
ESTIMATORS = ("kf", "rls", "ekf")  # the estimators with a lateral model and no compiled kernels
N, DT = 400, 0.01
EMPTY_ROWS = (50, 51, 230)  # 0-based data rows whose vx cell is emptied (two in a row, one alone)


def _cells(seed: int = 0) -> list[list[str]]:
    """The cells of a drive at rising speed (15 -> 23 m/s, so a held vx differs from the
    next sample's) with a steer sine and the steady-state a^Y and yaw rate plus noise."""
    rng = np.random.default_rng(seed)
    t = DT * np.arange(N)
    vx = 15.0 + 2.0 * t
    delta = 0.03 * np.sin(2 * np.pi * 0.5 * t)
    yaw_rate = vx * delta / 2.8 + 0.002 * rng.standard_normal(N)
    ay = vx * yaw_rate + 0.05 * rng.standard_normal(N)
    ax = 2.0 + 0.05 * rng.standard_normal(N)
    return [[repr(float(v)) for v in row] for row in zip(t, delta, ax, ay, yaw_rate, vx)]


def _log(tmp_path: Path, name: str, cells: list[list[str]]):
    path = tmp_path / f"{name}.csv"
    path.write_text("t,delta,ax,ay,yaw_rate,vx\n" + "".join(",".join(row) + "\n" for row in cells))
    return read_log(path)


def _replay(estimator: str, log):
    est = build_log_estimator(estimator, load_vehicle(VEHICLE), log.t, log.signals, model="lateral",
                              particles=None, config={})
    return replay_log(log, estimator=est, keep_rows=True)


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_an_empty_vx_cell_holds_the_last_vx(estimator, tmp_path):
    cells = _cells()
    empty = [row.copy() for row in cells]
    filled = [row.copy() for row in cells]
    for k in EMPTY_ROWS:
        empty[k][5] = ""
        filled[k][5] = filled[k - 1][5]  # the previous row's cell (k - 1 is filled itself for k = 51)
    log_empty, log_filled = _log(tmp_path, "empty", empty), _log(tmp_path, "filled", filled)
    assert np.flatnonzero(np.isnan(log_empty.signals["vx"])).tolist() == list(EMPTY_ROWS)
    assert log_filled.signals["vx"][EMPTY_ROWS[0]] != float(cells[EMPTY_ROWS[0]][5])  # holding is not the truth

    summary, rows = _replay(estimator, log_empty)
    assert summary.status == "ok" and summary.steps == N
    _, rows_filled = _replay(estimator, log_filled)
    n = len(ESTIMATE_COLUMNS)
    np.testing.assert_array_equal(rows[:, :n], rows_filled[:, :n])  # bit for bit, NaN columns included
    vx = rows[:, ESTIMATE_COLUMNS.index("vx")]
    np.testing.assert_array_equal(vx, log_filled.signals["vx"])  # the estimate's vx is the held input
    assert np.isfinite(rows[:, ESTIMATE_COLUMNS.index("vy")]).all()


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_vx_missing_before_the_first_finite_one_is_an_error(estimator, tmp_path):
    cells = _cells()
    for k in (0, 1):
        cells[k][5] = ""
    with pytest.raises(ReplayError, match=r"data row 1 .*needs vx; none given up to t = 0\.0 s"):
        _replay(estimator, _log(tmp_path, "late_vx", cells))
    assert math.isnan(read_log(tmp_path / "late_vx.csv").signals["vx"][1])
