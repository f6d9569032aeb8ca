"""The MPF step of this checkout against another version's, in one process (issue 14).

    git archive main src | tar -x -C /tmp/base
    .venv/bin/python benchmarks/bench_mpf_ab.py --base /tmp/base/src [--particles 500 8] [--rounds 3]

On a shared machine two separate benchmark runs see different loads; here both filters step
through the same 5 s of recorded paper-sim samples (seed 0) in the same process, one
after the other, `--rounds` times, with the same configuration (this checkout's defaults,
as `tirefilter run` builds them; options the other version lacks are dropped). The other
version's MPF (its `estimators/mpf/` package with `vehicle/single_track.py` and
`single_track_numba.py`, or an older checkout's `stiffness_mpf.py` and `mpf_numba.py`) and its
`baseline_common.py` are copied into a temporary folder with their imports renamed, so both
compile and cache apart. Prints the median and 10th
percentile of the thread's CPU time per `step()` (after 10 warm-up steps) and their ratios.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import importlib  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cost import WARMUP, record  # noqa: E402

from tirefilter.estimators import build_estimator  # noqa: E402


def load_base(src: Path, into: Path):
    """The other version's StiffnessMPF and MPFConfig, from `src` (a `src` directory)."""
    est_dir = src / "tirefilter" / "estimators"
    (into / "base_baseline_common.py").write_text((est_dir / "baseline_common.py").read_text())
    sys.path.insert(0, str(into))
    if (est_dir / "mpf").is_dir():  # the MPF package and the vehicle model it calls
        swaps = [("from tirefilter.estimators.mpf", "from base_mpf"),
                 ("from tirefilter.estimators.baseline_common import", "from base_baseline_common import"),
                 ("from tirefilter.vehicle import single_track_numba\n",
                  "import base_single_track_numba as single_track_numba\n"),
                 ("from tirefilter.vehicle import single_track\n", "import base_single_track as single_track\n"),
                 ("from tirefilter.vehicle.single_track_numba import", "from base_single_track_numba import"),
                 ("from tirefilter.vehicle.single_track import", "from base_single_track import")]

        def copy(path: Path, to: Path) -> None:
            text = path.read_text()
            for a, b in swaps:
                text = text.replace(a, b)
            to.write_text(text)

        (into / "base_mpf").mkdir()
        for path in (est_dir / "mpf").glob("*.py"):
            copy(path, into / "base_mpf" / path.name)
        for name in ("single_track", "single_track_numba"):
            copy(src / "tirefilter" / "vehicle" / f"{name}.py", into / f"base_{name}.py")
        return importlib.import_module("base_mpf")
    (into / "base_mpf_numba.py").write_text((est_dir / "mpf_numba.py").read_text())
    text = (est_dir / "stiffness_mpf.py").read_text()
    text = text.replace("from tirefilter.estimators import mpf_numba\n", "import base_mpf_numba as mpf_numba\n")
    text = text.replace("from tirefilter.estimators.baseline_common import", "from base_baseline_common import")
    (into / "base_stiffness_mpf.py").write_text(text)
    return importlib.import_module("base_stiffness_mpf")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, required=True, help="the other version's src directory")
    ap.add_argument("--particles", type=int, nargs="+", default=[500, 8])
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="mpf_ab_"))
    base = load_base(args.base.resolve(), tmp)
    sim, samples = record("paper-sim", 5.0)
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    for n in args.particles:
        new = build_estimator("mpf", sim, model="auto", particles=n, config={})
        fields = {f.name for f in dataclasses.fields(base.MPFConfig)}
        cfg = base.MPFConfig(**{k: v for k, v in dataclasses.asdict(new.cfg).items() if k in fields})
        old = base.StiffnessMPF(new.vehicle, cfg)
        cpu: dict[str, list[float]] = {"base": [], "this": []}
        for _ in range(args.rounds):
            for name, est in (("base", old), ("this", new)):
                est.reset(np.random.default_rng(1))
                for k, s in enumerate(samples):
                    c0 = time.thread_time_ns()
                    est.step(*s)
                    if k >= WARMUP:
                        cpu[name].append((time.thread_time_ns() - c0) / 1e3)
        med = {k: float(np.median(v)) for k, v in cpu.items()}
        p10 = {k: float(np.percentile(v, 10)) for k, v in cpu.items()}
        ratio, ratio10 = med["this"] / med["base"], p10["this"] / p10["base"]
        print(f"N = {n}: base {med['base']:.0f} us (p10 {p10['base']:.0f}), this {med['this']:.0f} us "
              f"(p10 {p10['this']:.0f}); this / base {ratio:.2f} (p10 {ratio10:.2f})")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
