"""The long fuzzing run of the readers (tests/fuzz_targets.py; tests/test_fuzz.py is the
bounded CI run of the same targets): the Log CSV reader (with check-log and the streamed
first pass), the vehicle, scenario and configuration TOML readers, and the state-file
reader, each with --examples inputs (default 2000), randomised unless --seed is given.

    .venv/bin/python tools/fuzz.py [--examples 2000] [--seed S] [--targets log vehicle ...]

Prints per target the examples run, the wall time and the first falsifying example (none
when every input gave a result or the error it deserves: tests/fuzz_targets.py).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: BLAS threads only contend (30x slower expm)

import argparse
import sys
import tempfile
import time
from pathlib import Path

from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import fuzz_targets as ft  # noqa: E402

TARGETS = {
    "log": (dict(raw=ft.log_texts(), gz=st.booleans(), vehicle=st.booleans()),
            lambda tmp, raw, gz, vehicle: ft.fuzz_log(tmp, raw, gz, vehicle)),
    "vehicle": (dict(data=ft.mutated(ft.base_vehicle())), lambda tmp, data: ft.fuzz_toml_data(tmp, data, "vehicle")),
    "scenario": (dict(data=ft.mutated(ft.base_scenario())),
                 lambda tmp, data: ft.fuzz_toml_data(tmp, data, "scenario")),
    "config": (dict(data=ft.mutated(ft.base_config())), lambda tmp, data: ft.fuzz_toml_data(tmp, data, "config")),
    "toml-text": (dict(text=st.text(max_size=200), reader=st.sampled_from(["vehicle", "scenario", "config"])),
                  lambda tmp, text, reader: ft.fuzz_toml_text(tmp, text, reader)),
    "state": (dict(content=st.one_of(ft.mutated(ft.base_state()), st.binary(max_size=200), ft.values)),
              lambda tmp, content: ft.fuzz_state(tmp, content)),
}


def run_target(name: str, examples: int, seed_value: int | None) -> tuple[int, float, str | None]:
    strategies, body = TARGETS[name]
    count = [0]

    def test(**kw):
        count[0] += 1
        with tempfile.TemporaryDirectory() as tmp:
            body(Path(tmp), **kw)

    test = settings(max_examples=examples, deadline=None, database=None,
                    suppress_health_check=list(HealthCheck))(given(**strategies)(test))
    if seed_value is not None:
        test = seed(seed_value)(test)
    t0 = time.perf_counter()
    try:
        test()
        failure = None
    except Exception as exc:  # the falsifying example, as hypothesis reports it
        failure = f"{type(exc).__name__}: {exc}"
    return count[0], time.perf_counter() - t0, failure


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--examples", type=int, default=2000)
    p.add_argument("--seed", type=int)
    p.add_argument("--targets", nargs="+", choices=list(TARGETS), default=list(TARGETS))
    args = p.parse_args(argv)
    failed = 0
    print("| target | examples | wall s | result |\n|---|---|---|---|")
    for name in args.targets:
        n, wall, failure = run_target(name, args.examples, args.seed)
        failed += failure is not None
        print(f"| {name} | {n} | {wall:.0f} | {'ok' if failure is None else failure.splitlines()[0][:200]} |",
              flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
