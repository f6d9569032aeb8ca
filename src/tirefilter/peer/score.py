"""Scores of an estimator's replay of a peer drive against the drive's references.

- Lateral stiffness error: the mean of the estimate (`Cf_y`, `Cr_y` of the Result CSV)
  over the last `last` seconds against the mean of `Cf_y_true`, `Cr_y_true` there, in %.
- Longitudinal stiffness error `Cx_err`, the same for `Cx` against `Cx_true` (the driven
  axle's slip stiffness at its load), where the estimate has a `Cx` (the full-model MPF;
  NaN otherwise).
- Sideslip RMSE: of the estimate `beta` against `beta_true` over the whole drive, in deg
  (and the RMSE of a zero-sideslip guess, for scale).
Rows are matched by position (the Result CSV has one row per log row, same `t`).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from tirefilter.errors import TirefilterError


def read_columns(path: str | Path, names: tuple[str, ...]) -> dict:
    """The named columns of a CSV as float arrays (empty cell: NaN)."""
    path = Path(path)
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader)
        missing = [n for n in names if n not in header]
        if missing:
            raise TirefilterError(f"{path}: missing column(s) {', '.join(missing)}")
        idx = [header.index(n) for n in names]
        rows = [[float(r[i]) if r[i] != "" else math.nan for i in idx] for r in reader]
    data = np.asarray(rows, float).reshape(-1, len(names))
    return {n: data[:, i] for i, n in enumerate(names)}


def _has_column(path: str | Path, name: str) -> bool:
    with open(path, newline="") as f:
        return name in next(csv.reader(f), [])


def score_replay(log_csv: str | Path, result_csv: str | Path, *, last: float = 30.0) -> dict:
    """`Cf_y_err`, `Cr_y_err`, `Cx_err` (%, mean over the last `last` s), `beta_rmse_deg`,
    `beta_zero_rmse_deg`, `window` (s) of a replay of the peer drive `log_csv`."""
    truth = read_columns(log_csv, ("t", "beta_true", "Cf_y_true", "Cr_y_true", "Cx_true"))
    est = read_columns(result_csv, ("t", "beta", "Cf_y", "Cr_y"))
    if _has_column(result_csv, "Cx"):
        est.update(read_columns(result_csv, ("Cx",)))
    if truth["t"].size != est["t"].size or not np.allclose(truth["t"], est["t"]):
        raise TirefilterError(f"{result_csv}: its rows do not match the log {log_csv} (t differs)")
    return score(truth, est, last=last)


def score(truth: dict, est: dict, *, last: float = 30.0) -> dict:
    """The scores of `score_replay` from arrays: `truth` with "t", "beta_true", "Cf_y_true",
    "Cr_y_true" (and "Cx_true"), `est` with "beta", "Cf_y", "Cr_y" (and "Cx"; all (n,), the
    same rows). `Cx_err` is NaN where either Cx is missing."""
    t = truth["t"]
    window = t >= t[-1] - last
    out = {"window": float(min(last, t[-1] - t[0]))}
    for p in ("Cf_y", "Cr_y"):
        e, tr = est[p][window], truth[f"{p}_true"][window]
        out[f"{p}_err"] = float(100.0 * (np.mean(e) / np.mean(tr) - 1.0)) if np.all(np.isfinite(e)) else math.inf
    if "Cx" in est and "Cx_true" in truth:
        e = np.asarray(est["Cx"], float)[window]
        out["Cx_err"] = (float(100.0 * (np.mean(e) / np.mean(truth["Cx_true"][window]) - 1.0))
                         if np.all(np.isfinite(e)) else math.inf)
    else:
        out["Cx_err"] = math.nan
    b = est["beta"]
    out["beta_rmse_deg"] = float(np.degrees(np.sqrt(np.mean((b - truth["beta_true"]) ** 2)))) if np.all(
        np.isfinite(b)) else math.inf
    out["beta_zero_rmse_deg"] = float(np.degrees(np.sqrt(np.mean(truth["beta_true"] ** 2))))
    return out
