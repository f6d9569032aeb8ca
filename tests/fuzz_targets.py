"""Property-based fuzzing of the readers (hypothesis): the Log CSV reader, the vehicle,
scenario and configuration TOML readers and the state-file reader. The property: any input
gives a result or the error it deserves, never another exception (a traceback):
- a Log CSV: a LogError naming the file; for a file that is not UTF-8 CSV, or whose header,
  row lengths or columns are wrong, the message of that problem (the reader's first pass done
  here independently, `log_first_pass`); for a bad cell, the column, data row, file line and
  value of a cell that has that problem. A log that reads has, in every column, the cells'
  numbers (NaN for an empty one). `check_log` gives the same error, `scan_log` in chunks fails
  where `read_log` does;
- a TOML file: a ConfigError naming the file; "not valid TOML" exactly where tomllib cannot
  read it; otherwise a key of the file's tables (or one it lacks, "missing");
- a state file: a ConfigError naming the file, for the key whose value is wrong.

Shared by tests/test_fuzz.py (a bounded CI run) and tools/fuzz.py (a long run).
Each target takes a `tmp` folder and hypothesis data and checks one input.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
import tomllib
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from tirefilter.errors import ConfigError, LogError, TirefilterError

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "src/tirefilter/scenarios/data"
VEHICLE_FILE = DATA / "vehicles" / "midsize-suv.toml"
SCENARIO_FILE = DATA / "paper-sim.toml"

# -- values -----------------------------------------------------------------------------------
numbers = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([0, 1, -1, 0.0, 1e-300, 1e300, 0.5, 2.0, 1e5]))
scalars = st.one_of(numbers, st.booleans(), st.text(max_size=12), st.sampled_from(["front", "rear", "all", "linear",
                                                                                   "pacejka", "snow", "normal"]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                      max_leaves=8)


def _toml_key(k: str) -> str:
    return json.dumps(k)  # a quoted key is always valid TOML


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def to_toml(data: dict) -> str:
    """TOML text of a dict (scalars and arrays first, then one [table] per dict value)."""
    lines = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(f"[{_toml_key(k)}]")
            lines += [f"{_toml_key(kk)} = {_toml_value(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


@st.composite
def mutated(draw, base: dict, depth: int = 2):
    """`base` with keys removed, values replaced by arbitrary ones and unknown keys added."""
    out = {}
    for k, v in base.items():
        action = draw(st.sampled_from(["keep", "keep", "keep", "drop", "replace"] + (["recurse"] if isinstance(v, dict)
                                                                                      and depth else [])))
        if action == "keep":
            out[k] = v
        elif action == "replace":
            out[k] = draw(values)
        elif action == "recurse":
            out[k] = draw(mutated(v, depth - 1))
    if draw(st.booleans()):
        out[draw(st.text(min_size=1, max_size=8))] = draw(values)
    return out


def expect_error(call, cls: type[TirefilterError], file):
    """Run `call`; only an error of class `cls` (the project's error for this reader) that names
    `file` may come out of it (it is returned)."""
    try:
        return call()
    except TirefilterError as exc:
        assert isinstance(exc, cls), f"{type(exc).__name__} where a {cls.__name__} is due: {exc}"
        assert exc.file == str(file) and str(exc).startswith(str(file)), f"the error names {exc.file!r}, not {file}"
        return exc


def _write(tmp: Path, name: str, content) -> Path:
    path = tmp / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8", errors="replace"))
    return path


# -- Log CSV ----------------------------------------------------------------------------------
LOG_COLUMNS = ("t", "delta", "steering_wheel_angle", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r", "omega_fl",
               "omega_fr", "omega_rl", "omega_rr", "beta_true", "other")
cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers(-5, 100).map(str),
                  st.sampled_from(["", "  ", "nan", "NaN", "inf", "-inf", " 1.5 ", "1e400", "abc", "1,5", '"2"', "0x10",
                                   "\u00e9", ";", "1;2"]),
                  st.text(max_size=5))


numeric_cells = st.one_of(st.floats(-100, 100).map(repr), st.integers(-5, 100).map(str),
                          st.sampled_from(["", "  ", "nan", " 1.5 "]))
SOUND_HEADERS = (("t", "delta", "ax", "ay", "yaw_rate", "vx"),
                 ("t", "steering_wheel_angle", "ax", "ay", "yaw_rate", "omega_f", "omega_r"),
                 ("t", "delta", "ax", "ay", "yaw_rate", "omega_fl", "omega_fr", "omega_rl", "omega_rr"))


@st.composite
def log_texts(draw) -> bytes:
    """A Log CSV's bytes. Half of them wild: a random header, rows of random cells (some
    short), separators and encodings of other programs, or random bytes. The other half sound
    in structure (every required column, comma-separated UTF-8, whole rows), their cells
    random or, three times in four, numbers and missing cells only, so that many logs read and every
    column's numbers are checked. The time column mostly increases."""
    sound = draw(st.booleans())
    header = draw(st.lists(st.sampled_from(LOG_COLUMNS), min_size=0, max_size=9))
    if sound:
        header = list(dict.fromkeys([*draw(st.sampled_from(SOUND_HEADERS)), *header[:3]]))
    elif draw(st.booleans()):
        header = list(dict.fromkeys(header))  # mostly without duplicates
    n = draw(st.integers(0, 12))
    t0, dt = draw(st.floats(-5, 5)), draw(st.sampled_from([0.01, 0.0, -0.01, 1.0, 0.01, 0.01]))
    some = numeric_cells if sound and draw(st.integers(0, 3)) else cells
    rows = []
    for k in range(n):
        row = [repr(t0 + k * dt) if h == "t" and draw(st.integers(0, 9)) else draw(some) for h in header]
        if not sound and draw(st.integers(0, 19)) == 0:
            row = row[:-1] if row else ["x"]  # a short row
        rows.append(row)
    sep = "," if sound else draw(st.sampled_from([",", ",", ",", ";", "\t"]))
    text = sep.join(header) + "\n" + "\n".join(sep.join(r) for r in rows) + ("\n" if draw(st.booleans()) else "")
    encoding = draw(st.sampled_from(["utf-8", "utf-8-sig"] + ([] if sound else ["latin-1"])))
    raw = text.encode(encoding, errors="replace")
    if not sound and draw(st.integers(0, 4)) == 0:
        raw = draw(st.binary(max_size=64))
    return raw


