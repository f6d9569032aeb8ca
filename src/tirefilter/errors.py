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
