"""Which part of a peer drive pulls the MPF's Cx (docs/derivations.md "Wheel-speed pre-filter"): the new user's
drive of issue 13 replayed with the defaults and with the wheel speeds taken as exact
(`[mpf] sigma_omega = 0`), as generated, without the wheel-speed noise, and without the peer
tire's zero-slip offset (p_hx1 = p_vx1 = 0).

    .venv/bin/python benchmarks/peer_cx_variants.py [--model std] [--vehicle 3] [--seed 21] [--speed 18]
        [--duration 60] [--last 30] [--replay-seeds 0 1 2 3 4]

Per variant: the stiffness errors (mean of the estimate over the last `--last` s against the
truth's mean there) and the sideslip RMSE, replayed with the first of `--replay-seeds` (0, as
`tirefilter replay`); then the drive as generated, filtered and taken as exact, over every
replay seed (the particle filter's random draws): the spread of one drive's Cx.
"""

from __future__ import annotations

import argparse
import dataclasses
import time


def replay(drive, config: dict, seed: int, last: float) -> dict:
    from bench_peer import replay_drive  # benchmarks/, the script's folder

    scores, est = replay_drive(drive, "mpf", config, seed, last)
    return {**scores, "sigma_omega": est.cfg.sigma_omega}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="std", choices=("std", "mb"))
    ap.add_argument("--vehicle", type=int, default=3, choices=(1, 2, 3))
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--speed", type=float, default=18.0)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--last", type=float, default=30.0)
    ap.add_argument("--replay-seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    args = ap.parse_args()

    import tirefilter.peer.drive as peer_drive
    from tirefilter.peer.sensors import SensorSpec

    spec = peer_drive.DriveSpec(model=args.model, vehicle=args.vehicle, maneuver="mixed", duration=args.duration,
                                seed=args.seed, speed=args.speed)
    exact = {"mpf": {"sigma_omega": 0.0}}
    load_model = peer_drive.load_model

    def no_offset(kind, vehicle_id, camber="off"):
        m = load_model(kind, vehicle_id, camber)
        m.p.tire.p_hx1 = m.p.tire.p_vx1 = 0.0
        return m

    variants = [("as generated", spec, None, {}), ("as generated", spec, None, exact),
                ("no wheel-speed noise", dataclasses.replace(spec, sensors=dataclasses.replace(
                    SensorSpec(), sigma_omega=0.0)), None, exact),
                ("no zero-slip offset (p_hx1 = p_vx1 = 0)", spec, no_offset, exact),
                ("no zero-slip offset (p_hx1 = p_vx1 = 0)", spec, no_offset, {})]
    print(f"{args.model.upper()} model, vehicle {args.vehicle}, mixed, {args.duration:g} s, seed {args.seed}, "
          f"{args.speed:g} m/s; errors over the last {args.last:g} s\n")
    print("| drive | wheel speeds in the MPF | Cf_y error | Cr_y error | Cx error | sideslip RMSE | wall |")
    print("|---|---|---|---|---|---|---|")
    drives = {}
    for name, s, patch, config in variants:
        peer_drive.load_model = patch or load_model
        try:
            drive = drives.get(name) or peer_drive.simulate(s)
        finally:
            peer_drive.load_model = load_model
        drives[name] = drive
        t0 = time.perf_counter()
        r = replay(drive, config, args.replay_seeds[0], args.last)
        how = "taken as exact" if not r["sigma_omega"] else f"filtered (sigma_omega {r['sigma_omega']:.3g} rad/s)"
        print(f"| {name} | {how} | {r['Cf_y_err']:+.1f} % | {r['Cr_y_err']:+.1f} % | {r['Cx_err']:+.1f} % | "
              f"{r['beta_rmse_deg']:.3f} deg | {time.perf_counter() - t0:.0f} s |", flush=True)
    print(f"\nThe drive as generated, replay seeds {', '.join(map(str, args.replay_seeds))}:\n")
    print("| wheel speeds in the MPF | Cx error per replay seed | mean | Cf_y / Cr_y error, mean |")
    print("|---|---|---|---|")
    for how, config in (("filtered (the default)", {}), ("taken as exact", exact)):
        rs = [replay(drives["as generated"], config, seed, args.last) for seed in args.replay_seeds]
        cx = [r["Cx_err"] for r in rs]
        print(f"| {how} | {', '.join(f'{c:+.1f}' for c in cx)} % | {sum(cx) / len(cx):+.1f} % | "
              f"{sum(r['Cf_y_err'] for r in rs) / len(rs):+.1f} / {sum(r['Cr_y_err'] for r in rs) / len(rs):+.1f} % |",
              flush=True)

if __name__ == "__main__":
    main()
