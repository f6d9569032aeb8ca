"""Properties of the Log and Result CSVs beyond "no crash": what is written reads back
bit for bit, a whitespace-only cell is a missing sample like an empty one, and a missing
measurement row equals a dropped one for the estimator that defines it so (the linear KF,
whose exact zero-order-hold discretisation composes over the gap). Derandomised hypothesis
runs of a few dozen examples each."""

from __future__ import annotations

import gzip
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from tirefilter.io.results import ESTIMATE_COLUMNS, ResultWriter, iter_results, read_results
from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.linear_kf import KFConfig, LinearKF
from tirefilter.io.log import iter_log_chunks, read_log, write_log
from tirefilter.replay.run import replay_log
from tirefilter.scenarios import load_scenario

CI = settings(derandomize=True, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal as float64 bit patterns (so -0.0 differs from 0.0), every NaN equal to every NaN."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape != b.shape:
        return False
    nan = np.isnan(a)
    return bool(np.array_equal(nan, np.isnan(b)) and np.array_equal(a[~nan].view(np.int64), b[~nan].view(np.int64)))


# -- the Log CSV: write_log, then read_log / iter_log_chunks -------------------------------------
finite = st.floats(allow_nan=False, allow_infinity=False)
cell = st.one_of(finite, st.just(math.nan), st.sampled_from([0.0, -0.0, 5e-324, -1.7976931348623157e308, 0.1]))


@st.composite
def logs(draw) -> dict[str, np.ndarray]:
    """Columns of a valid Log CSV: strictly increasing finite t, a steering column, the IMU,
    a speed source, optional references and an unknown column; any finite value or NaN
    elsewhere (vx never below -0.1 m/s: reverse driving is an error)."""
    n = draw(st.integers(1, 12))
    t0 = draw(st.floats(-1e6, 1e6))
    steps = draw(st.lists(st.floats(1e-3, 10.0), min_size=n - 1, max_size=n - 1))
    t = t0 + np.concatenate([[0.0], np.cumsum(steps)])
    if not np.all(np.diff(t) > 0):  # (rounding at a large t0)
        t = t0 + np.arange(n, dtype=float)
    names = [draw(st.sampled_from(["delta", "steering_wheel_angle"])), "ax", "ay", "yaw_rate"]
    names += draw(st.sampled_from([["vx"], ["omega_f", "omega_r"], ["vx", "omega_f", "omega_r"],
                                   ["vx", "omega_fl", "omega_fr", "omega_rl", "omega_rr"]]))
    names += draw(st.lists(st.sampled_from(["beta_true", "true_vy", "Cf_y_true", "other"]), unique=True, max_size=3))
    names = draw(st.permutations(names))
    cols = {"t": t}
    for name in names:
        x = np.array(draw(st.lists(cell, min_size=n, max_size=n)), float)
        if name == "vx":
            x = np.where(x < -0.1, np.abs(x), x)
        cols[name] = x
    return cols


BIG = 1.7976931348623157e308  # the largest double: the corner mean must not overflow


@settings(CI, max_examples=60)
@given(cols=logs(), gz=st.booleans(), chunk=st.integers(1, 5))
@example(cols={"t": np.array([0.0, 0.01]), "delta": np.array([0.0, 0.01]), "ax": np.array([0.1, math.nan]),
               "ay": np.array([math.nan, 0.2]), "yaw_rate": np.array([0.0, -0.0]), "vx": np.array([20.0, 20.0]),
               "omega_fl": np.array([BIG, -BIG]), "omega_fr": np.array([BIG, -BIG]),
               "omega_rl": np.array([5e-324, 1.0]), "omega_rr": np.array([BIG, 3.0])}, gz=False, chunk=1)
def test_log_written_and_read_back_is_the_same_log(cols, gz, chunk):
    """`write_log` then `read_log`: every column (the references as `true_<name>`) bit for bit,
    NaN where it was NaN, the unknown column ignored; `iter_log_chunks` in chunks of `chunk`
    rows gives the same columns, chunk after chunk."""
    with tempfile.TemporaryDirectory() as tmp:
        path = write_log(Path(tmp) / ("log.csv.gz" if gz else "log.csv"), cols)
        log = read_log(path, need_steering_ratio=False)
        chunks = list(iter_log_chunks(path, chunk_rows=chunk, need_steering_ratio=False))
    assert log.header == tuple(cols)
    assert log.ignored == (("other",) if "other" in cols else ())
    for name, x in cols.items():
        if name == "other":
            continue
        got = log.references[_ref(name)] if _ref(name) else log.columns[name]
        assert _same_bits(got, x), name
        joined = np.concatenate([c.references[_ref(name)] if _ref(name) else c.columns[name] for c in chunks])
        assert _same_bits(joined, x), name
    assert [c.row0 for c in chunks] == list(range(0, len(cols["t"]), chunk))
    # what the estimators get: every sample a finite number or missing (the reader rejects an
    # infinite cell), an axle's speed the mean of its corners where the log has only those
    for name, x in log.signals.items():
        assert not np.isinf(x).any(), name
    for axle, (left, right) in (("omega_f", ("omega_fl", "omega_fr")), ("omega_r", ("omega_rl", "omega_rr"))):
        if axle not in cols and left in cols:
            mean = ((np.longdouble(cols[left]) + np.longdouble(cols[right])) / 2).astype(float)
            np.testing.assert_allclose(log.signals[axle], mean, rtol=2**-52, atol=1e-323)


def _ref(name: str) -> str | None:
    return {"beta_true": "true_beta", "true_vy": "true_vy", "Cf_y_true": "true_Cf_y"}.get(name)


# -- the Result CSV: ResultWriter, then read_results / iter_results -------------------------------
anything = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([-0.0, 5e-324, math.inf]))


