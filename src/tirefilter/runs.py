"""What every estimator run shares, whether its samples come from the vehicle FMU
(`cosim.run`) or from a recorded log (`replay.run`): the seed split, the sinks of the rows
(Result CSV, Rerun recording, rows kept in memory), the timing of `Estimator.step`, the
progress bar, the run summary and its JSON (docs/usage.md, "Run summary").
"""

from __future__ import annotations

import dataclasses
import json
import platform
import signal
import sys
import time
from array import array
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tirefilter import __version__
from tirefilter.estimators.base import Estimate, Estimator, Inputs, Measurement

WARMUP_STEPS = 10  # steps left out of the median step time (first calls, caches)
KEEP_BLOCK = 4096  # rows kept in memory are gathered in float64 blocks of this many (keep_rows)


def spawn_seeds(seed: int) -> tuple[int, np.random.Generator]:
    """One SeedSequence -> (the FMU's 31-bit seed, the estimator's Generator).

    A replay spawns the same two children and uses the second, so a log written by a
    co-simulation and replayed with the same seed gives the same estimates."""
    fmu_ss, est_ss = np.random.SeedSequence(seed).spawn(2)
    fmu_seed = int(fmu_ss.generate_state(1, dtype=np.uint32)[0] & 0x7FFFFFFF)
    return fmu_seed, np.random.default_rng(est_ss)


@dataclass(kw_only=True)
class StepSummary:
    """The fields every run summary has; co-simulation and replay add their own."""

    seed: int
    estimator: str
    steps: int = 0  # estimator samples (Result-CSV rows)
    wall_time_s: float = 0.0
    median_step_us: float | None = None  # median wall time of Estimator.step after warm-up
    status: str = "ok"  # "ok" | "failed" | "interrupted" (SIGINT / SIGTERM, see `interruptible`)
    error: str | None = None
    t_reached: float | None = None  # s: time of the last row written (set when a run is interrupted)
    results: str | None = None  # the Result CSV
    metrics: dict | None = None  # metrics.run_metrics of the rows written (run.json `metrics`)
    guard: dict | None = None  # samples the measurement guard marked missing (estimators.guard)


