"""Shared fixtures: the vehicle FMUs are built once (into fmu/build) if missing; the Python
FMUs (estimator, driver; FMI 2.0 and 3.0) once per session, on first use; under xdist, the
compiled kernels compiled (the MPF's C core built) once for all workers, before the first test
(`warm_up_kernels`)."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

# One BLAS thread: the batched solves of the numpy references are small, and OpenBLAS's
# threads spin against each other on a loaded 2-core machine (a 100 x 100 batch took 30 s).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from tirefilter.cosim.fmu import build_vehicle_fmu, vehicle_fmu_path  # noqa: E402

# Truth without randomness: what the numpy model and the closed-form checks compare with.
NOISE_OFF = {
    "stiffness_dev_std": 0.0, "sigma_ax": 0.0, "sigma_ay": 0.0, "sigma_yaw_rate": 0.0, "sigma_omega": 0.0,
    "sigma_delta": 0.0, "bias_q_ax": 0.0, "bias_q_ay": 0.0, "bias_q_yaw_rate": 0.0, "bias0_std_ax": 0.0,
    "bias0_std_ay": 0.0, "bias0_std_yaw_rate": 0.0, "vx0_std": 0.0, "vy0_std": 0.0, "yaw_rate0_std": 0.0,
}


# ---- the compiled kernels: each compiled once per suite run, not once per xdist worker -----------
# A clean clone has no numba cache (`cache=True` writes it beside the sources), and compiling the
# kernels was about 40 % of a cold suite's CPU time (docs/development.md, "How long `make test` takes").
# Left to the tests, both workers of `make test` reach the same kernels at about the same time and
# both compile them. With two or more workers, each worker first runs these small warm-up tasks,
# each under a file lock shared by the workers: a task the other worker holds is skipped and
# come back to last, when its kernels are on disk and load in a fraction of a second; a task
# done by either worker is marked done. The two workers so compile disjoint halves, in parallel.
# The order (the MPF's C core first on one worker, the GP-SSM's largest task first on the other) keeps
# them from building the same thing at the same time. Each worker runs its tasks in one fresh
# interpreter (`python tests/conftest.py --warm-up LOCK_DIR [--reverse]`) that writes the disk
# cache; the tests then load the kernels from it: inside a pytest process the same compile took
# 1.6 times the CPU (page faults, system time; docs/development.md, "How long `make test` takes").
# One interpreter for all of a worker's tasks, not one per task: each start imports numpy, scipy,
# numba and the package again (about 1.5 CPU s). Python's cyclic garbage collector is held off
# while a task compiles: numba's compile allocates millions of objects, and the collections they
# set off (mostly full ones) took a tenth of the compile's CPU.


def _warm_mpf_c() -> None:
    """The MPF's C core (its default backend) built into the user's cache, once for both workers."""
    from tirefilter.estimators.mpf import native

    native.library()


def _warm_gpssm(**config) -> None:
    from tirefilter.estimators.base import Inputs, Measurement
    from tirefilter.estimators.gpssm.filter import FrictionGPSSM, GPSSMConfig
    from tirefilter.scenarios import load_scenario

    est = FrictionGPSSM(load_scenario("friction-snow").vehicle, GPSSMConfig(particles=8, **config))
    est.reset(np.random.default_rng(0))
    for k in range(8):
        est.step(0.04 * k, Inputs(delta=0.02, vx=15.0), Measurement(ax=0.0, ay=1.0, yaw_rate=0.05))
    est.friction()  # the curve: the statistics' flush, features and moments on the grid
    est.posterior()


# The order: one worker takes them first to last, the other last to first, each skipping what the
# other holds. The MPF's default backend is its C core (estimators/mpf/native.py): one build of a few
# seconds, no numba kernels to compile; the tests that run its numba backend on purpose (the equality
# tests) compile those kernels on their first call.
WARM_UP = {  # name: task
    "mpf-c": _warm_mpf_c,
    "gpssm-axle-exact": lambda: _warm_gpssm(basis="axle"),
    "gpssm-tensor-rank1": lambda: _warm_gpssm(stats="rank1"),
    "gpssm-tensor-exact": lambda: _warm_gpssm(),
}


def warm_up_kernels(lock_dir: Path, reverse: bool = False, tasks=None) -> tuple[list[str], list[str]]:
    """Run the tasks (`WARM_UP` by default) not yet marked done in `lock_dir`, in this process
    and in reverse order when `reverse`; returns the names this process ran first-hand (compiled,
    unless the disk cache had them) and those that raised (not marked done; the traceback is
    printed to stderr, and the tests that use their kernels will say what is wrong)."""
    import fcntl
    import gc
    import traceback

    tasks = WARM_UP if tasks is None else tasks
    names = list(tasks)[::-1] if reverse else list(tasks)
    ran, failed, later = [], [], []
    for blocking in (False, True):
        for name in (names if not blocking else later):
            done = lock_dir / f"{name}.done"
            if done.exists():
                continue
            with open(lock_dir / f"{name}.lock", "w") as lock:
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
                except BlockingIOError:
                    later.append(name)  # the other worker compiles it: come back when it is on disk
                    continue
                if done.exists():
                    continue
                gc.disable()  # see above; the task's garbage is collected once, after it
                try:
                    tasks[name]()
                except Exception:
                    traceback.print_exc()
                    failed.append(name)
                    continue
                finally:
                    gc.enable()
                    gc.collect()
                done.touch()
                ran.append(name)
    return ran, failed


@pytest.fixture(scope="session", autouse=True)
def _kernels_compiled_once(tmp_path_factory, worker_id):
    """With two or more xdist workers: `warm_up_kernels` before the first test of each
    worker (a single process compiles on first use, as before)."""
    if worker_id == "master" or int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) < 2:
        return
    lock_dir = tmp_path_factory.getbasetemp().parent / "numba-warm-up"  # shared by the workers
    lock_dir.mkdir(exist_ok=True)
    command = [sys.executable, __file__, "--warm-up", str(lock_dir)]
    if int(worker_id.removeprefix("gw")) % 2 == 1:
        command.append("--reverse")
    proc = subprocess.run(command, capture_output=True, text=True)  # in a fresh interpreter (see above)
    if proc.returncode != 0:  # the tests that use these kernels will say what is wrong
        warnings.warn(f"kernel warm-up failed: {proc.stderr[-3000:]}", stacklevel=1)


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


# ---- what CI must not skip -------------------------------------------------------------------------
# CI runs `bash .ci/run` with CI=true; .ci/run installs Debian's chromium and stops unless the
# shared data sets are beside the clone (../shared/data). Under CI a test that lacks either fails,
# so a green run means the browser and real-data tests ran; elsewhere it skips, saying what is missing.
CHROMIUM = Path("/usr/bin/chromium")  # Debian's chromium, driven by Playwright (never its own download)


def in_ci() -> bool:
    """Whether the tests run under CI (the environment variable CI is true, as .ci/run sets it)."""
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def skip_or_fail_in_ci(reason: str) -> None:
    """Skip the current test for `reason`; under CI (`in_ci`) fail it instead."""
    if in_ci():
        pytest.fail(f"{reason}: under CI (CI={os.environ['CI']}) this test must run, not skip", pytrace=False)
    pytest.skip(reason)


@pytest.fixture(scope="session")
def chromium() -> Path:
    """The browser of the browser tests: skips without it, fails under CI (`skip_or_fail_in_ci`)."""
    if not CHROMIUM.is_file():
        skip_or_fail_in_ci(f"{CHROMIUM} is absent (Debian package `chromium`; .ci/run installs it)")
    return CHROMIUM


# ---- the order in which make test's workers get the tests: the long ones first ---------------------
# `--dist loadgroup` (pytest-xdist) makes each xdist group one unit of work and every other test a
# unit of its own; it sends the units with the most tests first (the groups `peer_drive` and
# `browser`, one to each worker), then the single tests in collection order, the next one to
# whichever worker has at most two left. In file order the long single tests (the FMU against the
# numpy integration in test_vehicle_model, test_viz's `--connect` / `--spawn`) came near the end,
# and one worker still ran them when the other had nothing left. On the workers the collection is
# sorted by module, the module with the longest test (`LONG_TESTS`) first, so the last units are
# short and the two workers end within about a test of each other. A single process (no xdist)
# keeps the file order. Seconds: setup + call with the numba cache filled
# (docs/development.md, "How long `make test` takes"); parameters share their test's entry.
# test_vehicle_model's FMU-against-numpy integrations are not in the list: 2-3 s, their reference
# runs on floats.
LONG_TESTS = {
    "test_faults.py::test_estimators_stay_finite_and_do_not_restart_on_spikes": 10.0,
    "test_metrics.py::test_streamed_metrics_equal_run_metrics": 9.0,
    "test_stiffness_mpf.py::test_paper_sim_tracks_the_surface_change": 3.0,
    "test_viz.py::test_connect_streams_to_a_local_grpc_receiver": 8.0,  # waits for its receiver (cold: 20 s)
    "test_viz.py::test_spawn_starts_a_viewer_process_and_streams_to_it": 8.0,  # waits for the viewer
    "test_estimator_fmu3.py::test_cli_builds_fmi2_and_fmi3_of_every_fmu_all_validated": 7.0,
    "test_baselines.py::test_converges_on_paper_sim": 5.5,
    "test_golden.py::test_outputs_equal_golden_master": 4.0,
    "test_study.py::test_bench_stiffness_command_writes_tables_and_plots": 5.5,
    "test_linear_kf.py::test_nees_and_nis_are_chi_square_consistent": 5.0,
    "test_faults.py::test_sideslip_recovers_within_5_s_of_the_fault_end": 3.5,
    "test_study.py::test_worker_pool_equals_one_process": 3.5,
    "test_metrics.py::test_a_replay_longer_than_a_chunk_states_the_metrics_of_its_results": 3.0,
    "test_interrupt.py::test_bench_resumes_where_it_stopped": 3.0,
}


def long_test_seconds(nodeid: str) -> float:
    """`LONG_TESTS`' seconds of a test id ("tests/test_x.py::test_y[params]@group"), 0 if not listed."""
    return LONG_TESTS.get(nodeid.rsplit("/", 1)[-1].split("[", 1)[0].split("@", 1)[0], 0.0)


def long_modules_first(nodeids: list[str]) -> list[int]:
    """The order (indices into `nodeids`) in which the workers get the tests: by module, the
    module with the longest test in `LONG_TESTS` first; a module's tests stay together and in
    file order (a worker that runs two of them in a row sets the module's fixtures up once), and
    modules without a listed test keep their order after the others."""
    module = [n.split("::", 1)[0] for n in nodeids]
    longest = {}
    for n, m in zip(nodeids, module):
        longest[m] = max(longest.get(m, 0.0), long_test_seconds(n))
    return sorted(range(len(nodeids)), key=lambda i: -longest[module[i]])


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
    if hasattr(config, "workerinput"):  # an xdist worker: the scheduler deals the units in this order
        items[:] = [items[i] for i in long_modules_first([item.nodeid for item in items])]


if __name__ == "__main__":
    # `python tests/conftest.py --warm-up LOCK_DIR [--reverse]`: a worker's share (`warm_up_kernels`);
    # `python tests/conftest.py TASK`: one task alone
    if sys.argv[1] == "--warm-up":
        _, failed = warm_up_kernels(Path(sys.argv[2]), reverse="--reverse" in sys.argv[3:])
        sys.exit(1 if failed else 0)
    WARM_UP[sys.argv[1]]()
