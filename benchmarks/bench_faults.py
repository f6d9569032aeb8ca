"""The fault matrix: every sensor fault of `scenarios.faults.fault_sets` against
every stiffness estimator, replayed over one drive: stiffness error, sideslip RMSE,
restarts, whether the estimates stayed finite, whether the sideslip recovered within 5 s of
the fault's end, and what the measurement guard removed.

    .venv/bin/python benchmarks/bench_faults.py                       # paper-sim, co-simulated once
    .venv/bin/python benchmarks/bench_faults.py --log DRIVE.csv --vehicle VEHICLE.toml
    options: [--estimators mpf augpf rls ekf kf] [--faults none combined ...] [--particles N]
             [--config FILE.toml] [--seed S] [--no-guard] [--json FILE]

The drive is a Log CSV with references `beta_true` (or `vy_true` with `vx`) and the lateral
stiffness `Cf_y_true`, `Cr_y_true` (paper-sim: from the co-simulation's truth, the surface
mean). Stiffness error: mean |relative error| (%) of Cf_y and Cr_y over the second half of
every stretch of constant true stiffness (a truth that follows the axle load, as in a peer
drive: over the drive's second half). Sideslip RMSE over the whole drive, in degrees.
Recovered: for the single faults that end (stuck, gap, spikes), the sideslip RMS error over [end + 5 s,
end + 10 s) is at most 0.1 deg above that of the clean replay over the same window.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: BLAS threads only contend (30x slower expm)

import argparse
import json
import math
import sys
import time

import numpy as np

from tirefilter.config import read_toml
from tirefilter.estimators import build_log_estimator
from tirefilter.replay import replay_log, result_columns
from tirefilter.io.log import SIGNALS, Log, read_log
from tirefilter.scenarios.faults import fault_log_columns, fault_rng, fault_sets, fault_windows

ESTIMATORS = ("mpf", "augpf", "rls", "ekf", "kf")
RECOVERED_DEG = 0.1  # recovered: sideslip RMS error at most this above the clean replay's (see the docstring)


def paper_sim_drive(seed: int = 0) -> tuple[Log, object]:
    """paper-sim co-simulated once without an estimator, as a Log with its references."""
    from tirefilter.io.results import result_columns as cosim_columns
    from tirefilter.cosim.run import run_scenario
    from tirefilter.scenarios import load_scenario

    scenario = load_scenario("paper-sim")
    from tirefilter.cosim.fmu import VehicleFMU

    fmu = VehicleFMU()
    try:
        _, rows = run_scenario(scenario, seed=seed, fmu=fmu, keep_rows=True)
        r = dict(zip(cosim_columns(fmu.output_names), rows.T))
    finally:
        fmu.close()
    signals = {s: r[f"meas_{s}"] if f"meas_{s}" in r else r[f"true_{s}"] for s in SIGNALS}
    columns = {"t": r["t"], **signals, "beta_true": r["true_beta"], "Cf_y_true": r["true_Cf_y_mean"],
               "Cr_y_true": r["true_Cr_y_mean"]}
    n = len(r["t"])
    log = Log(path=f"paper-sim (seed {seed})", t=r["t"], signals=signals, columns=columns,
              header=tuple(columns), lines=np.arange(2, n + 2))
    return log, scenario.vehicle


def drive_from_file(path: str, vehicle_file: str) -> tuple[Log, object]:
    from tirefilter.vehicle.params import load_vehicle

    vehicle = load_vehicle(vehicle_file)
    log = read_log(path, vehicle, vehicle_name=vehicle_file)
    extra = _reference_columns(path)
    return Log(path=log.path, t=log.t, signals=log.signals, columns={**log.columns, **extra}, header=log.header,
               lines=log.lines, derived=log.derived), vehicle


def _reference_columns(path: str) -> dict:
    """The `*_true` columns of a Log CSV (the reader ignores them)."""
    import csv
    import gzip

    opener = gzip.open if str(path).endswith(".gz") else open
    with opener(path, "rt", newline="") as f:
        reader = csv.reader(f)
        header = [h.strip() for h in next(reader)]
        keep = [(j, h) for j, h in enumerate(header) if h.endswith("_true")]
        data = {h: [] for _, h in keep}
        for row in reader:
            if row:
                for j, h in keep:
                    data[h].append(float(row[j]) if row[j].strip() else math.nan)
    return {h: np.asarray(v) for h, v in data.items()}


def faulty_log(log: Log, faults, seed: int) -> tuple[Log, np.ndarray]:
    """The log with `faults` applied, and the indices of the clean rows it keeps."""
    names = list(log.signals) + [c for c in log.columns if c.endswith("_true")]
    data = {n: (log.signals[n] if n in log.signals else log.columns[n]) for n in names}
    data["_row"] = np.arange(log.rows, dtype=float)
    ref_names = [n for n in names if n.endswith("_true")] + ["_row"]
    # references and the row index ride along untouched (no fault names them)
    t, out = fault_log_columns(log.t, data, faults, fault_rng(seed))
    signals = {n: out[n] for n in log.signals}
    cols = {"t": t, **signals, **{n: out[n] for n in ref_names}}
    rows = out["_row"].astype(int)
    return Log(path=log.path, t=t, signals=signals, columns=cols, header=tuple(cols),
               lines=log.lines[rows] if log.lines is not None else None), rows


def replay_one(log: Log, vehicle, name: str, *, seed: int, particles: int | None, config: dict) -> dict:
    est = build_log_estimator(name, vehicle, log.t, {s: log.signals[s] for s in log.available}, model="auto",
                              particles=particles, config=config, source=log.path)
    t0 = time.perf_counter()
    summary, rows = replay_log(log, estimator=est, seed=seed, keep_rows=True)
    r = dict(zip(result_columns(log), rows.T))
    g = summary.guard or {}
    return {"r": r, "wall_s": time.perf_counter() - t0, "restarts": getattr(est, "restarts", None),
            "guard_removed": sum(sum(v.values()) for k, v in g.items() if k in ("held", "outliers"))}


def score(r: dict, log: Log) -> dict:
    t = r["t"]
    beta_true = log.columns["beta_true"]
    err_deg = np.degrees(r["beta"] - beta_true)
    out = {"beta_rmse_deg": float(np.sqrt(np.mean(err_deg ** 2))),
           "finite": bool(all(np.isfinite(r[c]).all() for c in ("vx", "vy", "yaw_rate", "beta", "Cf_y", "Cr_y")))}
    for p in ("Cf_y", "Cr_y"):
        truth = log.columns.get(f"{p}_true")
        if truth is None:
            continue
        mask = np.zeros(t.shape, bool)
        change = np.flatnonzero(np.diff(truth) != 0) + 1
        if change.size > 10:  # a truth that moves with the load (peer drives): the drive's second half
            change = np.array([], int)
        for a, b in zip(np.r_[0, change], np.r_[change, t.size]):
            mid = t[a] + 0.5 * (t[b - 1] - t[a])
            mask[a:b] |= t[a:b] >= mid
        rel = np.abs(r[p][mask] - truth[mask]) / truth[mask]
        out[f"{p}_err_pct"] = float(100 * np.mean(np.where(np.isfinite(rel), rel, np.inf)))
    out["err_deg"] = err_deg
    return out


def recovered(scored: dict, clean: dict, t: np.ndarray, t_clean: np.ndarray, faults) -> bool | None:
    windows = fault_windows(faults)
    if not windows or any(f.kind in ("dropout", "bias_step", "held", "jitter") for f in faults):
        return None  # nothing ends, or a lasting fault confounds the comparison
    for _, end in windows:
        w = (t >= end + 5.0) & (t < end + 10.0)
        wc = (t_clean >= end + 5.0) & (t_clean < end + 10.0)
        if not w.any() or not wc.any():
            continue
        rms = float(np.sqrt(np.mean(scored["err_deg"][w] ** 2)))
        ref = float(np.sqrt(np.mean(clean["err_deg"][wc] ** 2)))
        if not rms <= ref + RECOVERED_DEG:
            return False
    return True


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--log", help="drive: a Log CSV with beta_true, Cf_y_true, Cr_y_true (default: paper-sim)")
    p.add_argument("--vehicle", help="vehicle TOML of --log")
    p.add_argument("--estimators", nargs="+", default=list(ESTIMATORS))
    p.add_argument("--faults", nargs="+", help="fault sets (default: none and all of scenarios.faults.fault_sets)")
    p.add_argument("--particles", type=int)
    p.add_argument("--config", help="estimator configuration TOML (as --config of replay)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-guard", action="store_true", help="[guard] enabled = false")
    p.add_argument("--json", help="write the matrix as JSON here")
    args = p.parse_args(argv)

    config = read_toml(args.config) if args.config else {}
    if args.no_guard:
        config = {**config, "guard": {**config.get("guard", {}), "enabled": False}}
    if args.log:
        if not args.vehicle:
            p.error("--log needs --vehicle")
        log, vehicle = drive_from_file(args.log, args.vehicle)
    else:
        log, vehicle = paper_sim_drive(args.seed)
    sets = {"none": (), **fault_sets(log.duration)}
    names = args.faults or list(sets)
    print(f"drive: {log.path}, {log.rows} rows over {log.duration:g} s; estimators {', '.join(args.estimators)}; "
          f"N = {args.particles or 'default'}; config {args.config or 'defaults'}; guard "
          f"{'off' if args.no_guard else 'on'}; seed {args.seed}", flush=True)
    print("| fault | estimator | Cf_y err % | Cr_y err % | sideslip RMSE deg | restarts | finite | recovered 5 s "
          "| guard removed | wall s |\n|---|---|---|---|---|---|---|---|---|---|", flush=True)
    clean: dict[str, tuple] = {}
    matrix = []
    for fname in ["none"] + [n for n in names if n != "none"]:
        flog, _ = faulty_log(log, sets[fname], args.seed) if fname != "none" else (log, None)
        for est in args.estimators:
            res = replay_one(flog, vehicle, est, seed=args.seed, particles=args.particles, config=config)
            s = score(res["r"], flog)
            if fname == "none":
                clean[est] = (s, flog.t)
            rec = None if fname == "none" else recovered(s, clean[est][0], flog.t, clean[est][1], sets[fname])
            row = {"fault": fname, "estimator": est, **{k: v for k, v in s.items() if k != "err_deg"},
                   "restarts": res["restarts"], "recovered_5s": rec, "guard_removed": res["guard_removed"],
                   "wall_s": res["wall_s"]}
            matrix.append(row)
            if fname in names:
                print(f"| {fname} | {est} | {row.get('Cf_y_err_pct', math.nan):.1f} | "
                      f"{row.get('Cr_y_err_pct', math.nan):.1f} | {row['beta_rmse_deg']:.3f} | "
                      f"{'-' if row['restarts'] is None else row['restarts']} | {'yes' if row['finite'] else 'NO'} | "
                      f"{'-' if rec is None else ('yes' if rec else 'no')} | {row['guard_removed']} | "
                      f"{row['wall_s']:.1f} |", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(matrix, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