def log_first_pass(raw: bytes) -> str | tuple:
    """The Log CSV's structure, read here without the reader: (header, [(file line, cells)]) of
    its data rows (blank lines skipped), or the problem that the reader must report before any
    cell is parsed, in the reader's order: not UTF-8 / not CSV, an empty header, a column named
    twice, a row of another length, no data rows, a required column missing. (A fuzzed file
    is far below the reader's 8 KB read-ahead, so a bad byte anywhere fails the first read.)"""
    from tirefilter.io.log import CORNERS, REQUIRED, STEERING

    try:  # (Python's text layer: a lone b"\xef", a BOM cut short, reads as nothing)
        text = io.TextIOWrapper(io.BytesIO(raw), encoding="utf-8-sig", newline="").read()
    except UnicodeDecodeError:
        return "cannot be read as a CSV file"
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader, None)
        if not header or not any(h.strip() for h in header):
            return "empty file"
        header = tuple(h.strip() for h in header)
        if len(set(header)) < len(header):
            return "more than once"
        rows = []
        for row in reader:
            if not row or (len(row) == 1 and not row[0].strip()):
                continue
            if len(row) != len(header):
                return "cells for the header's"
            rows.append((reader.line_num, row))
    except csv.Error:
        return "cannot be read as a CSV file"
    if not rows:
        return "no data rows after the header"
    have = set(header)
    speed = "vx" in have or all(a in have or set(CORNERS[a]) <= have for a in CORNERS)
    if not (set(REQUIRED) <= have and have & set(STEERING) and speed):
        return "missing required column"
    return header, rows


def _number(cell: str) -> float:
    return float(cell) if cell.strip() else math.nan


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _check_log_cells(log, header: tuple, rows: list) -> None:
    """A log that reads: every known and reference column holds its cells' numbers (NaN for an
    empty cell), time is finite and increases, no signal is infinite."""
    from tirefilter.io.log import reference_name

    assert log.header == header and list(log.lines) == [line for line, _ in rows]
    for j, name in enumerate(header):
        ref = reference_name(name)
        x = log.references.get(ref) if ref else log.columns.get(name)
        if x is None:
            assert name in log.ignored, name
            continue
        cells = np.array([_number(r[j]) for _, r in rows])
        nan = np.isnan(cells)
        assert np.array_equal(np.isnan(x), nan) and np.array_equal(x[~nan], cells[~nan]), name
    assert np.isfinite(log.t).all() and np.all(np.diff(log.t) > 0)
    for name, x in log.signals.items():
        assert not np.isinf(x).any(), name


