"""Where the MPF's compiled step spends its time, per stage (issue 14).

    .venv/bin/python benchmarks/profile_mpf_step.py [--particles 500] [--duration 5] [--repeat 200]

The filter (this checkout's defaults, as `tirefilter run` builds them) steps through the
first `--duration` s of recorded paper-sim samples (seed 0); at every step after the warm-up
each call of a compiled pass (`mpf_numba.<name>`) and each draw of the generator is timed
(the thread's CPU time, ns), and the rest of `step()` is the Python around them. Printed:
the median and 10th percentile per step of each, over the steps (a pass that does not run at a step, such as the
resampling copies, counts at the steps where it runs, with its share of steps).

Then `--repeat` calls of each pass alone on one saved state of the filter (the minimum: what
the pass costs without the noise of a shared machine), and of an empty numba function with
the same arguments (the dispatcher's cost of typing the arguments).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402

import argparse  # noqa: E402
import copy  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cost import WARMUP, record  # noqa: E402

from tirefilter.estimators import build_estimator  # noqa: E402
from tirefilter.estimators import mpf_numba  # noqa: E402

PASSES = ("predict_weigh", "resample_gate", "sample_update", "fused_step")
clock = time.thread_time_ns


class _Timed:
    """A stand-in for a module or a generator whose callables add their CPU time to `log`."""

    def __init__(self, inner, log, prefix=""):
        self._inner, self._log, self._prefix = inner, log, prefix

    def __getattr__(self, name):
        f = getattr(self._inner, name)
        if not callable(f):
            return f
        log, key = self._log, self._prefix + name

        def timed(*args, **kw):
            c0 = clock()
            out = f(*args, **kw)
            log[key] += clock() - c0
            return out

        return timed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--duration", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=200)
    args = ap.parse_args()
    sim, samples = record("paper-sim", args.duration)
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    est = build_estimator("mpf", sim, model="auto", particles=args.particles, config={})
    est.reset(np.random.default_rng(1))
    per_step: list[dict] = []
    for k, s in enumerate(samples):
        log: dict[str, int] = defaultdict(int)
        if k >= WARMUP:
            est._nb = _Timed(mpf_numba, log)
            est.rng = _Timed(est.rng, log, "rng.")
        c0 = clock()
        est.step(*s)
        total = clock() - c0
        if k >= WARMUP:
            est._nb, est.rng = mpf_numba, est.rng._inner
            log["step()"] = total
            log["Python (rest)"] = total - sum(v for key, v in log.items() if key != "step()")
            per_step.append(dict(log))
        if k == len(samples) // 2:
            saved = copy.deepcopy(est)
    keys = sorted({key for d in per_step for key in d}, key=lambda k: (k != "step()", k))
    print(f"N = {args.particles}, {len(per_step)} steps: CPU us per step, median and 10th percentile over the "
          "steps where it ran")
    for key in keys:
        vals = [d[key] / 1e3 for d in per_step if key in d]
        print(f"  {key:24s} {np.median(vals):8.1f} {np.percentile(vals, 10):8.1f}  "
              f"({len(vals) / len(per_step):4.0%} of steps)")
    # each pass alone on the saved state (the minimum over repeats)
    print(f"each pass alone on one saved state, minimum of {args.repeat} calls (us):")
    captured: dict[str, tuple] = {}

    class _Capture:
        def __getattr__(self, name):
            f = getattr(mpf_numba, name)

            def cap(*a):
                captured.setdefault(name, copy.deepcopy(a))
                return f(*a)

            return cap

    probe = copy.deepcopy(saved)
    probe._nb = _Capture()
    probe.step(*samples[len(samples) // 2 + 1])
    from numba import njit

    @njit
    def empty(*a):
        return 0

    for name, a in captured.items():
        f = getattr(mpf_numba, name)
        runs = [(name, a)]
        if name == "resample_gate" and not a[2]:
            runs.append((name + " (resampling)", (a[0], a[1], True) + a[3:]))
        for label, aa in runs:
            best = min(_once(f, copy.deepcopy(aa)) for _ in range(args.repeat))
            print(f"  {label:24s} {best / 1e3:8.1f}")
        empty(*a)
        best = min(_once(empty, a) for _ in range(args.repeat))
        print(f"  {'(dispatch of ' + str(len(a)) + ' args)':24s} {best / 1e3:8.1f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


def _once(f, a) -> int:
    c0 = clock()
    f(*a)
    return clock() - c0


if __name__ == "__main__":
    raise SystemExit(main())
