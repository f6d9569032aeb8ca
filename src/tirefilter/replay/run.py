"""The replay: a recorded log as the sample source of the run loop (`runs.run`).

The co-simulation of `cosim.run` with the vehicle FMU replaced by the rows of a log:
`estimator.reset(rng)` with the generator `spawn_seeds(seed)` gives a co-simulation, then
`estimator.step(t, Inputs, Measurement)` for every row at the row's own time (the
estimator takes dt = t - t_prev itself, so irregular sampling and gaps pass through),
with missing samples passed on as NaN. The Result CSV has the estimate columns, then the
log's signals as `meas_<name>`, then its reference columns as `true_<name>` (scored by
`metrics.RunMetrics` into the summary).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tirefilter.errors import ReplayError
from tirefilter.estimators.base import Estimator, Inputs, Measurement
from tirefilter.io.log import SIGNALS, Log
from tirefilter.io.results import ESTIMATE_COLUMNS
from tirefilter.runs import KeptRows, Run, Sample, StepSummary, output_sinks, run, spawn_seeds


@dataclass(kw_only=True)
class ReplaySummary(StepSummary):
    log: str
    vehicle: str | None = None  # the vehicle TOML
    rows: int = 0  # rows of the log
    duration_s: float = 0.0  # time span of the log
    final: dict | None = None  # the last row's estimates (Result-CSV names; None for empty cells)


def result_columns(log: Log) -> tuple[str, ...]:
    """ESTIMATE_COLUMNS, then `meas_<name>` for each signal of the log, then the log's
    reference columns as `true_<name>` (`Log.references`)."""
    return ESTIMATE_COLUMNS + tuple(f"meas_{s}" for s in log.present) + tuple(log.references)


class LogSource:
    """The samples of a log (a Log, or a replay.stream.LogScan, which reads its file again
    chunk by chunk: memory does not grow with its length): a `runs.Sample` per row, k its
    0-based data row, NaN for a missing sample or a signal the log lacks, the row values
    the log's signals (`meas_`) and references (`true_`) as `result_columns` lists them."""

    def __init__(self, log):
        self.log = log
        self.chunk: Log | None = None  # the chunk of the sample handed out last

    def __iter__(self):
        present, references = self.log.present, tuple(self.log.references)
        for chunk in self.log.chunks():  # a Log is one chunk
            self.chunk = chunk
            data = np.column_stack([chunk.signals[s] for s in present] + [chunk.references[n] for n in references])
            sig = {s: chunk.signal(s).tolist() for s in SIGNALS}  # Python floats, as the co-simulation passes
            d, wf, wr, vx, ax, ay, r = (sig[s] for s in ("delta", "omega_f", "omega_r", "vx", "ax", "ay", "yaw_rate"))
            for k, t in enumerate(chunk.t.tolist()):
                yield Sample(chunk.row0 + k, t, Inputs(d[k], wf[k], wr[k], vx[k]), Measurement(ax[k], ay[k], r[k]),
                             (data[k],))

    def error(self, sample: Sample, estimator: str | None, exc: Exception) -> ReplayError:
        """The error of an estimator failing on `sample`: names the file, row, line and time."""
        return replay_error(self.chunk, sample.k - self.chunk.row0, sample.t, estimator, exc)


def replay_error(log: Log, k: int, t: float, estimator: str | None, exc: Exception) -> ReplayError:
    """The error of an estimator failing on row k of `log`: names the file, row, line and time."""
    where = log.where(k)
    return ReplayError(f"{log.path}: data row {where['row']} (file line {where['line']}, t = {t!r} s): "
                       f"{estimator} failed: {exc}")


class _FinalEstimates:
    """The sink that gives a finished replay's summary the last row's estimates (`final`)."""

    def __init__(self):
        self.last, self.finished = None, False

    def write(self, row) -> None:
        self.last = row

    def finish(self) -> None:
        self.finished = True

    def summarize(self, summary: ReplaySummary) -> None:
        if self.finished and self.last is not None:
            summary.final = {c: (None if math.isnan(v) else float(v))
                             for c, v in zip(ESTIMATE_COLUMNS, self.last[:len(ESTIMATE_COLUMNS)])}


def replay_log(
    log: Log,
    *,
    estimator: Estimator | None = None,
    seed: int = 0,
    results_csv: str | Path | None = None,
    rrd: str | Path | None = None,
    progress: bool | str = False,  # runs.Progress: True a bar, "lines" a line every few seconds
    keep_rows: bool = False,
    vehicle_file: str | Path | None = None,
    friction_csv: str | Path | None = None,
    recording=None,
    sinks=(),
) -> tuple[ReplaySummary, np.ndarray | None]:
    """Run `estimator` (None: the log's signals only) over `log` (a Log, or a
    replay.stream.LogScan, which streams its file); returns the summary and, with keep_rows,
    the result rows (n, len(result_columns(log))).

    The rows go to the sinks of `runs.output_sinks` (Result CSV, recording, friction CSV,
    metrics, progress bar), then to `sinks` (e.g. the command line's summary JSON). They are
    written incrementally: when the estimator fails, every row before the failure is in the
    CSV and the recording, and a ReplayError naming the row and its time is raised after the
    summary has been filled in (`summary.status = "failed"`, also as `exc.summary`). A
    friction estimator with `friction_csv` also writes its curve snapshots there
    (`io.friction`, no truth columns); those written before a failure stay. `recording`
    (viz.options.RecordingOptions) streams the replay to Rerun; `rrd` alone is a file-only
    recording.
    """
    from tirefilter.viz.options import RecordingContext

    _, rng = spawn_seeds(seed)  # the same generator a co-simulation with this seed gives its estimator
    est_name = getattr(estimator, "name", None) if estimator is not None else None
    columns = result_columns(log)
    summary = ReplaySummary(log=str(log.path), vehicle=str(vehicle_file) if vehicle_file else None, seed=seed,
                            estimator=est_name or "none", rows=log.rows, duration_s=log.duration,
                            results=str(results_csv) if results_csv else None)
    kept = KeptRows() if keep_rows else None
    outputs = output_sinks(columns, estimator, results_csv=results_csv, rrd=rrd, recording=recording,
                           context=RecordingContext(vehicle=getattr(estimator, "vehicle", None)),
                           friction_csv=friction_csv, progress=progress, total=log.rows)
    source = LogSource(log)
    final = [_FinalEstimates()] if estimator is not None else []
    stepper = Run(estimator, columns, [*outputs, *([kept] if kept else []), *final, *sinks],
                  on_error=lambda sample, exc: source.error(sample, est_name, exc))
    run(source, stepper, summary, rng=rng)
    return summary, kept.rows() if kept else None
