"""Metrics of DESIGN.md on Result-CSV columns (windows from the scenario's schedule)."""

from __future__ import annotations

import numpy as np


def steady_state_mask(t: np.ndarray, scenario) -> np.ndarray:
    """From 5 s after each excitation start to its end, minus 5 s after surface changes."""
    mask = np.zeros(t.shape, bool)
    for start, end in scenario.excitation:
        mask |= (t >= start + 5.0) & (t <= end)
    for tc in scenario.surface_changes:
        mask &= ~((t >= tc) & (t < tc + 5.0))
    return mask


def stiffness_errors(r: dict, scenario, param: str) -> dict:
    """Steady-state relative errors (%) of `param` against the surface mean; NaN
    estimates inside the window count as errors (inf)."""
    t = r["t"]
    mask = steady_state_mask(t, scenario)
    truth = r[f"true_{param}_mean"][mask]
    est = r[param][mask]
    err = 100.0 * (est - truth) / truth
    err = np.where(np.isnan(err), np.inf, err)
    std = r.get(f"{param}_std")
    out = {"mean": float(np.mean(err)), "mean_abs": float(np.mean(np.abs(err))), "max_abs": float(np.max(np.abs(err)))}
    if std is not None:
        z90 = 1.6448536269514722
        inside = np.abs(est - truth) <= z90 * std[mask]
        out["coverage90"] = float(np.mean(inside))
    sigma = r.get(f"{param}_sigma")
    if sigma is not None:
        out["sigma_pct"] = float(np.mean(100.0 * sigma[mask] / truth))
    return out


def settling_time(r: dict, param: str, t_change: float, tol: float = 0.05) -> float:
    """Time after `t_change` until the estimate stays within tol of the new surface mean."""
    t = r["t"]
    after = t >= t_change
    rel = np.abs(r[param][after] - r[f"true_{param}_mean"][after]) / r[f"true_{param}_mean"][after]
    outside = np.flatnonzero(~(rel <= tol))
    if outside.size == 0:
        return 0.0
    if outside[-1] == rel.size - 1:
        return float("inf")
    return float(t[after][outside[-1] + 1] - t_change)
