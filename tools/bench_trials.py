"""Chosen trials of a `tirefilter bench stiffness` study, with the study's own seeds (screening).

    .venv/bin/python tools/bench_trials.py paper-sim 44 34 8 [--config X.toml] [--set key=value ...]
        [--particles 500] [--workers 2] [--study-seed 0]

Trial i of a study with study seed S runs with `trial_seeds(S, i + 1)[i]`, the same truth, noise and
filter random numbers as trial i of `tirefilter bench stiffness` (study/montecarlo.py); N = 500, the
studies' default. Prints per trial whether it converged (time-averaged |error| of Cf_y and Cr_y below
10%), the time-averaged mean abs error, the settling time after the first surface change, the mean
over the last 100 s (signed) and the restarts, for Cf_y, Cr_y and Cx.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402

import argparse  # noqa: E402
import ast  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from multiprocessing import get_context  # noqa: E402

import numpy as np  # noqa: E402

from tirefilter.study.montecarlo import TrialSpec, _worker_trial, trial_seeds  # noqa: E402
from tirefilter.study.stiffness import converged  # noqa: E402


def parse_set(items: list[str]) -> dict:
    """`key=value` pairs of the [mpf] table (values as Python literals, else strings)."""
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        try:
            out[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            out[key.strip()] = value.strip()
    return out


def line(m: dict) -> str:
    if m["status"] != "ok":
        return f"trial {m['trial']:3d}: {m['status']} {m['error']}"
    parts = [f"trial {m['trial']:3d}: {'conv' if converged(m) else 'FAIL'} restarts {m['restarts']}"]
    for p in ("Cf_y", "Cr_y", "Cx"):
        if p in m:
            e = m[p]
            parts.append(f"{p} abs {e['mean_abs']:.2f}% settle {e['settle']:.2f} s last100 {e['final']:+.2f}%")
    parts.append(f"vy {m['vy_rmse']:.4f}")
    return " | ".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenario")
    ap.add_argument("trials", type=int, nargs="+")
    ap.add_argument("--config", help="a TOML file with estimator tables, as `--config` of bench stiffness")
    ap.add_argument("--set", nargs="*", default=[], help="[mpf] key=value on top of --config")
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--study-seed", type=int, default=0)
    ap.add_argument("--save", help="a directory: each trial's series as trial-<i>.npz (decimated 10)")
    args = ap.parse_args()
    config = tomllib.loads(open(args.config).read()) if args.config else {}
    if args.set:
        config.setdefault("mpf", {}).update(parse_set(args.set))
    spec = TrialSpec(args.scenario, "mpf", particles=args.particles, model="auto", config=config)
    seeds = trial_seeds(args.study_seed, max(args.trials) + 1)
    t0 = time.perf_counter()
    results = []
    with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(_worker_trial, spec, i, seeds[i]) for i in args.trials]
        for f in futures:
            res = f.result()
            m = res.metrics
            if args.save:
                os.makedirs(args.save, exist_ok=True)
                np.savez_compressed(os.path.join(args.save, f"trial-{res.index}.npz"), **res.series)
            results.append(m)
            print(line(m), flush=True)
    ok = [m for m in results if m["status"] == "ok"]
    for p in ("Cf_y", "Cr_y", "Cx"):
        s = [m[p]["settle"] for m in ok if p in m]
        if s:
            print(f"{p}: max settle {max(s):.2f} s, mean abs {sum(m[p]['mean_abs'] for m in ok) / len(ok):.2f}%")
    print(f"config {config}; {len(ok)} trials, {sum(map(converged, ok))} converged, "
          f"wall {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
