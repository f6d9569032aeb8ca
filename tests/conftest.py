"""Shared fixtures: the vehicle FMUs are built once (into fmu/build) if missing."""

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
    "sigma_delta": 0.0, "bias_rw_ax": 0.0, "bias_rw_ay": 0.0, "bias_rw_yaw_rate": 0.0, "bias0_std_ax": 0.0,
    "bias0_std_ay": 0.0, "bias0_std_yaw_rate": 0.0, "vx0_std": 0.0, "vy0_std": 0.0, "yaw_rate0_std": 0.0,
}


@pytest.fixture(scope="session")
def fmu_paths():
    paths = {v: vehicle_fmu_path(v) for v in ("2", "3")}
    if not all(p.is_file() for p in paths.values()):
        build_vehicle_fmu()
    return paths
