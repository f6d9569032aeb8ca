"""A log replayed without holding it in memory: a first pass over the file (`scan_log`)
gathers what building an estimator and the start of a replay need (the sample times, the
signals present, each signal's first sample, the IMU channels and wheel speeds for the
white-noise estimates of `estimators.sensors`, the plausibility warnings); the replay then
reads the file again chunk by chunk (`LogScan.chunks`, `io.log.iter_log_chunks`).

The samples kept are 48 bytes a row (the times, three IMU channels and two wheel speeds:
35 MB for a 2-hour log at 100 Hz), each gathered chunk by chunk and joined one at a time
(the join doubles one channel, not all); `LogScan.release` drops them once the estimator's
setting is made (`estimators.for_log` keeps nothing of the log's length), so that a replay
holds one chunk of the file, whatever its length.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tirefilter.io.log import CHUNK_ROWS, SIGNALS, iter_log_chunks, vehicle_arg
from tirefilter.replay.plausibility import IMU, Plausibility

NOISE_CHANNELS = IMU + ("omega_f", "omega_r")  # kept whole for the white-noise estimates (IMU and wheel speeds)


@dataclass
class LogScan:
    """What the first pass over a log found; replay_log takes it in place of a Log."""

    path: Path
    vehicle: object  # VehicleParams or None
    vehicle_name: str | None
    chunk_rows: int
    rows: int  # data rows
    duration: float  # s, time span
    t: np.ndarray | None  # (rows,) s, every sample time (None once released)
    present: tuple[str, ...]  # SIGNALS with a column (in SIGNALS order)
    first: dict[str, float]  # signal -> its first finite sample (absent: none)
    header: tuple[str, ...] = ()
    ignored: tuple[str, ...] = ()
    references: tuple[str, ...] = ()  # reference columns as `true_<name>` (Log.references), in file order
    derived: dict = field(default_factory=dict)
    plausibility: Plausibility = field(default_factory=Plausibility)
    # ax, ay, yaw_rate, omega_f, omega_r: (rows,) each, for the noise estimates (empty once released)
    imu: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def available(self) -> tuple[str, ...]:
        return tuple(s for s in SIGNALS if s in self.first)

    @property
    def signals(self) -> dict[str, np.ndarray]:
        """What `estimators.for_log` reads of the signals: the IMU channels and wheel speeds whole
        (their white noise is estimated from them, `estimators.sensors`), every other available
        signal as a one-sample array holding its first finite sample (its presence and first
        value are all that is used)."""
        if self.t is None:
            raise RuntimeError(f"{self.path}: the scan's samples were released")
        return {s: self.imu[s] if s in self.imu else np.array([self.first[s]]) for s in self.available}

    def release(self) -> None:
        """Drop the sample times and the noise channels (what the estimator's setting is made
        from): the replay needs nothing of the log's length but `rows` and `duration`."""
        self.t, self.imu = None, {}

    def chunks(self):
        """The log again, chunk by chunk."""
        return iter_log_chunks(self.path, self.vehicle, chunk_rows=self.chunk_rows, vehicle_name=self.vehicle_name)


def _join(parts: list[np.ndarray]) -> np.ndarray:
    """One array of the chunks in `parts`, emptying the list as it goes (the chunks are freed
    as soon as they are copied: the join holds one channel twice at most)."""
    out = np.empty(sum(len(p) for p in parts))
    k = 0
    while parts:
        p = parts.pop(0)
        out[k:k + len(p)] = p
        k += len(p)
    return out


def scan_log(path, vehicle=None, *, vehicle_name: str | None = None, chunk_rows: int = CHUNK_ROWS) -> LogScan:
    """The first pass over the Log CSV at `path` (every check of `read_log` runs here, so a
    bad file fails before the replay starts)."""
    vehicle, name = vehicle_arg(vehicle)
    vehicle_name = vehicle_name or name
    times, first, plaus, imu = [], {}, Plausibility(), {c: [] for c in NOISE_CHANNELS}
    head = None
    for chunk in iter_log_chunks(path, vehicle, chunk_rows=chunk_rows, vehicle_name=vehicle_name):
        head = head or chunk
        times.append(chunk.t)
        for c in NOISE_CHANNELS:
            if c in chunk.signals:
                imu[c].append(chunk.signals[c])
        plaus.add(chunk)
        for s, x in chunk.signals.items():
            if s not in first:
                k = np.flatnonzero(np.isfinite(x))
                if k.size:
                    first[s] = float(x[k[0]])
    t = _join(times)
    return LogScan(path=Path(path), vehicle=vehicle, vehicle_name=vehicle_name, chunk_rows=chunk_rows, rows=len(t),
                   duration=float(t[-1] - t[0]), t=t, present=head.present, first=first, header=head.header,
                   ignored=head.ignored, references=tuple(head.references), derived=head.derived, plausibility=plaus,
                   imu={c: _join(x) for c, x in imu.items() if x})
