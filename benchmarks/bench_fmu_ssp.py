"""Speed of the SSP driver -> vehicle FMU -> estimator FMU run by fmpy's simulate_ssp, and
how its estimates compare with the in-process co-simulation of the same scenario and seed.

    python benchmarks/bench_fmu_ssp.py [--scenario snow-sine] [--duration 60] [--particles 500]
                                       [--seed 0] [--repeats 3]

Prints the wall time of each repeat, the median and the speed factor against real time
(simulated seconds per wall second), the same for the in-process co-simulation
(`tirefilter run`), and the final stiffness estimates of both with their errors against
the surface mean. The SSP's estimates differ from the in-process ones because fmpy's
Jacobi master delivers different samples (no sample at t = 0, sensors read before the new
inputs, speed hold one step late: tirefilter.fmu_export.ssp); the estimator FMU itself
equals the Python estimator on the samples it gets (tests/test_estimator_fmu.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from tirefilter.io.results import ESTIMATE_COLUMNS  # noqa: E402
from tirefilter.cosim.run import run_scenario  # noqa: E402
from tirefilter.estimators import build_estimator  # noqa: E402
from tirefilter.fmu_export.ssp import build_ssp, run_ssp  # noqa: E402
from tirefilter.scenarios import load_scenario  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", default="snow-sine")
    p.add_argument("--duration", type=float, default=60.0, help="simulated time [s] (default 60)")
    p.add_argument("--particles", type=int, default=500)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args(argv)

    sc = load_scenario(args.scenario)
    with tempfile.TemporaryDirectory() as tmp:
        path = build_ssp(args.scenario, Path(tmp) / "run.ssp", seed=args.seed, particles=args.particles,
                         stop_time=args.duration)
        walls = []
        for i in range(args.repeats):
            t0 = time.perf_counter()
            r = run_ssp(path)
            walls.append(time.perf_counter() - t0)
            print(f"SSP run {i + 1}: {walls[-1]:.2f} s wall for {args.duration:g} s "
                  f"({args.duration / walls[-1]:.2f}x real time)")
    med = statistics.median(walls)
    print(f"SSP ({args.scenario}, N = {args.particles}, {len(r)} steps of {sc.communication_step:g} s, "
          f"fmpy simulate_ssp): median {med:.2f} s over {args.repeats} -> {args.duration / med:.2f}x real time")

    long = dataclasses.replace(sc, duration=args.duration)
    inproc = []
    for i in range(args.repeats):
        est = build_estimator("mpf", sc, model="auto", particles=args.particles, config={})
        t0 = time.perf_counter()
        summary, rows = run_scenario(long, estimator=est, seed=args.seed, keep_rows=True)
        inproc.append(time.perf_counter() - t0)
    med_in = statistics.median(inproc)
    print(f"in-process co-simulation (tirefilter run): median {med_in:.2f} s -> {args.duration / med_in:.2f}x "
          f"real time; median step {summary.median_step_us:.0f} us")

    cols = list(ESTIMATE_COLUMNS)
    truth = {"Cf_y": r["vehicle.true_Cf_y_mean"][-1], "Cr_y": r["vehicle.true_Cr_y_mean"][-1],
             "Cx": r["vehicle.true_Cx_mean"][-1]}
    print(f"final estimates at t = {r['estimator.t'][-1]:g} s (SSP) / {rows[-1, 0]:g} s (in-process):")
    for c in ("Cf_y", "Cr_y", "Cx"):
        a, b = r["estimator." + c][-1], rows[-1, cols.index(c)]
        sa, sb = r["estimator." + c + "_std"][-1], rows[-1, cols.index(c + "_std")]
        print(f"  {c:5s} SSP {a:10.5g} +- {sa:8.3g} ({100 * (a / truth[c] - 1):+6.2f}%)   in-process {b:10.5g} +- "
              f"{sb:8.3g} ({100 * (b / truth[c] - 1):+6.2f}%)   difference {100 * (a / b - 1):+6.2f}% = "
              f"{abs(a - b) / np.hypot(sa, sb):.2f} combined posterior std")
    return 0


if __name__ == "__main__":
    sys.exit(main())
