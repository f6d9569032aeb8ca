"""Shared fixtures: the vehicle FMUs are built once (into fmu/build) if missing; the Python
FMUs (estimator, driver; FMI 2.0 and 3.0) once per session, on first use."""

from __future__ import annotations

import os

# One BLAS thread: the batched solves of the numpy references are small, and OpenBLAS's
# threads spin against each other on a loaded 2-core machine (a 100 x 100 batch took 30 s).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402

from tirefilter.cosim.fmu import build_vehicle_fmu, vehicle_fmu_path  # noqa: E402

# Truth without randomness: what the numpy model and the closed-form checks compare with.
NOISE_OFF = {
    "stiffness_dev_std": 0.0, "sigma_ax": 0.0, "sigma_ay": 0.0, "sigma_yaw_rate": 0.0, "sigma_omega": 0.0,
    "sigma_delta": 0.0, "bias_q_ax": 0.0, "bias_q_ay": 0.0, "bias_q_yaw_rate": 0.0, "bias0_std_ax": 0.0,
    "bias0_std_ay": 0.0, "bias0_std_yaw_rate": 0.0, "vx0_std": 0.0, "vy0_std": 0.0, "yaw_rate0_std": 0.0,
}


@pytest.fixture(scope="session")
def fmu_paths():
    paths = {v: vehicle_fmu_path(v) for v in ("2", "3")}
    if not all(p.is_file() for p in paths.values()):
        build_vehicle_fmu()
    return paths


@pytest.fixture(scope="session")
def python_fmu(tmp_path_factory):
    """python_fmu(name, fmi): the FMU of estimator `name` (a key of ESTIMATOR_FMUS) or of
    the driver ("driver", scenario snow-sine), FMI "2" or "3", built once per session."""
    from tirefilter.fmu_export.build import build_driver_fmu, build_estimator_fmu

    root = tmp_path_factory.mktemp("python_fmus")
    cache = {}

    def get(name: str = "mpf", fmi: str = "2"):
        if (name, fmi) not in cache:
            dest = root / f"fmi{fmi}"
            cache[name, fmi] = (build_driver_fmu("snow-sine", dest, fmi=fmi) if name == "driver"
                                else build_estimator_fmu(name, dest, fmi=fmi))
        return cache[name, fmi]

    return get


# The Python FMUs (pythonfmu, pythonfmu3) run an embedded interpreter's objects inside this
# process. Their libraries are unloaded during the interpreter's own teardown, after every
# test has run and the summary is printed, and that unloading intermittently corrupts the
# heap ("corrupted double-linked list", SIGABRT), which would turn a passing run into a
# failed one. The session therefore ends with its own exit status, skipping that teardown.
_EXIT = {}


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session, exitstatus):
    _EXIT["status"] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    import os
    import sys

    if "status" in _EXIT:
        reporter = config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            reporter._tw.flush()
        for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
            stream.flush()
        os._exit(_EXIT["status"])
