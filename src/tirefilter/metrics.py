"""Metrics (docs/usage.md, "Run summary") on Result-CSV columns (windows from the scenario's schedule)."""

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
Z90 = 1.6448536269514722  # the 90% interval of the coverage (docs/usage.md): estimate +- Z90 * *_std
CX_EXCITED = 0.5  # a run whose excitation weight of Cx (derivations, "The undriven axle") stays below this: "not excited"
DIVERGED_VY = 1.0  # m/s: |v^Y - reference| beyond this is a diverged state ...
DIVERGED_BETA = 0.1  # rad: ... or |beta - reference| beyond this, where v^Y has no reference
STARTUP_S = 5.0  # s: without a schedule (a replay) the states' settled RMSE leaves out the first seconds


def run_metrics(r: dict, schedule=None, *, restarts: int | None = None, resamples: int | None = None,
                cx_excitation: float | None = None) -> dict:
    """The accuracy and health figures of one run (docs/usage.md, "Run summary"), from
    its Result-CSV columns `r` (name -> (n,) array).

    - per stiffness parameter with a reference: the mean absolute relative error (%) over
      every sample with an estimate (`mean_abs_pct`: errors cannot cancel), the same over the
      settled window (`settled_mean_abs_pct`: the steady state, from the scenario's
      `schedule` -- its `excitation` windows and `surface_changes`; None without a schedule,
      e.g. a replay), the final error, the coverage of the 90% interval estimate
      +- 1.645 `*_std` (whole run and settled window; about 0.9 when calibrated) and the
      settling time after each surface change;
    - state RMSE of v^Y, beta, yaw rate, v^X against `true_<s>` or a log's `<s>_true`, over
      the whole run (`rmse`) and settled (`settled_rmse`: over the schedule's settled windows,
      or without a schedule from STARTUP_S after the first sample; `state_settled` says which);
    - diverged samples: |v^Y error| > DIVERGED_VY (else |beta error| > DIVERGED_BETA), with
      their time windows;
    - restarts and resamples (the estimator's counters, None where it has none), the share
      of samples with the learning gate open (`active`);
    - `cx_excitation`: the largest excitation weight of Cx in the run (the MPF's
      `cx_weight_max`, derivations, "The undriven axle"; None without one);
    - `warnings`: one line per restart, divergence, NaN estimate or coverage below 50%, and
      one when Cx was never excited (`cx_excitation` below CX_EXCITED).

    `RunMetrics` (below) fed the whole table as one chunk: a run's summary feeds it chunk by
    chunk as the rows are written (`runs.Metrics`), a study or the dashboard the rows they keep.
    """
    m = RunMetrics(list(r), schedule)
    m.update(r)
    return m.finalize(restarts=restarts, resamples=resamples, cx_excitation=cx_excitation)


# ---- the metrics streamed: constant memory over a run of any length --------------------------------

def _cov_warning(p: str, cov: float) -> str:
    return (f"{p}: the 90% band (+-1.645 {p}_std) holds the reference in only {100 * cov:.0f}% "
            "of the samples: the posterior is overconfident")


class _Sum:
    """Sum and count of the finite values seen (chunk by chunk): their mean, None without one."""

    __slots__ = ("s", "n")

    def __init__(self):
        self.s, self.n = 0.0, 0

    def add(self, x: np.ndarray) -> None:
        x = x[np.isfinite(x)]
        if x.size:
            self.s += float(np.sum(x))
            self.n += x.size

    def mean(self) -> float | None:
        return self.s / self.n if self.n else None


