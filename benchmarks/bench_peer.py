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

    .venv/bin/python benchmarks/bench_peer.py --set [--duration 60] [--workers 2] [--config FILE.toml] [--drives 2 6 ...]
        [--vehicle-key KEY=VALUE ...]

The peer set (`SET_DRIVES`): 14 drives of the multi-body CommonRoad model (MB, body roll)
and of the two-track model (TT: load transfer, load-sensitive tyres with relaxation, the IMU
0.4 m ahead of the CG, logger dropouts), three cars, several maneuvers, speeds and lateral
accelerations (some beyond |a^Y| = 4 m/s^2), each replayed with the MPF as `tirefilter
replay` does it (`scan_log`, `estimators.for_log`, `estimators.build`; N = 500, seed 0,
the defaults unless `--config`) in `--workers` processes. Per drive and in total
(`peer.score.final_scores`): the lateral stiffness error at the last row (%) and in
reported std, the coverage of the truth by the 90 % band over the second half, the
sideslip RMSE over the drive and over the rows with |a^Y| >= 4 m/s^2, the roll gradient and
(where estimated) the load sensitivity kappa at the last row, restarts; against the targets
SET_TARGETS. `--vehicle-key relaxation_length=0` (say): every drive's vehicle file states that key;
`--drives`: a subset. It measures; it tunes nothing.
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

# The peer set: (model, vehicle, maneuver, set speed m/s, steady-state a^Y of the steer amplitude m/s^2, seed)
SET_DRIVES = (
    ("tt", 1, "sine", 20.0, 3.0, 0), ("tt", 2, "mixed", 20.0, 4.0, 1), ("tt", 3, "steps", 15.0, 5.0, 2),
    ("tt", 1, "slalom", 25.0, 5.0, 3), ("tt", 2, "sweep", 30.0, 3.0, 4), ("tt", 3, "mixed", 25.0, 5.0, 5),
    ("tt", 2, "steps", 20.0, 6.0, 6),
    ("mb", 1, "sine", 20.0, 3.0, 0), ("mb", 2, "mixed", 20.0, 4.0, 1), ("mb", 3, "steps", 15.0, 5.0, 2),
    ("mb", 1, "slalom", 25.0, 5.0, 3), ("mb", 2, "sweep", 30.0, 3.0, 4), ("mb", 3, "mixed", 25.0, 5.0, 5),
    ("mb", 2, "steps", 20.0, 6.0, 6),
)
# final stiffness error (%), 90 % band coverage over the second half (share), final error in std,
# sideslip RMSE over the drive and where |a^Y| >= 4 m/s^2 (deg)
SET_TARGETS = {"final_err": 5.0, "cover": (0.70, 0.97), "final_z": 2.0, "beta": 0.05, "beta_hi": 0.15}
AY_HIGH = 4.0  # m/s^2

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


def replay_as_cli(log_path: Path, vehicle_path: Path, result_path: Path, config: dict, seed: int = 0):
    """`tirefilter replay LOG --vehicle V --out RESULT [--config]` with the MPF's defaults:
    the first pass (`scan_log`), the setting from the log (`estimators.for_log`), the log's
    samples released, `estimators.build`, `replay_log` streaming the file. Returns the estimator."""
    from tirefilter.estimators import build, for_log
    from tirefilter.replay import replay_log
    from tirefilter.replay.stream import scan_log
    from tirefilter.vehicle.params import load_vehicle

    vehicle = load_vehicle(vehicle_path)
    log = scan_log(log_path, vehicle, vehicle_name=str(vehicle_path))
    setting = for_log(vehicle, log.t, log.signals, source=log.path)
    log.release()
    est = build("mpf", setting, model="auto", particles=None, config=config)
    replay_log(log, estimator=est, seed=seed, results_csv=result_path, vehicle_file=str(vehicle_path))
    return est


