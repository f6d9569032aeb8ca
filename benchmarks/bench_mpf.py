"""Stiffness MPF on paper-sim: accuracy against the metrics of docs/usage.md, and per-step cost.

    .venv/bin/python benchmarks/bench_mpf.py [--seeds 1 2 3] [--particles 500] [--model full]
                                             [--duration 60] [--option KEY=VALUE ...] [--skip-cost]

`--duration` shortens the run (below 30 s there is no surface change and no settling
time); `--option` sets an `[mpf]` option, e.g. `--option roll_estimate=false`.

Per stiffness parameter, over the seeds:
- the signed mean steady-state error and each trial's time-averaged absolute error;
- the settling time after the 30 s surface change;
- the 90% coverage of `*_std`;
- `*_sigma` against the true 5% spread.

Then the median step time at N and 10 N (the `median_step_us` of the run summary).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np

from tirefilter.io.results import read_results
from tirefilter.cosim.run import run_scenario
from tirefilter.estimators import build_estimator
from tirefilter.metrics import settling_time, stiffness_errors
from tirefilter.scenarios import load_scenario


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--model", default="full", choices=("full", "lateral"))
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="an [mpf] option (TOML value)")
    ap.add_argument("--skip-cost", action="store_true", help="no N versus 10 N cost comparison")
    args = ap.parse_args()
    options = tomllib.loads("\n".join(args.option))
    config = {"mpf": options}
    scenario = load_scenario("paper-sim")
    scenario = replace(scenario, duration=args.duration,
                       surface_changes=tuple(t for t in scenario.surface_changes if t < args.duration))
    params = ("Cx", "Cf_y", "Cr_y") if args.model == "full" else ("Cf_y", "Cr_y")
    rows = {p: [] for p in params}
    steps, restarts = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            est = build_estimator("mpf", scenario, model=args.model, particles=args.particles, config=config)
            path = Path(tmp) / f"{seed}.csv"
            summary, _ = run_scenario(scenario, estimator=est, seed=seed, results_csv=path)
            steps.append(summary.median_step_us)
            restarts.append(est.restarts)
            r = read_results(path)
            for p in params:
                e = stiffness_errors(r, scenario, p)
                e["settle"] = settling_time(r, p, 30.0) if scenario.surface_changes else math.nan
                rows[p].append(e)
        print(f"paper-sim ({args.duration:g} s), model {args.model}, N = {args.particles}, "
              f"lambda = {est.cfg.forgetting}, seeds {args.seeds}" + (f", options {options}" if options else ""))
        converged = [all(rows[p][i]["mean_abs"] < 10.0 for p in params if p != "Cx") for i in range(len(args.seeds))]
        print(f"trials with the lateral stiffness converged (time-averaged |err| < 10%): {sum(converged)} of "
              f"{len(converged)}; restarts per trial: {restarts}")
        _table(rows, params, [True] * len(converged), "all trials")
        if not all(converged):
            _table(rows, params, converged, "converged trials only")
        print(f"median step at N = {args.particles}: {np.median(steps):.0f} us")
        if args.skip_cost:
            return
        big = build_estimator("mpf", scenario, model=args.model, particles=10 * args.particles, config={})
        s_big, _ = run_scenario(replace(scenario, duration=3.0), estimator=big, seed=1)
        s_small, _ = run_scenario(replace(scenario, duration=3.0), estimator=build_estimator(
            "mpf", scenario, model=args.model, particles=args.particles, config={}), seed=1)
        print(f"median step at N = {10 * args.particles}: {s_big.median_step_us:.0f} us "
              f"(ratio to N = {args.particles} over the same 3 s: {s_big.median_step_us / s_small.median_step_us:.1f})")


def _table(rows, params, keep, label) -> None:
    print(f"{label}:\n{'param':6s} {'mean err %':>10s} {'max trial |err| %':>18s} {'max |err| %':>12s} "
          f"{'settle s (max)':>15s} {'coverage90':>11s} {'sigma % (true 5)':>17s}")
    for p in params:
        e = [x for x, k in zip(rows[p], keep) if k]
        print(f"{p:6s} {np.mean([x['mean'] for x in e]):10.2f} {max(x['mean_abs'] for x in e):18.2f} "
              f"{max(x['max_abs'] for x in e):12.1f} {max(x['settle'] for x in e):15.2f} "
              f"{np.mean([x['coverage90'] for x in e]):11.2f} {np.mean([x['sigma_pct'] for x in e]):17.2f}")


if __name__ == "__main__":
    main()
