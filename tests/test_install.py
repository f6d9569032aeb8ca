"""The package installed from its wheel, away from the checkout.

A wheel of the working tree (built from a copy of it, so the build writes nothing into the
checkout) is installed into a fresh virtual environment in a temporary folder. From a
temporary working directory, that environment's `tirefilter fmu build vehicle` builds the
vehicle FMU from the C sources the wheel ships (package data) into the per-user cache
(`$XDG_CACHE_HOME/tirefilter/fmu`), and `tirefilter run` co-simulates a scenario with it:
its `results.csv` equals, byte for byte, the checkout's run of the same scenario against
that FMU (`$TIREFILTER_FMU_DIR`).

No network: the wheel is built without build isolation (setuptools >= 77 and wheel, from
the `test` extra) and installed with `--no-deps`; the dependencies (numpy, fmpy, ...) are
the running interpreter's site-packages, made visible to the new environment by a `.pth`
file. A folder named in a `.pth` file is added to `sys.path` without running the `.pth`
files inside it, so an editable install of tirefilter there stays out; the test checks that
tirefilter is imported from the wheel.
"""

from __future__ import annotations

import importlib.metadata
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from tirefilter.vehicle_fmu import build

REPO = Path(__file__).resolve().parents[1]
SCENARIO, ESTIMATOR = "paper-sim", "rls"  # rls: a real estimator, no numba compile (about 3 s)


def _build_backend_problem() -> str | None:
    """Why the wheel cannot be built offline here, or None."""
    try:
        setuptools_major = int(importlib.metadata.version("setuptools").split(".")[0])
        importlib.metadata.version("wheel")
    except importlib.metadata.PackageNotFoundError as exc:
        return f"{exc.name} is not installed"
    if setuptools_major < 77:
        return f"setuptools {importlib.metadata.version('setuptools')} < 77"
    return None


def _site_packages() -> list[str]:
    """The running interpreter's site-packages folders (where the dependencies are), not the
    checkout's src/ or viewer/ that PYTHONPATH may name."""
    paths = sysconfig.get_paths()
    found = [paths["purelib"], paths["platlib"]]
    found += [p for p in sys.path if p.endswith(("site-packages", "dist-packages"))]
    sources = (REPO / "src", REPO / "viewer")  # the checkout's packages (a venv inside the checkout is fine)
    return [p for p in dict.fromkeys(found)
            if Path(p).is_dir() and not any(Path(p).resolve().is_relative_to(s) for s in sources)]


def _run(cmd: list, **kwargs) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=300, **kwargs)
    assert proc.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    problem = _build_backend_problem()
    if problem:
        pytest.skip(f"building the wheel offline needs setuptools >= 77 and wheel (the test extra: "
                    f"pip install -e '.[test]'): {problem}")
    tmp = tmp_path_factory.mktemp("wheel")
    tree = tmp / "tree"
    junk = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", "build")
    for name in ("src", "viewer"):
        shutil.copytree(REPO / name, tree / name, ignore=junk)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, tree / name)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
          "-w", tmp / "dist", tree], cwd=tmp)
    (whl,) = (tmp / "dist").glob("tirefilter-*.whl")
    return whl


def test_installed_wheel_builds_the_fmu_and_runs_a_scenario(wheel, tmp_path):
    try:
        build.compiler()
    except build.BuildError as exc:
        pytest.skip(f"building the vehicle FMU needs a C compiler: {exc}")
    assert not tmp_path.resolve().is_relative_to(REPO)
    venv, cache, work = tmp_path / "venv", tmp_path / "cache", tmp_path / "work"
    work.mkdir()
    _run([sys.executable, "-m", "venv", "--without-pip", venv])
    python = venv / "bin" / "python"
    # the running pip installs into the new environment, before the .pth below exists
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index", "-q", wheel])
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON") and k not in ("TIREFILTER_FMU_DIR",
                                                                                          "VIRTUAL_ENV")}
    env.update(PYTHONNOUSERSITE="1", XDG_CACHE_HOME=str(cache), OPENBLAS_NUM_THREADS="1")
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     env=env).stdout.strip())
    (site / "tirefilter_test_dependencies.pth").write_text("".join(f"{p}\n" for p in _site_packages()))

    where = _run([python, "-c", "import tirefilter, tirefilter_viewer, tirefilter.vehicle_fmu.build as b; "
                  "print(tirefilter.__file__); print(b.SRC_DIR); print(b.default_out_dir())"],
                 env=env, cwd=work).stdout.split("\n")
    assert Path(where[0]).is_relative_to(site), f"tirefilter imported from {where[0]}, not from the wheel"
    assert Path(where[1]).is_relative_to(site)
    fmu_dir = cache / "tirefilter" / "fmu"
    assert Path(where[2]) == fmu_dir

    built = _run([venv / "bin" / "tirefilter", "fmu", "build", "vehicle"], env=env, cwd=work).stdout
    for version in ("2", "3"):
        assert f"(FMI {version}.0): {fmu_dir / f'TirefilterVehicle_fmi{version}.fmu'}" in built, built
    assert "validated 2 FMUs" in built
    assert list(work.iterdir()) == []  # nothing written into the working directory

    out = work / "run"
    _run([venv / "bin" / "tirefilter", "run", "--scenario", SCENARIO, "--estimator", ESTIMATOR, "--out", out],
         env=env, cwd=work)
    results = (out / "results.csv").read_text()
    header, *rows = results.splitlines()
    assert {"t", "Cf_y", "true_vx", "true_Cf_y"} <= set(header.split(","))
    assert len(rows) > 1000

    # the checkout's run of the same scenario, against the FMU the installed package built
    checkout_env = {**os.environ, "TIREFILTER_FMU_DIR": str(fmu_dir), "OPENBLAS_NUM_THREADS": "1",
                    "PYTHONPATH": os.pathsep.join([str(REPO / "src"), str(REPO / "viewer"),
                                                   *filter(None, [os.environ.get("PYTHONPATH")])])}
    _run([sys.executable, "-m", "tirefilter.cli", "run", "--scenario", SCENARIO, "--estimator", ESTIMATOR,
          "--out", tmp_path / "checkout_run"], env=checkout_env, cwd=tmp_path)
    assert (tmp_path / "checkout_run" / "results.csv").read_text() == results


def test_the_wheel_ships_the_mpf_c_core(wheel):
    """The MPF's default backend builds its C core from the package's sources on first use: the wheel
    carries them (package data)."""
    import zipfile

    from tirefilter.estimators.mpf import native

    names = set(zipfile.ZipFile(wheel).namelist())
    for f in (*native.SOURCES, *native.HEADERS):
        assert f"tirefilter/estimators/mpf/native/{f}" in names, f


def test_the_build_folder_is_overridden_by_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("TIREFILTER_FMU_DIR", str(tmp_path))
    assert build.default_out_dir() == tmp_path
    monkeypatch.delenv("TIREFILTER_FMU_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert build.default_out_dir() == REPO / "fmu" / "build"  # a checkout builds into fmu/build/
