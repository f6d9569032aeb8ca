"""Where the friction GP-SSM's compiled step spends its time, per pass, and this checkout's
step against another version's in one process (issue 14).

    git archive main src | tar -x -C /tmp/gbase
    .venv/bin/python benchmarks/profile_gpssm_step.py [--particles 200] [--duration 6]
        [--bases gpssm-axle gpssm-tensor gpssm-tensor100] [--repeat 100] [--base /tmp/gbase/src]

Each basis (the names of bench_cost.py: exact statistics, friction-snow, seed 0, the first
`--duration` s) is built as `tirefilter run` builds it. Stepping through the samples, after
the warm-up (bench_cost.WARMUP steps) each call of a compiled pass (`gpssm_numba.<name>`)
and of `t_draws` and each draw of the generator is timed (the thread's CPU time); the rest of
`step()` is the Python around them (plus about a microsecond per timed call for the timing;
a generator call made inside `t_draws` counts in both, not in the rest).
Printed: the median and 10th percentile per step of each (a pass that does not run at every
step, resampling, over the steps where it runs).

With `--base` (another version's `src`) that version's `gpssm_numba.py` is copied into a
temporary module (compiled and cached apart) and its `CompiledStep` drives a second filter
of the same configuration; the two filters then step through the same samples alternately,
sample by sample (the same load on both), and the median and 10th percentile of the thread's
CPU time per `step()` of each, their mean (which also sees the resampling steps), and their
ratios are printed. The per-pass profile is printed
for both. Then each pass alone, `--repeat` calls on the arguments it got at the middle
sample (fresh copies each time; the resampling passes at the last resampling before it),
alternating call by call between the versions: the minimum, what a pass costs without the
noise of a shared machine.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402

import argparse  # noqa: E402
import importlib  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cost import GPSSM, WARMUP, record  # noqa: E402

from tirefilter.estimators import build_estimator  # noqa: E402
from tirefilter.estimators import gpssm_numba  # noqa: E402

clock = time.thread_time_ns
PASSES = ("front", "exact_forget_predictive", "exact_forget_predictive_lapack", "exact_forget_predictive_rows",
          "rank1_forget_predictive", "weigh", "resample", "lanes_load", "lanes_store",
          "systematic_ancestors", "gather_rows", "gather_lower", "sample", "rank1_update", "t_draws", "common_dof",
          "exact_update", "mirror")


def load_base(src: Path, into: Path):
    """The other version's gpssm_numba module, from `src` (a `src` directory)."""
    text = (src / "tirefilter" / "estimators" / "gpssm_numba.py").read_text()
    (into / "base_gpssm_numba.py").write_text(text)
    sys.path.insert(0, str(into))
    return importlib.import_module("base_gpssm_numba")


_depth = [0]  # nesting of timed calls: only the outermost count towards the Python rest


def _timed(log, key, f):
    def timed(*args, **kw):
        _depth[0] += 1
        c0 = clock()
        try:
            return f(*args, **kw)
        finally:
            dt = clock() - c0
            _depth[0] -= 1
            log[key] += dt
            if _depth[0] == 0:
                log["\0top"] += dt
    return timed


class _TimedRng:
    def __init__(self, inner, log):
        self._inner, self._log = inner, log

    def __getattr__(self, name):
        f = getattr(self._inner, name)
        if not callable(f):
            return f
        return _timed(self._log, "rng." + name, f)


def _build(name, snow, n, module=None):
    est = build_estimator("gpssm", snow, model="auto", particles=n, config={"gpssm": GPSSM[name]})
    est.reset(np.random.default_rng(1))
    if module is not None:
        est._compiled = module.CompiledStep(est)
    return est


def profile(est, module, samples) -> None:
    """The median and 10th percentile of each pass's CPU time per step."""
    log: dict[str, int] = defaultdict(int)
    originals = {p: getattr(module, p) for p in PASSES if hasattr(module, p)}

    def wrap(key, f):
        return _timed(log, key, f)

    rows = []
    try:
        for k, s in enumerate(samples):
            log.clear()
            timing = k >= WARMUP
            if timing:
                for p, f in originals.items():
                    setattr(module, p, wrap(p, f))
                rng = est.rng
                est.rng = _TimedRng(rng, log)
            c0 = clock()
            est.step(*s)
            total = clock() - c0
            if timing:
                for p, f in originals.items():
                    setattr(module, p, f)
                est.rng = rng
                d = dict(log)
                top = d.pop("\0top", 0)
                d["step()"] = total
                d["Python (rest)"] = total - top
                rows.append(d)
    finally:
        for p, f in originals.items():
            setattr(module, p, f)
    keys = sorted({key for d in rows for key in d}, key=lambda k: (k != "step()", k))
    print(f"    {len(rows)} steps: CPU us per step, median and 10th percentile (over the steps where it ran)")
    for key in keys:
        vals = [d[key] / 1e3 for d in rows if key in d]
        print(f"      {key:32s} {np.median(vals):8.1f} {np.percentile(vals, 10):8.1f}  "
              f"({len(vals) / len(rows):4.0%} of steps)")


