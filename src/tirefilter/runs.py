"""The run loop: a sample source drives an estimator, whose estimates go to sinks.

    source (Sample, Sample, ...)  ->  Run.step: guard, Estimator.step (timed), the row  ->  sinks

The sources are the vehicle FMU (`cosim.run.cosim_samples`), a recorded log
(`replay.run.LogSource`), the dashboard (a sample per tick) and the estimator FMU (the
samples of each FMI step). The sinks are the Result CSV (`io.results.ResultWriter`), the
Rerun recording (`viz.rerun_log.RerunRecorder`), the friction CSV (`io.friction.FrictionWriter`),
the run's metrics (`Metrics`), the rows kept in memory (`KeptRows`), the progress bar and the
run summary JSON (`SummaryJson`, docs/usage.md, "Run summary"). `run` is the loop of
`tirefilter run`, `replay` and the studies' trials; the dashboard and the FMU call `Run.step`.
Here too: the seed split (`spawn_seeds`), the run summary, and the SIGINT / SIGTERM handling
that ends a run at a row boundary (`interruptible`).
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
from tirefilter.io.results import ESTIMATE_COLUMNS, estimate_values

WARMUP_STEPS = 10  # steps left out of the median step time (first calls, caches)
KEEP_BLOCK = 4096  # rows kept in memory are gathered in float64 blocks of this many (KeptRows)
N_ESTIMATES = len(ESTIMATE_COLUMNS)  # the estimate columns that start every Result-CSV row


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
    metrics: dict | None = None  # metrics.RunMetrics of the rows written (run.json `metrics`)
    guard: dict | None = None  # samples the measurement guard marked missing (estimators.guard)
    model_check: dict | None = None  # the posterior-predictive check (model_check.PredictiveCheck.result)


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
    `Run.step` after every row, and between trials of a study) then raises
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


# ---- the samples and the run loop -------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Sample:
    """One sample of a source: what the estimator is given at t, and what the Result-CSV row
    carries after the estimates (`values`: 1-D float arrays, laid end to end; a co-simulation's
    FMU outputs and inputs, a log's signals and references)."""

    k: int  # index in the source, from 0
    t: float  # s
    inputs: Inputs
    meas: Measurement
    values: tuple = ()


class Run:
    """One estimator (None: none) stepped sample by sample, each sample's Result-CSV row
    handed to the sinks; what `run` loops over, and what the dashboard and the estimator FMU
    step themselves.

    A sink is any object with some of these methods, called in the order of `sinks`:
    `stepped(estimator, est)` (the estimator's step, whose row follows), `write(row)` (every
    row, a new float64 array each time: a sink may keep it), `finish()` (the source ran out:
    no failure, no interruption), `close()` (at the end, whatever happened) and
    `summarize(summary)` (the run's summary is complete: metrics, run.json).

    `on_error(sample, exc)` turns an exception of the estimator into the one to raise (it
    names the log row, the time, ...). `guard=False` leaves out the estimator's measurement
    guard (`estimator.guard`, estimators.guard), which is otherwise applied to every
    measurement and reset on the first step.
    """

    def __init__(self, estimator: Estimator | None, columns: tuple[str, ...], sinks=(), *, on_error=None,
                 guard: bool = True):
        self.estimator = estimator
        self.columns = tuple(columns)
        self.sinks = list(sinks)
        self.on_error = on_error
        self._use_guard = guard
        self.guard = None  # the estimator's measurement guard, once it has stepped
        self.est: Estimate | None = None  # the last estimate
        self.last: np.ndarray | None = None  # the last row
        self.rows = 0
        self.step_times = array("f")  # s, 4 bytes a step: an hour at 100 Hz is 1.4 MB
        self._hooks = {name: [getattr(s, name) for s in self.sinks if hasattr(s, name)]
                       for name in ("stepped", "write", "finish", "close", "summarize")}

    def step(self, sample) -> np.ndarray:
        """The estimator's step on `sample` (the guard first, timed), then its row to every
        sink; returns the row. Interrupted (`interruptible`) after the row, never inside it."""
        t = sample.t
        est = None
        if self.estimator is not None:
            try:
                est = self._step(t, sample.inputs, sample.meas)
            except Exception as exc:
                if self.on_error is None:
                    raise
                raise self.on_error(sample, exc) from exc
        row = np.empty(len(self.columns))
        row[:N_ESTIMATES] = estimate_values(t, est)
        j = N_ESTIMATES
        for v in sample.values:
            row[j:j + len(v)] = v
            j += len(v)
        if j != len(row):
            raise ValueError(f"a sample of {j - N_ESTIMATES} values for the {len(row) - N_ESTIMATES} columns "
                             "after the estimates")
        if self.estimator is not None:
            for stepped in self._hooks["stepped"]:
                stepped(self.estimator, est)
        for write in self._hooks["write"]:
            write(row)
        self.est, self.last = est, row
        self.rows += 1
        check_interrupt()  # at a row boundary: the row above is whole in every sink
        return row

    def _step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        estimator = self.estimator
        guard = getattr(estimator, "guard", None) if self._use_guard else None
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
        return est

    def median_step_us(self) -> float | None:
        """Median wall time of Estimator.step [us], the first WARMUP_STEPS left out."""
        if not self.step_times:
            return None
        times = np.frombuffer(self.step_times, dtype=np.float32)
        return float(np.median(times[min(WARMUP_STEPS, len(times) - 1):]) * 1e6)

    def finish(self) -> None:
        for finish in self._hooks["finish"]:
            finish()

    def close(self) -> None:
        """Close every sink, each even if one before it failed (the first error goes on)."""
        error = None
        for close in self._hooks["close"]:
            try:
                close()
            except Exception as exc:
                error = error or exc
        if error is not None:
            raise error

    def summarize(self, summary) -> None:
        for summarize in self._hooks["summarize"]:
            summarize(summary)


def run(samples, stepper: Run, summary: StepSummary, *, rng: np.random.Generator | None = None) -> StepSummary:
    """The run loop: `stepper.estimator.reset(rng)` (with an `rng`), `stepper.step` for every
    sample, then the sinks' `finish`; whatever happened, the sinks are closed, the summary
    gets the steps, the wall time and the median step time, and the sinks' `summarize`
    complete it (metrics, then the run.json of the command line, in the order of the sinks).

    An exception marks the summary failed, is given it as `exc.summary` (a caller can still
    report a failed run) and goes on; Interrupted marks it "interrupted" with the time of the
    last row written. A sink that fails to close (a full disk) fails a run that had not
    failed; after a failure or an interruption, its error is added to the summary's and the
    first exception goes on.
    """
    t0 = time.perf_counter()
    pending = False  # an exception is leaving the loop
    try:
        if rng is not None and stepper.estimator is not None:
            stepper.estimator.reset(rng)
        for sample in samples:
            stepper.step(sample)
        stepper.finish()
    except Interrupted as exc:
        pending = True
        summary.status = "interrupted"
        summary.error = str(exc)
        summary.t_reached = None if stepper.last is None else float(stepper.last[0])
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
            stepper.close()
            close_error = None
        except Exception as exc:
            close_error = exc
        summary.wall_time_s = time.perf_counter() - t0
        summary.steps = stepper.rows
        summary.median_step_us = stepper.median_step_us()
        if stepper.guard is not None:
            summary.guard = stepper.guard.counts()
        if close_error is not None:
            if pending:
                summary.error = (f"{summary.error}; closing the outputs failed too: {close_error}" if summary.error
                                 else f"closing the outputs failed: {close_error}")
            else:
                summary.status = "failed"
                summary.error = str(close_error)
                close_error.summary = summary
        stepper.summarize(summary)
        if close_error is not None and not pending:
            raise close_error
    return summary


# ---- sinks -------------------------------------------------------------------------------------------

def output_sinks(columns: tuple[str, ...], estimator, *, results_csv: str | Path | None = None,
                 rrd: str | Path | None = None, recording=None, context=None, friction_csv: str | Path | None = None,
                 friction_truth=None, metrics: bool = True, schedule=None, progress: bool | str = False,
                 total: int = 0) -> list:
    """The sinks of a run of the command line, in this order: the Rerun recording
    (`recording`, viz.options.RecordingOptions, or a file-only `rrd`; `context` what it draws
    besides the rows), the Result CSV, the friction CSV of a friction estimator (with
    `friction_truth(alpha, surface)` its truth columns), the run's metrics (`metrics`;
    scored against the `schedule`'s settled windows) and, with them, the model check of an
    estimator with a one-step predictive (`model_check.ModelCheck`), the progress over `total` rows
    (`Progress`: True a bar, "lines" a line every few seconds)."""
    from tirefilter.io.friction import FrictionWriter, is_friction_estimator
    from tirefilter.io.results import ResultWriter
    from tirefilter.model_check import ModelCheck, has_predictive
    from tirefilter.viz.options import recording_options

    sinks: list = []
    try:
        recording = recording_options(rrd, recording)  # file, viewer, decimation (None: no recording)
        if recording is not None:  # first: an unreachable viewer stops the run before a file is opened
            from tirefilter.viz.rerun_log import RerunRecorder

            sinks.append(RerunRecorder(recording, columns, getattr(estimator, "name", None), context=context))
        if results_csv:
            sinks.append(ResultWriter(results_csv, columns))
        if friction_csv and is_friction_estimator(estimator):
            sinks.append(FrictionWriter(friction_csv, estimator, truth=friction_truth, columns=columns))
        if metrics and estimator is not None:  # nothing to score without an estimator
            sinks.append(Metrics(columns, estimator, schedule))
            if has_predictive(estimator):
                sinks.append(ModelCheck(estimator))
        if progress:
            sinks.append(Progress(total, progress))
    except BaseException:
        for sink in sinks:
            sink.close()
        raise
    return sinks


class KeptRows:
    """Every row, kept in memory in float64 blocks of KEEP_BLOCK rows (a study's trials)."""

    def __init__(self):
        self.blocks: list[np.ndarray] = []
        self._n = 0  # rows in the last block

    def write(self, row) -> None:
        if not self.blocks or self._n == KEEP_BLOCK:
            self.blocks.append(np.empty((KEEP_BLOCK, len(row))))
            self._n = 0
        self.blocks[-1][self._n] = row
        self._n += 1

    def rows(self) -> np.ndarray | None:
        """The rows written, (rows, columns) float64; None before the first."""
        if not self.blocks:
            return None
        return np.concatenate(self.blocks[:-1] + [self.blocks[-1][:self._n]])


SCORED_ESTIMATES = ("t", "active", "vx", "vy", "yaw_rate", "beta", "Cf_y", "Cr_y", "Cx", "Cf_y_std", "Cr_y_std",
                    "Cx_std")
SCORED_REFERENCES = tuple(f"{pre}{n}{post}" for n in ("vx", "vy", "yaw_rate", "beta", "Cf_y", "Cr_y", "Cx",
                                                      "Cf_y_mean", "Cr_y_mean", "Cx_mean")
                          for pre, post in (("true_", ""), ("", "_true")))


def _scored(column: str) -> bool:
    """The Result-CSV columns `metrics.RunMetrics` reads: the estimates it scores and their
    truth or reference columns."""
    return column in SCORED_ESTIMATES or column in SCORED_REFERENCES


class Metrics:
    """The run's metrics (`metrics.RunMetrics`, run.json `metrics`): the scored columns of the
    rows, gathered CHUNK rows at a time and handed on chunk by chunk, so that they take
    constant memory (one chunk of 8192 rows, whatever the run's length); `summarize` adds
    the estimator's restart and resample counters and its own warnings (`run_warnings()`,
    where it has them) (`summary.metrics`, None before a row)."""

    CHUNK = 8192

    def __init__(self, columns: tuple[str, ...], estimator, schedule=None):
        from tirefilter.metrics import RunMetrics

        self.names = [c for c in columns if _scored(c)]
        self.estimator = estimator
        self.metrics = RunMetrics(self.names, schedule) if "t" in self.names else None
        self.index = np.array([columns.index(c) for c in self.names], int)
        self.buf = np.empty((len(self.names), self.CHUNK))  # a column per row of buf: contiguous for the metrics
        self.n = 0  # rows in buf
        self.rows = 0

    def write(self, row) -> None:
        self.rows += 1
        if self.metrics is None:
            return
        self.buf[:, self.n] = row.take(self.index)
        self.n += 1
        if self.n == self.CHUNK:
            self.flush()

    def flush(self) -> None:
        if self.n:
            self.metrics.update({c: self.buf[j, :self.n] for j, c in enumerate(self.names)})
            self.n = 0

    def summarize(self, summary) -> None:
        if not self.rows or self.metrics is None:
            return
        self.flush()
        summary.metrics = self.metrics.finalize(restarts=getattr(self.estimator, "restarts", None),
                                                resamples=getattr(self.estimator, "resamples", None),
                                                cx_excitation=getattr(self.estimator, "cx_weight_max", None))
        own = getattr(self.estimator, "run_warnings", None)  # an estimator's own (the GP-SSM's divergences)
        if callable(own):
            summary.metrics["warnings"] += own()


class Progress:
    """The run's progress on stderr over `total` rows: a percentage bar redrawn in place
    (`enabled` True: a terminal), or a line every LINE_EVERY_S seconds (`enabled` "lines":
    a log file or CI, where a bar redrawn in place is one endless line); nothing when off."""

    EVERY = 256  # rows
    LINE_EVERY_S = 5.0  # s between two progress lines

    def __init__(self, total: int, enabled: bool | str):
        self.total, self.enabled, self._last, self.rows = total, enabled, -1, 0
        self._t0 = self._line_at = time.perf_counter()

    def write(self, row) -> None:
        if self.rows % self.EVERY == 0:
            self.update(self.rows)
        self.rows += 1

    def update(self, k: int) -> None:
        if not self.enabled:
            return
        pct = int(100 * k / max(self.total, 1))
        if self.enabled == "lines":
            now = time.perf_counter()
            if now - self._line_at >= self.LINE_EVERY_S:
                self._line_at = now
                sys.stderr.write(f"progress: {pct}% ({k} of {self.total} rows) after {now - self._t0:.0f} s\n")
                sys.stderr.flush()
            return
        if pct != self._last:
            self._last = pct
            bar = "#" * (pct // 4)
            sys.stderr.write(f"\r[{bar:<25}] {pct:3d}%")
            sys.stderr.flush()

    def close(self) -> None:
        if self.enabled is True:
            sys.stderr.write("\n")


class SummaryJson:
    """The run summary JSON (`write_summary_json`), written once the summary is complete,
    whether the run succeeded, failed or was interrupted; `record()` gives the rest of its
    fields (command, model, N, the estimator's configuration, ...) at that moment."""

    def __init__(self, path: str | Path, record):
        self.path, self.record = Path(path), record

    def summarize(self, summary) -> None:
        write_summary_json(self.path, summary, **self.record())


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
