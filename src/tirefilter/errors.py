"""Errors that reach the user: each names what is wrong and where."""

from __future__ import annotations


class TirefilterError(Exception):
    """Base class: a problem the user can fix, shown without a traceback by the CLI."""


class ConfigError(TirefilterError):
    """A malformed scenario, vehicle or configuration file: names file, key and expectation."""

    def __init__(self, file, key: str, problem: str):
        self.file, self.key, self.problem = str(file), key, problem
        where = f"{self.file}: {key}" if key else self.file
        super().__init__(f"{where}: {problem}")


class FMUError(TirefilterError):
    """The vehicle FMU is missing or failed while running."""


class LogError(TirefilterError):
    """A recorded log (replay input) that cannot be used: names the file and, where they
    apply, the column, the data row (1-based, the header not counted) with its file line,
    and the offending value."""

    def __init__(self, file, problem: str, *, column: str | None = None, row: int | None = None,
                 line: int | None = None, value=None):
        self.file, self.problem, self.column, self.row, self.line, self.value = str(file), problem, column, row, line, value
        where = [self.file]
        if column is not None:
            where.append(f"column {column!r}")
        if row is not None:
            where.append(f"data row {row}" + (f" (file line {line})" if line is not None else ""))
        elif line is not None:
            where.append(f"file line {line}")
        super().__init__(f"{', '.join(where)}: {problem}")


class ReplayError(TirefilterError):
    """The estimator failed on a row of a log: names the file, the row, its time and the cause."""
