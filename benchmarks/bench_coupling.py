"""How much the master's coupling changes a run: the in-process co-simulation with the
default Gauss-Seidel coupling against the Jacobi coupling (what fmpy's SSP master does),
same scenario, seed and estimator.

    .venv/bin/python benchmarks/bench_coupling.py [--scenario snow-sine] [--seed 0] [--particles 200]

Prints the largest differences of the vehicle truth and sensors over the run and the
stiffness estimate at the end of each run (docs/using-the-fmus.md, "Coupling").
"""

from __future__ import annotations

import argparse

import numpy as np

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.io.results import ESTIMATE_COLUMNS, INPUT_TRUTH_COLUMNS, truth_column
from tirefilter.cosim.run import run_scenario
from tirefilter.estimators import build_estimator
from tirefilter.scenarios import load_scenario


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", default="snow-sine")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--particles", type=int, default=200)
    args = p.parse_args()
    sc = load_scenario(args.scenario)
    with VehicleFMU() as fmu:
        names = list(ESTIMATE_COLUMNS) + [truth_column(n) for n in fmu.output_names] + list(INPUT_TRUTH_COLUMNS)
    rows = {}
    for coupling in ("gauss-seidel", "jacobi"):
        est = build_estimator("mpf", sc, model="auto", particles=args.particles, config={})
        _, rows[coupling] = run_scenario(sc, estimator=est, seed=args.seed, keep_rows=True, coupling=coupling)
    gs, ja = rows["gauss-seidel"], rows["jacobi"]
    # Jacobi has no sample at t = 0: align on the sample times
    t_gs, t_ja = gs[:, names.index("t")], ja[:, names.index("t")]
    common = np.intersect1d(np.round(t_gs, 9), np.round(t_ja, 9))
    a = gs[np.isin(np.round(t_gs, 9), common)]
    b = ja[np.isin(np.round(t_ja, 9), common)]
    print(f"{sc.name}, seed {args.seed}, N = {args.particles}, {len(common)} common samples "
          f"(Jacobi starts at t = {t_ja[0]:g} s)")
    for col, unit in (("true_vx", "m/s"), ("true_vy", "m/s"), ("true_yaw_rate", "rad/s"), ("meas_ay", "m/s2"),
                      ("meas_ax", "m/s2"), ("true_drive_torque", "N.m")):
        if col in names:
            d = np.abs(a[:, names.index(col)] - b[:, names.index(col)])
            print(f"  max |{col} (Gauss-Seidel) - {col} (Jacobi)| = {np.nanmax(d):.3g} {unit}")
    for col in ("Cf_y", "Cr_y"):
        x, y = a[-1, names.index(col)], b[-1, names.index(col)]
        truth = a[-1, names.index(f"true_{col}_mean")]
        print(f"  final {col}: Gauss-Seidel {x:.6g} N/rad, Jacobi {y:.6g} N/rad, truth {truth:.6g} N/rad "
              "(the particle filter's random draws are not aligned: Jacobi has one sample fewer)")


if __name__ == "__main__":
    main()
