"""The stiffness paper's baselines (augpf, rls, ekf) next to the MPF on paper-sim: per-step
cost and accuracy per seed.

    .venv/bin/python benchmarks/bench_baselines.py [--estimators mpf augpf rls ekf]
                                                   [--particles 500] [--seeds 1 2 3]
                                                   [--duration 60] [--model auto]
                                                   [--config FILE.toml] [--label NAME]

For each estimator and seed: the median wall time of `step()` (`median_step_us` of the run
summary, after warm-up, inside this process), the mean and the time-averaged absolute
steady-state error of Cf_y and Cr_y (docs/usage.md metrics, against the surface mean), and the
v^Y RMSE after 5 s. Then the median over seeds. Particle filters run at `--particles`; rls
and ekf ignore it. `--config` is an estimator configuration TOML as for `tirefilter run`
(e.g. `[augpf] proposal = "bootstrap"`), `--label` names its rows.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.io.results import ESTIMATE_COLUMNS, INPUT_TRUTH_COLUMNS, truth_column
from tirefilter.cosim.run import run_scenario
from tirefilter.estimators import build_estimator
from tirefilter.metrics import stiffness_errors
from tirefilter.scenarios import load_scenario


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--estimators", nargs="+", default=["mpf", "augpf", "rls", "ekf"])
    p.add_argument("--particles", type=int, default=500)
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--model", default="auto")
    p.add_argument("--scenario", default="paper-sim")
    p.add_argument("--config", help="estimator configuration TOML ([augpf], [rls], [ekf], [mpf] tables)")
    p.add_argument("--label", default="", help="suffix of the estimator names in the table")
    args = p.parse_args()
    config = {}
    if args.config:
        import tomllib

        with open(args.config, "rb") as f:
            config = tomllib.load(f)

    s = load_scenario(args.scenario)
    scenario = replace(s, duration=args.duration, surface_changes=tuple(t for t in s.surface_changes
                                                                        if t < args.duration))
    with VehicleFMU("2") as fmu:
        names = ESTIMATE_COLUMNS + tuple(map(truth_column, fmu.output_names)) + INPUT_TRUTH_COLUMNS
    print(f"{args.scenario}, {args.duration:g} s, N = {args.particles} (particle filters), model {args.model}, "
          f"seeds {' '.join(map(str, args.seeds))}")
    print(f"{'estimator':10s} {'seed':>4s} {'step [us]':>10s} {'Cf_y mean%':>10s} {'Cf_y |e|%':>9s} "
          f"{'Cr_y mean%':>10s} {'Cr_y |e|%':>9s} {'vy RMSE':>8s}")
    for name in args.estimators:
        table = []
        label = f"{name}{args.label}"
        for seed in args.seeds:
            est = build_estimator(name, scenario, model=args.model, particles=args.particles, config=config)
            summary, rows = run_scenario(scenario, estimator=est, seed=seed, keep_rows=True)
            r = {c: rows[:, j] for j, c in enumerate(names)}
            ef, er = stiffness_errors(r, scenario, "Cf_y"), stiffness_errors(r, scenario, "Cr_y")
            late = r["t"] > 5.0
            vy = float(np.sqrt(np.mean((r["vy"] - r["true_vy"])[late] ** 2)))
            row = (summary.median_step_us, ef["mean"], ef["mean_abs"], er["mean"], er["mean_abs"], vy)
            table.append(row)
            print(f"{label:10s} {seed:4d} {row[0]:10.1f} {row[1]:+10.2f} {row[2]:9.2f} {row[3]:+10.2f} "
                  f"{row[4]:9.2f} {row[5]:8.3f}")
        med = np.median(np.array(table), axis=0)
        print(f"{label:10s} {'med':>4s} {med[0]:10.1f} {med[1]:+10.2f} {med[2]:9.2f} {med[3]:+10.2f} "
              f"{med[4]:9.2f} {med[5]:8.3f}")


if __name__ == "__main__":
    main()
