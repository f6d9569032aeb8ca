"""Reading TOML files with checks that name the file, the key and what was expected."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

from tirefilter.errors import ConfigError

_MISSING = object()


def read_toml(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, "", "file not found")
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(path, "", f"not valid TOML ({exc})") from None
    except UnicodeDecodeError as exc:  # (TOML is UTF-8; tomllib lets the decoding error through)
        raise ConfigError(path, "", f"not valid TOML (not UTF-8: {exc})") from None


def _missing(file, name: str, default: Any, expected: str) -> Any:
    """The value of an absent key: its default, or an error when it has none."""
    if default is _MISSING:
        raise ConfigError(file, name, f"missing (expected {expected})")
    return default


def get_number(
    table: dict,
    key: str,
    file,
    *,
    prefix: str = "",
    default: Any = _MISSING,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    integer: bool = False,
):
    """A finite number from `table[key]` within [lo, hi] ((lo, hi] with lo_open)."""
    name = f"{prefix}{key}"
    if key not in table:
        return _missing(file, name, default, "a number")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(file, name, f"expected {'an integer' if integer else 'a number'}, got {value!r}")
    if integer and not isinstance(value, int):
        raise ConfigError(file, name, f"expected an integer, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(file, name, f"expected a finite number, got {value!r}")
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise ConfigError(file, name, f"{value!r} is out of range: expected {'>' if lo_open else '>='} {lo}"
                          + (f" and <= {hi}" if hi is not None else ""))
    if hi is not None and value > hi:
        raise ConfigError(file, name, f"{value!r} is out of range: expected <= {hi}")
    return int(value) if integer else float(value)


def get_choice(table: dict, key: str, file, choices: tuple[str, ...], *, prefix: str = "", default: Any = _MISSING):
    name = f"{prefix}{key}"
    if key not in table:
        return _missing(file, name, default, f"one of {', '.join(choices)}")
    value = table[key]
    if value not in choices:
        raise ConfigError(file, name, f"expected one of {', '.join(choices)}, got {value!r}")
    return value


def get_table(table: dict, key: str, file, *, prefix: str = "", default: Any = _MISSING) -> dict:
    name = f"{prefix}{key}"
    if key not in table:
        return _missing(file, name, default, "a table")
    value = table[key]
    if not isinstance(value, dict):
        raise ConfigError(file, name, f"expected a table, got {type(value).__name__}")
    return value


def check_known_keys(table: dict, known: set[str], file, *, prefix: str = "") -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(file, f"{prefix}{unknown[0]}", f"unknown key (known: {', '.join(sorted(known))})")
