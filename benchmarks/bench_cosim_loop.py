"""What a co-simulated sample costs besides `Estimator.step`.

    .venv/bin/python benchmarks/bench_cosim_loop.py [--scenario paper-sim] [--repeat 5]

Runs `run_scenario` on one vehicle FMU (FMI 2.0) with a zero-cost estimator: an MPF whose
`step` returns one fixed Estimate, so its measurement guard, the timing of its steps, the
metrics stream and the row sinks all run as in a real run while the step itself costs
nothing. Cases:
- `none, no CSV`: no estimator, rows in no sink (the master and the FMU);
- `none, CSV`: no estimator, the Result CSV written (`tirefilter run --estimator none`);
- `null, rows kept`: the zero-cost estimator, rows kept in memory (a study trial);
- `null, CSV`: the zero-cost estimator, the Result CSV written (`tirefilter run`).
Per case, the median over repeats of the wall time per sample and of this process's CPU
time per sample (`time.process_time`), and the CPU time of helper processes per sample
(the CSV formatter, `io/csv_format.py`, where the code has one).

With `--mpf N` it runs the real MPF (N particles) instead, rows kept (a study trial) and
with the CSV (`tirefilter run`), and splits the main thread's CPU time
(`time.thread_time`, which a loaded machine's preemption does not inflate as it does the
wall time) into `Estimator.step` (mean and median per step) and the rest of the sample. The load average is
printed before and after: the machine is shared, so compare figures of one run only, or
runs made alternately in the same minutes. Runs with any tirefilter source tree first on
PYTHONPATH (the base of a comparison) as long as it has `run_scenario`.
"""

from __future__ import annotations

import argparse
import inspect
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import tirefilter
from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.cosim.run import run_scenario
from tirefilter.estimators import build_estimator
from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.scenarios import load_scenario


def null_estimator(scenario):
    """An MPF (N = 50) with its guard whose step returns the estimate of one real step."""
    est = build_estimator("mpf", scenario, model="auto", particles=50, config={})
    est.reset(np.random.default_rng(0))
    e0 = est.step(0.0, Inputs(delta=0.0, omega_f=20.0, omega_r=20.0, vx=20.0),
                  Measurement(ax=0.0, ay=0.0, yaw_rate=0.0))
    est.step = lambda t, u, y: e0
    est.reset = lambda rng: None
    return est


def mpf_split(scenario, fmu, particles: int, repeat: int, tmp: Path) -> None:
    """The real MPF: the main thread's CPU per sample in and outside `Estimator.step`."""
    clock = time.thread_time
    print(f"MPF N = {particles}: main-thread CPU, us per sample (each run)")
    print(f"{'case':>16s} {'step mean':>10s} {'step median':>12s} {'outside step':>13s} {'helper CPU':>11s} {'wall':>8s}")
    for rep in range(repeat):
        for name, kw in {"MPF, rows kept": dict(keep_rows=True), "MPF, CSV": dict(results_csv=tmp / "m.csv")}.items():
            if "metrics" in inspect.signature(run_scenario).parameters and "keep_rows" in kw:
                kw["metrics"] = False  # as a study trial runs (where the code has the option)
            est = build_estimator("mpf", scenario, model="auto", particles=particles, config={})
            raw, cpu = est.step, []

            def step(t, u, y, raw=raw, cpu=cpu):
                c = clock()
                e = raw(t, u, y)
                cpu.append(clock() - c)
                return e

            est.step = step
            c0, h0 = clock(), children_cpu()
            summary, _ = run_scenario(scenario, fmu=fmu, seed=0, estimator=est, **kw)
            total, helper, n = clock() - c0, children_cpu() - h0, summary.steps
            c = 1e6 * np.array(cpu)
            print(f"{name:>16s} {c.mean():10.0f} {np.median(c[10:]):12.0f} {(1e6 * total - c.sum()) / n:13.0f} "
                  f"{1e6 * helper / n:11.0f} {1e6 * summary.wall_time_s / n:8.0f}")


def children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="paper-sim")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--mpf", type=int, metavar="N", help="the real MPF with N particles (see above)")
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    print(f"tirefilter from {Path(tirefilter.__file__).parent}; load average {os.getloadavg()}")
    if args.mpf:
        with tempfile.TemporaryDirectory() as tmp, VehicleFMU() as fmu:
            mpf_split(scenario, fmu, args.mpf, args.repeat, Path(tmp))
        print(f"load average {os.getloadavg()}")
        return
    with tempfile.TemporaryDirectory() as tmp, VehicleFMU() as fmu:
        est = null_estimator(scenario)
        cases = {"none, no CSV": dict(estimator=None),
                 "none, CSV": dict(estimator=None, results_csv=Path(tmp) / "a.csv"),
                 "null, rows kept": dict(estimator=est, keep_rows=True),
                 "null, CSV": dict(estimator=est, results_csv=Path(tmp) / "b.csv")}
        figures = {name: [] for name in cases}
        for rep in range(args.repeat + 1):  # the first round warms up
            for name, kw in cases.items():
                w0, c0, h0 = time.perf_counter(), time.process_time(), children_cpu()
                summary, _ = run_scenario(scenario, fmu=fmu, seed=1, **kw)
                w, c, h = time.perf_counter() - w0, time.process_time() - c0, children_cpu() - h0
                if rep:
                    n = summary.steps
                    figures[name].append((1e6 * w / n, 1e6 * c / n, 1e6 * h / n))
    print(f"{scenario.name}: {summary.steps} samples; median of {args.repeat} runs, us per sample")
    print(f"{'case':>16s} {'wall':>8s} {'CPU':>8s} {'helper CPU':>11s}")
    for name, rows in figures.items():
        w, c, h = (statistics.median(x) for x in zip(*rows))
        print(f"{name:>16s} {w:8.1f} {c:8.1f} {h:11.1f}")
    print(f"load average {os.getloadavg()}")


if __name__ == "__main__":
    main()
