"""What a log holds and what can run on it (`tirefilter check-log`): sampling, gaps,
missing samples and ranges per column, the models it supports and why, and how much of
it the stiffness MPF's default gates leave for learning."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from tirefilter.errors import LogError
from tirefilter.io.log import CORNERS, Log, read_log, reference_name, vehicle_arg

GAP_FACTOR = 2.0  # a time step longer than this times the median is a gap


@dataclass(frozen=True)
class LogSummary:
    file: str
    rows: int
    t_start: float  # s
    t_end: float  # s
    duration: float  # s
    median_dt: float  # s
    median_rate: float  # Hz
    dt_min: float  # s
    dt_max: float  # s
    gaps: dict  # count, threshold [s], largest and first (up to 10): {dt, t (where it starts), row (after it)}
    columns: dict  # name -> {missing, min, max[, derived | note]}: the known columns, then derived signals
    ignored: tuple[str, ...]  # the file's columns the reader does not use
    models: dict  # "full" / "lateral" -> {supported, reason}; "auto" -> the model auto picks (or None)
    gates: dict  # the MPF's default linear-region and speed gates and the shares of samples beyond them
    warnings: tuple[str, ...]
    references: tuple[str, ...] = ()  # reference columns (`*_true`, `true_*`): carried into results, scored
    noise: dict = None  # IMU white noise estimated from the log (and the vehicle's figures): sensors.SensorModel

    @property
    def usable(self) -> bool:
        return self.models["auto"] is not None

    def to_dict(self) -> dict:
        return _json_safe(asdict(self) | {"usable": self.usable})

    def format(self) -> str:
        """The human-readable report of `tirefilter check-log`."""
        g = self.gaps
        out = [f"{self.file}: {self.rows} rows, t = {self.t_start:g} ... {self.t_end:g} s ({self.duration:g} s)",
               f"sampling: median {self.median_rate:.4g} Hz (dt {self.median_dt:.4g} s), dt {self.dt_min:.4g} ... "
               f"{self.dt_max:.4g} s; gaps (dt > {g['threshold']:.4g} s): {g['count']}"
               + (f", largest {g['largest']['dt']:.4g} s from t = {g['largest']['t']:g} s (before data row "
                  f"{g['largest']['row']})" if g["count"] else ""),
               f"{'column':24s}{'missing':>9s}{'min':>13s}{'max':>13s}"]
        for name, c in self.columns.items():
            label = name + (" *" if c.get("derived") or c.get("note") else "")
            out.append(f"{label:24s}{c['missing']:9d}{_g(c['min']):>13s}{_g(c['max']):>13s}")
        out += [f"  * {n}: {c.get('derived') or c['note']}" for n, c in self.columns.items()
                if c.get("derived") or c.get("note")]
        if self.references:
            out.append(f"reference columns (scored, never given to the estimator): {', '.join(self.references)}")
        if self.ignored:
            out.append(f"ignored columns: {', '.join(self.ignored)}")
        for model in ("full", "lateral"):
            m = self.models[model]
            out.append(f"{model} model: {'yes' if m['supported'] else 'no'} ({m['reason']})")
        out.append(f"--model auto: {self.models['auto'] or 'none (no model can run on this log)'}")
        ga = self.gates
        out.append(f"|ay| > {ga['ay_max']:g} m/s^2 (MPF linear-region gate): {_pct(ga['share_ay_above'])} of samples")
        if self.noise:
            n = self.noise
            from tirefilter.estimators.sensors import CHANNELS, UNITS

            units = dict(zip(CHANNELS, UNITS))
            out.append("white noise estimated from the log: " + ", ".join(
                f"{c} {_g3(n['sigma_from_data'][c])} {units[c]}" + (
                    f" (vehicle file: {_g3(n['sigma'][c])} {units[c]})" if n["sigma_source"][c] == "vehicle file"
                    else "") for c in n["sigma_from_data"])
                + (f"; wheel speeds {_g3(n['sigma_omega'])} rad/s" if n.get("sigma_omega") else ""))
        out.append(f"speed < {ga['speed_min']:g} m/s (MPF gate speed): " + (
            f"{_pct(ga['share_speed_below'])} of samples (speed from {ga['speed_from']})" if ga["speed_from"]
            else "n/a (no vx; give a vehicle TOML for the speed from the wheel speeds)"))
        out += [f"warning: {w}" for w in self.warnings]
        return "\n".join(out)


def check_log(path, vehicle=None) -> LogSummary:
    """Read and check the log at `path` (raising LogError when it cannot be used) and
    summarise it. `vehicle` (VehicleParams or a vehicle TOML path) converts a steering-wheel
    angle and gives the wheel radius for a speed from wheel speeds."""
    from tirefilter.estimators.sensors import sensors_for_log
    from tirefilter.estimators.mpf import MPFConfig

    vehicle, name = vehicle_arg(vehicle)
    log = read_log(path, vehicle, need_steering_ratio=vehicle is not None, vehicle_name=name)
    dt = np.diff(log.t)
    median = float(np.median(dt)) if dt.size else math.nan
    noise = sensors_for_log(vehicle, log.signals)
    summary = LogSummary(
        file=str(log.path), rows=log.rows, t_start=float(log.t[0]), t_end=float(log.t[-1]), duration=log.duration,
        median_dt=median, median_rate=1.0 / median if dt.size else math.nan,
        dt_min=float(dt.min()) if dt.size else math.nan, dt_max=float(dt.max()) if dt.size else math.nan,
        gaps=_gaps(log, dt, median), columns=_columns(log), ignored=log.ignored, models=_models(log),
        gates=_gates(log, vehicle, MPFConfig()), warnings=tuple(_warnings(log) + list(noise.warnings)),
        references=tuple(h for h in log.header if reference_name(h) is not None), noise=noise.to_dict(),
    )
    if not summary.usable:
        raise LogError(log.path, "no model can run on this log: " + "; ".join(
            f"{m}: {summary.models[m]['reason']}" for m in ("full", "lateral")))
    return summary


def _gaps(log: Log, dt: np.ndarray, median: float) -> dict:
    threshold = GAP_FACTOR * median if dt.size else math.nan
    idx = np.flatnonzero(dt > threshold)
    record = {"count": int(idx.size), "threshold": threshold, "largest": None, "first": []}
    if idx.size:
        def gap(j):  # from data row j + 1 to data row j + 2 (1-based)
            return {"dt": float(dt[j]), "t": float(log.t[j]), "row": int(j + 2)}

        record["largest"] = gap(int(idx[np.argmax(dt[idx])]))
        record["first"] = [gap(int(j)) for j in idx[:10]]
    return record


def _columns(log: Log) -> dict:
    out = {}
    names = [c for c in log.columns if c != "t"] + [s for s in log.signals if s not in log.columns]
    for name in names:
        x = log.signals[name] if name not in log.columns else log.columns[name]
        finite = x[np.isfinite(x)]
        out[name] = {"missing": int(x.size - finite.size),
                     "min": float(finite.min()) if finite.size else math.nan,
                     "max": float(finite.max()) if finite.size else math.nan}
        if name in log.derived:
            out[name]["derived"] = log.derived[name]
    if "delta" not in log.signals and "steering_wheel_angle" in log.columns:
        out["steering_wheel_angle"]["note"] = "not converted to delta: give a vehicle TOML with steering_ratio"
    return out


def _models(log: Log) -> dict:
    from tirefilter.estimators import resolve_model

    have = set(log.available)
    steer = "delta" in log.columns or "steering_wheel_angle" in log.columns
    wheels = [a for a in CORNERS if a in have]
    source = "; ".join(f"{a}: {log.derived[a]}" for a in wheels if a in log.derived)
    full = {"supported": steer and len(wheels) == 2,
            "reason": ("wheel speeds omega_f and omega_r" + (f" ({source})" if source else "")) if len(wheels) == 2
            else "needs wheel speeds omega_f and omega_r (or omega_fl, omega_fr, omega_rl, omega_rr); "
                 + (f"the log has only {wheels[0]}" if wheels else "the log has none")}
    lateral = {"supported": steer and "vx" in have,
               "reason": "vx given as an input" if "vx" in have
               else "needs vx (" + ("the column has no samples" if "vx" in log.columns else "no vx column") + ")"}
    auto = resolve_model("auto", have)
    return {"full": full, "lateral": lateral, "auto": auto if {"full": full, "lateral": lateral}[auto]["supported"]
            else None}


def _gates(log: Log, vehicle, cfg) -> dict:
    ay = log.signal("ay")
    ay = ay[np.isfinite(ay)]
    speed, source = None, None
    if "vx" in log.available:
        speed, source = log.signal("vx"), "vx"
    elif vehicle is not None and {"omega_f", "omega_r"} & set(log.available):
        axle = "omega_f" if vehicle.drive == "rear" or "omega_r" not in log.available else "omega_r"
        speed, source = vehicle.wheel_radius * log.signal(axle), f"wheel_radius * {axle}"
    if speed is not None:
        speed = speed[np.isfinite(speed)]
    return {
        "ay_max": cfg.gate_ay_max,
        "share_ay_above": float(np.mean(np.abs(ay) > cfg.gate_ay_max)) if ay.size else None,
        "speed_min": cfg.gate_speed,
        "share_speed_below": float(np.mean(speed < cfg.gate_speed)) if speed is not None and speed.size else None,
        "speed_from": source,
    }


def _warnings(log: Log) -> list[str]:
    out = []
    for name in log.available:
        x = log.signals[name]
        if not math.isfinite(x[0]) and name in ("delta", "omega_f", "omega_r", "vx"):
            k = int(np.flatnonzero(np.isfinite(x))[0])
            out.append(f"{name} is missing in the first {k} rows (before t = {log.t[k]:g} s): the estimator has no "
                       f"value to hold there")
    for name in set(log.signals) - set(log.available):
        out.append(f"{name} has no samples at all")
    from tirefilter.replay.plausibility import Plausibility

    plausibility = Plausibility()
    plausibility.add(log)
    return out + plausibility.warnings()


def _g(x: float) -> str:
    return "-" if x != x else f"{x:.6g}"


def _g3(x: float | None) -> str:
    return "-" if x is None or x != x else f"{x:.3g}"


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f}%"


def _json_safe(x):
    """NaN -> None, tuples -> lists: strict JSON."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
