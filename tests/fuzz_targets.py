"""Property-based fuzzing of the readers (hypothesis): the Log CSV reader, the vehicle,
scenario and configuration TOML readers and the state-file reader. The property: any input
gives a result or the project's own error (TirefilterError, which the CLI prints as one
line), never another exception (a traceback).

Shared by tests/test_fuzz.py (a bounded CI run) and benchmarks/bench_fuzz.py (a long run).
Each target takes a `tmp` folder and hypothesis data and checks one input.
"""

from __future__ import annotations

import gzip
import json
import math
import tomllib
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from tirefilter.errors import TirefilterError

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


def expect_own_error(call):
    """Run `call`; only TirefilterError may come out of it."""
    try:
        return call()
    except TirefilterError as exc:
        assert str(exc), "the error has a message"
        return exc


def _write(tmp: Path, name: str, content) -> Path:
    path = tmp / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8", errors="replace"))
    return path


# -- Log CSV ----------------------------------------------------------------------------------
LOG_COLUMNS = ("t", "delta", "steering_wheel_angle", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r", "omega_fl",
               "omega_fr", "omega_rl", "omega_rr", "beta_true", "other")
cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers(-5, 100).map(str),
                  st.sampled_from(["", "nan", "NaN", "inf", "-inf", " 1.5 ", "1e400", "abc", "1,5", '"2"', "0x10",
                                   "\u00e9", ";", "1;2"]),
                  st.text(max_size=5))


@st.composite
def log_texts(draw) -> bytes:
    header = draw(st.lists(st.sampled_from(LOG_COLUMNS), min_size=0, max_size=9))
    if draw(st.booleans()):
        header = list(dict.fromkeys(header))  # mostly without duplicates
    n = draw(st.integers(0, 12))
    t0, dt = draw(st.floats(-5, 5)), draw(st.sampled_from([0.01, 0.0, -0.01, 1.0]))
    rows = []
    for k in range(n):
        row = [repr(t0 + k * dt) if h == "t" and draw(st.integers(0, 9)) else draw(cells) for h in header]
        if draw(st.integers(0, 19)) == 0:
            row = row[:-1] if row else ["x"]  # a short row
        rows.append(row)
    sep = draw(st.sampled_from([",", ",", ",", ";", "\t"]))
    text = sep.join(header) + "\n" + "\n".join(sep.join(r) for r in rows) + ("\n" if draw(st.booleans()) else "")
    raw = text.encode(draw(st.sampled_from(["utf-8", "utf-8-sig", "latin-1"])), errors="replace")
    if draw(st.integers(0, 9)) == 0:
        raw = draw(st.binary(max_size=64))
    return raw


def fuzz_log(tmp: Path, raw: bytes, gz: bool, vehicle: bool) -> None:
    from tirefilter.replay import check_log, read_log
    from tirefilter.replay.stream import scan_log

    path = tmp / ("log.csv.gz" if gz else "log.csv")
    path.write_bytes(gzip.compress(raw) if gz else raw)
    v = str(VEHICLE_FILE) if vehicle else None
    log = expect_own_error(lambda: read_log(path, v, need_steering_ratio=vehicle))
    if not isinstance(log, TirefilterError):
        assert np.all(np.diff(log.t) > 0)
    expect_own_error(lambda: check_log(path, v))
    expect_own_error(lambda: scan_log(path, v, chunk_rows=3) if vehicle else None)


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
    from tirefilter.config import read_toml

    if reader == "vehicle":
        from tirefilter.vehicle.params import load_vehicle

        expect_own_error(lambda: load_vehicle(path))
    elif reader == "scenario":
        from tirefilter.scenarios import load_scenario

        expect_own_error(lambda: load_scenario(path))
    else:
        expect_own_error(lambda: _build_with_config(read_toml(path)))


def _build_with_config(config: dict) -> None:
    """Every estimator built with `config` (as `replay --config` builds them)."""
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
    from tirefilter.estimators.state_file import load_state
    from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
    from tirefilter.vehicle.params import load_vehicle

    path = tmp / "state.json"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(json.dumps(content, allow_nan=True))
    est = StiffnessMPF(load_vehicle(VEHICLE_FILE), MPFConfig(particles=4, model="lateral"))
    result = expect_own_error(lambda: load_state(est, path))
    if not isinstance(result, TirefilterError):
        est.reset(np.random.default_rng(0))  # the loaded state is used
        assert np.all(np.isfinite(est.stats.mu))
