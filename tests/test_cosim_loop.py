"""The co-simulation loop's speed-ups change no number: the Result
CSV's text, the rows kept in memory, the CSV read back and the FMU's outputs are those of
the straightforward code they replace."""

from __future__ import annotations

import math
import signal
from dataclasses import replace

import numpy as np
import pytest

from tirefilter import runs
from tirefilter.io import results
from tirefilter.io.csv_format import format_rows
from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.io.results import ESTIMATE_COLUMNS, ResultWriter, iter_results, read_results
from tirefilter.cosim.run import cosim_samples
from tirefilter.scenarios import load_scenario

SPECIAL = [0.0, -0.0, 1.0, 0.1, 1 / 3, 1e16, 1e15, 1e-5, 1e-4, 1e-300, 5e-324, 1.7976931348623157e308,
           math.inf, -math.inf, math.nan, 123456789.123, -2.5e-7, 50000.0, 2.0 ** 60, -1e22]


def cell_by_cell(rows) -> str:
    """The Result CSV's rows as the writer formatted them before: repr per cell, NaN empty."""
    return "".join(",".join("" if x != x else repr(float(x)) for x in row) + "\n" for row in rows)


def table(n_rows: int, n_cols: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n_rows, n_cols)) * 10.0 ** rng.integers(-8, 9, (n_rows, n_cols))
    a.flat[rng.choice(a.size, len(SPECIAL), replace=False)] = SPECIAL
    a[rng.random(a.shape) < 0.05] = math.nan
    return a


def test_format_rows_is_repr_cell_by_cell():
    rows = [SPECIAL, SPECIAL[::-1]] + table(50, 9).tolist()
    assert format_rows(rows) == cell_by_cell(rows)
    assert format_rows([]) == ""
    assert format_rows([[math.nan]]) == "\n"


@pytest.mark.parametrize("background_after", [None, 150])
def test_result_writer_text_with_and_without_the_helper_process(tmp_path, monkeypatch, background_after):
    """The file is the header and the rows formatted cell by cell, whether the rows are
    formatted here or (after `background_after` rows) in the helper process; rows handed
    over before an error are in the file."""
    if background_after is not None:
        monkeypatch.setattr(results, "BACKGROUND_AFTER_ROWS", background_after)
    cols = tuple(f"c{j}" for j in range(7))
    rows = table(1234, len(cols), seed=1)
    path = tmp_path / "r.csv"
    with pytest.raises(RuntimeError, match="stop"):
        with ResultWriter(path, cols, background=background_after is not None) as w:
            for j, row in enumerate(rows):
                w.write(row if j % 2 else row.tolist())  # arrays and lists alike
                if j == 300:
                    assert (w._child is not None) == (background_after is not None)
            raise RuntimeError("stop")
    assert path.read_text() == ",".join(cols) + "\n" + cell_by_cell(rows)
    assert w.rows == len(rows)


def test_result_writer_checks_the_row_length(tmp_path):
    with ResultWriter(tmp_path / "r.csv", ("a", "b")) as w:
        with pytest.raises(ValueError, match="3 values for 2 columns"):
            w.write([1.0, 2.0, 3.0])


def test_read_results_columns_are_the_whole_tables(tmp_path):
    cols = tuple(f"c{j}" for j in range(6))
    rows = table(300, len(cols), seed=2)
    path = tmp_path / "r.csv"
    path.write_text(",".join(cols) + "\n" + cell_by_cell(rows))
    whole = read_results(path)
    for max_rows in (None, 1, 77, 300, 1000):
        part = read_results(path, max_rows=max_rows, columns=["c4", "c1", "missing"])
        assert list(part) == ["c4", "c1"]
        for c in part:
            np.testing.assert_array_equal(part[c], whole[c][:max_rows])
            assert part[c].dtype == float
    chunks = list(iter_results(path, chunk_rows=128, columns=["c0", "c5"]))
    assert [len(c["c0"]) for c in chunks] == [128, 128, 44]
    np.testing.assert_array_equal(np.concatenate([c["c5"] for c in chunks]), whole["c5"])
    empty = tmp_path / "e.csv"
    empty.write_text(",".join(cols) + "\n")
    assert {k: len(v) for k, v in read_results(empty, columns=["c2", "x"]).items()} == {"c2": 0}


