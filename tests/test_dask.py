"""Monte-Carlo trials on a Dask cluster (`run_study(scheduler=...)`, `tirefilter bench
stiffness --scheduler`): a LocalCluster of 2 worker processes on loopback gives the same
trials, digit for digit, as the local run; resuming and a missing scheduler."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tirefilter.cli import main
from tirefilter.errors import ConfigError
from tirefilter.study import montecarlo
from tirefilter.study.montecarlo import TrialSpec, run_study

distributed = pytest.importorskip("dask.distributed")

SPEC = TrialSpec("paper-sim", "mpf", particles=30, duration=3.0)
VOLATILE = ("wall_time_s", "median_step_us")  # timings differ run to run


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as c:
        yield c


def _same(a: dict, b: dict) -> None:
    strip = lambda m: json.dumps({k: v for k, v in m.items() if k not in VOLATILE}, sort_keys=True)  # noqa: E731
    assert strip(a) == strip(b)


def test_dask_trials_equal_the_local_run_and_resume(tmp_path, cluster):
    local = run_study(SPEC, 3, tmp_path / "local", study_seed=7, workers=1)
    d = tmp_path / "dask"
    run_study(SPEC, 2, d, study_seed=7, scheduler=cluster.scheduler_address)
    first = (d / "metrics.jsonl").read_text()
    remote = run_study(SPEC, 3, d, study_seed=7, scheduler=cluster.scheduler_address)  # resumes: runs trial 2 only
    assert (d / "metrics.jsonl").read_text().startswith(first) and len(remote.metrics) == 3
    for i in range(3):
        assert remote.metrics[i]["status"] == "ok"
        _same(remote.metrics[i], local.metrics[i])
        a, b = remote.series(i), local.series(i)
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)


def test_bench_stiffness_cli_on_dask_writes_the_same_tables(tmp_path, cluster):
    args = ["bench", "stiffness", "--part", "accuracy", "--trials", "2", "--particles", "30", "--estimators", "mpf",
            "--duration", "3", "--no-plots", "--quiet"]
    assert main(args + ["--workers", "1", "--out", str(tmp_path / "l")]) == 0
    assert main(args + ["--scheduler", cluster.scheduler_address, "--out", str(tmp_path / "d")]) == 0
    table = lambda p: [x for x in (p / "report.md").read_text().splitlines() if x.startswith("|")]  # noqa: E731
    assert table(tmp_path / "d") and table(tmp_path / "d") == table(tmp_path / "l")


def test_no_scheduler_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setattr(montecarlo, "DASK_CONNECT_TIMEOUT_S", 2.0)  # nothing answers at port 9: no need to wait 20 s
    with pytest.raises(ConfigError, match="scheduler"):
        run_study(SPEC, 1, tmp_path / "x", scheduler="tcp://127.0.0.1:9")
