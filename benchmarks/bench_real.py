"""The real recording in ../shared/data/mbds-sideslip/ (race track, lateral model, v^X given):
sideslip RMSE of the stiffness MPF against `beta_true`, beside the linear single-track
Kalman filter with fixed stiffness (the publishers' values, and the least-squares fit the
data README mentions) and the EKF baseline with its default settings (state and stiffness),
and the lateral stiffness the MPF converges to.

    .venv/bin/python benchmarks/bench_real.py [--particles 500] [--seeds 0 1 2] [--start T --end T]
        [--config FILE.toml] [--mpf-only] [--friction] [--vehicle FILE.toml]

Everything runs with default settings: the vehicle file holds the publishers' values only, so
the sensor noise is estimated from the log and the IMU bias model is the MEMS default (the
kf and ekf baselines use the same noise), and the MPF runs with a replay's defaults (the stiffness
statistics drawn again after the gate first opens, the log giving no initial v^Y: derivations,
"State noise from the data"); `--config` applies an estimator configuration TOML
(its [mpf] table, say) to the MPF runs; `--mpf-only` leaves out the kf and ekf rows (which no
[mpf] setting changes); `--vehicle` replaces examples/mbds-sideslip/vehicle.toml (for a
diagnosis: the target is scored with the publishers' values). Sideslip RMSE in degrees over all samples and over
|a^Y| < 4 m/s^2 (the linear tire region the MPF's gate learns in). Stiffness: the median over the samples where learning was
active in the second half of the drive, and the final value.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import tempfile
from pathlib import Path

import numpy as np

from tirefilter.config import read_toml
from tirefilter.estimators import build_log_estimator
from tirefilter.replay import read_log, replay_log, result_columns
from tirefilter.vehicle.params import load_vehicle

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "mbds-sideslip"
PUBLISHED = (7.0e4, 1.2e5)  # N/rad, the publishers' Cf, Cr
LEAST_SQUARES = (5.5e4, 7.1e4)  # N/rad, the data README's fit over |ay| < 4 m/s^2


def _convert_module():
    spec = importlib.util.spec_from_file_location("mbds_convert", EXAMPLE / "convert.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _replay(log, vehicle, name, seed, particles, config):
    est = build_log_estimator(name, vehicle, log.t, {s: log.signals[s] for s in log.available}, model="lateral",
                              particles=particles, config=config, source=log.path)
    summary, rows = replay_log(log, estimator=est, seed=seed, keep_rows=True)
    return summary, dict(zip(result_columns(log), rows.T)), est


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--start", type=float)
    ap.add_argument("--end", type=float)
    ap.add_argument("--config", help="estimator configuration TOML for the MPF runs (default: none, the defaults)")
    ap.add_argument("--mpf-only", action="store_true", help="only the MPF runs (no kf and ekf baselines)")
    ap.add_argument("--friction", action="store_true",
                    help="also the friction GP-SSM and combined (their default N and basis; --config applies)")
    ap.add_argument("--vehicle", type=Path, default=EXAMPLE / "vehicle.toml",
                    help="vehicle TOML (default: the example's, the publishers' values)")
    args = ap.parse_args()
    convert = _convert_module()
    if not convert.DATA.exists():
        raise SystemExit(f"the recording is not there: {convert.DATA} (see examples/mbds-sideslip/README.md)")
    vehicle = load_vehicle(args.vehicle)
    with tempfile.TemporaryDirectory() as tmp:
        path = convert.convert(out=Path(tmp) / "log.csv", start=args.start, end=args.end)
        log = read_log(path, vehicle)
    rec = convert.to_log(convert.read_recording(convert.DATA), args.start, args.end)
    beta_true, ay = rec["beta_true"], rec["ay"]
    linear = np.abs(ay) < 4.0
    print(f"mbds-sideslip: {log.rows} samples over {log.duration:.0f} s, |ay| < 4 m/s^2 on {100 * linear.mean():.0f}%")
    print(f"{'estimator':34s} {'beta RMSE deg':>13s} {'|ay|<4':>8s} {'Cf_y':>9s} {'Cr_y':>9s} "
          f"{'Cf_y end':>9s} {'Cr_y end':>9s} {'active':>7s} {'restarts':>8s} {'step us':>8s}")

    def report(label, summary, r, est):
        err = np.degrees(r["beta"] - beta_true)
        rmse, rmse_lin = math.sqrt(np.mean(err**2)), math.sqrt(np.mean(err[linear] ** 2))
        late = (r["active"] > 0) & (r["t"] >= r["t"][0] + 0.5 * log.duration)
        med = [np.median(r[p][late]) if late.any() else r[p][-1] for p in ("Cf_y", "Cr_y")]
        print(f"{label:34s} {rmse:13.3f} {rmse_lin:8.3f} {med[0]:9.4g} {med[1]:9.4g} {r['Cf_y'][-1]:9.4g} "
              f"{r['Cr_y'][-1]:9.4g} {np.mean(r['active'] > 0):7.2f} {getattr(est, 'restarts', 0):8d} "
              f"{summary.median_step_us:8.0f}")
        return rmse

    if not args.mpf_only:
        kf_pub = report("kf, publishers' stiffness", *_replay(log, vehicle, "kf", 0, None, {}))
        kf_ls = report("kf, least-squares stiffness", *_replay(
            log, vehicle, "kf", 0, None, {"kf": {"Cf_y": LEAST_SQUARES[0], "Cr_y": LEAST_SQUARES[1]}}))
        report("ekf, default settings", *_replay(log, vehicle, "ekf", 0, None, {}))
    config = read_toml(args.config) if args.config else {}
    runs = [_replay(log, vehicle, "mpf", seed, args.particles, config) for seed in args.seeds]
    mpf = [report(f"mpf N = {args.particles}, seed {seed}", *run) for seed, run in zip(args.seeds, runs)]
    friction = {name: [report(f"{name}, seed {seed}", *_replay(log, vehicle, name, seed, None, config))
                       for seed in args.seeds] for name in (("gpssm", "combined") if args.friction else ())}
    print("\n".join(runs[0][2].sensors.describe()))
    print(f"settings of the mpf runs: {'--config ' + args.config if args.config else 'the defaults'}")
    line = f"sideslip RMSE: mpf {np.mean(mpf):.3f} deg (mean over seeds), worst seed {np.max(mpf):.3f} deg"
    if not args.mpf_only:
        line += (f", vs kf {kf_pub:.3f} deg with the publishers' stiffness ({PUBLISHED[0]:.3g} / {PUBLISHED[1]:.3g} "
                 f"N/rad), {kf_ls:.3f} deg with the least-squares fit ({LEAST_SQUARES[0]:.3g} / {LEAST_SQUARES[1]:.3g} "
                 "N/rad)")
    print(line)
    for name, rmse in friction.items():
        print(f"sideslip RMSE: {name} {np.mean(rmse):.3f} deg (mean over seeds), worst seed {np.max(rmse):.3f} deg")


if __name__ == "__main__":
    main()
