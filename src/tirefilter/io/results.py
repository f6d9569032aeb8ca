"""The Result CSV (docs/usage.md, "Results table"), written incrementally so a failed run keeps its rows."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tirefilter.io import csv_format
from tirefilter.io.csv_format import HEADER, format_rows
from tirefilter.estimators.base import Estimate

ESTIMATE_COLUMNS = (
    "t", "active", "vx", "vy", "yaw_rate", "beta",
    "Cf_y", "Cr_y", "Cx", "Cf_y_std", "Cr_y_std", "Cx_std", "Cf_y_sigma", "Cr_y_sigma", "Cx_sigma",
    "b_ax", "b_ay", "b_yaw_rate", "ess", "roll_gradient", "roll_gradient_std",
)
INPUT_TRUTH_COLUMNS = ("true_delta", "true_drive_torque", "true_brake_torque", "true_surface", "true_bank")


def truth_column(fmu_output: str) -> str:
    """Result-CSV column of a vehicle-FMU output: sensors get `meas_`, truth `true_`."""
    if fmu_output.startswith("true_"):
        return fmu_output
    if fmu_output.endswith("_meas"):
        return "meas_" + fmu_output[: -len("_meas")]
    return "true_" + fmu_output


def result_columns(fmu_outputs) -> tuple[str, ...]:
    """The Result-CSV header of a co-simulation: estimates, FMU outputs, FMU inputs."""
    return ESTIMATE_COLUMNS + tuple(truth_column(n) for n in fmu_outputs) + INPUT_TRUTH_COLUMNS


def estimate_values(t: float, est: Estimate | None) -> list[float]:
    """The estimate part of a row (NaN where there is no estimate)."""
    if est is None:
        return [t] + [math.nan] * (len(ESTIMATE_COLUMNS) - 1)
    return [
        t, 1.0 if est.active else 0.0, est.vx, est.vy, est.yaw_rate, est.beta,
        est.Cf_y, est.Cr_y, est.Cx, est.Cf_y_std, est.Cr_y_std, est.Cx_std,
        est.Cf_y_sigma, est.Cr_y_sigma, est.Cx_sigma, est.b_ax, est.b_ay, est.b_yaw_rate, est.ess,
        est.roll_gradient, est.roll_gradient_std,
    ]


BACKGROUND_AFTER_ROWS = 2000  # rows formatted here before a longer run hands its rows to a helper process


class ResultWriter:
    """Appends rows to a CSV, flushing to disk every `flush_every` rows and on close.

    Used as a context manager: whatever happens inside, the rows handed over so far end
    up in the file. Rows are gathered as float64 in a block of `flush_every` rows; each
    full block is formatted (`csv_format.format_rows`: `repr` of every value, NaN empty)
    and written. With `background` (the default), once a run has written
    BACKGROUND_AFTER_ROWS rows the blocks go as raw bytes to a helper process
    (`csv_format.py`) that formats and appends them, so a long run's formatting runs on
    another core; `close` waits for it, and the file is the same byte for byte.
    """

    def __init__(self, path: str | Path, columns: tuple[str, ...], flush_every: int = 100, background: bool = True):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns = tuple(columns)
        self._file = self.path.open("w", newline="")
        self._file.write(",".join(self.columns) + "\n")
        self._flush_every = max(1, int(flush_every))
        self._block = np.empty((self._flush_every, len(self.columns)))
        self._n = 0  # rows in the block
        self._background = background
        self._child = None  # the helper process, once started
        self.rows = 0

    def write(self, values) -> None:
        if len(values) != len(self.columns):
            raise ValueError(f"row has {len(values)} values for {len(self.columns)} columns")
        self._block[self._n] = values
        self._n += 1
        self.rows += 1
        if self._n == self._flush_every:
            self.flush()

    def flush(self) -> None:
        """Hand the rows gathered so far on: formatted here and written to disk, or sent to
        the helper process (which writes each block as it arrives)."""
        if self._child is None and self._background and self.rows >= BACKGROUND_AFTER_ROWS and not self._file.closed:
            self._start_child()
        block, self._n = self._block[:self._n], 0
        if self._child is not None:
            if len(block):
                self._send(block.tobytes())
            return
        if len(block):
            self._file.write(format_rows(block.tolist()))
        self._file.flush()

    def _start_child(self) -> None:
        import subprocess
        import sys

        # an embedded interpreter (sys.executable empty, or the host application): no Python to start
        if not Path(sys.executable or "").name.lower().startswith(("python", "pypy")):
            self._background = False
            return
        self._file.close()  # the helper appends after what is there
        try:
            self._child = subprocess.Popen([sys.executable, "-I", "-S", csv_format.__file__, str(self.path),
                                            str(len(self.columns))], stdin=subprocess.PIPE, stderr=subprocess.PIPE,
                                           start_new_session=True)
        except BaseException as exc:  # no helper: the rows are formatted here, as in a short run
            self._background = False
            self._file = self.path.open("a", newline="")
            if not isinstance(exc, OSError):  # (an interrupt still goes up; the rows stay to be written)
                raise

    def _send(self, data: bytes) -> None:
        try:
            self._child.stdin.write(HEADER.pack(len(data)) + data)
        except (BrokenPipeError, OSError):
            self._finish_child()  # raises with the helper's error
            raise OSError(f"writing {self.path}: the formatting process stopped") from None

    def _finish_child(self) -> None:
        child, self._child = self._child, None
        try:
            child.stdin.close()
        except OSError:
            pass
        err = child.stderr.read().decode("utf-8", "replace").strip()
        child.stderr.close()
        if child.wait() != 0:
            raise OSError(f"writing {self.path} failed (exit status {child.returncode}): {err.splitlines()[-1:]}")

    def close(self) -> None:
        if self._child is not None:
            self.flush()
            self._finish_child()
        elif not self._file.closed:
            self.flush()
            self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_results(path: str | Path, max_rows: int | None = None, columns=None) -> dict[str, np.ndarray]:
    """Read a Result CSV into columns of floats (empty cells are NaN); `max_rows`: only
    the first rows; `columns`: only these (those the file has), parsed from text only
    where named (much faster than the whole table when a few are wanted)."""
    if columns is not None:
        return next(iter_results(path, chunk_rows=max_rows, columns=columns), None) or _no_rows(path, columns)
    path = Path(path)
    with path.open() as f:
        header = f.readline().strip().split(",")
        data = np.genfromtxt(f, delimiter=",", dtype=float, ndmin=2, max_rows=max_rows)
    if data.size == 0:
        data = np.empty((0, len(header)))
    return {name: data[:, j] for j, name in enumerate(header)}


def _no_rows(path, columns) -> dict[str, np.ndarray]:
    with Path(path).open() as f:
        header = f.readline().strip().split(",")
    return {name: np.empty(0) for name in columns if name in header}


def iter_results(path: str | Path, chunk_rows: int | None = 8192, columns=None):
    """A Result CSV chunk by chunk: dicts of columns of floats (empty cells are NaN), at
    most `chunk_rows` rows each (None: one chunk of every row), so that a long run's table
    is summarised in constant memory. `columns`: only these (those the file has); the
    other cells are not converted."""
    import csv

    with Path(path).open(newline="") as f:
        reader = csv.reader(f)
        header = next(reader, None) or []
        names = header if columns is None else [c for c in columns if c in header]
        index = [header.index(c) for c in names]
        rows: list[list[str]] = []

        def chunk():
            if columns is None:
                data = np.array([[float(c) if c else math.nan for c in r] for r in rows], float).reshape(-1, len(header))
            else:
                data = np.array([[float(r[j]) if r[j] else math.nan for j in index] for r in rows],
                                float).reshape(-1, len(index))
                return {name: data[:, j] for j, name in enumerate(names)}
            return {name: data[:, j] for j, name in enumerate(header)}

        for row in reader:
            if row:
                rows.append(row)
            if chunk_rows is not None and len(rows) >= chunk_rows:
                yield chunk()
                rows = []
        if rows:
            yield chunk()
