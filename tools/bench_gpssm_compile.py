"""First-run cost of the compiled GP-SSM step: the time of a short run (60 steps of a
synthetic slalom, N = 50, resampling at every step so that every kernel is used), run in a
fresh process with the numba cache directory given. Run it twice with the same empty
directory: the first run compiles and fills the cache, the second loads it.

    D=$(mktemp -d); for i in 1 2; do NUMBA_CACHE_DIR=$D .venv/bin/python tools/bench_gpssm_compile.py; done

Prints, per basis, the first step() call and the whole run (first call included) in ms, and
the import of numba and the kernels' modules."""

from __future__ import annotations

import math
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as bench_cost.py: one BLAS thread
t0 = time.perf_counter()
import numpy as np  # noqa: E402

from tirefilter.estimators.gpssm import compiled  # noqa: E402,F401  (imports numba and the kernels' modules)
from tirefilter.estimators.base import Inputs, Measurement  # noqa: E402
from tirefilter.estimators.gpssm.filter import FrictionGPSSM, GPSSMConfig  # noqa: E402
from tirefilter.scenarios import load_scenario  # noqa: E402

print(f"import: {(time.perf_counter() - t0) * 1e3:.0f} ms")
vehicle = load_scenario("friction-snow").vehicle
for basis, symmetry in (("axle", "odd"), ("tensor", "odd"), ("tensor", "none")):
    est = FrictionGPSSM(vehicle, GPSSMConfig(particles=50, basis=basis, symmetry=symmetry, resample_threshold=1.0))
    est.reset(np.random.default_rng(1))
    rng = np.random.default_rng(2)
    t1 = time.perf_counter()
    first = None
    for k in range(60):
        delta = 0.03 * math.sin(math.pi * 0.04 * k)
        r = 15.0 * delta / 2.8
        est.step(0.04 * k, Inputs(delta=delta, vx=15.0),
                 Measurement(ay=15.0 * r + 0.05 * rng.standard_normal(), yaw_rate=r + 0.003 * rng.standard_normal()))
        first = first or time.perf_counter() - t1
    est.friction()
    size = est.basis.size * (2 if basis == "axle" else 1)
    print(f"{basis} ({symmetry}, {size} functions): first call {first * 1e3:.0f} ms, "
          f"60 steps and a friction snapshot {(time.perf_counter() - t1) * 1e3:.0f} ms")
