"""What `tirefilter run` / `replay` print besides the metrics: the numba kernels' one-time
compile announced and timed apart from the run, progress lines when stderr is no terminal,
and a unit on every figure (stiffness in kN/rad and kN per unit slip, beta in degrees)."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tirefilter import cli
from tirefilter.compiling import ANNOUNCEMENT, CompileWatch
from tirefilter.runs import Progress


def _fresh_kernels():
    """Two new numba functions, the outer calling the inner (no cache: they compile on
    their first call, every time this runs)."""
    import numba

    @numba.njit(cache=False)
    def inner(x):
        return 2.0 * x

    @numba.njit(cache=False)
    def outer(x):
        return inner(x) + 1.0

    return outer


def test_compile_watch_times_the_outermost_compiles_and_announces_once():
    outer = _fresh_kernels()
    said = []
    with CompileWatch(said.append) as watch:
        assert outer(1.0) == 3.0  # compiles outer, and inner inside it: one outermost compile
        first = watch.seconds
        assert outer(2.0) == 5.0  # compiled already: no event
        assert watch.seconds == first
        assert outer(3) == 7.0  # a new signature compiles again
    assert watch.kernels == 2 and watch.seconds > first > 0
    assert said == [ANNOUNCEMENT]  # at the first compile only
    other = _fresh_kernels()
    other(1.0)  # outside the watch: not counted
    assert watch.kernels == 2


def test_the_timing_line_leaves_the_compile_out(capsys):
    summary = SimpleNamespace(wall_time_s=22.0, compile_s=20.0, median_step_us=180.0)
    compiled = SimpleNamespace(kernels=3, seconds=20.5)  # 0.5 s of it in building the estimator
    cli._print_timing(summary, 60.0, compiled)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("compile 20.5 s: the estimator's numba kernels (3), once")
    assert lines[1] == "wall time 2.00 s (30x real time), median step 180.0 us"
    cli._print_timing(SimpleNamespace(wall_time_s=2.0, compile_s=0.0, median_step_us=None), 60.0,
                      SimpleNamespace(kernels=0, seconds=0.0))
    assert capsys.readouterr().out == "wall time 2.00 s (30x real time)\n"  # no compile: no line


def test_progress_without_a_terminal_is_a_line_every_few_seconds(monkeypatch, capsys):
    clock = iter(np.arange(0.0, 1000.0, 1.0))  # each read of the clock: one second later
    monkeypatch.setattr("tirefilter.runs.time.perf_counter", lambda: float(next(clock)))
    p = Progress(total=10 * Progress.EVERY, enabled="lines")
    for _ in range(10 * Progress.EVERY):
        p.write(None)
    p.close()
    err = capsys.readouterr().err
    assert "\r" not in err and "[" not in err  # no bar redrawn in place
    lines = err.splitlines()
    assert lines and all(re.fullmatch(r"progress: \d+% \(\d+ of 2560 rows\) after \d+ s", line) for line in lines)
    assert len(lines) == 2  # 10 updates, one clock second apart: a line at most every LINE_EVERY_S = 5 s
    assert cli._progress(SimpleNamespace(quiet=False)) == "lines"  # pytest's stderr is no terminal
    assert cli._progress(SimpleNamespace(quiet=True)) is False


@pytest.fixture(scope="module")
def peer_log(tmp_path_factory, fmu_paths):
    from tirefilter.io.log import write_log
    from tirefilter.peer.drive import DriveSpec, simulate, vehicle_toml

    directory = tmp_path_factory.mktemp("peer")
    drive = simulate(DriveSpec(model="std", maneuver="sine", duration=8.0, seed=3))
    vehicle = directory / "peer.toml"
    vehicle.write_text(vehicle_toml(drive))
    return write_log(directory / "peer.csv", {k: np.asarray(v, float) for k, v in drive.columns.items()}), vehicle


def test_replay_prints_units_on_every_figure(peer_log, tmp_path, capsys):
    log, vehicle = peer_log
    out = tmp_path / "result.csv"
    assert cli.main(["replay", str(log), "--vehicle", str(vehicle), "--particles", "40", "--seed", "1",
                     "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    final = next(line for line in printed.splitlines() if line.startswith("final stiffness"))
    numbers = re.findall(r"(Cf_y|Cr_y|Cx) ([-+0-9.e]+) \+- ([0-9.e+-]+) (kN/rad|kN/unit slip)", final)
    assert [(p, u) for p, _, _, u in numbers] == [("Cf_y", "kN/rad"), ("Cr_y", "kN/rad"), ("Cx", "kN/unit slip")]
    import json

    summary = json.loads(out.with_suffix(".json").read_text())
    assert float(numbers[0][1]) == pytest.approx(summary["final"]["Cf_y"] * 1e-3, rel=1e-3)  # kN, not N
    noise = next(line for line in printed.splitlines() if line.startswith("sensor noise"))
    assert re.search(r"ax [0-9.e-]+ m/s\^2, ay [0-9.e-]+ m/s\^2, yaw_rate [0-9.e-]+ rad/s", noise), noise
    bias = next(line for line in printed.splitlines() if line.startswith("IMU bias"))
    assert "yaw_rate 0.01 rad/s" in bias and "yaw_rate 0.0001 rad/s/sqrt(s)" in bias, bias
    beta = next(line for line in printed.splitlines() if line.startswith("beta "))
    rmse = summary["metrics"]["state"]["beta"]["rmse"]
    assert beta.split()[1:3] == [f"{np.degrees(rmse):.3g}", "deg"]
    head = next(k for k, line in enumerate(printed.splitlines()) if line.startswith("state error"))
    assert "after 5 s" in printed.splitlines()[head + 1]  # a replay: its settled column leaves out the start-up
    assert "compile_s" in summary and summary["compile_s"] >= 0.0


def test_a_compile_inside_a_run_is_announced_and_left_out_of_the_real_time(monkeypatch, tmp_path, capsys, fmu_paths):
    """A kernel that compiles in the first step (as a fresh clone's MPF does): announced on
    stderr when it starts, its time printed on a line of its own and not in the wall time."""
    from tirefilter.estimators.base import Estimate

    class Compiling:
        name = "compiling"
        outer = None

        def reset(self, rng):
            pass

        def step(self, t, u, y):
            if self.outer is None:
                self.outer = _fresh_kernels()
                self.outer(1.0)  # compiles here, inside the run
            return Estimate(active=False, vx=20.0, vy=0.0, yaw_rate=0.0, Cf_y=1e5, Cr_y=1e5)

    monkeypatch.setattr("tirefilter.estimators.build", lambda *a, **k: Compiling())
    short = tmp_path / "short.toml"
    from tirefilter.scenarios import load_scenario

    short.write_text(load_scenario("paper-sim").file.read_text().replace("duration = 60.0", "duration = 1.0")
                     .replace("excitation = [[0.0, 60.0]]", "excitation = [[0.0, 1.0]]"))
    assert cli.main(["run", "--scenario", str(short), "--out", str(tmp_path / "run")]) == 0
    out, err = capsys.readouterr()
    assert ANNOUNCEMENT in err
    compile_line = next(line for line in out.splitlines() if line.startswith("compile "))
    wall_line = next(line for line in out.splitlines() if line.startswith("wall time "))
    compiled = float(compile_line.split()[1])
    wall = float(wall_line.split()[2])
    import json

    summary = json.loads(Path(tmp_path / "run" / "run.json").read_text())
    total, compile_s = summary["wall_time_s"], summary["compile_s"]
    assert compile_s > 0 and compiled == pytest.approx(compile_s, abs=0.051)  # printed to 0.1 s
    assert wall == pytest.approx(total - compile_s, abs=0.006)  # printed to 0.01 s
