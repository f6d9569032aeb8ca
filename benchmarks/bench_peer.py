"""Peer drives: the estimators with their default settings on drives
simulated by the CommonRoad vehicle models (`tirefilter peer-drive`; the `peer` extra),
with data-sheet vehicle TOMLs (guessed nominal stiffness, no noise or bias keys).

    .venv/bin/python benchmarks/bench_peer.py [--models std mb] [--vehicles 1 2 3] [--seeds 0 1]
        [--estimators mpf ekf kf augpf] [--maneuver mixed] [--duration 60] [--speed 20] [--ay 3] [--last 30]
        [--config FILE.toml] [--workers 1] [--no-vx]

Per drive and estimator: the lateral stiffness error (mean of the estimate over the last
`--last` seconds against the mean of `Cf_y_true`, `Cr_y_true` there, in %), the sideslip
RMSE over the whole drive (deg; "zero guess" is the RMSE of a zero-sideslip guess), the
longitudinal stiffness error of the estimators that have a Cx (the full-model MPF; the same
mean against `Cx_true`, the driven axle's slip stiffness), the
restarts of the particle filters, and the wall time of the replay; per drive also its
largest |a^Y| and the IMU's a^Y gain 1 + g k from body roll (k the roll gradient; 1 for
STD). Then the mean absolute errors per model and estimator, as markdown tables on stdout
(docs/results.md, "Peer drives"). The default run is modest (12 drives of 60 s, one worker).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

def replay_drive(drive, name: str, config: dict, seed: int, last: float, no_vx: bool = False):
    """Replay the peer drive `drive` through its CSV log and vehicle TOML, as a user would,
    with estimator `name` and `config`; returns its scores against the drive's truth (last
    `last` s, `peer.score`) and the estimator. `no_vx`: the log without its `vx` column (wheel
    speeds only)."""
    from tirefilter.estimators import build_log_estimator
    from tirefilter.peer.drive import write_drive
    from tirefilter.peer.score import score
    from tirefilter.replay import read_log, replay_log, result_columns
    from tirefilter.vehicle.params import load_vehicle

    with tempfile.TemporaryDirectory() as tmp:
        log_path, vehicle_path = write_drive(drive, Path(tmp) / "drive.csv", Path(tmp) / "vehicle.toml")
        if no_vx:
            lines = log_path.read_text().splitlines()
            keep = [i for i, c in enumerate(lines[0].split(",")) if c != "vx"]
            log_path.write_text("\n".join(",".join(r.split(",")[i] for i in keep) for r in lines) + "\n")
        vehicle = load_vehicle(vehicle_path)
        log = read_log(log_path, vehicle)
    est = build_log_estimator(name, vehicle, log.t, {s: log.signals[s] for s in log.available}, model="auto",
                              particles=None, config=config, source=log.path)
    _, kept = replay_log(log, estimator=est, seed=seed, keep_rows=True)
    c = drive.columns
    truth = {k: c[k] for k in ("t", "beta_true", "Cf_y_true", "Cr_y_true", "Cx_true")}
    return score(truth, dict(zip(result_columns(log), kept.T)), last=last), est


def run_drive(job: tuple) -> list[dict]:
    """Generate one drive and replay it with every estimator; one row per estimator."""
    from tirefilter.config import read_toml
    from tirefilter.peer.drive import DriveSpec, simulate

    model, vehicle_id, seed, estimators, maneuver, duration, speed, last, config_path, ay, no_vx = job
    config = read_toml(config_path) if config_path else {}
    t0 = time.perf_counter()
    drive = simulate(DriveSpec(model=model, vehicle=vehicle_id, maneuver=maneuver, duration=duration, seed=seed,
                                speed=speed, ay=ay))
    gen_s = time.perf_counter() - t0
    rows = []
    for name in estimators:
        t1 = time.perf_counter()
        s, est = replay_drive(drive, name, config, seed, last, no_vx)
        rows.append({"model": model, "vehicle": vehicle_id, "seed": seed, "estimator": name, **s,
                     "restarts": getattr(est, "restarts", None), "wall_s": time.perf_counter() - t1,
                     "gen_s": gen_s, "ay_max": float(np.max(np.abs(drive.columns["ay_true"]))),
                     "roll_gradient": drive.roll_gradient})
    return rows


def _fmt(x: float, spec: str) -> str:
    return "fails" if not math.isfinite(x) else format(x, spec)


def _cx(x: float, spec: str) -> str:
    """A Cx error cell: "-" where the estimator has no Cx (NaN)."""
    return "-" if math.isnan(x) else _fmt(x, spec) + (" %" if math.isfinite(x) else "")


def tables(rows: list[dict], args) -> str:
    lines = ["| model | vehicle | seed | max abs a^Y | IMU a^Y gain | estimator | Cf_y error | Cr_y error "
             "| Cx error | sideslip RMSE | zero guess | restarts | wall |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['vehicle']} | {r['seed']} | {r['ay_max']:.1f} m/s^2 | "
                     f"{1 + 9.81 * r['roll_gradient']:.3f} | {r['estimator']} | "
                     f"{_fmt(r['Cf_y_err'], '+.1f')} % | {_fmt(r['Cr_y_err'], '+.1f')} % | "
                     f"{_cx(r['Cx_err'], '+.1f')} | "
                     f"{_fmt(r['beta_rmse_deg'], '.3f')} deg | {r['beta_zero_rmse_deg']:.3f} deg | "
                     f"{'-' if r['restarts'] is None else r['restarts']} | {r['wall_s']:.0f} s |")
    lines += ["", "Mean over the drives (absolute errors; a failed replay counts as infinite):", "",
              "| model | estimator | mean abs Cf_y error | mean abs Cr_y error | worst abs error "
              "| mean abs Cx error | worst abs Cx error | mean sideslip RMSE | drives within 10 % and 0.1 deg "
              "| restarts |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for model in args.models:
        for name in args.estimators:
            sel = [r for r in rows if r["model"] == model and r["estimator"] == name]
            if not sel:
                continue
            cf = np.array([abs(r["Cf_y_err"]) for r in sel])
            cr = np.array([abs(r["Cr_y_err"]) for r in sel])
            beta = np.array([r["beta_rmse_deg"] for r in sel])
            ok = sum(1 for a, b, c in zip(cf, cr, beta) if a <= 10 and b <= 10 and c <= 0.1)
            restarts = [r["restarts"] for r in sel if r["restarts"] is not None]
            cx = np.array([abs(r["Cx_err"]) for r in sel])
            cx_cells = ("- | -" if np.all(np.isnan(cx)) else
                        f"{_fmt(float(np.mean(cx)), '.1f')} % | {_fmt(float(np.max(cx)), '.1f')} %")
            lines.append(f"| {model} | {name} | {_fmt(float(np.mean(cf)), '.1f')} % | "
                         f"{_fmt(float(np.mean(cr)), '.1f')} % | "
                         f"{_fmt(float(max(cf.max(), cr.max())), '.1f')} % | {cx_cells} | "
                         f"{_fmt(float(np.mean(beta)), '.3f')} deg | "
                         f"{ok} / {len(sel)} | {sum(restarts) if restarts else '-'} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", nargs="+", default=["std", "mb"], choices=("std", "mb"))
    ap.add_argument("--vehicles", nargs="+", type=int, default=[1, 2, 3], choices=(1, 2, 3))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--estimators", nargs="+", default=["mpf", "ekf", "kf", "augpf"])
    ap.add_argument("--maneuver", default="mixed")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--speed", type=float, default=20.0, help="set speed of the drives (m/s)")
    ap.add_argument("--ay", type=float, default=3.0, help="steady-state |a^Y| the steering is set for (m/s^2)")
    ap.add_argument("--no-vx", action="store_true", help="replay the logs without their vx column (wheel speeds only)")
    ap.add_argument("--last", type=float, default=30.0, help="window of the stiffness mean (s)")
    ap.add_argument("--config", help="estimator configuration TOML for every replay (default: none, the defaults)")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    jobs = [(m, v, s, tuple(args.estimators), args.maneuver, args.duration, args.speed, args.last,
             args.config, args.ay, args.no_vx)
            for m in args.models for v in args.vehicles for s in args.seeds]
    t0 = time.perf_counter()
    rows = []
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as pool:
            for out in pool.map(run_drive, jobs):
                rows += out
                print(f"  {out[0]['model']} vehicle {out[0]['vehicle']} seed {out[0]['seed']} done", file=sys.stderr)
    else:
        for job in jobs:
            out = run_drive(job)
            rows += out
            print(f"  {job[0]} vehicle {job[1]} seed {job[2]} done ({out[0]['gen_s']:.0f} s to generate)",
                  file=sys.stderr)
    table = tables(rows, args)
    header = (f"{len(jobs)} drives ({', '.join(args.models)}; vehicles {', '.join(map(str, args.vehicles))}; seeds "
              f"{', '.join(map(str, args.seeds))}), maneuver `{args.maneuver}`, {args.duration:g} s at 100 Hz, "
              f"set speed {args.speed:g} m/s, steering for {args.ay:g} m/s^2"
              f"{', logs without vx' if args.no_vx else ''}; "
              f"settings: {'`--config ' + args.config + '`' if args.config else 'the defaults (no --config)'}; "
              f"stiffness error over the last {args.last:g} s; run time {time.perf_counter() - t0:.0f} s.")
    print(header + "\n\n" + table)


if __name__ == "__main__":
    main()