def run_set_drive(job: tuple) -> dict:
    """Generate one drive of the peer set, replay it as the command line does, score it."""
    from tirefilter.config import read_toml
    from tirefilter.peer.drive import DriveSpec, simulate, write_drive
    from tirefilter.peer.score import final_scores, read_columns

    (model, vehicle_id, maneuver, speed, ay, seed), duration, config_path, keys = job
    config = read_toml(config_path) if config_path else {}
    t0 = time.perf_counter()
    drive = simulate(DriveSpec(model=model, vehicle=vehicle_id, maneuver=maneuver, duration=duration, seed=seed,
                               speed=speed, ay=ay))
    gen_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        log, vehicle = write_drive(drive, Path(tmp) / "drive.csv", Path(tmp) / "vehicle.toml")
        if keys:  # --vehicle-key: stated in every drive's vehicle file
            with open(vehicle, "a") as f:
                f.write("".join(f"{key} = {value}\n" for key, value in keys))
        t1 = time.perf_counter()
        est = replay_as_cli(log, vehicle, Path(tmp) / "result.csv", config)
        wall = time.perf_counter() - t1
        result = read_columns(Path(tmp) / "result.csv", ("t", "beta", "Cf_y", "Cr_y", "Cf_y_std", "Cr_y_std",
                                                          "roll_gradient"))
    c = drive.columns
    scores = final_scores({k: c[k] for k in ("t", "beta_true", "ay_true", "Cf_y_true", "Cr_y_true")}, result,
                          ay_min=AY_HIGH)
    hi = np.abs(c["ay_true"]) >= AY_HIGH
    return {"model": model, "vehicle": vehicle_id, "maneuver": maneuver, "speed": speed, "ay": ay, "seed": seed,
            **scores, "ay_max": float(np.max(np.abs(c["ay_true"]))), "hi_share": float(np.mean(hi)),
            "eff_f": float(c["Cf_y_eff_true"][0] / c["Cf_y_true"][-1] - 1.0),
            "eff_r": float(c["Cr_y_eff_true"][0] / c["Cr_y_true"][-1] - 1.0),
            "restarts": getattr(est, "restarts", None), "gen_s": gen_s, "wall_s": wall,
            "k_true": float(drive.roll_gradient), "k_est": float(result["roll_gradient"][-1]),
            "dropped": drive.dropped,
            "kappa": est._load_moments()[0] if hasattr(est, "_load_moments") else math.nan}


def _ok(value: float, target) -> bool:
    if isinstance(target, tuple):
        return target[0] <= value <= target[1]
    return math.isfinite(value) and abs(value) <= target


def set_tables(rows: list[dict]) -> str:
    """Per drive, then per model family and in total, as markdown."""
    T = SET_TARGETS
    lines = ["| drive | max abs a^Y | eff. / static Cf_y, Cr_y | Cf_y final | Cr_y final | coverage f / r "
             "| final err / std f / r | sideslip RMSE | at abs a^Y >= 4 (rows) | roll gradient est. / true "
             "| kappa est. (1e-3 s^4/m^2) | restarts |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        hi = ("-" if not math.isfinite(r["beta_rmse_hi_deg"])
              else f"{r['beta_rmse_hi_deg']:.3f} deg ({100 * r['hi_share']:.0f} %)")
        lines.append(
            f"| {r['model'].upper()} v{r['vehicle']} {r['maneuver']} {r['speed']:g} m/s a^Y {r['ay']:g} s{r['seed']} | "
            f"{r['ay_max']:.1f} | {100 * r['eff_f']:+.1f} / {100 * r['eff_r']:+.1f} % | "
            f"{_fmt(r['Cf_y_final_err'], '+.1f')} % | {_fmt(r['Cr_y_final_err'], '+.1f')} % | "
            f"{100 * r['Cf_y_cover']:.0f} / {100 * r['Cr_y_cover']:.0f} % | "
            f"{_fmt(r['Cf_y_final_z'], '+.1f')} / {_fmt(r['Cr_y_final_z'], '+.1f')} | "
            f"{_fmt(r['beta_rmse_deg'], '.3f')} deg | {hi} | {_k(r['k_est'])} / {_k(r['k_true'])} | "
            f"{_k(r['kappa'])} | "
            f"{'-' if r['restarts'] is None else r['restarts']} |")
    lines += ["", f"Totals (targets: final error within {T['final_err']:g} %, coverage {100 * T['cover'][0]:.0f}-"
              f"{100 * T['cover'][1]:.0f} %, final error <= {T['final_z']:g} std, sideslip RMSE <= {T['beta']:g} deg "
              f"overall and <= {T['beta_hi']:g} deg where abs(a^Y) >= {AY_HIGH:g}; sideslip pooled over the rows):", "",
              "| drives | mean abs final error f / r | worst | within 5 % | coverage mean (min-max) | within 70-97 % "
              "| worst final err / std | within 2 std | sideslip RMSE (within) | at abs a^Y >= 4 (within) | restarts |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    groups = [(f"{m.upper()} ({sum(r['model'] == m for r in rows)})", [r for r in rows if r["model"] == m])
              for m in dict.fromkeys(r["model"] for r in rows)] + [(f"all ({len(rows)})", rows)]
    for name, sel in groups:
        ef = np.array([abs(r["Cf_y_final_err"]) for r in sel])
        er = np.array([abs(r["Cr_y_final_err"]) for r in sel])
        cov = np.array([[r["Cf_y_cover"], r["Cr_y_cover"]] for r in sel])
        z = np.array([[abs(r["Cf_y_final_z"]), abs(r["Cr_y_final_z"])] for r in sel])
        n_err = sum(_ok(a, T["final_err"]) and _ok(b, T["final_err"]) for a, b in zip(ef, er))
        n_cov = sum(_ok(a, T["cover"]) and _ok(b, T["cover"]) for a, b in cov)
        n_z = sum(_ok(a, T["final_z"]) and _ok(b, T["final_z"]) for a, b in z)
        beta = np.degrees(np.sqrt(sum(r["beta_se"] for r in sel) / sum(r["beta_n"] for r in sel)))
        n_hi = sum(r["beta_n_hi"] for r in sel)
        beta_hi = np.degrees(np.sqrt(sum(r["beta_se_hi"] for r in sel) / n_hi)) if n_hi else math.nan
        n_beta = sum(_ok(r["beta_rmse_deg"], T["beta"]) for r in sel)
        with_hi = [r for r in sel if r["beta_n_hi"]]
        n_beta_hi = sum(_ok(r["beta_rmse_hi_deg"], T["beta_hi"]) for r in with_hi)
        restarts = [r["restarts"] for r in sel if r["restarts"] is not None]
        lines.append(
            f"| {name} | {_fmt(float(np.mean(ef)), '.1f')} / {_fmt(float(np.mean(er)), '.1f')} % | "
            f"{_fmt(float(max(ef.max(), er.max())), '.1f')} % | {n_err} / {len(sel)} | "
            f"{100 * cov.mean():.0f} % ({100 * cov.min():.0f}-{100 * cov.max():.0f} %) | {n_cov} / {len(sel)} | "
            f"{_fmt(float(z.max()), '.1f')} | {n_z} / {len(sel)} | "
            f"{_fmt(float(beta), '.3f')} deg ({n_beta} / {len(sel)}) | "
            + (f"{beta_hi:.3f} deg ({n_beta_hi} / {len(with_hi)})" if n_hi else "-")
            + f" | {sum(restarts) if restarts else '-'} |")
    return "\n".join(lines)


