"""Replay of recorded logs: the Log CSV reader and its checks (`log`), the summary of
`tirefilter check-log` (`check`), and the replay loop (`run`)."""

from tirefilter.replay.check import LogSummary, check_log
from tirefilter.replay.log import Log, read_log, write_log
from tirefilter.replay.run import ReplaySummary, replay_log, result_columns

__all__ = ["Log", "LogSummary", "ReplaySummary", "check_log", "read_log", "replay_log", "result_columns", "write_log"]
