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


def final_scores(truth: dict, est: dict, *, ay_min: float = 4.0) -> dict:
    """The peer set's scores (benchmarks/bench_peer.py --set) of one replay, from arrays of
    the same rows: `truth` with "t", "beta_true", "ay_true", "Cf_y_true", "Cr_y_true",
    `est` with "beta", "Cf_y", "Cr_y", "Cf_y_std", "Cr_y_std" (all (n,)).

    Per axle p: `{p}_final_err` (%) and `{p}_final_z` (error over the reported std) at the
    last row with a finite estimate; `{p}_cover`, the share of the rows of the second half
    of the drive (t >= (t_0 + t_end) / 2) whose truth lies inside estimate +- Z90 std
    (metrics.Z90, the 90 % band). Sideslip: `beta_rmse_deg` over every row and
    `beta_rmse_hi_deg` over the rows with |ay_true| >= ay_min (NaN without one), with
    the sums of squared errors and counts (`beta_se`, `beta_n`, `beta_se_hi`, `beta_n_hi`,
    rad^2) for pooling over drives. A non-finite sideslip estimate counts as an infinite error."""
    from tirefilter.metrics import Z90

    t = np.asarray(truth["t"], float)
    out = {}
    for p in ("Cf_y", "Cr_y"):
        e, s, tr = (np.asarray(a, float) for a in (est[p], est[f"{p}_std"], truth[f"{p}_true"]))
        ok = np.flatnonzero(np.isfinite(e) & np.isfinite(s))
        if ok.size == 0:
            out.update({f"{p}_final_err": math.inf, f"{p}_final_z": math.inf, f"{p}_cover": 0.0})
            continue
        k = ok[-1]
        out[f"{p}_final_err"] = float(100.0 * (e[k] / tr[k] - 1.0))
        out[f"{p}_final_z"] = float((e[k] - tr[k]) / s[k]) if s[k] > 0 else math.inf
        half = t >= 0.5 * (t[0] + t[-1])
        inside = np.abs(e[half] - tr[half]) <= Z90 * s[half]  # NaN: outside
        out[f"{p}_cover"] = float(np.mean(inside))
    err = np.asarray(est["beta"], float) - np.asarray(truth["beta_true"], float)
    err = np.where(np.isfinite(err), err, np.inf)
    hi = np.abs(np.asarray(truth["ay_true"], float)) >= ay_min
    out.update(beta_se=float(np.sum(err**2)), beta_n=int(err.size), beta_se_hi=float(np.sum(err[hi] ** 2)),
               beta_n_hi=int(np.count_nonzero(hi)))
    out["beta_rmse_deg"] = float(np.degrees(np.sqrt(out["beta_se"] / err.size)))
    out["beta_rmse_hi_deg"] = float(np.degrees(np.sqrt(out["beta_se_hi"] / out["beta_n_hi"]))) if hi.any() else math.nan
    return out
