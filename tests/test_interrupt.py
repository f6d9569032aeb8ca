"""SIGINT and SIGTERM end `run`, `replay` and `bench` at a row (trial) boundary: real
signals sent to a `tirefilter` subprocess, then the files it left are read back."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tirefilter.replay import write_log

TIREFILTER = [sys.executable, "-m", "tirefilter.cli"]


def _wait_for(predicate, proc, timeout=120.0):
    t0 = time.monotonic()
    while not predicate():
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"exited with {proc.returncode} before the signal:\n{out}\n{err}")
        if time.monotonic() - t0 > timeout:
            proc.kill()
            pytest.fail("the condition never came")
        time.sleep(0.05)


def _data_rows(path: Path) -> int:
    return max(0, len(path.read_text().splitlines()) - 1) if path.is_file() else 0


def _check_whole_rows(results: Path, summary: dict) -> None:
    lines = results.read_text().split("\n")
    assert lines[-1] == "", "the file ends with a whole line"
    header, rows = lines[0].split(","), lines[1:-1]
    assert rows and all(len(r.split(",")) == len(header) for r in rows)
    assert summary["steps"] == len(rows)
    assert summary["t_reached"] == pytest.approx(float(rows[-1].split(",")[0]), abs=0)


def _interrupt(cmd, ready, signum, cwd):
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd)
    _wait_for(ready, proc)
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=120)
    return proc.returncode, out, err


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_run_ends_at_a_row_boundary(fmu_paths, tmp_path, signum, code):
    out = tmp_path / "run"
    results = out / "results.csv"
    rc, stdout, stderr = _interrupt(
        TIREFILTER + ["run", "--scenario", "paper-sim", "--estimator", "mpf", "--particles", "50", "--out", str(out),
                      "--quiet"],
        lambda: _data_rows(results) >= 300, signum, tmp_path)
    assert rc == code, stderr
    summary = json.loads((out / "run.json").read_text())
    assert summary["status"] == "interrupted" and signal.Signals(signum).name in summary["error"]
    assert 300 <= summary["steps"] < 6001
    _check_whole_rows(results, summary)
    assert stdout == ""
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"interrupted by {signal.Signals(signum).name} at t = ")


def test_replay_ends_at_a_row_boundary(tmp_path):
    t = np.arange(20000) * 0.01
    write_log(tmp_path / "drive.csv", {"t": t, "delta": 0.02 * np.sin(t), "ax": 0.1 * np.sin(3 * t),
                                       "ay": 2 * np.sin(t), "yaw_rate": 0.1 * np.sin(t), "vx": 20 + 0 * t})
    vehicle = Path(__file__).resolve().parents[1] / "src/tirefilter/scenarios/data/vehicles/midsize-suv.toml"
    result = tmp_path / "result.csv"
    rc, stdout, stderr = _interrupt(
        TIREFILTER + ["replay", str(tmp_path / "drive.csv"), "--vehicle", str(vehicle), "--estimator", "mpf",
                      "--particles", "50", "--out", str(result), "--quiet"],
        lambda: _data_rows(result) >= 300, signal.SIGTERM, tmp_path)
    assert rc == 143, stderr
    summary = json.loads(result.with_suffix(".json").read_text())
    assert summary["status"] == "interrupted" and summary["steps"] < 20000
    _check_whole_rows(result, summary)
    assert len([ln for ln in stderr.splitlines() if ln.strip()]) == 1


def test_bench_resumes_where_it_stopped(fmu_paths, tmp_path):
    out = tmp_path / "bench"
    cmd = TIREFILTER + ["bench", "stiffness", "--part", "accuracy", "--estimators", "rls", "--trials", "6",
                        "--duration", "2", "--workers", "1", "--no-plots", "--quiet", "--out", str(out)]
    metrics = out / "accuracy" / "paper-sim" / "rls-2s" / "metrics.jsonl"
    rc, _, stderr = _interrupt(cmd, lambda: _data_rows(metrics) + 1 >= 2, signal.SIGINT, tmp_path)
    assert rc == 130, stderr
    assert "the same command resumes" in stderr and len([ln for ln in stderr.splitlines() if ln.strip()]) == 1
    done = [json.loads(ln) for ln in metrics.read_text().splitlines()]
    assert 2 <= len(done) < 6
    finished = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert finished.returncode == 0, finished.stderr
    again = [json.loads(ln) for ln in metrics.read_text().splitlines()]
    assert sorted(m["trial"] for m in again) == list(range(6))  # each trial once: the first ones were not run again
    assert again[:len(done)] == done