class _Runs:
    """[t_first, t_last] of each run of True in a mask that arrives chunk by chunk."""

    def __init__(self):
        self.windows: list[list[float]] = []
        self.open = False  # the last sample seen was inside a run

    def add(self, mask: np.ndarray, t: np.ndarray) -> None:
        if not mask.size:
            return
        m = mask.astype(np.int8)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], m, [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            if a == 0 and self.open:  # the run goes on from the previous chunk
                self.windows[-1][1] = float(t[b - 1])
            else:
                self.windows.append([float(t[a]), float(t[b - 1])])
        self.open = bool(mask[-1])


class _Settling:
    """`settling_time` after t_change, streamed: the time of the first sample after the
    last one outside the tolerance band."""

    def __init__(self, t_change: float, tol: float = 0.05):
        self.t_change, self.tol = t_change, tol
        self.outside = False  # any sample after t_change outside the band
        self.pending = False  # the last sample after t_change was outside
        self.t_in = None  # time of the first sample after the last outside one

    def add(self, t: np.ndarray, est: np.ndarray, mean: np.ndarray) -> None:
        after = t >= self.t_change
        if not after.any():
            return
        ta = t[after]
        rel = np.abs(est[after] - mean[after]) / mean[after]
        out = np.flatnonzero(~(rel <= self.tol))
        if out.size:
            self.outside = True
            last = out[-1]
            self.pending = last == ta.size - 1
            if not self.pending:
                self.t_in = float(ta[last + 1])
        elif self.pending:
            self.pending, self.t_in = False, float(ta[0])

    def value(self) -> float:
        if not self.outside:
            return 0.0
        return float("inf") if self.pending else float(self.t_in - self.t_change)


class _StiffnessAgainst:
    """The figures of one stiffness parameter against one candidate reference column."""

    def __init__(self, p: str, ref: str, has_std: bool):
        self.p, self.ref, self.has_std = p, ref, has_std
        self.ref_finite = False
        self.abs_err, self.settled_abs = _Sum(), _Sum()
        self.have = self.inside = 0  # samples with an error; of those inside the band
        self.w_have = self.w_inside = self.missing = 0
        self.final = None

    def add(self, c: dict, settled) -> None:
        p = self.p
        est, truth = c[p], c[self.ref]
        self.ref_finite |= bool(np.isfinite(truth).any())
        err = 100.0 * (est - truth) / truth
        have = np.isfinite(err)
        self.abs_err.add(np.abs(err))
        if have.any():
            self.final = float(err[have][-1])
        self.have += int(np.count_nonzero(have))
        inside = np.abs(est - truth) <= Z90 * c[f"{p}_std"] if self.has_std else None
        if inside is not None:
            self.inside += int(np.count_nonzero(inside & have))
        if settled is not None:
            w = settled & np.isfinite(truth)
            self.missing += int(np.count_nonzero(w & ~have))
            self.settled_abs.add(np.abs(err[w]))
            self.w_have += int(np.count_nonzero(w & have))
            if inside is not None:
                self.w_inside += int(np.count_nonzero(inside & w & have))


class _StateAgainst:
    """Squared and absolute errors of one state against one candidate reference column,
    and the samples beyond the divergence threshold."""

    def __init__(self, s: str, ref: str):
        self.s, self.ref = s, ref
        self.ref_finite = False
        self.sq, self.n, self.max = 0.0, 0, -np.inf
        self.sq_settled, self.n_settled = 0.0, 0
        self.bad, self.max_e = 0, None  # divergence: samples beyond the threshold, nanmax of |e|
        self.any_ok = False
        self.bad_runs = _Runs()

    def add(self, c: dict, t: np.ndarray, limit: float | None, settled: np.ndarray) -> None:
        truth = c[self.ref]
        self.ref_finite |= bool(np.isfinite(truth).any())
        e = c[self.s] - truth
        ok = np.isfinite(e)
        if ok.any():
            eo = e[ok]
            self.sq += float(np.sum(eo ** 2))
            self.n += eo.size
            self.max = max(self.max, float(np.max(np.abs(eo))))
            es = e[ok & settled]
            self.sq_settled += float(np.sum(es ** 2))
            self.n_settled += es.size
        if limit is not None:
            a = np.abs(e)
            bad = np.nan_to_num(a, nan=0.0) > limit
            self.bad += int(np.count_nonzero(bad))
            self.any_ok |= bool(ok.any())
            seen = ~np.isnan(a)  # np.nanmax: an infinite error counts
            if seen.any():
                m = float(np.max(a[seen]))
                self.max_e = m if self.max_e is None else max(self.max_e, m)
            self.bad_runs.add(bad, t)


class RunMetrics:
    """The metrics of `run_metrics`, streamed: `update` with each chunk of rows (the
    Result-CSV columns as name -> (k,) arrays, the same names in every chunk), `finalize`
    for the figures of all the rows so far (the same however the rows were cut into chunks,
    up to the order of summation: a relative 1e-12). What it keeps does not grow with the
    run: sums and counts, the last error, the windows of the settled mask and of divergence,
    and per surface change the state of its settling time (the time of the first sample after
    the last one outside the 5 % band, `settling_time`)."""

    def __init__(self, columns, schedule=None):
        cols = set(columns)
        if "t" not in cols:
            raise ValueError("RunMetrics needs the column t")
        self.schedule = schedule
        self.n = 0
        self.t_first = self.t_last = None
        self.settled_runs = _Runs() if schedule is not None else None
        self.active = _Sum() if "active" in cols else None
        self.stiffness: dict[str, list[_StiffnessAgainst]] = {}
        self.est_finite: dict[str, bool] = {}
        self.settling: dict[str, list[_Settling]] = {}
        for p in PARAMS:
            if p not in cols:
                continue
            self.est_finite[p] = False
            refs = [c for c in (f"true_{p}_mean", f"{p}_mean_true", f"true_{p}", f"{p}_true") if c in cols]
            self.stiffness[p] = [_StiffnessAgainst(p, c, f"{p}_std" in cols) for c in refs]
            if schedule is not None and f"true_{p}_mean" in cols:
                self.settling[p] = [_Settling(tc) for tc in schedule.surface_changes]
        self.states: dict[str, list[_StateAgainst]] = {}
        for s, _ in STATES:
            if s in cols:
                self.states[s] = [_StateAgainst(s, c) for c in (f"true_{s}", f"{s}_true") if c in cols]
        self._limits = {"vy": DIVERGED_VY, "beta": DIVERGED_BETA}

    def update(self, c: dict) -> None:
        """Add a chunk of rows: `c` maps the columns given at construction to (k,) arrays."""
        c = {k: np.asarray(v, float) for k, v in c.items()}
        t = c["t"]
        if not t.size:
            return
        self.n += t.size
        if self.t_first is None:
            self.t_first = float(t[0])
        self.t_last = float(t[-1])
        settled = steady_state_mask(t, self.schedule) if self.schedule is not None else None
        if settled is not None:
            self.settled_runs.add(settled, t)
        state_settled = settled if settled is not None else t >= self.t_first + STARTUP_S
        for p, cands in self.stiffness.items():
            self.est_finite[p] |= bool(np.isfinite(c[p]).any())
            for a in cands:
                a.add(c, settled)
            for st in self.settling.get(p, ()):
                st.add(t, c[p], c[f"true_{p}_mean"])
        for s, cands in self.states.items():
            for a in cands:
                a.add(c, t, self._limits.get(s), state_settled)
        if self.active is not None:
            self.active.add(c["active"])

    def finalize(self, *, restarts: int | None = None, resamples: int | None = None,
                 cx_excitation: float | None = None) -> dict:
        """The figures of the rows so far, as `run_metrics` gives them."""
        sched = self.schedule
        out: dict = {"samples": int(self.n),
                     "settled_windows": self.settled_runs.windows if sched is not None else None,
                     "stiffness": {}, "state": {}}
        warnings: list[str] = []
        for p, cands in self.stiffness.items():
            if not self.est_finite[p]:
                continue
            by_ref = {a.ref: a for a in cands if a.ref_finite}
            a = next((by_ref[c] for c in (f"true_{p}_mean", f"{p}_mean_true", f"true_{p}", f"{p}_true")
                      if c in by_ref), None)
            if a is None:
                continue
            m = {"reference": a.ref, "mean_abs_pct": a.abs_err.mean(), "final_pct": a.final,
                 "coverage90": a.inside / a.have if a.has_std and a.have else None}
            if sched is not None:
                m.update(settled_mean_abs_pct=a.settled_abs.mean(),
                         settled_coverage90=a.w_inside / a.w_have if a.has_std and a.w_have else None,
                         settled_missing=a.missing)
                if a.missing:
                    warnings.append(f"{p}: no estimate at {a.missing} samples of the settled window")
                if p in self.settling:
                    m["settling_s"] = [st.value() for st in self.settling[p] if st.t_change < self.t_last]
            cov = m.get("settled_coverage90", m["coverage90"])
            if cov is not None and cov < 0.5:
                warnings.append(_cov_warning(p, cov))
            out["stiffness"][p] = m
        chosen = {}
        for s, unit in STATES:
            cands = [a for a in self.states.get(s, ()) if a.ref_finite]
            if not cands:
                continue
            a = chosen[s] = cands[0]
            if a.n:
                out["state"][s] = {"reference": a.ref, "rmse": float(np.sqrt(a.sq / a.n)),
                                   "settled_rmse": float(np.sqrt(a.sq_settled / a.n_settled)) if a.n_settled else None,
                                   "max_abs": a.max, "unit": unit}
        out["state_settled"] = "settled windows" if sched is not None else f"after {STARTUP_S:g} s"
        out["diverged"] = None
        for s, limit, unit in (("vy", DIVERGED_VY, "m/s"), ("beta", DIVERGED_BETA, "rad")):
            if s in chosen:
                a = chosen[s]
                out["diverged"] = {"signal": s, "reference": a.ref, "threshold": limit, "unit": unit,
                                   "samples": a.bad, "share": a.bad / self.n if self.n else 0.0,
                                   "max_abs": a.max_e if a.any_ok else None, "windows": a.bad_runs.windows}
                break
        _finish(out, warnings, restarts, resamples, self.active.mean() if self.active is not None else None,
                cx_excitation)
        return out


def _finish(out: dict, warnings: list[str], restarts, resamples, gate_open_share, cx_excitation=None) -> None:
    """The divergence warning, the counters, the gate share, the excitation of Cx and the
    warnings of `out`."""
    if out["diverged"] is not None and out["diverged"]["samples"]:
        d = out["diverged"]
        spans = ", ".join(f"{a:g}-{b:g} s" for a, b in d["windows"][:3]) + (", ..." if len(d["windows"]) > 3 else "")
        k, unit = _shown(d["signal"], d["unit"])
        largest = "inf" if d["max_abs"] is None else f"{k * d['max_abs']:.3g}"  # (None: no finite error, all infinite)
        warnings.append(f"state diverged at {d['samples']} samples ({spans}): |{d['signal']} error| up to "
                        f"{largest} {unit} (threshold {k * d['threshold']:.3g}" + (f" {unit})" if k != 1 else ")"))
    out["restarts"] = None if restarts is None else int(restarts)
    out["resamples"] = None if resamples is None else int(resamples)
    if restarts:
        warnings.append(f"the filter restarted {restarts} time{'s' if restarts > 1 else ''} from its prior "
                        "(every particle implausible): estimates around then are not converged")
    out["gate_open_share"] = gate_open_share
    out["cx_excitation"] = None if cx_excitation is None else float(cx_excitation)
    if cx_excitation is not None and cx_excitation < CX_EXCITED:
        warnings.append(f"Cx: no wheel-slip excitation (excitation weight at most {cx_excitation:.2f} of 1, "
                        "docs/derivations.md, 'The undriven axle'): this drive cannot teach Cx, so its estimate is no measurement "
                        "of it (it can drift from the vehicle file's value with the state and the a^X bias)")
    out["warnings"] = warnings


def _pct(x) -> str:
    return "n/a" if x is None else f"{x:.2f} %"


def _signed_pct(x) -> str:
    return "n/a" if x is None else f"{x:+.2f} %"


def _shown(state: str, unit: str) -> tuple[float, str]:
    """Factor and unit a state's figures are printed in: the sideslip in degrees (as the
    recording shows it, viz/units.py), the rest in their SI unit."""
    return (180.0 / np.pi, "deg") if unit == "rad" else (1.0, unit)


def _with_unit(x, k: float, unit: str) -> str:
    return "-" if x is None else f"{k * x:.3g} {unit}"


def format_metrics(m: dict, sensor_noise: dict | None = None) -> list[str]:
    """The lines of the printed run summary, each column headed by what it is and the
    window it covers: per stiffness parameter the mean absolute error over the whole run
    and over the settled windows, the error at the end, how often the 90% band held the
    reference; per state the RMSE over the whole run and settled (the schedule's settled
    windows, or after the start-up of a replay), the largest error, and the white-noise std
    of the sensor that measures it (`sensor_noise`: state -> (std in the state's unit, the
    sensor's name), e.g. the gyro for the yaw rate); restarts, resamples, the gate; then the
    warnings, each on a line starting with `warning:`. The sideslip is printed in degrees."""
    lines = []
    scheduled = m.get("settled_windows") is not None
    settled = "settled" if scheduled else m.get("state_settled") or "settled"
    if m["stiffness"]:
        cov_window = "settled" if any("settled_coverage90" in s for s in m["stiffness"].values()) else "whole run"
        lines.append(f"{'stiffness error':16s}{'mean |err|':>12s}{'mean |err|':>12s}{'error':>10s}"
                     f"{'truth in the':>19s}  reference")
        lines.append(f"{'':16s}{'whole run':>12s}{'settled':>12s}{'at end':>10s}"
                     f"{'  90% band, ' + cov_window:>19s}")  # (the whole run's label overflows the column)
        for p, s in m["stiffness"].items():
            cov = s.get("settled_coverage90", s["coverage90"])
            lines.append(f"{p:16s}{_pct(s['mean_abs_pct']):>12s}{_pct(s.get('settled_mean_abs_pct')):>12s}"
                         f"{_signed_pct(s['final_pct']):>10s}"
                         f"{('n/a' if cov is None else f'{100 * cov:.0f} %'):>19s}  {s['reference']}")
    if m["state"]:
        noise = sensor_noise or {}
        lines.append(f"{'state error':16s}{'RMSE':>15s}{'RMSE':>15s}{'max |err|':>15s}{'sensor noise':>20s}  reference")
        lines.append(f"{'':16s}{'whole run':>15s}{settled:>15s}{'whole run':>15s}{'(std)':>20s}")
        for s, v in m["state"].items():
            k, unit = _shown(s, v["unit"])
            sensor = noise.get(s)
            sensor = "-" if sensor is None else f"{_with_unit(sensor[0], k, unit)} {sensor[1]}"
            rmse, settled_rmse = _with_unit(v["rmse"], k, unit), _with_unit(v.get("settled_rmse"), k, unit)
            lines.append(f"{s:16s}{rmse:>15s}{settled_rmse:>15s}{_with_unit(v['max_abs'], k, unit):>15s}{sensor:>20s}"
                         f"  {v['reference']}")
    if scheduled and (m["stiffness"] or m["state"]):
        w = ", ".join(f"{a:g}-{b:g} s" for a, b in m["settled_windows"]) or "none"
        lines.append(f"  (settled: from 5 s after each excitation start / surface change: {w}; "
                     "90% band: estimate +- 1.645 std)")
    elif m["state"] and m.get("state_settled"):
        lines.append(f"  ({m['state_settled']}: from {STARTUP_S:g} s after the first sample, the start-up left out)")
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
