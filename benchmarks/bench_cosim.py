"""Co-simulation speed: a 60 s scenario with no estimator, FMU internal step 1 ms,
communication step 10 ms, FMI 2.0 and FMI 3.0, single process (one core).

    .venv/bin/python benchmarks/bench_cosim.py [--scenario paper-sim] [--repeat 5] [--mpf N]

Prints, per FMI version, the median over repeats of
- fmu loop:  set inputs + doStep + get outputs only (the FMU and its Python binding);
- master:    the full master (inputs, speed control, sampling, rows kept in memory);
- with CSV:  the master writing the Result CSV;
- with CSV + rrd: and a Rerun recording;
- with `--mpf N`, MPF N + CSV: the stiffness MPF with N particles (built as `tirefilter run
  --estimator mpf --particles N` builds it) and the Result CSV, the end-to-end case;
  its run's `median_step_us` is printed beside it;
as wall time (`wall_time_s` of the run summary, as run.json has it, for the master's cases)
and real-time factor (simulated seconds per wall second).
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
from tirefilter.estimators import build_estimator
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
    parser.add_argument("--mpf", type=int, metavar="N", help="also the MPF with N particles and the Result CSV")
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
                step_us = []
                if args.mpf:
                    def with_mpf():
                        est = build_estimator("mpf", scenario, model="auto", particles=args.mpf, config={})
                        summary = run_scenario(scenario, fmu=fmu, seed=1, estimator=est,
                                               results_csv=Path(tmp) / "r.csv")[0]
                        step_us.append(summary.median_step_us)
                        return summary.wall_time_s

                    cases[f"MPF {args.mpf} + CSV"] = with_mpf
                for name, case in cases.items():
                    case()  # warm-up (the MPF's: its kernels' compile or load)
                    step_us.clear()
                    wall = statistics.median(case() for _ in range(args.repeat))
                    extra = f"   median step {statistics.median(step_us):.0f} us" if step_us else ""
                    print(f"{version:>4s} {name:>16s} {1e3 * wall:10.1f} {scenario.duration / wall:12.0f}{extra}")


if __name__ == "__main__":
    main()
