"""The run loop (`runs.run`, `runs.Run.step`): what every source and sink relies on."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tirefilter import runs
from tirefilter.estimators.base import Estimate, Inputs, Measurement
from tirefilter.io.results import ESTIMATE_COLUMNS

COLUMNS = ESTIMATE_COLUMNS + ("a", "b", "c")
U, Y = Inputs(0.0, 1.0, 1.0, 20.0), Measurement(0.1, 0.2, 0.3)


class _Constant:
    """An estimator whose estimate is its step count; `fails_at` raises there."""

    name = "constant"

    def __init__(self, fails_at: int | None = None):
        self.k, self.fails_at, self.seen = 0, fails_at, []

    def reset(self, rng):
        self.k = 0

    def step(self, t, u, y):
        if self.k == self.fails_at:
            raise FloatingPointError("diverged")
        self.k += 1
        self.seen.append((t, u, y))
        return Estimate(active=True, vx=20.0, vy=0.0, yaw_rate=0.0, Cf_y=float(self.k), Cr_y=2.0)


class _Log:
    """A sink noting the order of every hook, by name."""

    def __init__(self, calls: list, name: str):
        self.calls, self.name = calls, name
        self.rows = []

    def stepped(self, estimator, est):
        self.calls.append((self.name, "stepped", est.Cf_y))

    def write(self, row):
        self.rows.append(row)
        self.calls.append((self.name, "write", row[0]))

    def finish(self):
        self.calls.append((self.name, "finish"))

    def close(self):
        self.calls.append((self.name, "close"))

    def summarize(self, summary):
        self.calls.append((self.name, "summarize", summary.steps))


def _samples(n: int):
    for k in range(n):
        yield runs.Sample(k, 0.01 * k, U, Y, (np.array([k, 2.0 * k]), np.array([-1.0])))


def test_every_sink_sees_every_row_in_order_and_the_summary_at_the_end():
    calls = []
    est = _Constant()
    stepper = runs.Run(est, COLUMNS, [_Log(calls, "first"), _Log(calls, "second")])
    summary = runs.run(_samples(2), stepper, runs.StepSummary(seed=0, estimator="constant"),
                       rng=np.random.default_rng(0))
    assert calls == [("first", "stepped", 1.0), ("second", "stepped", 1.0), ("first", "write", 0.0),
                     ("second", "write", 0.0), ("first", "stepped", 2.0), ("second", "stepped", 2.0),
                     ("first", "write", 0.01), ("second", "write", 0.01), ("first", "finish"), ("second", "finish"),
                     ("first", "close"), ("second", "close"), ("first", "summarize", 2), ("second", "summarize", 2)]
    row = stepper.last
    assert row.shape == (len(COLUMNS),) and row[COLUMNS.index("Cf_y")] == 2.0
    np.testing.assert_array_equal(row[len(ESTIMATE_COLUMNS):], [1.0, 2.0, -1.0])  # the sample's values, in order
    assert summary.status == "ok" and summary.steps == 2 and summary.median_step_us > 0
    assert est.seen[1] == (0.01, U, Y)


def test_a_failure_is_named_by_on_error_and_leaves_the_rows_before_it():
    calls = []
    sink = _Log(calls, "sink")
    stepper = runs.Run(_Constant(fails_at=3), COLUMNS, [sink],
                       on_error=lambda sample, exc: ValueError(f"row {sample.k} at t = {sample.t:g} s: {exc}"))
    summary = runs.StepSummary(seed=0, estimator="constant")
    with pytest.raises(ValueError, match="row 3 at t = 0.03 s: diverged") as info:
        runs.run(_samples(5), stepper, summary)
    assert isinstance(info.value.__cause__, FloatingPointError) and info.value.summary is summary
    assert summary.status == "failed" and summary.steps == 3 and len(sink.rows) == 3
    assert ("sink", "finish") not in calls and calls[-2:] == [("sink", "close"), ("sink", "summarize", 3)]


def test_without_an_estimator_the_row_has_no_estimates_and_a_short_sample_is_refused():
    stepper = runs.Run(None, COLUMNS)
    row = stepper.step(runs.Sample(0, 1.5, U, Y, (np.arange(3.0),)))
    assert row[0] == 1.5 and np.isnan(row[1:len(ESTIMATE_COLUMNS)]).all() and stepper.median_step_us() is None
    with pytest.raises(ValueError, match="a sample of 2 values for the 3 columns"):
        stepper.step(runs.Sample(1, 1.6, U, Y, (np.arange(2.0),)))


def test_the_guard_is_reset_on_the_first_step_and_left_out_on_request():
    from tirefilter.estimators.guard import guard_from_config

    est = _Constant()
    est.guard = guard_from_config({})
    est.guard(-0.01, Y)  # a history the run's first step must not see: its Y would repeat it (held)
    stepper = runs.Run(est, COLUMNS)
    for k in range(3):
        stepper.step(runs.Sample(k, 0.01 * k, U, Y, (np.zeros(3),)))
    assert stepper.guard is est.guard
    assert est.seen[0][2] == Y and math.isnan(est.seen[1][2].ax)  # the second is an exact repeat: held
    unguarded = _Constant()
    unguarded.guard = guard_from_config({})
    stepper = runs.Run(unguarded, COLUMNS, guard=False)
    for k in range(3):
        stepper.step(runs.Sample(k, 0.01 * k, U, Y, (np.zeros(3),)))
    assert stepper.guard is None and all(seen[2] == Y for seen in unguarded.seen)
