"""Cost of the Rerun recording: a run with N = 500 recorded to an .rrd file against the
same run without a recording, for several `--log-every` values.

    .venv/bin/python benchmarks/bench_viz.py [--scenario paper-sim] [--particles 500]
        [--log-every 5 10 20 50] [--repeat 3] [--seed 0]

Every case is the full run of `tirefilter run` (vehicle FMU, stiffness MPF, Result CSV):
only the recording differs. Cases are interleaved per repeat (off, then each K), so a
machine shared with other work slows them alike; the figures are the medians over repeats
of the wall time and of the process CPU time (all threads: rerun-sdk encodes and writes in
background threads), and the ratios of medians, recording on / off. On an otherwise idle
machine with a core to spare the wall ratio is at most the CPU ratio; on a loaded one
the background threads compete with the run and the wall ratio exceeds it. `series only` records the Result-CSV
series, the bands and the vehicle pose but no posterior snapshot (K larger than the run).
Also printed: the size of the .rrd and the number of posterior snapshots. The default
`--log-every` (viz.options.DEFAULT_LOG_EVERY) must keep the ratio at or below 2.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.cosim.run import run_scenario
from tirefilter.estimators import build_estimator
from tirefilter.scenarios import load_scenario
from tirefilter.viz.options import DEFAULT_LOG_EVERY, RecordingOptions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="paper-sim")
    parser.add_argument("--particles", type=int, default=500)
    parser.add_argument("--log-every", type=int, nargs="+", default=sorted({5, 10, DEFAULT_LOG_EVERY, 50}))
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    steps = int(round(scenario.duration * scenario.estimator_rate)) + 1
    estimator = build_estimator("mpf", scenario, model="auto", particles=args.particles, config={})
    cases = [("off", None), ("series only", steps + 1)] + [(f"K = {k}", k) for k in args.log_every]
    times: dict[str, list[float]] = {name: [] for name, _ in cases}
    cpu: dict[str, list[float]] = {name: [] for name, _ in cases}
    sizes: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp, VehicleFMU("2") as fmu:
        for _ in range(args.repeat):
            for name, k in cases:
                rrd = Path(tmp) / "r.rrd"
                recording = None if k is None else RecordingOptions(rrd=rrd, log_every=k)
                t0, c0 = time.perf_counter(), time.process_time()
                run_scenario(scenario, estimator=estimator, fmu=fmu, seed=args.seed, results_csv=Path(tmp) / "r.csv",
                             recording=recording)
                times[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
                if k is not None:
                    sizes[name] = rrd.stat().st_size
    off, off_cpu = statistics.median(times["off"]), statistics.median(cpu["off"])
    print(f"scenario {scenario.name}: {scenario.duration:g} s, {steps} estimator steps, MPF N = {args.particles}, "
          f"median of {args.repeat} runs; default --log-every {DEFAULT_LOG_EVERY}")
    print(f"{'case':>12s} {'wall [s]':>9s} {'wall on/off':>12s} {'CPU [s]':>8s} {'CPU on/off':>11s} {'snapshots':>10s} "
          f"{'rrd [MB]':>9s}")
    for name, k in cases:
        wall, c = statistics.median(times[name]), statistics.median(cpu[name])
        snaps = "-" if k is None else str(0 if k > steps else (steps - 1) // k + 1)
        size = f"{sizes[name] / 1e6:.1f}" if name in sizes else "-"
        print(f"{name:>12s} {wall:9.2f} {wall / off:12.2f} {c:8.2f} {c / off_cpu:11.2f} {snaps:>10s} {size:>9s}")
    print(f"load average over the last 1/5/15 min at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())} "
          f"on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
