"""The CI peer drives of tests/test_peer_drive.py (40 s, 0.5 Hz steer sine, vehicle 2, seed 1), replayed
as `test_default_replay_meets_the_peer_drive_targets` replays them, with `[mpf]` settings given as TOML files.

    .venv/bin/python tools/bench_peer_ci.py [--kind mb] [CONFIG.toml ...]

Prints, per configuration (first the defaults), the lateral stiffness errors over the last 20 s (%,
target 10), the Cx error and the sideslip RMSE (deg, target 0.1), as the test scores them. `--kind`:
std, mb (the multi-body drive with the data-sheet vehicle file, its roll gradient left out: the IMU's
a^Y reads 1.156 times the model's) or mb-roll (the roll gradient given).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import test_peer_drive as T  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("configs", nargs="*", type=Path)
    ap.add_argument("--kind", default="mb", choices=("std", "mb", "mb-roll"))
    args = ap.parse_args()
    model = args.kind.split("-")[0]
    drive = T.simulate(T.DriveSpec(model=model, vehicle=2, maneuver="sine", duration=T.DURATION, seed=1))
    folder = Path(tempfile.mkdtemp(prefix="peer_ci_"))
    log, vehicle = T.write_drive(drive, folder / "drive.csv", folder / "vehicle.toml")
    if args.kind == "mb-roll":
        import dataclasses

        with_roll = dataclasses.replace(drive, vehicle=T.vehicle_values(
            drive.model, dataclasses.replace(drive.spec, roll_gradient_in_vehicle=True), drive.roll_gradient))
        vehicle = folder / "vehicle-roll.toml"
        vehicle.write_text(T.vehicle_toml(with_roll))
    rows = []
    for cfg in [None, *args.configs]:
        out = Path(tempfile.mkdtemp(prefix="peer_ci_run_"))
        s = T._replay(out, log, vehicle, None if cfg is None else cfg.read_text())
        name = "defaults" if cfg is None else cfg.name
        rows.append(f"| {name} | {s['Cf_y_err']:+.1f}% | {s['Cr_y_err']:+.1f}% | {s['Cx_err']:+.1f}% | "
                    f"{s['beta_rmse_deg']:.3f} deg |")
    print(f"\n{args.kind} drive, last {T.LAST:g} s:\n")
    print("| config | Cf_y | Cr_y | Cx | beta RMSE |\n|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
