"""The dashboard's data root: every path typed in the page (Log CSV, vehicle TOML, scenario
TOML, Result CSV) must lie inside one folder (`tirefilter dashboard --data-dir`, default the
working directory). With `--host 0.0.0.0` anyone who reaches the port types those paths,
so the server must not read anything else the user can read.

A path is refused when it names a parent (`..`), when it is absolute and not inside the
root, or when it resolves (symlinks followed) to a place outside the root; what comes back
is the resolved path, so a symlink cannot be swapped between the check and the read of
something else outside.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from tirefilter.errors import ConfigError


class DataRoot:
    """Resolves the page's paths inside `root` (see the module docstring)."""

    def __init__(self, root: str | Path | None = None):
        root = Path.cwd() if root is None else Path(root)
        if not root.is_dir():
            raise ConfigError("--data-dir", "", f"{root} is not a directory")
        self.root = root.resolve()

    def resolve(self, typed: str, what: str) -> Path:
        """The path `typed` in the field `what`, inside the root; ConfigError (shown in the
        page) when it is empty or leads outside."""
        text = str(typed).strip()
        if not text:
            raise ConfigError("dashboard", what, "no path given")
        if "\x00" in text:
            raise ConfigError("dashboard", what, "the path holds a NUL character")
        path = Path(text)
        if ".." in path.parts:
            raise ConfigError("dashboard", what, f"{text!r}: '..' is not allowed; give a path inside the data "
                              f"directory {self.root} (tirefilter dashboard --data-dir)")
        lexical = path if path.is_absolute() else self.root / path
        real = lexical.resolve()
        if not real.is_relative_to(self.root):
            how = " through a symlink" if lexical.is_relative_to(self.root) else ""
            raise ConfigError("dashboard", what, f"{text!r} leads outside the data directory {self.root}{how} "
                              f"(tirefilter dashboard --data-dir)")
        return real

    def inside(self, path: str | Path) -> bool:
        """Whether `path` (symlinks followed) lies inside the root."""
        return Path(path).resolve().is_relative_to(self.root)

    def settings(self, s):
        """The page's Settings with their file paths resolved inside the root (a scenario
        given by name, not as a .toml file, stays a name)."""
        changes = {}
        if s.source == "log":
            changes["log"] = str(self.resolve(s.log, "Log CSV"))
            changes["vehicle"] = str(self.resolve(s.vehicle, "vehicle TOML"))
        elif str(s.scenario).strip().endswith(".toml"):
            changes["scenario"] = str(self.resolve(s.scenario, "scenario"))
        return dataclasses.replace(s, **changes)
