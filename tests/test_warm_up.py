"""The kernels' warm-up before a multi-worker `make test` (tests/conftest.py, `warm_up_kernels`;
docs/development.md, "How long make test takes"): every task run once by one of the workers,
failures reported and not marked done, the garbage collector back on afterwards."""

from __future__ import annotations

import gc
import subprocess
import sys
import threading
import time
from pathlib import Path

from conftest import WARM_UP, warm_up_kernels


def _recording_tasks(names, log, fail=(), gc_states=None):
    gc_states = [] if gc_states is None else gc_states

    def task(name):
        def run():
            gc_states.append(gc.isenabled())
            time.sleep(0.05)
            log.append((threading.current_thread().name, name))
            if name in fail:
                raise RuntimeError(f"{name} failed")
        return run
    return {name: task(name) for name in names}


def test_two_workers_run_every_task_once_from_opposite_ends(tmp_path):
    names = [f"task{i}" for i in range(7)]
    log, results = [], {}
    tasks = _recording_tasks(names, log)

    def worker(reverse):
        results[reverse] = warm_up_kernels(tmp_path, reverse=reverse, tasks=tasks)

    threads = [threading.Thread(target=worker, args=(r,), name=f"gw{int(r)}") for r in (False, True)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(name for _, name in log) == names  # each task once, by one worker or the other
    forward, backward = results[False][0], results[True][0]
    assert sorted(forward + backward) == names and not results[False][1] and not results[True][1]
    assert forward[0] == names[0] and backward[0] == names[-1]
    assert all((tmp_path / f"{n}.done").exists() for n in names)
    assert gc.isenabled()
    assert warm_up_kernels(tmp_path, tasks=tasks) == ([], [])  # a second run finds them done


def test_a_failed_task_is_reported_not_marked_done_and_the_rest_run(tmp_path, capsys):
    names = ["a", "b", "c"]
    log = []
    gc_states = []
    ran, failed = warm_up_kernels(tmp_path, tasks=_recording_tasks(names, log, fail={"b"}, gc_states=gc_states))
    assert (ran, failed) == (["a", "c"], ["b"])
    assert gc_states == [False] * 3  # the collector held off during each task (one process, one thread)
    assert [n for _, n in log] == names
    assert not (tmp_path / "b.done").exists() and (tmp_path / "c.done").exists()
    assert "RuntimeError: b failed" in capsys.readouterr().err
    assert gc.isenabled()


def test_the_command_line_runs_a_workers_share(tmp_path):
    """`python tests/conftest.py --warm-up DIR`, as the fixture starts it: with every task
    already done it has nothing to run and exits 0 (the tasks themselves compile the kernels)."""
    for name in WARM_UP:
        (tmp_path / f"{name}.done").touch()
    conftest = Path(__file__).with_name("conftest.py")
    for extra in ([], ["--reverse"]):
        proc = subprocess.run([sys.executable, str(conftest), "--warm-up", str(tmp_path), *extra],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
