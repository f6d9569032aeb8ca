"""Property-based fuzzing of the readers, bounded for CI (tests/fuzz_targets.py says what
is fuzzed and the property: the result, or the error the input deserves; tools/fuzz.py
runs the same targets much longer). A few hundred examples in all, derandomised so that a CI
run is reproducible; the explicit examples are inputs that once raised a traceback."""

from __future__ import annotations

import tempfile
from pathlib import Path

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import fuzz_targets as ft

CI = settings(derandomize=True, deadline=None, database=None,
              suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _tmp():
    return tempfile.TemporaryDirectory()


@settings(CI, max_examples=150)
@given(raw=ft.log_texts(), gz=st.booleans(), vehicle=st.booleans())
def test_log_reader(raw, gz, vehicle):
    with _tmp() as tmp:
        ft.fuzz_log(Path(tmp), raw, gz, vehicle)


@settings(CI, max_examples=40)
@given(data=ft.mutated(ft.base_vehicle()))
def test_vehicle_toml(data):
    with _tmp() as tmp:
        ft.fuzz_toml_data(Path(tmp), data, "vehicle")


@settings(CI, max_examples=40)
@given(data=ft.mutated(ft.base_scenario()))
def test_scenario_toml(data):
    with _tmp() as tmp:
        ft.fuzz_toml_data(Path(tmp), data, "scenario")


@settings(CI, max_examples=30)
@given(data=ft.mutated(ft.base_config()))
def test_config_toml(data):
    with _tmp() as tmp:
        ft.fuzz_toml_data(Path(tmp), data, "config")


@settings(CI, max_examples=30)
@given(text=st.one_of(st.text(max_size=80), st.binary(max_size=40)),
       reader=st.sampled_from(["vehicle", "scenario", "config"]))
@example(text=b'mass = 1\nname = "\xe9"\n', reader="vehicle")  # latin-1, not UTF-8
def test_toml_text(text, reader):
    with _tmp() as tmp:
        ft.fuzz_toml_text(Path(tmp), text, reader)


@settings(CI, max_examples=50)
@given(content=st.one_of(ft.mutated(ft.base_state()), st.binary(max_size=40), ft.values))
@example(content=ft.base_state() | {"vehicle": 0})
@example(content=ft.base_state() | {"vehicle": []})
@example(content=ft.base_state() | {"log_weights": 0})
@example(content=ft.base_state() | {"log_weights": [float("nan"), 0.0, 0.0]})
def test_state_file(content):
    with _tmp() as tmp:
        ft.fuzz_state(Path(tmp), content)
