"""Memory of long runs: `tirefilter replay` streams the log and the results, so
its peak memory does not grow with the drive's length; a long co-simulation with the MPF
does not grow either.

    .venv/bin/python benchmarks/bench_memory.py replay [--minutes 120] [--estimators none kf mpf ...]
                                                       [--backend numba|c|numpy] [--peer] [--particles N]
    .venv/bin/python benchmarks/bench_memory.py soak [--minutes 60] [--particles 500] [--backend numba|c|numpy]
    .venv/bin/python benchmarks/bench_memory.py numba

`replay` writes a synthetic Log CSV of the given length at 100 Hz (a sine-steered drive,
written chunk by chunk), then replays it with each estimator in a fresh process
(`tirefilter replay`, as a user runs it) and prints the peak resident memory (VmHWM)
and the resident memory sampled every second: at 10 % of the wall time (after start-up
and the first pass) and its maximum after that, i.e. the growth during the replay.
`--peer`: the log is a peer drive instead (`tirefilter peer-drive --maneuver mixed`: the
CommonRoad single-track model, 27 columns with the `*_true` references), 10 minutes of it
simulated and repeated, time-shifted, to the length asked for (a 2-hour peer drive takes
the generator an hour and several GB); its vehicle TOML goes with it. `--particles`: the
particle filters' N.
`soak` co-simulates paper-sim stretched to the given length (its square-wave inputs
repeat) with the MPF, samples the resident memory every second, and prints its value at
10 % of the wall time, its maximum after that, the difference and the MPF's restarts.
`--backend` sets `backend` of the [mpf] and [augpf] tables (default: each estimator's own; "c", the MPF's
C core, the [mpf] table only).
`numba` prints the resident memory a fresh process adds by running the MPF on its C core (loading the
library, building it first if there is none) and then by importing numba and loading the MPF's compiled
kernels (from the cache, compiling them first if there is none): the part of an MPF run's peak that does
not depend on the run.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: BLAS threads only contend (30x slower expm)

import argparse
import json
import math
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
VEHICLE = REPO / "src/tirefilter/scenarios/data/vehicles/midsize-suv.toml"


def rss_mb(field: str = "VmRSS") -> float:
    """This process's resident memory (VmHWM: its peak) in MB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    return math.nan


class RssSampler:
    """Resident memory every `period` s in a daemon thread."""

    def __init__(self, period: float = 1.0):
        self.samples: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._t0 = time.perf_counter()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            self.samples.append((time.perf_counter() - self._t0, rss_mb()))
            self._stop.wait(1.0)

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join()
        self.samples.append((time.perf_counter() - self._t0, rss_mb()))
        t = np.array([s[0] for s in self.samples])
        m = np.array([s[1] for s in self.samples])
        k = int(np.searchsorted(t, 0.1 * t[-1]))
        # the peak of this process's memory since its exec (ru_maxrss would carry over the RSS
        # of the parent it was forked from, large after it simulated a peer drive)
        peak = rss_mb("VmHWM")
        return {"wall_s": float(t[-1]), "rss_at_10pct_mb": float(m[k]), "rss_max_after_mb": float(m[k:].max()),
                "growth_mb": float(m[k:].max() - m[k]), "peak_rss_mb": peak}


def write_drive(path: Path, minutes: float, rate: float = 100.0) -> Path:
    """A sine-steered drive at 20 m/s with plausible IMU signals, written 60 s at a time."""
    n_total = int(round(minutes * 60 * rate)) + 1
    rng = np.random.default_rng(0)
    with open(path, "w") as f:
        f.write("t,delta,ax,ay,yaw_rate,vx\n")
        for start in range(0, n_total, int(60 * rate)):
            k = np.arange(start, min(n_total, start + int(60 * rate)))
            t = k / rate
            delta = 0.02 * np.sin(2 * np.pi * 0.2 * t)
            vx = 20.0 + 0 * t
            yaw = vx * delta / 2.9 + 0.003 * rng.standard_normal(t.size)
            ay = vx * vx * delta / 2.9 + 0.05 * rng.standard_normal(t.size)
            ax = 0.05 * rng.standard_normal(t.size)
            f.write("\n".join(f"{a!r},{b!r},{c!r},{d!r},{e!r},{g!r}" for a, b, c, d, e, g in
                              zip(t.tolist(), delta.tolist(), ax.tolist(), ay.tolist(), yaw.tolist(), vx.tolist())))
            f.write("\n")
    return path