def _check_log_cell_error(exc, header: tuple, rows: list, need_steering_ratio: bool) -> None:
    """An error of a log whose structure is sound: it names a column, data row, file line and
    value that have the problem it states."""
    from tirefilter.io.log import VX_REVERSE_TOL

    p, k = exc.problem, None if exc.row is None else exc.row - 1
    if k is not None:
        assert 0 <= k < len(rows) and exc.line == rows[k][0], (exc, len(rows))
    cell = rows[k][1][header.index(exc.column)] if k is not None and exc.column in header else None
    if p.endswith("is not a finite number"):
        assert cell == exc.value and math.isinf(float(cell)), exc
    elif p.endswith("is not a number"):
        assert cell == exc.value and cell.strip() and not _is_number(cell), exc
    elif p.startswith("missing time"):
        assert exc.column == "t" and math.isnan(_number(cell)), exc
    elif p.startswith("time must increase strictly"):
        before = _number(rows[k - 1][1][header.index("t")])
        assert exc.column == "t" and k >= 1 and exc.value == _number(cell) and not _number(cell) > before, exc
    elif "reverse driving" in p:
        assert exc.column == "vx" and exc.value == _number(cell) < -VX_REVERSE_TOL, exc
    elif "converting the steering-wheel angle needs steering_ratio" in p:
        assert need_steering_ratio and "delta" not in header and exc.column == "steering_wheel_angle", exc
    elif p.startswith("two reference columns"):
        name = exc.column[len("true_"):] if exc.column.startswith("true_") else exc.column[:-len("_true")]
        assert {f"true_{name}", f"{name}_true"} <= set(header), exc
    else:
        raise AssertionError(f"an error this log does not deserve: {exc}")


def fuzz_log(tmp: Path, raw: bytes, gz: bool, vehicle: bool) -> None:
    from tirefilter.replay import check_log, read_log
    from tirefilter.replay.stream import scan_log

    path = tmp / ("log.csv.gz" if gz else "log.csv")
    path.write_bytes(gzip.compress(raw) if gz else raw)
    v = str(VEHICLE_FILE) if vehicle else None
    first = log_first_pass(raw)
    log = expect_error(lambda: read_log(path, v, need_steering_ratio=vehicle), LogError, path)
    if isinstance(first, str):
        assert isinstance(log, LogError) and first in log.problem, (first, log)
    elif isinstance(log, LogError):
        _check_log_cell_error(log, *first, vehicle)
    else:
        _check_log_cells(log, *first)
    summary = expect_error(lambda: check_log(path, v), LogError, path)
    if isinstance(log, LogError):
        assert isinstance(summary, LogError) and str(summary) == str(log)
    elif isinstance(summary, LogError):
        assert summary.problem.startswith("no model can run on this log"), summary
    if vehicle:  # the streamed first pass of a replay fails where the whole-file reader does
        scan = expect_error(lambda: scan_log(path, v, chunk_rows=3), LogError, path)
        assert isinstance(scan, LogError) == isinstance(log, LogError), (scan, log)


# -- TOML readers -----------------------------------------------------------------------------
def base_vehicle() -> dict:
    return tomllib.loads(VEHICLE_FILE.read_text())


def base_scenario() -> dict:
    data = tomllib.loads(SCENARIO_FILE.read_text())
    data["vehicle"] = str(VEHICLE_FILE)
    data["faults"] = [{"kind": "spike", "signal": "ay", "size": 20.0, "times": [1.0]},
                      {"kind": "dropout", "signal": "ax", "rate": 0.2, "start": 0.0, "end": 10.0}]
    return data


def base_config() -> dict:
    return {"mpf": {"particles": 20, "forgetting": 0.99, "bias_rw": [0.001, 0.001, 0.0001]},
            "kf": {}, "ekf": {}, "rls": {}, "augpf": {"particles": 20}, "gpssm": {"particles": 20},
            "guard": {"threshold": 8.0, "window": 9, "jump": [8.0, 8.0, 0.3]}}


def fuzz_toml_text(tmp: Path, text: str, reader: str) -> None:
    path = _write(tmp, "x.toml", text)
    _read(path, reader)


def fuzz_toml_data(tmp: Path, data: dict, reader: str) -> None:
    try:
        text = to_toml(data)
    except TypeError:
        return
    path = tmp / "x.toml"
    path.write_text(text, encoding="utf-8", errors="replace")
    _read(path, reader)


def _read(path: Path, reader: str) -> None:
    """Read `path` with `reader`: not valid TOML (tomllib's own verdict on the file's bytes)
    exactly where the reader says so, otherwise a ConfigError about a key of the file."""
    from tirefilter.config import read_toml

    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        data = None
    if reader == "vehicle":
        from tirefilter.vehicle.params import load_vehicle

        exc = expect_error(lambda: load_vehicle(path), ConfigError, path)
    elif reader == "scenario":
        from tirefilter.scenarios import load_scenario

        exc = expect_error(lambda: load_scenario(path), ConfigError, path)
    else:
        exc = expect_error(lambda: read_toml(path), ConfigError, path)
    if data is None:
        assert isinstance(exc, ConfigError) and exc.key == "" and exc.problem.startswith("not valid TOML"), exc
        return
    if isinstance(exc, ConfigError):
        assert not exc.problem.startswith("not valid TOML"), exc
        _names_a_key(exc, data)
    elif reader == "config":
        _build_with_config(exc)