def ab(ests: dict, samples, rounds: int) -> None:
    """Both filters step through the samples alternately; CPU us per step()."""
    times = {k: [] for k in ests}
    for _ in range(rounds):
        for est in ests.values():
            est.reset(np.random.default_rng(1))
        for name, est in ests.items():
            if name == "base":
                est._compiled = BASE.CompiledStep(est)
        for k, s in enumerate(samples):
            for name, est in ests.items():
                c0 = clock()
                est.step(*s)
                if k >= WARMUP:
                    times[name].append(clock() - c0)
    med = {k: np.median(v) / 1e3 for k, v in times.items()}
    p10 = {k: np.percentile(v, 10) / 1e3 for k, v in times.items()}
    mean = {k: np.mean(v) / 1e3 for k, v in times.items()}  # the resampling steps (a third) count here
    print("    alternating, CPU us per step(): " + ", ".join(f"{k} median {med[k]:.0f} (p10 {p10[k]:.0f}, "
                                                         f"mean {mean[k]:.0f})" for k in ests)
          + (f"; this / base {med['this'] / med['base']:.2f} (p10 {p10['this'] / p10['base']:.2f}, "
             f"mean {mean['this'] / mean['base']:.2f})" if "base" in ests else ""))


BASE = None


def captured(est, module, samples) -> dict:
    """Each compiled pass and a copy of its arguments at the middle sample (the resampling
    passes at the last resampling step before it)."""
    import copy

    args = {}
    originals = {p: getattr(module, p) for p in PASSES if hasattr(module, p) and p != "t_draws"}

    def cap(key, f):
        def inner(*a):
            args[key] = (f, copy.deepcopy(a))
            return f(*a)
        return inner

    mid = len(samples) // 2
    try:
        for k, s in enumerate(samples[:mid + 1]):
            for p, f in originals.items():
                setattr(module, p, cap(p, f))
            est.step(*s)
    finally:
        for p, f in originals.items():
            setattr(module, p, f)
    return args


def passes_alone(ests: dict, samples, repeat: int) -> None:
    """Each pass alone on its arguments at the middle sample, minimum of `repeat` calls (fresh
    copies each time), alternating call by call between the versions."""
    import copy

    caps = {}
    for label, est in ests.items():
        est.reset(np.random.default_rng(1))
        module = BASE if label == "base" else gpssm_numba
        if label == "base":
            est._compiled = BASE.CompiledStep(est)
        caps[label] = captured(est, module, samples)
    names = [n for n in caps["this"] if all(n in c for c in caps.values())]
    print(f"    each pass alone at the middle sample, minimum of {repeat} calls, us ({' / '.join(ests)}):")
    for kname in names:
        best = {label: 10**18 for label in caps}
        for _ in range(repeat):
            for label, cap in caps.items():
                f, a = cap[kname]
                a = copy.deepcopy(a)
                c0 = clock()
                f(*a)
                best[label] = min(best[label], clock() - c0)
        print(f"      {kname:32s} " + " / ".join(f"{best[n] / 1e3:8.1f}" for n in caps))


def main() -> int:
    global BASE
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--bases", nargs="+", default=["gpssm-axle", "gpssm-tensor"], choices=sorted(GPSSM))
    ap.add_argument("--rounds", type=int, default=2, help="alternating passes through the samples (default 2)")
    ap.add_argument("--repeat", type=int, default=100, help="calls of each pass alone (default 100; 0: none)")
    ap.add_argument("--base", type=Path, help="another version's src directory, timed alongside")
    args = ap.parse_args()
    snow, samples = record("friction-snow", args.duration)
    if args.base is not None:
        BASE = load_base(args.base.resolve(), Path(tempfile.mkdtemp(prefix="gpssm_prof_")))
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; {len(samples)} samples")
    for name in args.bases:
        ests = {}
        if BASE is not None:
            ests["base"] = _build(name, snow, args.particles, BASE)
        ests["this"] = _build(name, snow, args.particles)
        print(f"{name}, N = {args.particles}:")
        for label, est in ests.items():
            print(f"  {label}:")
            est.reset(np.random.default_rng(1))
            if label == "base":
                est._compiled = BASE.CompiledStep(est)
            profile(est, BASE if label == "base" else gpssm_numba, samples)
        if args.repeat:
            passes_alone(ests, samples, args.repeat)
        ab(ests, samples, args.rounds)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
