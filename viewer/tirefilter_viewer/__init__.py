"""The tirefilter dashboard: a small viser web app (`tirefilter dashboard`) that runs a
scenario or replays a log with a chosen estimator and shows the filter live, or shows a
Result CSV written earlier."""

from tirefilter_viewer.app import DEFAULT_HOST, DEFAULT_PORT, Dashboard, serve
from tirefilter_viewer.session import LiveRun, Settings

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "Dashboard", "LiveRun", "Settings", "serve"]