class Interrupted(BaseException):
    """SIGINT or SIGTERM arrived during a run: raised at the next row boundary (after a
    whole row has been written), never in the middle of one. A BaseException, like
    KeyboardInterrupt, so that code catching an estimator's failures lets it through."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}")

    @property
    def exit_code(self) -> int:
        return 128 + self.signum  # 130 for SIGINT, 143 for SIGTERM, as a shell reports them


_PENDING_SIGNAL: int | None = None  # set by the handlers of `interruptible`


@contextmanager
def interruptible():
    """While inside, SIGINT and SIGTERM only note the signal; `check_interrupt()` (called by
    `RunOutputs.write` after every row, and between trials of a study) then raises
    Interrupted. The previous handlers come back on leaving. Outside such a block nothing
    changes (library use keeps Python's own KeyboardInterrupt)."""
    global _PENDING_SIGNAL

    def note(signum, frame):
        global _PENDING_SIGNAL
        _PENDING_SIGNAL = signum

    _PENDING_SIGNAL = None
    old = {s: signal.signal(s, note) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        _PENDING_SIGNAL = None


def check_interrupt() -> None:
    """Raise Interrupted if a signal arrived inside `interruptible()`."""
    if _PENDING_SIGNAL is not None:
        raise Interrupted(_PENDING_SIGNAL)


SCORED_ESTIMATES = ("t", "active", "vx", "vy", "yaw_rate", "beta", "Cf_y", "Cr_y", "Cx", "Cf_y_std", "Cr_y_std",
                    "Cx_std")
SCORED_REFERENCES = tuple(f"{pre}{n}{post}" for n in ("vx", "vy", "yaw_rate", "beta", "Cf_y", "Cr_y", "Cx",
                                                      "Cf_y_mean", "Cr_y_mean", "Cx_mean")
                          for pre, post in (("true_", ""), ("", "_true")))


def _scored(column: str) -> bool:
    """The Result-CSV columns `metrics.run_metrics` reads: the estimates it scores and their
    truth or reference columns."""
    return column in SCORED_ESTIMATES or column in SCORED_REFERENCES


class _ScoredStream:
    """The scored columns of the rows, gathered CHUNK rows at a time and handed to a
    `metrics.RunMetrics` chunk by chunk: a run's metrics in constant memory (one chunk of
    8192 rows, whatever the run's length)."""

    CHUNK = 8192

    def __init__(self, names: list[str], schedule=None):
        from tirefilter.metrics import RunMetrics

        self.names = names
        self.metrics = RunMetrics(names, schedule) if "t" in names else None
        self.buf = np.empty((len(names), self.CHUNK))  # a column per row of buf: contiguous for the metrics
        self.n = 0  # rows in buf
        self.index: np.ndarray | None = None

    def append(self, row, columns: tuple[str, ...]) -> None:
        if self.metrics is None:
            return
        if self.index is None:
            self.index = np.array([columns.index(c) for c in self.names], int)
        self.buf[:, self.n] = (row if isinstance(row, np.ndarray) else np.asarray(row, float)).take(self.index)
        self.n += 1
        if self.n == self.CHUNK:
            self.flush()

    def flush(self) -> None:
        if self.n:
            self.metrics.update({c: self.buf[j, :self.n] for j, c in enumerate(self.names)})
            self.n = 0

    def finalize(self, **counters) -> dict:
        """`RunMetrics.finalize` of the rows so far (the last partial chunk included)."""
        self.flush()
        return self.metrics.finalize(**counters)


class Progress:
    """A percentage bar on stderr (only when enabled, i.e. on a terminal)."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled, self._last = total, enabled, -1

    def update(self, k: int) -> None:
        if not self.enabled:
            return
        pct = int(100 * k / max(self.total, 1))
        if pct != self._last:
            self._last = pct
            bar = "#" * (pct // 4)
            sys.stderr.write(f"\r[{bar:<25}] {pct:3d}%")
            sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


class RunOutputs:
    """The sinks of one run's rows and the clock of its estimator steps.

    Every row goes to the Result CSV (written incrementally), the Rerun recording and,
    with `keep_rows`, a list in memory; `close` flushes what was handed over, so a run
    that fails keeps its rows up to the failure.
    """

    def __init__(self, columns: tuple[str, ...], *, results_csv: str | Path | None = None, rrd: str | Path | None = None,
                 estimator: str | None = None, keep_rows: bool = False, total: int = 0, progress: bool = False,
                 recording=None, context=None, schedule=None, metrics: bool = True):
        from tirefilter.io.results import ResultWriter
        from tirefilter.viz.options import recording_options

        self.columns = tuple(columns)
        self.recorder = None
        recording = recording_options(rrd, recording)  # viz.options.RecordingOptions: file, viewer, decimation
        if recording is not None:  # first: an unreachable viewer stops the run before a file is opened
            from tirefilter.viz.rerun_log import RerunRecorder

            self.recorder = RerunRecorder(recording, self.columns, estimator, context=context)
        self.writer = ResultWriter(results_csv, self.columns) if results_csv else None
        self.keep_rows = keep_rows
        self.kept: list[np.ndarray] = []  # with keep_rows, every row: blocks of KEEP_BLOCK rows (see kept_rows)
        self._kept_n = 0  # rows in the last block
        self.schedule = schedule  # the scenario (excitation windows, surface changes) of the settled metrics
        # what the metrics read (none without `metrics`: summary.metrics is then None)
        self.scored = _ScoredStream([c for c in self.columns if _scored(c)] if metrics else [], schedule)
        self.estimator: Estimator | None = None
        self.bar = Progress(total, progress)
        self.step_times = array("f")  # s, 4 bytes a step: an hour at 100 Hz is 1.4 MB
        self.rows = 0
        self.last: np.ndarray | None = None
        self.guard = None  # the estimator's measurement guard, once it has stepped

    def step(self, estimator: Estimator, t: float, u: Inputs, y: Measurement) -> Estimate:
        """`estimator.step(t, u, y)`, timed; the measurement first passes the estimator's
        guard (`estimator.guard`, estimators.guard), reset on the run's first step."""
        self.estimator = estimator
        guard = getattr(estimator, "guard", None)
        if guard is not None:
            if self.guard is None:
                self.guard = guard
                guard.reset()
            y = guard(t, y)
            if guard.after_gap and getattr(estimator, "t_start", None) is not None:
                estimator.t_start = t  # learning warms up again after a gap (estimators.guard)
        ts = time.perf_counter()
        est = estimator.step(t, u, y)
        self.step_times.append(time.perf_counter() - ts)
        if self.recorder:
            self.recorder.note_step(estimator, est)  # its posterior is logged with the row that follows
        return est

    def write(self, row) -> None:
        if self.writer:
            self.writer.write(row)
        if self.recorder:
            self.recorder.log_row(row)
        if self.keep_rows:
            if not self.kept or self._kept_n == KEEP_BLOCK:
                self.kept.append(np.empty((KEEP_BLOCK, len(self.columns))))
                self._kept_n = 0
            self.kept[-1][self._kept_n] = row
            self._kept_n += 1
        if self.estimator is not None:  # nothing to score without an estimator
            self.scored.append(row, self.columns)
        self.last = row
        self.rows += 1
        check_interrupt()  # at a row boundary: the row above is whole in every sink

    def progress(self, k: int) -> None:
        self.bar.update(k)

    def median_step_us(self) -> float | None:
        if not self.step_times:
            return None
        times = np.frombuffer(self.step_times, dtype=np.float32)
        return float(np.median(times[min(WARMUP_STEPS, len(times) - 1):]) * 1e6)

    def kept_rows(self) -> np.ndarray | None:
        """With keep_rows, the rows written, (rows, columns) float64; None without."""
        if not self.kept or not self.keep_rows:
            return None
        return np.concatenate(self.kept[:-1] + [self.kept[-1][:self._kept_n]])

    def metrics(self) -> dict | None:
        """`metrics.run_metrics` of the rows so far (streamed: `metrics.RunMetrics`), with the
        estimator's restart and resample counters (None before the first row)."""
        if not self.rows or self.estimator is None or self.scored.metrics is None:
            return None
        return self.scored.finalize(restarts=getattr(self.estimator, "restarts", None),
                                    resamples=getattr(self.estimator, "resamples", None),
                                    cx_excitation=getattr(self.estimator, "cx_weight_max", None))

    def close(self) -> None:
        """Close every sink, each even if one before it failed (the first error goes on)."""
        self.bar.close()
        try:
            if self.writer:
                self.writer.close()
        finally:
            if self.recorder:
                self.recorder.close()


@contextmanager
def run_outputs(summary: StepSummary, columns: tuple[str, ...], **options):
    """`RunOutputs(columns, **options)` for the body of a run, filling in `summary`.

    On leaving, whatever happened: the sinks are closed, and the summary gets the steps,
    the wall time and the median step time. An exception marks the summary failed, is
    given it as `exc.summary` (callers write the summary of a failed run too) and goes on;
    Interrupted marks it "interrupted" with the time of the last row written. A sink that
    fails to close (a full disk) fails a run that had not failed; after a failure or an
    interruption, its error is added to the summary's and the first exception goes on.
    """
    out = RunOutputs(columns, **options)
    t0 = time.perf_counter()
    pending = False  # an exception is leaving the body
    try:
        yield out
    except Interrupted as exc:
        pending = True
        summary.status = "interrupted"
        summary.error = str(exc)
        summary.t_reached = None if out.last is None else float(out.last[0])
        exc.summary = summary
        raise
    except Exception as exc:
        pending = True
        summary.status = "failed"
        summary.error = str(exc)
        exc.summary = summary
        raise
    except BaseException:  # KeyboardInterrupt, SystemExit outside `interruptible`: goes on as it is
        pending = True
        raise
    finally:
        try:
            out.close()
            close_error = None
        except Exception as exc:
            close_error = exc
        summary.wall_time_s = time.perf_counter() - t0
        summary.steps = out.rows
        summary.median_step_us = out.median_step_us()
        summary.metrics = out.metrics()
        if out.guard is not None:
            summary.guard = out.guard.counts()
        if close_error is not None:
            if pending:
                summary.error = (f"{summary.error}; closing the outputs failed too: {close_error}" if summary.error
                                 else f"closing the outputs failed: {close_error}")
            else:
                summary.status = "failed"
                summary.error = str(close_error)
                close_error.summary = summary
                raise close_error


def write_summary_json(path: str | Path, summary: StepSummary, *, command: list[str], model: str | None,
                       particles: int | None, estimator_config: dict, **extra) -> None:
    """The run summary JSON (docs/usage.md): version, command line, the summary's fields,
    model, N, the full estimator configuration, `extra`, and the platform."""
    record = {
        "version": __version__,
        "command": list(command),
        **dataclasses.asdict(summary),
        "model": model,
        "N": particles,
        "estimator_config": estimator_config,
        **extra,
        "python": platform.python_version(),
        "platform": platform.platform(),
    }
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(record, indent=2) + "\n")