def write_peer_drive(path: Path, minutes: float, piece_s: float = 600.0) -> tuple[Path, Path]:
    """A mixed-maneuver peer drive (10 minutes simulated, repeated with its time shifted) of
    `minutes`, and its vehicle TOML."""
    from tirefilter.peer.drive import DriveSpec, simulate, vehicle_toml

    drive = simulate(DriveSpec(model="std", maneuver="mixed", duration=min(piece_s, 60.0 * minutes), seed=0))
    vehicle = path.with_suffix(".toml")
    vehicle.write_text(vehicle_toml(drive))
    names = list(drive.columns)
    piece = np.column_stack([np.asarray(drive.columns[n], float) for n in names])
    span = piece[-1, 0] - piece[0, 0]
    n_total = int(round(minutes * 60 / span * (len(piece) - 1))) + 1
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        done, shift = 0, 0.0
        while done < n_total:
            rows = piece if done == 0 else piece[1:]  # the next piece starts where this one ends
            rows = rows[:n_total - done].copy()
            rows[:, 0] += shift
            f.write("\n".join(",".join("" if x != x else repr(x) for x in r) for r in rows.tolist()) + "\n")
            done, shift = done + len(rows), shift + span
    return path, vehicle


def backend_config(path: Path, backend: str | None) -> list[str]:
    """`--config FILE` setting the backend of the particle filters ([] for their defaults)."""
    if backend is None:
        return []
    augpf = f'\n[augpf]\nbackend = "{backend}"\n' if backend != "c" else ""  # (the AUGPF has no C core)
    path.write_text(f'[mpf]\nbackend = "{backend}"\n{augpf}')
    return ["--config", str(path)]


def one_replay(log: str, vehicle: str, estimator: str, out: str, *options: str) -> dict:
    """`tirefilter replay` in this process, with the memory sampled."""
    from tirefilter.cli import main

    sampler = RssSampler()
    rc = main(["replay", log, "--vehicle", vehicle, "--estimator", estimator, "--out", out, "--quiet", *options])
    memory = sampler.stop()
    summary_path = Path(out).with_suffix(".json")
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}  # a failed replay may write none
    return {"rc": rc, **memory, "restarts": (summary.get("metrics") or {}).get("restarts")}


def cmd_replay(args) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        if args.peer:
            log, vehicle = write_peer_drive(Path(tmp) / "drive.csv", args.minutes)
        else:
            log, vehicle = write_drive(Path(tmp) / "drive.csv", args.minutes), VEHICLE
        size = log.stat().st_size / 1e6
        config = backend_config(Path(tmp) / "backend.toml", args.backend)
        if args.particles:
            config += ["--particles", str(args.particles)]
        print(f"log: {'peer drive, ' if args.peer else ''}{args.minutes:g} min at 100 Hz "
              f"({int(args.minutes * 6000) + 1} rows, {size:.0f} MB), backend {args.backend or 'default'}"
              + (f", N = {args.particles}" if args.particles else ""), flush=True)
        print("| estimator | log min | wall s | peak RSS MB | RSS at 10 % MB | max after MB | growth MB | restarts |\n"
              "|---|---|---|---|---|---|---|---|", flush=True)
        for est in args.estimators:
            res = subprocess.run([sys.executable, __file__, "_one", str(log), str(vehicle), est,
                                  str(Path(tmp) / f"{est}.csv"), *config], capture_output=True, text=True)
            if res.returncode != 0:
                print(f"| {est} | failed: {res.stderr.strip().splitlines()[-1:]} |", flush=True)
                continue
            r = json.loads(res.stdout.strip().splitlines()[-1])
            print(f"| {est} | {args.minutes:g} | {r['wall_s']:.0f} | {r['peak_rss_mb']:.0f} | "
                  f"{r['rss_at_10pct_mb']:.0f} | {r['rss_max_after_mb']:.0f} | {r['growth_mb']:+.1f} | "
                  f"{r['restarts']} |", flush=True)


