"""Replay `make test`'s scheduling (pytest-xdist `--dist loadgroup`, two workers) on measured
per-test times, in file order and in the order tests/conftest.py gives the workers
(`long_modules_first`), and print when each worker would end (docs/development.md, "How long `make test` takes"):

    .venv/bin/python tools/suite_schedule.py runs/suite-stats/stats [--durations LOG] [--warm-up A B]

STATS: the prefix of `suite_stats`' timelines (STATS_gw0.timeline.json, ...): each test's wall time.
`--durations LOG`: pytest's `--durations` output of another run (an idle machine's); its setup +
call + teardown replace the wall time of the tests it lists, and the others take their CPU time
from STATS (on a loaded machine the CPU time is the steadier figure). `--warm-up A B`: seconds
before each worker's first test (a cold run's kernel compile).

The scheduler as pytest-xdist 3.8 has it (xdist/scheduler/loadscope.py, loadgroup.py): an xdist group
is one unit of work, every other test a unit of its own; the units are sorted by their number of
tests, largest first (stable; `--loadscope-reorder`, the default); each worker gets one unit, then
a worker gets the next unit whenever it has at most two tests left. The spread of the two ends
over 300 runs with each test's time multiplied by a lognormal factor (sigma 0.2 and 0.4) shows how
much of a measured end difference is the order and how much the luck of the last few tests.
"""

from __future__ import annotations

import argparse
import glob
import json
import random
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def load_times(stats: str, durations: str | None) -> dict[str, float]:
    wall, cpu = {}, {}
    for f in glob.glob(stats + "_gw*.timeline.json"):
        for nodeid, _, w, c, _ in json.loads(Path(f).read_text()):
            wall[nodeid], cpu[nodeid] = w, c
    if not durations:
        return wall
    listed = {}
    for line in Path(durations).read_text().splitlines():
        m = re.match(r"\s*([0-9.]+)s (setup|call|teardown)\s+(\S+)", line)
        if m:
            listed[m.group(3)] = listed.get(m.group(3), 0.0) + float(m.group(1))
    return {n: listed.get(n, cpu[n]) for n in wall}


def file_order(times: dict[str, float]) -> list[str]:
    """The collection's ids (file order), with the xdist group suffix the timelines carry."""
    out = subprocess.run([sys.executable, "-m", "pytest", "tests", "--collect-only", "-q", "-o", "addopts=",
                          "-p", "no:cacheprovider"], cwd=REPO, capture_output=True, text=True).stdout
    with_group = {n.split("@")[0]: n for n in times}
    return [with_group.get(line.strip(), line.strip()) for line in out.splitlines() if "::" in line]


def schedule(order: list[str], times: dict[str, float], warm=(0.0, 0.0)) -> list[float]:
    """The two workers' end times."""
    units = {}
    for n in order:
        units.setdefault(n.split("@")[1] if "@" in n else n, []).append(n)
    queue = sorted(units.values(), key=len, reverse=True)
    workers = [{"t": warm[i], "pending": []} for i in range(2)]
    for w in workers:
        w["pending"] += queue.pop(0) if queue else []
    for w in workers:
        if len(w["pending"]) <= 2 and queue:
            w["pending"] += queue.pop(0)
    while any(w["pending"] for w in workers):
        w = min((w for w in workers if w["pending"]), key=lambda w: w["t"])
        w["t"] += times.get(w["pending"].pop(0), 0.0)
        if len(w["pending"]) <= 2 and queue:
            w["pending"] += queue.pop(0)
    return [w["t"] for w in workers]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("stats")
    p.add_argument("--durations")
    p.add_argument("--warm-up", type=float, nargs=2, default=(0.0, 0.0))
    p.add_argument("--draws", type=int, default=300)
    args = p.parse_args()
    sys.path.insert(0, str(REPO / "tests"))
    from conftest import long_modules_first

    times = load_times(args.stats, args.durations)
    base = file_order(times)
    orders = {"file order": base, "long modules first": [base[i] for i in long_modules_first(base)]}
    print(f"{len(base)} tests, {sum(times.values()):.1f} s of tests")
    for label, order in orders.items():
        ends = schedule(order, times, args.warm_up)
        print(f"{label}: the workers end at {ends[0]:.1f} / {ends[1]:.1f} s "
              f"(difference {abs(ends[0] - ends[1]):.1f} s)")
    for sigma in (0.2, 0.4):
        for label, order in orders.items():
            rng = random.Random(0)
            diffs = sorted(abs(a - b) for a, b in (
                schedule(order, {n: t * rng.lognormvariate(0.0, sigma) for n, t in times.items()}, args.warm_up)
                for _ in range(args.draws)))
            print(f"times x lognormal(0, {sigma}), {args.draws} runs, {label}: end difference mean "
                  f"{sum(diffs) / len(diffs):.1f} s, median {diffs[len(diffs) // 2]:.1f} s, "
                  f"90th percentile {diffs[int(0.9 * len(diffs))]:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
