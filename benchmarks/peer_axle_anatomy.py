"""What the two-track peer drives' axles do that a linear single-track axle does not: per band
of |a^Y|, the share of the static-load stiffness that is left

- at the current wheel loads (`Cf_y_load / Cf_y`: the lateral load transfer alone),
- in the axle force over the relaxed slip (least squares of F_y on the axle mean of the
  wheels' relaxed slip angles: load transfer and the tyre's saturation in the slip),
- in the axle force over the single-track slip angle at the axle centre (what the MPF's
  model can see: the above plus the tyres' relaxation, which lags the force behind the slip),

and a fit F_y = C_0 (1 - kappa a^Y^2) alpha over the relaxed slips (every sample with
|a^Y| > 0.3 m/s^2): the stiffness at a^Y = 0 and the load sensitivity kappa that the model of
derivations, "Load transfer" assumes. Truth only (no filter): a few seconds per drive.

    .venv/bin/python benchmarks/peer_axle_anatomy.py [--drives 0 2 6]

Drives: the TT drives of `bench_peer.SET_DRIVES` (indices 0-6).
"""

from __future__ import annotations

import argparse

import numpy as np

from bench_peer import SET_DRIVES

BANDS = ((0.3, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 4.0), (4.0, 5.0), (5.0, 7.0))


def _ls(F, s):
    return float(F @ s) / float(s @ s)


def anatomy(index: int) -> list[str]:
    from tirefilter.peer import drive as peer_drive
    from tirefilter.peer import two_track_drive as ttd
    from tirefilter.peer.drive import DriveSpec
    from tirefilter.peer.two_track import SLIP_Y, sample, static_stiffness

    model_name, vid, man, speed, ay, seed = SET_DRIVES[index]
    spec = DriveSpec(model=model_name, vehicle=vid, maneuver=man, duration=60.0, seed=seed, speed=speed, ay=ay)
    model = ttd.load(spec)
    _, X, U, _ = ttd.trajectory_tt(spec, model, rate=peer_drive.RATE, substeps=peer_drive.SUBSTEPS,
                                   settle=peer_drive.SETTLE, k_speed=peer_drive.K_SPEED)
    s = sample(X, U, model)
    C = static_stiffness(model)[:2]
    a = s["ay"]
    tan_relaxed = X[:, SLIP_Y]
    axles = (("f", s["Fy_f"], s["alpha_f"], np.arctan(0.5 * (tan_relaxed[:, 0] + tan_relaxed[:, 1])), s["Cf_y_load"]),
             ("r", s["Fy_r"], s["alpha_r"], np.arctan(0.5 * (tan_relaxed[:, 2] + tan_relaxed[:, 3])), s["Cr_y_load"]))
    name = f"TT v{vid} {man} {speed:g} m/s a^Y {ay:g} s{seed}"
    rows = []
    for lo, hi in BANDS:
        m = (np.abs(a) >= lo) & (np.abs(a) < hi)
        if m.sum() < 20:
            continue
        cells = []
        for k, (_, F, single, relaxed, load) in enumerate(axles):
            cells.append((np.mean(load[m]) / C[k] - 1, _ls(F[m], relaxed[m]) / C[k] - 1, _ls(F[m], single[m]) / C[k] - 1))
        rows.append(f"| {name} | {lo:g}-{hi:g} ({100 * m.mean():.0f} %) | "
                    + " | ".join(f"{100 * cells[0][j]:+.1f} / {100 * cells[1][j]:+.1f} %" for j in range(3)) + " | |")
    m = np.abs(a) > 0.3
    fit = []
    for k, (_, F, _, relaxed, _) in enumerate(axles):
        c, *_ = np.linalg.lstsq(np.column_stack([relaxed[m], a[m] ** 2 * relaxed[m]]), F[m], rcond=None)
        fit.append((c[0] / C[k] - 1, -c[1] / c[0]))
    rows.append(f"| {name} | fit over abs a^Y > 0.3 | | | | C_0 {100 * fit[0][0]:+.1f} / {100 * fit[1][0]:+.1f} %, "
                f"kappa {1e3 * fit[0][1]:.1f} / {1e3 * fit[1][1]:.1f} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    tt = [i for i, d in enumerate(SET_DRIVES) if d[0] == "tt"]
    ap.add_argument("--drives", nargs="+", type=int, default=tt, choices=tt)
    args = ap.parse_args()
    print("| drive | abs a^Y band, m/s^2 (share of rows) | at the loads, f / r | force over the relaxed slip, f / r "
          "| force over the single-track slip, f / r | C_0 (1 - kappa a^Y^2) over the relaxed slips "
          "(kappa 1e-3 s^4/m^2) |")
    print("|---|---|---|---|---|---|")
    for i in args.drives:
        print("\n".join(anatomy(i)))


if __name__ == "__main__":
    main()
