"""Replay of recorded logs: the first pass over a log (`stream`), its plausibility warnings
(`plausibility`), the summary of `tirefilter check-log` (`check`) and the replay loop (`run`).
The Log CSV itself (schema, reader, writer) is a file format: `tirefilter.io.log`, also
importable from here."""

from tirefilter.io.log import Log, read_log, write_log
from tirefilter.replay.check import LogSummary, check_log
from tirefilter.replay.run import ReplaySummary, replay_log, result_columns

__all__ = ["Log", "LogSummary", "ReplaySummary", "check_log", "read_log", "replay_log", "result_columns", "write_log"]
