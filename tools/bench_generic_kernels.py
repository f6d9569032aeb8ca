"""What the MPF's specialised kernels buy (docs/development.md, "How long `make test` takes"): the step with the shipped kernels against the same step with the generic ones
(`estimators.mpf.kernels.predict_weigh` / `sample_update` with `SIZES_ANY`, the sizes as variables, which the
step already uses when a channel is missing) in place of `SIZES_FULL` / `SIZES_LATERAL`, in one process, alternated round by round:

    .venv/bin/python tools/bench_generic_kernels.py [--particles 500] [--rounds 5]

Both filters step through the same 5 s of recorded paper-sim samples (seed 0) with the
defaults of `tirefilter run` (full model; `--model lateral` for the lateral one) and print the
median and 10th percentile of the thread's CPU time per `step()` after the warm-up, and
whether the two give the same estimates (they must: the same arithmetic on the same random
numbers). Each specialised entry point costs about as much compile as the generic one
(docs/development.md, "How long `make test` takes"); a cold cache compiles the ones a run
uses. The kernels themselves are not changed here.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_cost import WARMUP, record  # noqa: E402

from tirefilter.estimators import build_estimator  # noqa: E402


def generic(est):
    """`est` with its kernel module replaced by one whose two passes get `SIZES_ANY` (the generic
    signatures; the wrapper's Python call is part of the generic figure)."""
    nb = est._nb
    proxy = types.SimpleNamespace(**{k: getattr(nb, k) for k in dir(nb) if not k.startswith("__")})
    proxy.predict_weigh = lambda *a: nb.predict_weigh(*a[:-1], nb.SIZES_ANY)
    proxy.sample_update = lambda *a: nb.sample_update(*a[:-1], nb.SIZES_ANY)
    est._nb = proxy
    return est


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, nargs="+", default=[500])
    ap.add_argument("--model", default="full", choices=("full", "lateral"))
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    sim, samples = record("paper-sim", 5.0)
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; model {args.model}")
    for n in args.particles:
        ests = {"shipped": build_estimator("mpf", sim, model=args.model, particles=n, config={}),
                "generic": generic(build_estimator("mpf", sim, model=args.model, particles=n, config={}))}
        cpu: dict[str, list[float]] = {k: [] for k in ests}
        out: dict[str, list] = {k: [] for k in ests}
        for r in range(args.rounds):
            for name, est in ests.items():
                est.reset(np.random.default_rng(1))
                for k, s in enumerate(samples):
                    c0 = time.thread_time_ns()
                    e = est.step(*s)
                    if k >= WARMUP:
                        cpu[name].append((time.thread_time_ns() - c0) / 1e3)
                    if r == 0:
                        out[name].append(np.array([e.vx, e.vy, e.yaw_rate, e.Cf_y, e.Cr_y, e.Cx, e.Cf_y_std], float))
        same = all(np.array_equal(a, b, equal_nan=True) for a, b in zip(out["shipped"], out["generic"]))
        med = {k: float(np.median(v)) for k, v in cpu.items()}
        p10 = {k: float(np.percentile(v, 10)) for k, v in cpu.items()}
        print(f"N = {n}: shipped {med['shipped']:.0f} us (p10 {p10['shipped']:.0f}), generic {med['generic']:.0f} us "
              f"(p10 {p10['generic']:.0f}); generic / shipped {med['generic'] / med['shipped']:.3f} "
              f"(p10 {p10['generic'] / p10['shipped']:.3f}); same estimates: {same}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