def _names_a_key(exc: ConfigError, table: dict) -> None:
    """A ConfigError about a table read from TOML names one of its keys (or a key inside it:
    `key.sub`, `key[i]`), or a key that the table lacks (a missing one)."""
    assert any(exc.key == k or exc.key.startswith((f"{k}.", f"{k}[")) for k in table) or "missing" in exc.problem, exc


def _build_with_config(config: dict) -> None:
    """Every estimator built with `config` (as `replay --config` builds them): a ConfigError
    that names the table (`--config`, the table's name as key) or the option that is wrong, in
    its table (`--config [name]` as it is read, `name configuration` as it is checked)."""
    try:
        _build_each(config)
    except ConfigError as exc:
        if exc.file == "--config":
            _names_a_key(exc, config)
            return
        if exc.file.startswith("--config [") and exc.file.endswith("]"):
            table = exc.file[len("--config ["):-1]
        else:
            assert exc.file.endswith(" configuration"), exc
            table = exc.file[:-len(" configuration")]
        assert isinstance(config.get(table), dict), exc
        _names_a_key(exc, config[table])


def _build_each(config: dict) -> None:
    from tirefilter.estimators import build_log_estimator
    from tirefilter.vehicle.params import load_vehicle

    vehicle = load_vehicle(VEHICLE_FILE)
    t = np.arange(5) * 0.01
    signals = {"delta": np.zeros(5), "ax": np.zeros(5), "ay": np.zeros(5), "yaw_rate": np.zeros(5),
               "vx": np.full(5, 20.0), "omega_f": np.full(5, 60.0), "omega_r": np.full(5, 60.0)}
    for name in ("mpf", "kf", "ekf", "rls", "augpf", "gpssm"):
        build_log_estimator(name, vehicle, t, signals, model="lateral", particles=20, config=config)


# -- state files ------------------------------------------------------------------------------
def base_state() -> dict:
    from tirefilter.estimators.state_file import FORMAT, _vehicle_record
    from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
    from tirefilter.vehicle.params import load_vehicle

    vehicle = load_vehicle(VEHICLE_FILE)
    est = StiffnessMPF(vehicle, MPFConfig(particles=3, model="lateral"))
    return {"format": FORMAT, "format_version": 1, "estimator": "mpf", "vehicle": _vehicle_record(vehicle),
            "model": "lateral", "params": ["Cf_y", "Cr_y"], "C_nominal": est.C_nom.tolist(),
            "log_weights": [0.0, -1.0, -2.0], "gamma": [0.05, 0.05, 0.05], "mu": [[0.0, 0.0]] * 3,
            "Lam": [[[1e6, 0.0], [0.0, 1e6]]] * 3, "nu": [30.0, 30.0, 30.0]}


def fuzz_state(tmp: Path, content) -> None:
    """`load_state`: a ConfigError naming the file and the key that is wrong, in the loader's
    order: not JSON, not this format, another format version, the vehicle (not a table, or
    another vehicle's), then the statistics; a state that loads is used by the next reset."""
    from tirefilter.estimators.state_file import FORMAT, FORMAT_VERSION, _vehicle_record, load_state
    from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
    from tirefilter.vehicle.params import load_vehicle

    path = tmp / "state.json"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(json.dumps(content, allow_nan=True))
    try:
        record = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        record = None
    vehicle = load_vehicle(VEHICLE_FILE)
    est = StiffnessMPF(vehicle, MPFConfig(particles=4, model="lateral"))
    result = expect_error(lambda: load_state(est, path), ConfigError, path)
    if record is None:
        assert isinstance(result, ConfigError) and result.problem.startswith("not a readable state file"), result
    elif not isinstance(record, dict) or record.get("format") != FORMAT:
        assert isinstance(result, ConfigError) and result.key == "format", result
    elif record.get("format_version") != FORMAT_VERSION:
        assert isinstance(result, ConfigError) and result.key == "format_version", result
    elif not isinstance(saved := record.get("vehicle", {}), dict) or any(
            saved.get(k) != ours.get(k) for ours in [_vehicle_record(vehicle)] for k in set(saved) | set(ours)):
        assert isinstance(result, ConfigError) and result.key == "vehicle", result  # (a key's value differs)
    elif isinstance(result, ConfigError):  # the statistics
        assert result.key in ("", "params", "C_nominal", "nu", "log_weights"), result
        assert result.key == "" or result.key in record, result
    else:
        est.reset(np.random.default_rng(0))  # the loaded state is used
        assert np.all(np.isfinite(est.stats.mu))
