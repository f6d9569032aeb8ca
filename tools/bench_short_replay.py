"""The MPF on the short paper-sim replay of tests/test_faults.py, over many estimator seeds.

paper-sim (drive seed 2) co-simulated without an estimator, cut to its first 20 s and replayed
as a log with default settings (so with the replay's bias estimation and noise from the data)
at N = 100, once per estimator seed: how often the filter diverges (restarts, sideslip RMSE),
the robustness behind that test's fixed seed.

    .venv/bin/python tools/bench_short_replay.py --seeds 0-23 [--particles N] [--config FILE.toml]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_faults import paper_sim_drive  # noqa: E402

from tirefilter.config import read_toml  # noqa: E402
from tirefilter.estimators import build_log_estimator  # noqa: E402
from tirefilter.replay import replay_log, result_columns  # noqa: E402
from tirefilter.io.log import Log  # noqa: E402

DURATION, DRIVE_SEED, N, DIVERGED_DEG = 20.0, 2, 100, 0.5


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-23", help="estimator seeds, FIRST-LAST")
    ap.add_argument("--config", help="estimator configuration TOML (as --config of replay)")
    ap.add_argument("--particles", type=int, default=N, help=f"N (default {N}, as the test)")
    args = ap.parse_args()
    first, last = (int(s) for s in args.seeds.split("-"))
    config = read_toml(args.config) if args.config else {}
    log, vehicle = paper_sim_drive(DRIVE_SEED)
    keep = log.t <= DURATION
    cut = {k: v[keep] for k, v in log.columns.items()}
    log = Log(path=log.path, t=cut["t"], signals={s: cut[s] for s in log.signals}, columns=cut, header=log.header,
              lines=log.lines[keep])
    rows_out = []
    for seed in range(first, last + 1):
        est = build_log_estimator("mpf", vehicle, log.t, {s: log.signals[s] for s in log.available}, model="auto",
                                  particles=args.particles, config=config, source=args.config or "defaults")
        _, rows = replay_log(log, estimator=est, seed=seed, keep_rows=True)
        r = dict(zip(result_columns(log), rows.T))
        rmse = float(np.sqrt(np.mean(np.degrees(r["beta"] - log.columns["beta_true"]) ** 2)))
        rows_out.append((seed, est.restarts, rmse))
    bad = [s for s, _, e in rows_out if e > DIVERGED_DEG]
    print(f"config: {args.config or 'defaults'}; seeds {first}-{last}; N = {args.particles}; first {DURATION:g} s of "
          f"paper-sim (drive seed {DRIVE_SEED}) replayed")
    print("per seed (seed, restarts, sideslip RMSE deg): "
          + ", ".join(f"({s}, {k}, {e:.3f})" for s, k, e in rows_out))
    print(f"sideslip RMSE above {DIVERGED_DEG} deg: {len(bad)} of {len(rows_out)} seeds ({', '.join(map(str, bad))}); "
          f"median {np.median([e for *_, e in rows_out]):.3f} deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
