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


# ---- the run summary's metrics (run.json `metrics`, the printed summary, the dashboard) ------------

PARAMS = ("Cf_y", "Cr_y", "Cx")
STATES = (("vy", "m/s"), ("beta", "rad"), ("yaw_rate", "rad/s"), ("vx", "m/s"))
Z90 = 1.6448536269514722  # the 90% interval of DESIGN.md's coverage: estimate +- Z90 * *_std
DIVERGED_VY = 1.0  # m/s: |v^Y - reference| beyond this is a diverged state ...
DIVERGED_BETA = 0.1  # rad: ... or |beta - reference| beyond this, where v^Y has no reference


def reference(r: dict, name: str) -> tuple[str | None, np.ndarray | None]:
    """The reference (truth) column of `name` in a Result CSV: `true_<name>` (co-simulation,
    or a log's reference carried into a replay's results) or `<name>_true`; (None, None)
    when there is none or it is all NaN."""
    for col in (f"true_{name}", f"{name}_true"):
        x = r.get(col)
        if x is not None and np.isfinite(x).any():
            return col, np.asarray(x, float)
    return None, None


def _stiffness_reference(r: dict, param: str) -> tuple[str | None, np.ndarray | None]:
    """The surface mean (`true_<p>_mean`, DESIGN.md's stiffness error) where it exists,
    else the effective stiffness `true_<p>` / `<p>_true` of a log."""
    col, x = reference(r, f"{param}_mean")
    return (col, x) if col else reference(r, param)


def _windows(mask: np.ndarray, t: np.ndarray) -> list[list[float]]:
    """[t_first, t_last] of each run of True in `mask`."""
    if not mask.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [[float(t[a]), float(t[b - 1])] for a, b in zip(edges[::2], edges[1::2])]


def _finite_mean(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.mean(x)) if x.size else None


def run_metrics(r: dict, schedule=None, *, restarts: int | None = None, resamples: int | None = None) -> dict:
    """The accuracy and health figures of one run (DESIGN.md, "Metric definitions"), from
    its Result-CSV columns `r` (name -> (n,) array).

    - per stiffness parameter with a reference: the mean absolute relative error (%) over
      every sample with an estimate (`mean_abs_pct`: errors cannot cancel), the same over the
      settled window (`settled_mean_abs_pct`: DESIGN.md's steady state, from the scenario's
      `schedule` -- its `excitation` windows and `surface_changes`; None without a schedule,
      e.g. a replay), the final error, the coverage of the 90% interval estimate
      +- 1.645 `*_std` (whole run and settled window; about 0.9 when calibrated) and the
      settling time after each surface change;
    - state RMSE of v^Y, beta, yaw rate, v^X against `true_<s>` or a log's `<s>_true`;
    - diverged samples: |v^Y error| > DIVERGED_VY (else |beta error| > DIVERGED_BETA), with
      their time windows;
    - restarts and resamples (the estimator's counters, None where it has none), the share
      of samples with the learning gate open (`active`);
    - `warnings`: one line per restart, divergence, NaN estimate or coverage below 50%.
    """
    t = np.asarray(r["t"], float)
    n = t.size
    settled = steady_state_mask(t, schedule) if schedule is not None else None
    out: dict = {"samples": int(n), "settled_windows": _windows(settled, t) if settled is not None else None,
                 "stiffness": {}, "state": {}}
    warnings: list[str] = []
    for p in PARAMS:
        est = r.get(p)
        if est is None or not np.isfinite(est).any():
            continue
        col, truth = _stiffness_reference(r, p)
        if col is None:
            continue
        est = np.asarray(est, float)
        err = 100.0 * (est - truth) / truth
        have = np.isfinite(err)
        std = r.get(f"{p}_std")
        inside = np.abs(est - truth) <= Z90 * np.asarray(std, float) if std is not None else None
        m = {"reference": col, "mean_abs_pct": _finite_mean(np.abs(err)),
             "final_pct": float(err[have][-1]) if have.any() else None,
             "coverage90": float(np.mean(inside[have])) if inside is not None and have.any() else None}
        if settled is not None:
            w = settled & np.isfinite(truth)
            missing = int(np.count_nonzero(w & ~have))
            m.update(settled_mean_abs_pct=_finite_mean(np.abs(err[w])),
                     settled_coverage90=(float(np.mean(inside[w & have])) if inside is not None and (w & have).any()
                                         else None),
                     settled_missing=missing)
            if missing:
                warnings.append(f"{p}: no estimate at {missing} samples of the settled window")
            if f"true_{p}_mean" in r:
                m["settling_s"] = [settling_time(r, p, tc) for tc in schedule.surface_changes if tc < t[-1]]
        cov = m.get("settled_coverage90", m["coverage90"])
        if cov is not None and cov < 0.5:
            warnings.append(f"{p}: the 90% band (+-1.645 {p}_std) holds the reference in only {100 * cov:.0f}% "
                            "of the samples: the posterior is overconfident")
        out["stiffness"][p] = m
    for s, unit in STATES:
        est = r.get(s)
        col, truth = reference(r, s)
        if est is None or col is None:
            continue
        e = np.asarray(est, float) - truth
        ok = np.isfinite(e)
        if ok.any():
            out["state"][s] = {"reference": col, "rmse": float(np.sqrt(np.mean(e[ok] ** 2))),
                               "max_abs": float(np.max(np.abs(e[ok]))), "unit": unit}
    out["diverged"] = _divergence(r, t)
    if out["diverged"] is not None and out["diverged"]["samples"]:
        d = out["diverged"]
        spans = ", ".join(f"{a:g}-{b:g} s" for a, b in d["windows"][:3]) + (", ..." if len(d["windows"]) > 3 else "")
        warnings.append(f"state diverged at {d['samples']} samples ({spans}): |{d['signal']} error| up to "
                        f"{d['max_abs']:.3g} {d['unit']} (threshold {d['threshold']:g})")
    out["restarts"] = None if restarts is None else int(restarts)
    out["resamples"] = None if resamples is None else int(resamples)
    if restarts:
        warnings.append(f"the filter restarted {restarts} time{'s' if restarts > 1 else ''} from its prior "
                        "(every particle implausible): estimates around then are not converged")
    active = r.get("active")
    out["gate_open_share"] = _finite_mean(np.asarray(active, float)) if active is not None else None
    out["warnings"] = warnings
    return out


