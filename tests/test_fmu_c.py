"""The vehicle FMU's C code on its own: the equations' unit test (fmu/tests/test_model.c,
no FMI code) and a plain C FMI 2.0 host (fmu/tests/host_fmi2.c) that runs the FMU without
Python and must agree with fmpy to roundoff.

Skipped only when no C compiler is installed.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.vehicle_fmu import build

TESTS_DIR = Path(__file__).resolve().parents[1] / "fmu" / "tests"
CFLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror"]
CLEAN_ENV = {"PATH": "/usr/bin:/bin"}  # no PYTHONPATH, no venv: the C programs must not need them

STEP, N_STEPS, DELTA = 0.01, 500, 0.02  # what host_fmi2.c runs


@pytest.fixture(scope="module")
def cc() -> str:
    try:
        return build.compiler()
    except build.BuildError as exc:
        pytest.skip(f"C tests need a C compiler: {exc}")


def _compile(cc: str, out: Path, sources: list[Path], flags: list[str], libs: list[str]) -> Path:
    cmd = [cc, *CFLAGS, *flags, "-o", str(out), *map(str, sources), *libs]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, f"compilation failed: {' '.join(cmd)}\n{proc.stderr}"
    return out


def _assert_no_libpython(binary: Path) -> None:
    """Neither a direct dependency (a DT_NEEDED name lives in the file's string table)
    nor, where ldd exists, an indirect one."""
    assert b"libpython" not in binary.read_bytes(), f"{binary} references libpython"
    if shutil.which("ldd"):
        proc = subprocess.run(["ldd", str(binary)], capture_output=True, text=True, env=CLEAN_ENV)
        assert proc.returncode == 0, proc.stderr
        assert "libpython" not in proc.stdout, f"{binary} links libpython:\n{proc.stdout}"


def test_model_equations_unit_test(cc, tmp_path):
    gen = tmp_path / "gen"
    build.write_generated(gen)  # the generated header, independent of an earlier build
    sources = [TESTS_DIR / "test_model.c", *(build.SRC_DIR / f for f in build.MODEL_SOURCES)]
    exe = _compile(cc, tmp_path / "test_model", sources, build.include_flags(gen), ["-lm"])
    proc = subprocess.run([str(exe)], capture_output=True, text=True, env=CLEAN_ENV, timeout=120)
    print(proc.stdout)
    assert proc.returncode == 0, f"test_model.c failed:\n{proc.stdout}\n{proc.stderr}"
    assert "FAIL" not in proc.stdout
    assert "all checks passed" in proc.stdout


def test_plain_c_host_matches_fmpy(cc, tmp_path):
    fmu = build.build_vehicle(tmp_path, ("2",))["2"]
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}

    # the host, compiled against fmpy's FMI 2.0 headers only
    host = _compile(cc, tmp_path / "host_fmi2", [TESTS_DIR / "host_fmi2.c"],
                    build.include_flags(tmp_path / "gen"), ["-ldl"])
    unzipped = tmp_path / "unzipped"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(unzipped)
    so = unzipped / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    assert so.is_file()
    _assert_no_libpython(so)
    _assert_no_libpython(host)

    proc = subprocess.run([str(host), str(so), md.guid, str(vr["delta"]), str(vr["yaw_rate"])],
                          capture_output=True, text=True, env=CLEAN_ENV, timeout=120)
    assert proc.returncode == 0, f"host_fmi2 failed:\n{proc.stdout}\n{proc.stderr}"
    last = proc.stdout.strip().splitlines()[-1]
    match = re.fullmatch(r"final t=(\S+) yaw_rate=(\S+)", last)
    assert match, f"unexpected last line from host_fmi2: {last!r}"
    t_host, yaw_rate_host = float(match[1]), float(match[2])
    assert t_host == pytest.approx(N_STEPS * STEP, rel=1e-12)

    # the same run through fmpy: default parameters, same inputs, same communication points
    with VehicleFMU("2", fmu) as vehicle:
        vehicle.reset({})
        for k in range(N_STEPS):
            out = vehicle.step(k * STEP, STEP, [DELTA, 0.0, 0.0, 1.0, 0.0])
        yaw_rate_fmpy = float(out[vehicle.output_names.index("yaw_rate")])

    assert abs(yaw_rate_fmpy) > 1e-3  # a real turn, not a trivial zero
    assert yaw_rate_host == pytest.approx(yaw_rate_fmpy, rel=1e-12)
