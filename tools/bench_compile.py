"""The compile cost of the kernels, per warm-up task of tests/conftest.py, in one process:

    NUMBA_CACHE_DIR=$(mktemp -d) .venv/bin/python tools/bench_compile.py

prints per task the numba compile time (wall), the process CPU time and the wall time. Run it
with an empty cache (a clean clone's first `make test`); with the cache filled it prints what
loading costs. docs/development.md, "How long `make test` takes"."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tools"), str(ROOT / "tests")]

import suite_stats  # noqa: E402  (registers the compile listener)
from conftest import WARM_UP  # noqa: E402


def main() -> int:
    import argparse

    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    print(f"NUMBA_CACHE_DIR={os.environ.get('NUMBA_CACHE_DIR', '(beside the sources)')}, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'task':20s} {'compile s':>10s} {'CPU s':>8s} {'wall s':>8s}")
    total = [0.0, 0.0, 0.0]
    for name, task in WARM_UP.items():
        k0, c0, w0 = suite_stats.compile_seconds(), time.process_time(), time.perf_counter()
        task()
        row = (suite_stats.compile_seconds() - k0, time.process_time() - c0, time.perf_counter() - w0)
        total = [a + b for a, b in zip(total, row)]
        print(f"{name:20s} {row[0]:10.1f} {row[1]:8.1f} {row[2]:8.1f}", flush=True)
    print(f"{'all':20s} {total[0]:10.1f} {total[1]:8.1f} {total[2]:8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
