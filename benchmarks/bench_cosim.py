"""Co-simulation speed: a 60 s scenario with no estimator, FMU internal step 1 ms,
communication step 10 ms, FMI 2.0 and FMI 3.0, single process (one core).

    .venv/bin/python benchmarks/bench_cosim.py [--scenario paper-sim] [--repeat 5]

Prints, per FMI version, the median over repeats of
- fmu loop:  set inputs + doStep + get outputs only (the FMU and its Python binding);
- master:    the full master (inputs, speed control, sampling, rows kept in memory);
- with CSV:  the master writing the Result CSV;
- with CSV + rrd: and a Rerun recording;
as wall time and real-time factor (simulated seconds per wall second).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.cosim.run import run_scenario
from tirefilter.scenarios import load_scenario


def fmu_loop(fmu: VehicleFMU, scenario, seed: int) -> float:
    h = scenario.communication_step
    n = int(round(scenario.duration / h))
    U = scenario.inputs.open_loop(np.arange(n) * h)
    fmu.reset(scenario.fmu_parameters(seed))
    t0 = time.perf_counter()
    for k in range(n):
        fmu.step(k * h, h, U[k])
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="paper-sim")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    print(f"scenario {scenario.name}: {scenario.duration:g} s, communication step {scenario.communication_step:g} s, "
          f"estimator rate {scenario.estimator_rate:g} Hz, median of {args.repeat} runs")
    print(f"{'FMI':>4s} {'case':>16s} {'wall [ms]':>10s} {'x real time':>12s}")
    with tempfile.TemporaryDirectory() as tmp:
        for version in ("2", "3"):
            with VehicleFMU(version) as fmu:
                cases = {
                    "fmu loop": lambda: fmu_loop(fmu, scenario, 1),
                    "master": lambda: run_scenario(scenario, fmu=fmu, seed=1)[0].wall_time_s,
                    "with CSV": lambda: run_scenario(scenario, fmu=fmu, seed=1,
                                                     results_csv=Path(tmp) / "r.csv")[0].wall_time_s,
                    "with CSV + rrd": lambda: run_scenario(scenario, fmu=fmu, seed=1, results_csv=Path(tmp) / "r.csv",
                                                           rrd=Path(tmp) / "r.rrd")[0].wall_time_s,
                }
                for name, case in cases.items():
                    case()  # warm-up
                    wall = statistics.median(case() for _ in range(args.repeat))
                    print(f"{version:>4s} {name:>16s} {1e3 * wall:10.1f} {scenario.duration / wall:12.0f}")


if __name__ == "__main__":
    main()
