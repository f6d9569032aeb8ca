"""Where the MPF's compiled step spends its time, per stage (issue 14).

    .venv/bin/python benchmarks/profile_mpf_step.py [--particles 500] [--duration 5] [--repeat 300]
        [--base /tmp/base/src]

The filter (this checkout's defaults, as `tirefilter run` builds them) steps through the
first `--duration` s of recorded paper-sim samples (seed 0); at every step after the warm-up
each call of a compiled pass (`estimators.mpf.kernels.<name>`) and each draw of the generator is timed
(the thread's CPU time), and the rest of `step()` is the Python around them (plus about a
microsecond per timed call for the timing itself). Printed: the median and 10th percentile
per step of each over the steps (a draw that is not made at every step, the resampling
uniform, over the steps where it is made).

Then each pass alone, `--repeat` calls on the arguments it got at the middle sample (fresh
copies each time), and an empty numba function with the same arguments (what the
dispatcher's typing and unboxing of the arguments costs): the minimum, what a pass costs
without the noise of a shared machine. With `--base` (another version's `src`, as for
bench_mpf_ab.py) that version's filter steps through the same samples alongside, and its
passes are timed on its own arguments at the same sample, alternating call by call with
this checkout's, so that both see the same load.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402

import argparse  # noqa: E402
import copy  # noqa: E402
import dataclasses  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cost import WARMUP, record  # noqa: E402

from tirefilter.estimators import build_estimator  # noqa: E402

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


class _Capture:
    """A stand-in for the kernel module that keeps each kernel and a copy of its first arguments,
    by the pass's name (before stop 26, `predict_weigh_full` and `predict_weigh_lateral` as `predict_weigh`)."""

    def __init__(self, module):
        self._module, self.args = module, {}

    def __getattr__(self, name):
        f = getattr(self._module, name)
        key = name.removesuffix("_full").removesuffix("_lateral")

        def cap(*a):
            self.args.setdefault(key, (f, copy.deepcopy(a)))
            return f(*a)

        return cap


@njit
def _empty(*a):
    return 0


def _once(f, a) -> int:
    c0 = clock()
    f(*a)
    return clock() - c0


def per_step(est, samples) -> None:
    """The median and 10th percentile of each stage's CPU time per step."""
    est.reset(np.random.default_rng(1))
    module = est._nb
    rows: list[dict] = []
    for k, s in enumerate(samples):
        log: dict[str, int] = defaultdict(int)
        if k >= WARMUP:
            est._nb = _Timed(module, log)
            est.rng = _Timed(est.rng, log, "rng.")
        c0 = clock()
        est.step(*s)
        total = clock() - c0
        if k >= WARMUP:
            est._nb, est.rng = module, est.rng._inner
            log["step()"] = total
            log["Python (rest)"] = total - sum(v for key, v in log.items() if key != "step()")
            rows.append(dict(log))
    keys = sorted({key for d in rows for key in d}, key=lambda k: (k != "step()", k))
    print(f"{len(rows)} steps: CPU us per step, median and 10th percentile (over the steps where it ran)")
    for key in keys:
        vals = [d[key] / 1e3 for d in rows if key in d]
        print(f"  {key:24s} {np.median(vals):8.1f} {np.percentile(vals, 10):8.1f}  "
              f"({len(vals) / len(rows):4.0%} of steps)")


def captured(est, samples) -> dict:
    """The kernels' arguments at the middle sample."""
    est.reset(np.random.default_rng(1))
    mid = len(samples) // 2
    for s in samples[:mid]:
        est.step(*s)
    module = est._nb
    est._nb = cap = _Capture(module)
    est.step(*samples[mid])
    est._nb = module
    return cap.args


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--duration", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=300)
    ap.add_argument("--base", type=Path, help="another version's src directory, timed alongside")
    args = ap.parse_args()
    sim, samples = record("paper-sim", args.duration)
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    ests = {"this": build_estimator("mpf", sim, model="auto", particles=args.particles, config={})}
    if args.base is not None:
        from bench_mpf_ab import load_base

        base = load_base(args.base.resolve(), Path(tempfile.mkdtemp(prefix="mpf_prof_")))
        fields = {f.name for f in dataclasses.fields(base.MPFConfig)}
        cfg = base.MPFConfig(**{k: v for k, v in dataclasses.asdict(ests["this"].cfg).items() if k in fields})
        ests = {"base": base.StiffnessMPF(ests["this"].vehicle, cfg), **ests}
    for name, est in ests.items():
        print(f"{name}, N = {args.particles}:")
        per_step(est, samples)
    caps = {name: captured(est, samples) for name, est in ests.items()}
    print(f"each pass alone at the middle sample, minimum of {args.repeat} calls, us "
          f"({' / '.join(ests)}; alternating call by call):")
    names = [n for n in caps["this"] if all(n in c for c in caps.values())]
    for kname in names:
        variants = [("", lambda a: a)]
        if kname == "resample_gate":  # with and without the copies of resampling
            variants = [(" (resampling)", lambda a: (a[0], a[1], True) + a[3:]),
                        (" (no resampling)", lambda a: (a[0], a[1], False) + a[3:])]
        for label, change in variants:
            best = {name: 10**18 for name in caps}
            for _ in range(args.repeat):
                for name, cap in caps.items():
                    f, a = cap[kname]
                    best[name] = min(best[name], _once(f, change(copy.deepcopy(a))))
            print(f"  {kname + label:30s} " + " / ".join(f"{best[n] / 1e3:7.1f}" for n in caps))
        a = caps["this"][kname][1]
        _empty(*a)
        best = min(_once(_empty, a) for _ in range(args.repeat))
        print(f"  {'(dispatch of ' + str(len(a)) + ' arguments)':30s} {best / 1e3:7.1f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