def main_set(args) -> None:
    drives = SET_DRIVES if args.drives is None else [SET_DRIVES[i] for i in args.drives]
    keys = [tuple(kv.split("=", 1)) for kv in args.vehicle_key]
    if any(len(kv) != 2 for kv in keys):
        sys.exit(f"--vehicle-key takes KEY=VALUE, got {args.vehicle_key!r}")
    jobs = [(d, args.duration, args.config, keys) for d in drives]
    t0 = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(max(1, args.workers)) as pool:
        for r in pool.map(run_set_drive, jobs):
            rows.append(r)
            print(f"  {r['model']} vehicle {r['vehicle']} {r['maneuver']} done ({r['gen_s']:.0f} s to generate, "
                  f"{r['wall_s']:.0f} s to replay)", file=sys.stderr)
    header = (f"Peer set: {len(jobs)} drives of {args.duration:g} s at 100 Hz (MB: CommonRoad multi-body, camber off; "
              f"TT: two-track, logger dropouts), data-sheet vehicle files, the MPF (N = 500, seed 0) replayed as "
              f"`tirefilter replay` does with "
              f"{'`--config ' + args.config + '`' if args.config else 'the default settings (no --config)'}"
              f"{''.join(', vehicle files with ' + kv for kv in args.vehicle_key)}; "
              f"{args.workers} workers, run time {time.perf_counter() - t0:.0f} s.")
    print(header + "\n\n" + set_tables(rows))


def _k(k: float) -> str:
    """A roll gradient in mrad per m/s^2 ("-": not estimated)."""
    return "-" if not math.isfinite(k) else f"{1000 * k:.1f}"


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
    ap.add_argument("--set", action="store_true",
                    help="the peer set (SET_DRIVES: MB and TT, the MPF) instead of the grid")
    ap.add_argument("--vehicle-key", action="append", default=[], metavar="KEY=VALUE",
                    help="with --set: every drive's vehicle file states this key (e.g. relaxation_length=0; repeatable)")
    ap.add_argument("--drives", nargs="+", type=int, choices=range(len(SET_DRIVES)),
                    help="with --set: only these drives of SET_DRIVES (indices 0-13, in the table's order)")
    args = ap.parse_args()
    if args.set:
        main_set(args)
        return
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
