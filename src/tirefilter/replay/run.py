"""The replay loop: a recorded log -> estimator -> Result CSV (and Rerun recording).

The co-simulation master of `cosim.run` with the vehicle FMU replaced by the rows of a
log: `estimator.reset(rng)` with the generator `spawn_seeds(seed)` gives a co-simulation,
then `estimator.step(t, Inputs, Measurement)` for every row at the row's own time (the
estimator takes dt = t - t_prev itself, so irregular sampling and gaps pass through),
with missing samples passed on as NaN. The Result CSV has the estimate columns, then the
log's signals as `meas_<name>`, then its reference columns as `true_<name>` (scored by
`metrics.run_metrics` into the summary).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import closing, nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tirefilter.io.friction import FrictionWriter, is_friction_estimator
from tirefilter.io.results import ESTIMATE_COLUMNS, estimate_values
from tirefilter.errors import ReplayError
from tirefilter.estimators.base import Estimator, Inputs, Measurement
from tirefilter.io.log import SIGNALS, Log
from tirefilter.runs import StepSummary, run_outputs, spawn_seeds

PROGRESS_EVERY = 256  # rows


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


def log_samples(log: Log) -> Iterator[tuple[int, float, Inputs, Measurement]]:
    """(k, t, Inputs, Measurement) for every row of `log` (0-based k; NaN for a missing
    sample or a signal the log lacks): the samples `replay_log` gives its estimator."""
    sig = {s: log.signal(s).tolist() for s in SIGNALS}  # Python floats, as the co-simulation passes
    for k, t in enumerate(log.t.tolist()):
        yield (k, t,
               Inputs(delta=sig["delta"][k], omega_f=sig["omega_f"][k], omega_r=sig["omega_r"][k], vx=sig["vx"][k]),
               Measurement(ax=sig["ax"][k], ay=sig["ay"][k], yaw_rate=sig["yaw_rate"][k]))


def replay_error(log: Log, k: int, t: float, estimator: str | None, exc: Exception) -> ReplayError:
    """The error of an estimator failing on row k of `log`: names the file, row, line and time."""
    where = log.where(k)
    return ReplayError(f"{log.path}: data row {where['row']} (file line {where['line']}, t = {t!r} s): "
                       f"{estimator} failed: {exc}")


def replay_log(
    log: Log,
    *,
    estimator: Estimator | None = None,
    seed: int = 0,
    results_csv: str | Path | None = None,
    rrd: str | Path | None = None,
    progress: bool = False,
    keep_rows: bool = False,
    vehicle_file: str | Path | None = None,
    friction_csv: str | Path | None = None,
    recording=None,
) -> tuple[ReplaySummary, np.ndarray | None]:
    """Run `estimator` (None: the log's signals only) over `log` (a Log, or a
    replay.stream.LogScan, which streams its file: memory does not grow with its length);
    returns the summary and, with keep_rows, the result rows (n, len(result_columns(log))).

    Rows are written incrementally: when the estimator fails, every row before the
    failure is in the CSV and the recording, and a ReplayError naming the row and its time
    is raised after the summary has been filled in (`summary.status = "failed"`, also as
    `exc.summary`). A friction estimator with `friction_csv` also writes its curve
    snapshots there (`io.friction`, no truth columns); those written before a failure stay.
    `recording` (viz.options.RecordingOptions) streams the replay to Rerun; `rrd` alone is a
    file-only recording.
    """
    _, rng = spawn_seeds(seed)  # the same generator a co-simulation with this seed gives its estimator
    est_name = getattr(estimator, "name", None) if estimator is not None else None
    columns = result_columns(log)
    present, references = log.present, tuple(log.references)
    summary = ReplaySummary(log=str(log.path), vehicle=str(vehicle_file) if vehicle_file else None, seed=seed,
                            estimator=est_name or "none", rows=log.rows, duration_s=log.duration,
                            results=str(results_csv) if results_csv else None)
    from tirefilter.viz.options import RecordingContext

    friction = FrictionWriter(friction_csv, estimator) if friction_csv and is_friction_estimator(estimator) else None
    with closing(friction) if friction is not None else nullcontext(), \
            run_outputs(summary, columns, results_csv=results_csv, rrd=rrd, estimator=est_name, keep_rows=keep_rows,
                        total=log.rows, progress=progress, recording=recording,
                        context=RecordingContext(vehicle=getattr(estimator, "vehicle", None))) as out:
        if estimator is not None:
            estimator.reset(rng)
        for chunk in log.chunks():  # a Log is one chunk; a replay.stream.LogScan reads its file chunk by chunk
            data = np.column_stack([chunk.signals[s] for s in present] + [chunk.references[n] for n in references])
            for k, t, u, y in log_samples(chunk):
                est = None
                if estimator is not None:
                    try:
                        est = out.step(estimator, t, u, y)
                    except Exception as exc:
                        raise replay_error(chunk, k, t, est_name, exc) from exc
                if friction is not None:
                    friction.sample(t)
                out.write(np.concatenate([estimate_values(t, est), data[k]]))
                if (chunk.row0 + k) % PROGRESS_EVERY == 0:
                    out.progress(chunk.row0 + k)
        if friction is not None:
            friction.finish()
        if out.last is not None and estimator is not None:
            summary.final = {c: (None if math.isnan(v) else float(v))
                             for c, v in zip(ESTIMATE_COLUMNS, out.last[:len(ESTIMATE_COLUMNS)])}
    return summary, out.kept_rows()