def cmd_soak(args) -> None:
    from dataclasses import replace

    from tirefilter.cosim.run import run_scenario
    from tirefilter.estimators import build_estimator
    from tirefilter.scenarios import load_scenario

    scenario = load_scenario("paper-sim")
    scenario = replace(scenario, duration=60.0 * args.minutes)
    config = {"mpf": {"backend": args.backend}} if args.backend else {}
    est = build_estimator("mpf", scenario, model="auto", particles=args.particles, config=config)
    with tempfile.TemporaryDirectory() as tmp:
        sampler = RssSampler()
        summary, _ = run_scenario(scenario, estimator=est, seed=0, results_csv=Path(tmp) / "results.csv")
        r = sampler.stop()
    print(f"soak: paper-sim stretched to {args.minutes:g} min, mpf N = {est.cfg.particles} ({est.cfg.backend}), "
          f"{summary.steps} steps, "
          f"status {summary.status}, wall {r['wall_s']:.0f} s, restarts {est.restarts}")
    print(f"RSS at 10 % of the wall time {r['rss_at_10pct_mb']:.1f} MB, max after it {r['rss_max_after_mb']:.1f} MB: "
          f"growth {r['growth_mb']:+.1f} MB; peak {r['peak_rss_mb']:.1f} MB")


def cmd_numba(args) -> None:
    """The resident memory of importing numba and loading the MPF's kernels, in a fresh process."""
    code = ("import json, resource, sys\n"
            "import numpy as np\n"
            "from bench_memory import rss_mb\n"
            "from tirefilter.estimators import build_estimator\n"
            "from tirefilter.estimators.base import Inputs, Measurement\n"
            "from tirefilter.scenarios import load_scenario\n"
            "def run(backend):\n"
            "    est = build_estimator('mpf', load_scenario('paper-sim'), model='auto', particles=500,\n"
            "                          config={'mpf': {'backend': backend}})\n"
            "    est.reset(np.random.default_rng(0))\n"
            "    for k in range(300):\n"
            "        t = 0.01 * k; d = 0.02 * np.sin(t)\n"
            "        est.step(t, Inputs(delta=d, omega_f=73.0, omega_r=73.0, vx=22.0),\n"
            "                 Measurement(ax=0.0, ay=22.0 * 22.0 * d / 2.9, yaw_rate=22.0 * d / 2.9))\n"
            "run('numpy')\n"
            "a = rss_mb()\n"
            "run('c')\n"
            "a_c = rss_mb(); assert 'numba' not in sys.modules\n"
            "import numba\n"
            "b = rss_mb()\n"
            "run('numba')\n"
            "c = rss_mb()\n"
            "print(json.dumps([a, a_c, b, c, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0]))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).parent)
    a, a_c, b, c, peak = json.loads(res.stdout.strip().splitlines()[-1])
    print(f"RSS after 300 steps of the MPF (N = 500, numpy backend): {a:.1f} MB; after 300 more with the C backend "
          f"(its library loaded): {a_c:.1f} MB (+{a_c - a:.1f}); after `import numba`: {b:.1f} MB (+{b - a_c:.1f}); "
          f"after 300 steps with the numba backend (its kernels loaded): {c:.1f} MB (+{c - a_c:.1f} in all); "
          f"peak {peak:.1f} MB")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_one":
        print(json.dumps(one_replay(*argv[1:])))
        return 0
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    rp = sub.add_parser("replay")
    rp.add_argument("--minutes", type=float, default=120.0)
    rp.add_argument("--estimators", nargs="+", default=["none", "kf", "mpf"])
    rp.add_argument("--backend", choices=["numba", "c", "numpy"],
                    help="backend of mpf and augpf (default: theirs; c: the MPF's only)")
    rp.add_argument("--peer", action="store_true", help="a mixed-maneuver peer drive (repeated 10 minutes)")
    rp.add_argument("--particles", type=int, help="N of the particle filters (default: theirs)")
    sk = sub.add_parser("soak")
    sk.add_argument("--minutes", type=float, default=60.0)
    sk.add_argument("--particles", type=int)
    sk.add_argument("--backend", choices=["numba", "c", "numpy"], help="the MPF's backend (default: its own)")
    sub.add_parser("numba")
    args = p.parse_args(argv)
    {"replay": cmd_replay, "soak": cmd_soak, "numba": cmd_numba}[args.cmd](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
