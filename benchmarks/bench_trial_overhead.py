"""What a study trial costs besides its co-simulation.

    .venv/bin/python benchmarks/bench_trial_overhead.py [--trials 3] [--particles 500]

In one fresh process, as a study worker sees it: the import of the study module (numpy,
fmpy, tirefilter), the vehicle FMU's load and instantiation (`VehicleFMU()`, once per
worker), then `--trials` trials of the paper-sim accuracy study (`run_trial`, MPF) on that
one FMU, each split into `run_scenario` (the co-simulation) and the rest (the estimator's
construction, and in the worker's first trial the MPF kernels loaded from the numba cache;
the trial's metrics), and the saving of its results (`StudyRun.save`).
"""

from __future__ import annotations

import time

t_start = time.perf_counter()

import argparse  # noqa: E402
import os  # noqa: E402
import tempfile  # noqa: E402

from tirefilter.study.montecarlo import StudyRun, TrialSpec, run_trial, trial_seeds  # noqa: E402

t_import = time.perf_counter() - t_start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--particles", type=int, default=500)
    args = parser.parse_args()
    from tirefilter.cosim.fmu import VehicleFMU

    t0 = time.perf_counter()
    fmu = VehicleFMU()
    t_fmu = time.perf_counter() - t0
    print(f"load average {os.getloadavg()}: import of the study module {t_import:.2f} s, VehicleFMU() {t_fmu:.2f} s")
    spec = TrialSpec("paper-sim", "mpf", particles=args.particles)
    with tempfile.TemporaryDirectory() as tmp:
        store = StudyRun(tmp, spec, 0)
        for i, seed in enumerate(trial_seeds(0, args.trials)):
            t0 = time.perf_counter()
            result = run_trial(spec, i, seed, fmu=fmu)
            t1 = time.perf_counter()
            store.save(result)
            t2 = time.perf_counter()
            cosim = result.metrics["wall_time_s"]
            print(f"trial {i}: {t1 - t0:.2f} s, of which run_scenario {cosim:.2f} s and the rest "
                  f"{1e3 * (t1 - t0 - cosim):.0f} ms; saving {1e3 * (t2 - t1):.0f} ms")
    fmu.close()
    print(f"load average {os.getloadavg()}")


if __name__ == "__main__":
    main()