@pytest.mark.filterwarnings("ignore:genfromtxt. Empty input file")  # (no rows: numpy says so)
@settings(CI, max_examples=60)
@given(data=st.data(), ncol=st.integers(2, 8), nrow=st.integers(0, 15), flush=st.integers(1, 6))
def test_result_rows_written_and_read_back_are_the_same_rows(data, ncol, nrow, flush):
    """`ResultWriter` (flushing every `flush` rows) then `read_results`, `iter_results` in
    chunks and `read_results(columns=...)`: every value bit for bit, infinities and -0.0 too,
    NaN as NaN."""
    names = list(ESTIMATE_COLUMNS[:ncol])
    rows = np.array(data.draw(st.lists(st.lists(anything, min_size=ncol, max_size=ncol), min_size=nrow,
                                       max_size=nrow)), float).reshape(nrow, ncol)
    some = data.draw(st.lists(st.sampled_from(names), min_size=1, max_size=ncol, unique=True))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.csv"
        with ResultWriter(path, tuple(names), flush_every=flush, background=False) as w:
            for row in rows:
                w.write(row.tolist())
        whole = read_results(path)
        chunks = list(iter_results(path, chunk_rows=3))
        subset = read_results(path, columns=some)
    assert list(whole) == names
    for j, name in enumerate(names):
        assert _same_bits(whole[name], rows[:, j]), name
        assert _same_bits(np.concatenate([c[name] for c in chunks]) if chunks else np.empty(0), rows[:, j]), name
    assert list(subset) == [c for c in some]
    for name in some:
        assert _same_bits(subset[name], rows[:, names.index(name)]), name


# -- a whitespace-only cell is a missing sample -------------------------------------------------
@pytest.mark.parametrize("blank", ["  ", " ", "\t", " \t "])
@pytest.mark.parametrize("gz", [False, True])
def test_whitespace_only_cells_read_as_missing_like_empty_cells(tmp_path, blank, gz):
    """docs/usage.md: an empty cell is a missing sample. A cell of only spaces or tabs is as
    empty (spreadsheet exports pad cells): the same log as with empty cells, NaN there, in
    every column kind (IMU, steering, speed, wheel corner, reference), whole or in chunks."""
    header = "t,delta,ax,ay,yaw_rate,vx,omega_fl,omega_fr,omega_r,beta_true"
    rows = [["0.0", "0.01", "0.1", "X", "0.02", "20.0", "55.0", "55.1", "55.2", "0.001"],
            ["0.01", "X", "X", "0.5", "0.03", "X", "X", "55.0", "X", "X"],
            ["0.02", "0.02", "0.2", "0.6", "X", "20.1", "55.3", "55.4", "55.5", "0.002"]]

    def write(name, fill):
        text = header + "\n" + "\n".join(",".join(fill if c == "X" else c for c in r) for r in rows) + "\n"
        path = tmp_path / (name + (".csv.gz" if gz else ".csv"))
        path.write_bytes(gzip.compress(text.encode()) if gz else text.encode())
        return path

    padded, empty = write("padded", blank), write("empty", "")
    a, b = read_log(padded), read_log(empty)
    assert set(a.columns) == set(b.columns) and set(a.signals) == set(b.signals)
    for name in a.columns:
        assert _same_bits(a.columns[name], b.columns[name]), name
    for name in a.signals:
        assert _same_bits(a.signals[name], b.signals[name]), name
    assert _same_bits(a.references["true_beta"], b.references["true_beta"])
    assert np.isnan(a.columns["ay"][0]) and np.isnan(a.columns["delta"][1]) and np.isnan(a.signals["omega_f"][1])
    assert np.count_nonzero(np.isnan(np.column_stack(list(a.columns.values())))) == 7  # the 8 X less beta_true
    chunked = list(iter_log_chunks(padded, chunk_rows=1))
    for name in a.columns:
        assert _same_bits(np.concatenate([c.columns[name] for c in chunked]), b.columns[name]), name