def test_rows_kept_across_blocks(monkeypatch):
    monkeypatch.setattr(runs, "KEEP_BLOCK", 4)
    rows = table(10, 3, seed=3)
    for n in (0, 3, 4, 5, 10):
        out = runs.KeptRows()
        for row in rows[:n]:
            out.write(row.copy())
        kept = out.rows()
        if n == 0:
            assert kept is None
        else:
            np.testing.assert_array_equal(kept, np.vstack([np.array(r, float) for r in rows[:n]]))


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_master_that_skips_reads_after_steps_sees_the_same_outputs(fmu_paths, fmi):
    """Without a speed hold the master does not read the outputs after a doStep (they are
    read after the next inputs are set): every sample's outputs equal, bit for bit, those of
    a loop that reads them after every step, as the master did before."""
    scenario = replace(load_scenario("paper-sim"), duration=3.0)
    assert scenario.inputs.speed_hold is None
    params = scenario.fmu_parameters(12345)
    h, n = scenario.communication_step, int(round(3.0 / scenario.communication_step))
    U = scenario.inputs.open_loop(np.arange(n + 1) * h)
    with VehicleFMU(fmi) as fmu:
        fast = [(s.k, s.y.copy(), s.inputs, s.meas) for s in cosim_samples(scenario, fmu, params)]
        fmu.reset(params)
        slow = []
        for k in range(n + 1):
            fmu.set_inputs(U[k])
            slow.append(fmu.outputs().copy())
            if k < n:
                fmu.do_step(k * h, h)
    assert len(fast) == len(slow) == n + 1
    names = fmu.output_names
    for (k, y, inputs, meas), y_ref in zip(fast, slow):
        np.testing.assert_array_equal(y, y_ref)
        assert inputs.delta == y_ref[names.index("delta_meas")] and meas.ay == y_ref[names.index("ay_meas")]
        assert meas.yaw_rate == y_ref[names.index("yaw_rate_meas")] and inputs.vx == y_ref[names.index("vx")]


@pytest.mark.parametrize("executable", ["", "/nonexistent/python", "/opt/some-fmi-tool/bin/simulator"])
def test_result_writer_without_a_helper_process_formats_the_rows_itself(tmp_path, monkeypatch, executable):
    import sys

    monkeypatch.setattr(results, "BACKGROUND_AFTER_ROWS", 150)
    monkeypatch.setattr(sys, "executable", executable)
    cols = ("a", "b", "c")
    rows = table(450, len(cols), seed=4)
    path = tmp_path / "r.csv"
    with ResultWriter(path, cols) as w:
        for row in rows:
            w.write(row)
        assert w._child is None
    assert path.read_text() == "a,b,c\n" + cell_by_cell(rows)


def test_result_writer_keeps_every_row_when_its_helper_start_is_interrupted(tmp_path, monkeypatch):
    """An interrupt while the formatting process starts goes up, and the rows handed over so
    far, the block that was being flushed included, end up in the file."""
    import subprocess

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(results, "BACKGROUND_AFTER_ROWS", 150)
    monkeypatch.setattr(subprocess, "Popen", interrupted)
    cols = ("a", "b")
    rows = table(450, len(cols), seed=5)
    path = tmp_path / "r.csv"
    written = 0
    with pytest.raises(KeyboardInterrupt):
        with ResultWriter(path, cols) as w:
            for row in rows:
                w.write(row)
                written += 1
    assert written == 199  # the 200th write took its row, then the flush of rows 101-200 was interrupted
    assert path.read_text() == "a,b\n" + cell_by_cell(rows[:200])


@pytest.mark.parametrize("body_error", [None, "interrupt", "failure", "keyboard"])
def test_the_run_fills_the_summary_when_the_csv_fails_to_close(tmp_path, monkeypatch, body_error):
    """A Result CSV that fails to close (a full disk) still leaves a filled summary: it fails a
    run that had not failed; after a failure or an interruption the first exception goes on
    and the summary names both."""
    def full_disk(self):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(ResultWriter, "close", full_disk)
    summary = runs.StepSummary(seed=0, estimator="none")
    columns = ESTIMATE_COLUMNS + ("x",)
    expected = {None: OSError, "interrupt": runs.Interrupted, "failure": ValueError,
                "keyboard": KeyboardInterrupt}[body_error]

    def samples():
        for k in range(3):
            yield runs.Sample(k, 0.01 * k, Inputs(0.0, 0.0, 0.0, 20.0), Measurement(0.0, 0.0, 0.0), (np.ones(1),))
        if body_error == "interrupt":
            raise runs.Interrupted(signal.SIGTERM)
        if body_error == "failure":
            raise ValueError("the estimator failed")
        if body_error == "keyboard":  # outside `interruptible`: no signal handler turned it into Interrupted
            raise KeyboardInterrupt

    with pytest.raises(expected) as info:
        runs.run(samples(), runs.Run(None, columns, [ResultWriter(tmp_path / "r.csv", columns)]), summary)
    assert summary.steps == 3 and summary.wall_time_s > 0.0
    if body_error == "keyboard":  # goes on as it is; the summary keeps its status
        assert summary.status == "ok"
        assert summary.error == "closing the outputs failed: [Errno 28] No space left on device"
        return
    assert info.value.summary is summary
    assert summary.status == {None: "failed", "interrupt": "interrupted", "failure": "failed"}[body_error]
    assert "No space left on device" in summary.error
    if body_error is not None:
        assert "closing the outputs failed too" in summary.error
    if body_error == "interrupt":
        assert summary.t_reached == 0.02
