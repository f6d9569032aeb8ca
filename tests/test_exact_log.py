"""The Log CSV reader (io/log.py) against exact answers on what the other tests leave
out: a log read in chunks (sizes, offsets, the time check and the error locations across
chunk boundaries), reference columns, blank lines, the edges of the reverse-driving
tolerance and a log's duration. Found by mutation testing (benchmarks/mutation.py): each
test kills mutants the other tests let through."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tirefilter.errors import LogError
from tirefilter.io.log import iter_log_chunks, read_log, reference_name, write_log

HEADER = "t,delta,ax,ay,yaw_rate,vx"


def _log(tmp_path, rows, header=HEADER, name="log.csv"):
    path = tmp_path / name
    path.write_text(header + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return path


def _rows(n, t0=5.0, vx=20.0):
    return [(round(t0 + 0.01 * k, 2), 0.01, 0.1, 0.5, 0.02, vx) for k in range(n)]


def _error(path, **kw) -> str:
    with pytest.raises(LogError) as info:
        for _ in iter_log_chunks(path, **kw):
            pass
    return str(info.value)


def test_chunks_partition_the_log(tmp_path):
    """10 rows in chunks of 4: chunks of 4, 4 and 2 rows at offsets 0, 4, 8, together the
    whole log; each chunk's rows, duration and error locations count from the file's start."""
    path = _log(tmp_path, _rows(10))
    whole = read_log(path)
    chunks = list(iter_log_chunks(path, chunk_rows=4))
    assert [c.rows for c in chunks] == [4, 4, 2] and [c.row0 for c in chunks] == [0, 4, 8]
    np.testing.assert_array_equal(np.concatenate([c.t for c in chunks]), whole.t)
    np.testing.assert_array_equal(np.concatenate([c.lines for c in chunks]), whole.lines)
    assert whole.duration == pytest.approx(0.09) and chunks[1].duration == pytest.approx(0.03)
    assert chunks[2].where(1) == {"row": 10, "line": 11}
    assert list(iter_log_chunks(path, chunk_rows=5))[1].row0 == 5  # 10 rows: exactly two chunks


def test_errors_in_later_chunks_name_the_files_rows(tmp_path):
    """Chunks of 3: a short row, a negative vx and a time step back across a chunk boundary
    are named by their data row and file line in the whole file."""
    rows = _rows(8)
    short = _log(tmp_path, rows[:5] + [rows[5][:5]] + rows[6:], name="short.csv")
    assert re.search(r"data row 6 \(file line 7\): 5 cells for the header's 6 columns", _error(short, chunk_rows=3))
    back = [r if k != 7 else (r[0],) + r[1:5] + (-0.5,) for k, r in enumerate(rows)]
    assert re.search(r"column 'vx', data row 8 \(file line 9\): vx = -0.5", _error(_log(tmp_path, back, name="v.csv"),
                                                                                  chunk_rows=3))
    inf = [r if k != 4 else r[:3] + ("inf",) + r[4:] for k, r in enumerate(rows)]
    assert re.search(r"column 'ay', data row 5 \(file line 6\): 'inf' is not a finite number",
                     _error(_log(tmp_path, inf, name="inf.csv"), chunk_rows=3))
    nan_cell = [r if k != 4 else r[:3] + ("abc",) + r[4:] for k, r in enumerate(rows)]
    assert re.search(r"column 'ay', data row 5 \(file line 6\): 'abc' is not a number",
                     _error(_log(tmp_path, nan_cell, name="abc.csv"), chunk_rows=3))
    no_t = [r if k != 7 else ("",) + r[1:] for k, r in enumerate(rows)]
    assert re.search(r"column 't', data row 8 \(file line 9\): missing time",
                     _error(_log(tmp_path, no_t, name="no_t.csv"), chunk_rows=3))
    step_back = list(rows)
    step_back[6] = (round(rows[4][0] + 0.001, 3),) + rows[6][1:]  # data row 7 (chunk 3's first) before row 6
    path = _log(tmp_path, step_back, name="t.csv")
    with pytest.raises(LogError) as info:
        list(iter_log_chunks(path, chunk_rows=3))
    assert re.search(r"column 't', data row 7 \(file line 8\): time must increase strictly: t = 5.041 s after "
                     r"t = 5.05 s in data row 6", str(info.value)), str(info.value)
    assert info.value.value == 5.041
    same = list(rows)
    same[6] = (rows[5][0],) + rows[6][1:]  # the first time of chunk 3 repeats the last of chunk 2
    assert "data row 7 (file line 8): time must increase strictly" in _error(_log(tmp_path, same, name="s.csv"),
                                                                              chunk_rows=3)
    inner = list(rows)
    inner[7] = (rows[6][0],) + rows[7][1:]  # inside chunk 3: row 8 repeats row 7's time
    assert re.search(r"data row 8 \(file line 9\): time must increase strictly: t = 5.06 s after t = 5.06 s in "
                     r"data row 7", _error(_log(tmp_path, inner, name="i.csv"), chunk_rows=3))


def test_blank_lines_are_skipped_and_an_empty_log_names_its_lines(tmp_path):
    """A line of spaces between rows is a blank line, not a row; a header without rows is
    an error at file line 2, an empty file at file line 1."""
    path = tmp_path / "blank.csv"
    path.write_text(HEADER + "\n5.0,0.01,0.1,0.5,0.02,20.0\n   \n5.01,0.01,0.1,0.5,0.02,20.0\n")
    log = read_log(path)
    assert log.rows == 2 and log.lines.tolist() == [2, 4]
    (tmp_path / "none.csv").write_text(HEADER + "\n")
    assert "file line 2" in _error(tmp_path / "none.csv")
    (tmp_path / "empty.csv").write_text("")
    assert "file line 1" in _error(tmp_path / "empty.csv")


def test_reverse_driving_tolerance_is_a_tenth_of_a_metre_per_second(tmp_path):
    """vx down to -0.1 m/s is standstill noise; below that the log is refused."""
    rows = _rows(6, vx=0.5)
    ok = [r if k != 3 else r[:5] + (-0.1,) for k, r in enumerate(rows)]
    assert read_log(_log(tmp_path, ok, name="ok.csv")).signals["vx"][3] == -0.1
    bad = [r if k != 3 else r[:5] + (-0.1005,) for k, r in enumerate(rows)]
    assert "reverse driving" in _error(_log(tmp_path, bad, name="bad.csv"))


def test_reference_columns_both_spellings(tmp_path):
    """`<name>_true` and `true_<name>` are references under `true_<name>`, with NaN for an
    empty cell; `true_` and `_true` alone are not; two spellings of one name are an error
    at the header (file line 1); the steering-wheel log without a vehicle needs its ratio
    unless asked not to."""
    assert reference_name("vy_true") == "true_vy" and reference_name("true_beta") == "true_beta"
    assert reference_name("true_") is None and reference_name("_true") is None and reference_name("vy") is None
    rows = [r + (0.1 * k, "" if k == 2 else 0.2 * k) for k, r in enumerate(_rows(4))]
    log = read_log(_log(tmp_path, rows, header=HEADER + ",vy_true,true_beta"))
    assert set(log.references) == {"true_vy", "true_beta"}
    np.testing.assert_allclose(log.references["true_vy"], [0.0, 0.1, 0.2, 0.30000000000000004])
    assert np.isnan(log.references["true_beta"][2]) and log.references["true_beta"][3] == pytest.approx(0.6)
    assert log.ignored == ()
    two = _log(tmp_path, [r + (0.0, 0.0) for r in _rows(3)], header=HEADER + ",vy_true,true_vy", name="two.csv")
    assert re.search(r"file line 1: two reference columns of 'vy' \(true_vy and vy_true\)", _error(two))
    swa = _log(tmp_path, _rows(3), header=HEADER.replace("delta", "steering_wheel_angle"), name="swa.csv")
    assert "steering_ratio" in _error(swa)
    assert "delta" not in next(iter_log_chunks(swa, need_steering_ratio=False)).signals


def test_write_log_round_trip_into_a_new_folder(tmp_path):
    """write_log creates missing folders, ends every row with a newline, writes NaN as an
    empty cell and values that read back exactly."""
    cols = {"t": np.array([0.0, 0.01, 0.02]), "delta": np.array([0.1, np.nan, 1 / 3]), "ax": np.zeros(3),
            "ay": np.ones(3), "yaw_rate": np.full(3, 0.2), "vx": np.full(3, 20.0)}
    path = write_log(tmp_path / "a" / "b" / "log.csv", cols)
    text = path.read_text()
    assert text.endswith("\n") and text.count("\n") == 4 and ",," in text
    log = read_log(path)
    np.testing.assert_array_equal(log.signals["delta"], cols["delta"])