# -- a missing measurement row equals a dropped row (linear KF) -----------------------------------
@settings(CI, max_examples=25)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 18), dt=st.floats(0.005, 0.05))
def test_a_missing_measurement_row_equals_the_row_dropped_for_the_kf(seed, k, dt):
    """docs/usage.md: an empty cell is a missing sample, the estimator skips that measurement
    and holds the last input; each row is processed at its own t. The linear KF predicts with
    the held inputs over each interval by the exact zero-order-hold discretisation, so a row
    whose measurements and steer are empty (its vx the held one) is a prediction to t_k and
    then on to t_k+1 with the same inputs: the same as one prediction over both intervals, i.e.
    as the row not being there. Replayed from Log CSVs, the estimates of every later row agree
    to rounding (1e-9; measured: 1.1e-14 at most), and the estimate of the empty row is the
    prediction from the row before, with no update."""
    rng = np.random.default_rng(seed)
    n = 20
    t = np.cumsum(np.full(n, dt) * rng.uniform(0.5, 1.5, n))
    cols = {"t": t, "delta": 0.03 * np.sin(3.0 * t) + rng.normal(0, 0.002, n), "ax": rng.normal(0, 0.1, n),
            "ay": 1.5 * np.sin(3.0 * t) + rng.normal(0, 0.1, n),
            "yaw_rate": 0.08 * np.sin(3.0 * t) + rng.normal(0, 0.004, n), "vx": 20.0 + rng.normal(0, 0.3, n)}
    missing = {c: v.copy() for c, v in cols.items()}
    for c in ("delta", "ax", "ay", "yaw_rate"):
        missing[c][k] = math.nan
    missing["vx"][k] = missing["vx"][k - 1]  # the held speed
    dropped = {c: np.delete(v, k) for c, v in cols.items()}
    vehicle = load_scenario("paper-sim").vehicle
    with tempfile.TemporaryDirectory() as tmp:
        runs = {}
        for name, c in (("missing", missing), ("dropped", dropped)):
            log = read_log(write_log(Path(tmp) / f"{name}.csv", c))
            _, rows = replay_log(log, estimator=LinearKF(vehicle, KFConfig()), keep_rows=True)
            runs[name] = rows[:, :len(ESTIMATE_COLUMNS)]
    a, b = runs["missing"], runs["dropped"]
    assert a.shape[0] == n and b.shape[0] == n - 1
    rest = np.delete(a, k, axis=0)
    est = [ESTIMATE_COLUMNS.index(c) for c in ("vy", "yaw_rate", "beta")]
    np.testing.assert_array_equal(rest[:k], b[:k])  # before the row: the same computation
    np.testing.assert_allclose(rest[k:, est], b[k:, est], rtol=1e-9, atol=1e-12)
    # the empty row's estimate: the filter of the rows before it, predicted to t_k, not updated
    kf = LinearKF(vehicle, KFConfig())
    kf.reset()
    for j in range(k):
        kf.step(t[j], Inputs(delta=cols["delta"][j], vx=cols["vx"][j]), Measurement(ay=cols["ay"][j],
                                                                                     yaw_rate=cols["yaw_rate"][j]))
    kf.predict(cols["vx"][k - 1], cols["delta"][k - 1], t[k] - t[k - 1])
    vy_r = [ESTIMATE_COLUMNS.index(c) for c in ("vy", "yaw_rate")]
    np.testing.assert_allclose(a[k, vy_r], kf.x, rtol=1e-12, atol=1e-15)
