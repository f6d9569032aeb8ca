"""`.ci/run`, the CI entry point: it stops with a message unless the real-data and browser
tests can run, and runs the README's `make test` with CI=true, under which those tests fail
instead of skipping (tests/conftest.py, `skip_or_fail_in_ci`). So a green CI run means they ran.

`.ci/run` runs here from a copy beside a fake `../shared`, with `make`, `apt-get` and `sudo`
replaced by scripts that only say they were called: nothing is installed."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import CHROMIUM, skip_or_fail_in_ci

REPO = Path(__file__).resolve().parents[1]


def _ci_run(tmp_path: Path, shared: bool) -> subprocess.CompletedProcess:
    repo = tmp_path / "repo"
    (repo / ".ci").mkdir(parents=True)
    shutil.copy(REPO / ".ci" / "run", repo / ".ci" / "run")
    if shared:
        (tmp_path / "shared" / "data" / "mbds-sideslip").mkdir(parents=True)
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "make").write_text('#!/bin/sh\necho "make $* CI=$CI"\n')
    for tool in ("apt-get", "sudo"):
        (fake / tool).write_text(f'#!/bin/sh\necho "{tool} $*" >&2\n')
    for script in fake.iterdir():
        script.chmod(0o755)
    env = dict(os.environ, PATH=f"{fake}{os.pathsep}{os.environ['PATH']}", CI="false")
    return subprocess.run(["bash", str(repo / ".ci" / "run")], capture_output=True, text=True, env=env, timeout=60)


def test_ci_run_stops_without_the_shared_data(tmp_path):
    proc = _ci_run(tmp_path, shared=False)
    assert proc.returncode == 1
    assert "error: ../shared/data/mbds-sideslip/ is missing" in proc.stderr and "tests/test_replay.py" in proc.stderr
    assert "make" not in proc.stdout and "apt-get" not in proc.stderr


def test_ci_run_runs_make_test_under_ci_once_chromium_is_there(tmp_path):
    proc = _ci_run(tmp_path, shared=True)
    if os.access(CHROMIUM, os.X_OK):
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.splitlines() == ["make test CI=true"]  # CI=false outside: CI=true for the tests
    else:  # the fake apt-get installs nothing
        assert proc.returncode == 1
        assert "/usr/bin/chromium" in proc.stderr and "error:" in proc.stderr and "make" not in proc.stdout


def test_under_ci_a_missing_requirement_fails_the_test_instead_of_skipping(monkeypatch):
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="^x is absent: under CI"):
        skip_or_fail_in_ci("x is absent")
    for value in ("", "false"):
        monkeypatch.setenv("CI", value)
        with pytest.raises(pytest.skip.Exception, match="^x is absent$"):
            skip_or_fail_in_ci("x is absent")
