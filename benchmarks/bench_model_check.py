"""The model check (run.json `model_check`; docs/derivations.md, "The model check") of the stiffness
MPF (or the EKF: `--estimator ekf`) with its defaults on drives with and without a model that fits: the paper-sim scenario (linear
tyres, the filter's own model), the peer set's two-track drives (load transfer onto load-sensitive
tyres; the `steps` drives beyond |a^Y| = 4 m/s^2) and the real race-track recording. Per case the
warning (or none) and, per bin of the predicted |a^Y|, the a^Y and yaw-rate residuals' mean square
(1 for a calibrated model) and signed mean (0; negative: the data fall short of the prediction).

    .venv/bin/python benchmarks/bench_model_check.py [--cases paper-sim tt-steps real] [--seeds 0] [--estimator mpf|ekf]
        [--bins]

`tt-steps` is the peer set's TT drives v3 steps 15 m/s a^Y 5 s2 and v2 steps 20 m/s a^Y 6 s6,
`tt-sine` its TT v1 sine 20 m/s a^Y 3 s0 (within the linear region); each replayed as `tirefilter
replay` does (benchmarks/bench_peer.py, `replay_as_cli`).
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TT = {"tt-steps": (("tt", 3, "steps", 15.0, 5.0, 2), ("tt", 2, "steps", 20.0, 6.0, 6)),
      "tt-sine": (("tt", 1, "sine", 20.0, 3.0, 0),)}


def _module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def paper_sim(seed: int, name: str = "mpf"):
    from tirefilter.cosim.run import run_scenario
    from tirefilter.estimators import build_estimator
    from tirefilter.scenarios import load_scenario

    scenario = load_scenario("paper-sim")
    est = build_estimator(name, scenario, model="auto", particles=None, config={})
    summary, _ = run_scenario(scenario, estimator=est, seed=seed)
    return [("paper-sim", summary.model_check)]


def peer(drives, seed: int, name: str = "mpf"):
    from tirefilter.estimators import build, for_log
    from tirefilter.peer.drive import DriveSpec, simulate, write_drive
    from tirefilter.replay import replay_log
    from tirefilter.replay.stream import scan_log
    from tirefilter.vehicle.params import load_vehicle

    out = []
    for model, vehicle_id, maneuver, speed, ay, drive_seed in drives:
        drive = simulate(DriveSpec(model=model, vehicle=vehicle_id, maneuver=maneuver, duration=60.0,
                                   seed=drive_seed, speed=speed, ay=ay))
        with tempfile.TemporaryDirectory() as tmp:
            log_path, vehicle_path = write_drive(drive, Path(tmp) / "drive.csv", Path(tmp) / "vehicle.toml")
            vehicle = load_vehicle(vehicle_path)
            log = scan_log(log_path, vehicle, vehicle_name=str(vehicle_path))
            setting = for_log(vehicle, log.t, log.signals, source=log.path)
            log.release()
            est = build(name, setting, model="auto", particles=None, config={})
            summary, _ = replay_log(log, estimator=est, seed=seed)
        out.append((f"{model.upper()} v{vehicle_id} {maneuver} {speed:g} m/s a^Y {ay:g} s{drive_seed}",
                    summary.model_check))
    return out


def real(seed: int, name: str = "mpf"):
    from tirefilter.estimators import build_log_estimator
    from tirefilter.replay import read_log, replay_log
    from tirefilter.vehicle.params import load_vehicle

    example = REPO / "examples" / "mbds-sideslip"
    convert = _module("mbds_convert", example / "convert.py")
    if not convert.DATA.exists():
        raise SystemExit(f"the recording is not there: {convert.DATA} (see examples/mbds-sideslip/README.md)")
    vehicle = load_vehicle(example / "vehicle.toml")
    with tempfile.TemporaryDirectory() as tmp:
        log = read_log(convert.convert(out=Path(tmp) / "log.csv"), vehicle)
    est = build_log_estimator(name, vehicle, log.t, {s: log.signals[s] for s in log.available}, model="lateral",
                              particles=None, config={}, source=log.path)
    summary, _ = replay_log(log, estimator=est, seed=seed)
    return [("real recording (mbds-sideslip)", summary.model_check)]


def _fmt(x, spec=".2f") -> str:
    return "-" if x is None else format(x, spec)


def print_case(name: str, check: dict, bins: bool) -> None:
    print(f"{name}: {check['warning'] or 'no warning'}; |a^Y| up to {check['ay_abs_max']:.3g} m/s^2 predicted, "
          f"{check['samples']} samples")
    if not bins:
        return
    print(f"  {'|a^Y| bin':>10s} {'samples':>8s} {'batches':>8s}  {'a^Y ms':>7s} {'bias':>6s}  {'r ms':>7s} "
          f"{'bias':>6s}  flagged")
    for b in check["bins"]:
        ay, r = b["ay"], b["yaw_rate"]
        flag = ("not tested" if not b["tested"] else
                ", ".join(n for n in ("ay", "yaw_rate") if b[n].get("flagged")) or "-")
        print(f"  {b['ay_abs_from']:>10.1f} {b['samples']:>8d} {b['batches']:>8d}  {_fmt(ay['var_ratio']):>7s} "
              f"{_fmt(ay['bias'], '+.2f'):>6s}  {_fmt(r['var_ratio']):>7s} {_fmt(r['bias'], '+.2f'):>6s}  {flag}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["paper-sim", "tt-steps", "real"],
                    choices=("paper-sim", "tt-steps", "tt-sine", "real"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="the estimator's seeds (and paper-sim's)")
    ap.add_argument("--estimator", default="mpf", choices=("mpf", "ekf"), help="the estimator (its defaults)")
    ap.add_argument("--bins", action="store_true", help="print every bin of the predicted |a^Y|")
    args = ap.parse_args()
    warned = runs = 0
    for case in args.cases:
        for seed in args.seeds:
            est = args.estimator
            for name, check in (paper_sim(seed, est) if case == "paper-sim" else real(seed, est) if case == "real"
                                else peer(TT[case], seed, est)):
                print_case(f"{name}, seed {seed}", check, args.bins)
                warned, runs = warned + bool(check["warning"]), runs + 1
    print(f"warnings: {warned} of {runs} runs")


if __name__ == "__main__":
    main()
