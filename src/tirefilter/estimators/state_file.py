"""The learned stiffness posterior on disk (`--save-state` / `--init-state`): one JSON
file per drive, checked against the format version and the vehicle on load."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from tirefilter import __version__
from tirefilter.errors import ConfigError

FORMAT = "tirefilter-stiffness-state"
FORMAT_VERSION = 1


def _vehicle_record(vehicle) -> dict:
    return {k: v for k, v in dataclasses.asdict(vehicle).items() if not (isinstance(v, float) and math.isnan(v))}


def save_state(estimator, path: str | Path) -> Path:
    """Write the estimator's learned stiffness posterior (see StiffnessMPF.learned_state)."""
    if not hasattr(estimator, "learned_state"):
        raise ConfigError("--save-state", "", f"estimator {getattr(estimator, 'name', estimator)!r} has no "
                          "learned stiffness posterior to save")
    record = {"format": FORMAT, "format_version": FORMAT_VERSION, "tirefilter": __version__,
              "estimator": estimator.name, "vehicle": _vehicle_record(estimator.vehicle)}
    record.update(estimator.learned_state())
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record) + "\n")
    return path


def load_state(estimator, path: str | Path) -> None:
    """Make the estimator's next reset start from the posterior saved in `path`.

    Errors name the file and what does not match: not a state file, another format
    version, another vehicle (the differing keys), another parameter set."""
    path = Path(path)
    if not hasattr(estimator, "carry_over"):  # also estimator None (`--estimator none`)
        raise ConfigError("--init-state", "", f"estimator {getattr(estimator, 'name', estimator)!r} cannot start "
                          "from a saved stiffness posterior")
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(path, "", "no such state file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(path, "", f"not a readable state file ({exc})") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise ConfigError(path, "format", f"not a {FORMAT} file")
    if record.get("format_version") != FORMAT_VERSION:
        raise ConfigError(path, "format_version", f"saved in format version {record.get('format_version')!r} "
                          f"(by tirefilter {record.get('tirefilter')}); this is tirefilter {__version__}, which "
                          f"reads version {FORMAT_VERSION}")
    saved, current = record.get("vehicle", {}), _vehicle_record(estimator.vehicle)
    if not isinstance(saved, dict):
        raise ConfigError(path, "vehicle", f"expected a table of the vehicle's parameters, got {saved!r}")
    # a key the saved file predates counts as its default (a vehicle key added since, e.g. relaxation_length)
    defaults = {f.name: f.default for f in dataclasses.fields(estimator.vehicle)
                if f.default is not dataclasses.MISSING}
    differ = sorted(k for k in set(saved) | set(current) if saved.get(k, defaults.get(k)) != current.get(k))
    if differ:
        detail = ", ".join(f"{k}: saved {saved.get(k)!r}, now {current.get(k)!r}" for k in differ[:6])
        raise ConfigError(path, "vehicle", f"saved for a different vehicle ({detail})")
    estimator.carry_over(record, source=str(path))
