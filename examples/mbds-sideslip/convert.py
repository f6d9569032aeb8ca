"""Turn the MBDS race-track recording into a Log CSV (the replay input, docs/usage.md).

    .venv/bin/python examples/mbds-sideslip/convert.py [--out runs/mbds-sideslip/log.csv]
                                                      [--start T] [--end T] [--data FILE]

The recording (A. Leanza, G. Reina, J.-L. Blanco-Claraco, Sensors 21(16):5409, 2021; MIT
licence) is not part of this repository: it is read from ../shared/data/mbds-sideslip/
relative to the repository root. Columns written: t, delta (road-wheel angle, the mean of
the two fronts), ax, ay, yaw_rate (IMU at the centre of gravity), vx (GPS/INS reference,
the "other logic" that gives v^X to the lateral model), and the references beta_true and
vy_true (ignored by the reader, kept to compare the sideslip estimate with). `--start` and
`--end` [s, recording time] cut a stretch. The script also prints the white-noise std of
the IMU channels of the rows written, estimated as `tirefilter check-log` and the replay
estimate it (`tirefilter.estimators.sensors.noise_from_data`), with their units.
"""

from __future__ import annotations

import argparse
import gzip
import sys
from pathlib import Path

import numpy as np

from tirefilter.estimators.sensors import CHANNELS, UNITS, noise_from_data
from tirefilter.replay import write_log

REPO = Path(__file__).resolve().parents[2]
DATA = REPO.parent / "shared" / "data" / "mbds-sideslip" / "mbds_20140222_01_01_03.csv.gz"
OUT = REPO / "runs" / "mbds-sideslip" / "log.csv"
# Log CSV column <- recording column
COLUMNS = {"t": "t", "delta": "delta", "ax": "axCG", "ay": "ayCG", "yaw_rate": "yawRate", "vx": "vx",
           "beta_true": "beta_true", "vy_true": "vy"}


def read_recording(path: Path) -> dict[str, np.ndarray]:
    with gzip.open(path, "rt") as f:
        header = f.readline().strip().split(",")
        data = np.loadtxt(f, delimiter=",", ndmin=2)
    return {name: data[:, j] for j, name in enumerate(header)}


def convert(data: Path = DATA, out: Path = OUT, start: float | None = None, end: float | None = None) -> Path:
    """Write the Log CSV of the recording at `data` (rows with start <= t <= end) to `out`."""
    return write_log(out, to_log(read_recording(Path(data)), start, end))


def to_log(rec: dict[str, np.ndarray], start: float | None = None, end: float | None = None) -> dict[str, np.ndarray]:
    """The Log CSV columns of the recording's rows with start <= t <= end."""
    keep = np.ones(len(rec["t"]), bool)
    if start is not None:
        keep &= rec["t"] >= start
    if end is not None:
        keep &= rec["t"] <= end
    if not keep.any():
        lo, hi = ("" if start is None else f"{start:g} s <= "), ("" if end is None else f" <= {end:g} s")
        raise ValueError(f"no samples with {lo}t{hi} (the recording spans "
                         f"{rec['t'][0]:g} ... {rec['t'][-1]:g} s)")
    return {name: rec[source][keep] for name, source in COLUMNS.items()}


def noise_summary(log: dict[str, np.ndarray]) -> str:
    """The white-noise std of the IMU channels of the Log CSV columns `log`, as check-log
    and the replay estimate it from the same rows (second differences, held samples
    dropped: docs/derivations.md, "White noise from the data")."""
    sigma, _ = noise_from_data(log, "the log")
    return ", ".join(f"{c} {s:.3g} {u}" for c, s, u in zip(CHANNELS, sigma, UNITS))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=DATA, help=f"the recording (default {DATA})")
    p.add_argument("--out", type=Path, default=OUT, help=f"Log CSV to write (default {OUT.relative_to(REPO)})")
    p.add_argument("--start", type=float, help="first time to keep [s]")
    p.add_argument("--end", type=float, help="last time to keep [s]")
    args = p.parse_args(argv)
    if not args.data.is_file():
        print(f"error: the recording is not at {args.data}.\nIt is shared beside the repository, in "
              f"../shared/data/mbds-sideslip/ relative to the repository root ({REPO}), and is not part of it; "
              "give its path with --data FILE.", file=sys.stderr)
        return 2
    rec = read_recording(args.data)
    try:
        log = to_log(rec, args.start, args.end)
        out = write_log(args.out, log)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}\nwhite noise estimated from the log (as check-log and the replay estimate it): "
          f"{noise_summary(log)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