def _divergence(r: dict, t: np.ndarray) -> dict | None:
    """Samples whose v^Y (else beta) error exceeds its threshold; None without a reference."""
    for s, limit, unit in (("vy", DIVERGED_VY, "m/s"), ("beta", DIVERGED_BETA, "rad")):
        col, truth = reference(r, s)
        if col is None or s not in r:
            continue
        e = np.abs(np.asarray(r[s], float) - truth)
        bad = np.nan_to_num(e, nan=0.0) > limit
        return {"signal": s, "reference": col, "threshold": limit, "unit": unit, "samples": int(bad.sum()),
                "share": float(bad.mean()) if bad.size else 0.0,
                "max_abs": float(np.nanmax(e)) if np.isfinite(e).any() else None, "windows": _windows(bad, t)}
    return None


def _pct(x) -> str:
    return "n/a" if x is None else f"{x:.2f} %"


def _signed_pct(x) -> str:
    return "n/a" if x is None else f"{x:+.2f} %"


def format_metrics(m: dict) -> list[str]:
    """The lines of the printed run summary: per stiffness parameter the mean absolute and
    settled errors, the final error and the coverage; the state RMSE; restarts, resamples,
    the gate; then the warnings, each on a line starting with `warning:`."""
    lines = []
    if m["stiffness"]:
        lines.append(f"{'stiffness error':16s}{'mean |err|':>12s}{'settled':>12s}{'final':>10s}"
                     f"{'coverage90':>12s}  reference")
        for p, s in m["stiffness"].items():
            cov = s.get("settled_coverage90", s["coverage90"])
            lines.append(f"{p:16s}{_pct(s['mean_abs_pct']):>12s}{_pct(s.get('settled_mean_abs_pct')):>12s}"
                         f"{_signed_pct(s['final_pct']):>10s}"
                         f"{('n/a' if cov is None else f'{100 * cov:.0f} %'):>12s}  {s['reference']}")
        if m.get("settled_windows") is not None:
            w = ", ".join(f"{a:g}-{b:g} s" for a, b in m["settled_windows"]) or "none"
            lines.append(f"  (settled: 5 s after each excitation start / surface change: {w}; "
                         "coverage: reference inside estimate +- 1.645 std)")
    for s, v in m["state"].items():
        lines.append(f"{s} RMSE {v['rmse']:.4g} {v['unit']} (max |err| {v['max_abs']:.3g}) against {v['reference']}")
    counts = [f"restarts {m['restarts']}" if m.get("restarts") is not None else None,
              f"resamples {m['resamples']}" if m.get("resamples") is not None else None,
              f"learning gate open {100 * m['gate_open_share']:.0f} % of the time"
              if m.get("gate_open_share") is not None else None]
    if any(counts):
        lines.append(", ".join(c for c in counts if c))
    lines += [f"warning: {w}" for w in m["warnings"]]
    return lines


def metrics_line(m: dict) -> str:
    """One line for a status bar: mean |error| per parameter, v^Y RMSE, restarts."""
    parts = [f"{p} |err| {s['mean_abs_pct']:.1f}%" for p, s in m["stiffness"].items() if s["mean_abs_pct"] is not None]
    if "vy" in m["state"]:
        parts.append(f"vy RMSE {m['state']['vy']['rmse']:.3f} m/s")
    if m.get("restarts"):
        parts.append(f"{m['restarts']} restart(s)")
    if m.get("diverged") and m["diverged"]["samples"]:
        parts.append("DIVERGED")
    return ", ".join(parts)
