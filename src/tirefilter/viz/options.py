"""Where a run's Rerun recording goes and how much of the posterior it holds (no rerun
import here: `tirefilter --help` and runs without a recording never load rerun-sdk)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tirefilter.errors import ConfigError

# Clouds, densities and friction curves are logged at every DEFAULT_LOG_EVERY-th estimator
# step (series every step): 5 per second at 100 Hz. Chosen with benchmarks/bench_viz.py:
# paper-sim with N = 500 takes 1.2 times the wall time and 1.4-1.5 times the CPU time with
# `--rrd` than without; K = 10 exceeds 2 in some runs (docs/results.md, "Cost of the
# Rerun recording"). The target is <= 2.
DEFAULT_LOG_EVERY = 20
DEFAULT_SPAWN_PORT = 9876


@dataclass(frozen=True)
class RecordingOptions:
    """The sinks of a recording and its decimation.

    rrd: write the recording to this .rrd file (headless); spawn: start a local Rerun
    viewer (port `spawn_port`) and stream to it; connect: stream to a running viewer or
    gRPC proxy at this URL (e.g. rerun+http://127.0.0.1:9876/proxy). Any combination.
    log_every: log particle clouds, posterior densities and friction curves at every
    log_every-th estimator step. density_points: points of each density snapshot, over
    the posterior's mean -+ 4 std (`viz.rerun_log.DENSITY_REACH`).
    """

    rrd: str | Path | None = None
    spawn: bool = False
    connect: str | None = None
    log_every: int = DEFAULT_LOG_EVERY
    density_points: int = 201
    spawn_port: int = DEFAULT_SPAWN_PORT

    @property
    def enabled(self) -> bool:
        return bool(self.rrd) or self.spawn or bool(self.connect)

    def validated(self) -> "RecordingOptions":
        if int(self.log_every) != self.log_every or self.log_every < 1:
            raise ConfigError("--log-every", "", f"must be an integer >= 1, got {self.log_every!r}")
        if int(self.density_points) != self.density_points or self.density_points < 2:
            raise ConfigError("recording", "density_points", f"must be an integer >= 2, got {self.density_points!r}")
        if self.connect is not None:
            url = str(self.connect)
            if not url.startswith(("rerun://", "rerun+http://", "rerun+https://")) or not url.rstrip("/").endswith(
                    "/proxy"):
                raise ConfigError("--connect", url, "expected a Rerun gRPC URL such as "
                                  "rerun+http://127.0.0.1:9876/proxy (scheme rerun://, rerun+http:// or "
                                  "rerun+https://, path /proxy)")
        return self


@dataclass(frozen=True)
class RecordingContext:
    """What the recorder knows about the simulated world besides the rows.

    vehicle: VehicleParams (lf, lr for the drawing of the car; None: the estimator's
    vehicle or a 4.5 m car); friction_truth: (alpha (G,), surface) -> (true mu_f, true
    mu_r), the true friction curves of the friction CSV (`io.friction.friction_truth`;
    co-simulation only).
    """

    vehicle: object | None = None
    friction_truth: object | None = None


def recording_options(rrd=None, recording: RecordingOptions | None = None) -> RecordingOptions | None:
    """`recording`, or a file-only recording for the older `rrd=` argument; None when
    nothing is to be recorded."""
    if recording is None and rrd:
        recording = RecordingOptions(rrd=rrd)
    if recording is not None and rrd and not recording.rrd:
        from dataclasses import replace

        recording = replace(recording, rrd=rrd)
    return recording.validated() if recording is not None and recording.enabled else None
