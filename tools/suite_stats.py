"""pytest plugin (docs/development.md, "How long `make test` takes"): per xdist worker, the
numba compile time (numba's own compile events: real compiles, not cache loads), the
signatures compiled per kernel, and per test its wall time, CPU time (the process and its
reaped children: chromium, subprocesses) and compile time. Written at the end of the session
to SUITE_STATS_OUT_<worker>.json and SUITE_STATS_OUT_<worker>.timeline.json
(SUITE_STATS_OUT defaults to runs/suite-stats/stats):

    PYTHONPATH=tools NUMBA_CACHE_DIR=$(mktemp -d) .venv/bin/python -m pytest tests -n 2 \\
        --dist loadgroup -p suite_stats -p no:cacheprovider --durations=30
"""

from __future__ import annotations

import os

# Before numpy is imported (numba imports it): a plugin loads before tests/conftest.py, whose
# one-BLAS-thread setting would otherwise come too late, and the numpy references' LAPACK calls
# would round differently (test_kernels' 100-function tensor then misses its 1e-12 by 1e-11).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402

import json  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
from numba.core import event as ev  # noqa: E402

_T = {"depth": 0, "t0": 0.0, "total": 0.0, "n": 0, "per": {}}
_TIMELINE = []
MODULES = ("tirefilter.estimators.mpf.kernels_weigh", "tirefilter.estimators.mpf.kernels_update",
           "tirefilter.estimators.gpssm.kernels_particles", "tirefilter.estimators.gpssm.kernels_stats",
           "tirefilter.estimators.gpssm.kernels_resample", "tirefilter.stats.mniw_numba",
           "tirefilter.stats.particles_numba", "tirefilter.vehicle.single_track_numba")


class _Compiles(ev.Listener):
    """Wall time of the outermost numba:compile events (a kernel's callees are in its time)."""

    def on_start(self, event):
        if _T["depth"] == 0:
            _T["t0"] = time.perf_counter()
        _T["depth"] += 1

    def on_end(self, event):
        _T["depth"] -= 1
        if _T["depth"] == 0:
            dt = time.perf_counter() - _T["t0"]
            _T["total"] += dt
            _T["n"] += 1
            name = event.data["dispatcher"].py_func.__qualname__
            _T["per"][name] = _T["per"].get(name, 0.0) + dt


ev.register("numba:compile", _Compiles())


def compile_seconds() -> float:
    return _T["total"]


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    w0, c0, ch0, k0 = time.time(), time.process_time(), _children_cpu(), _T["total"]
    yield
    _TIMELINE.append([item.nodeid, w0, time.time() - w0, time.process_time() - c0 + _children_cpu() - ch0,
                      _T["total"] - k0])


def signatures() -> dict:
    out = {}
    for mod in MODULES:
        m = sys.modules.get(mod)
        for k, v in vars(m).items() if m else ():
            if hasattr(v, "signatures") and hasattr(v, "py_func") and v.signatures:
                out[f"{mod.rsplit('.', 1)[-1]}.{k}"] = [str(s) for s in v.signatures]
    return out


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session, exitstatus):
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    base = Path(os.environ.get("SUITE_STATS_OUT", "runs/suite-stats/stats"))
    base.parent.mkdir(parents=True, exist_ok=True)
    Path(f"{base}_{worker}.json").write_text(json.dumps(
        {"compile_s": _T["total"], "n_compiles": _T["n"], "per": _T["per"], "sigs": signatures()}, indent=1))
    Path(f"{base}_{worker}.timeline.json").write_text(json.dumps(_TIMELINE))
