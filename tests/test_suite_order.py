"""The order in which make test's xdist workers get the tests (tests/conftest.py, `LONG_TESTS`,
`long_modules_first`; docs/development.md, "How long make test takes")."""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import LONG_TESTS, long_modules_first, long_test_seconds

TESTS = Path(__file__).resolve().parent


def test_every_long_test_names_a_test_function_of_its_file():
    """A renamed or moved test would silently drop out of the order: each entry is a file of
    tests/ that defines that test function."""
    for key in LONG_TESTS:
        file, name = key.split("::")
        tree = ast.parse((TESTS / file).read_text())
        assert name in {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}, key


def test_long_modules_come_first_with_their_tests_together_in_file_order():
    ids = ["tests/test_a.py::test_1", "tests/test_a.py::test_2[x]",
           "tests/test_metrics.py::test_a_short_one[15.0-0.01]",
           "tests/test_b.py::test_1@g",
           "tests/test_metrics.py::test_streamed_metrics_equal_run_metrics[sizes0]",
           "tests/test_faults.py::test_guard_removes_exactly_the_spikes_of_a_noisy_signal",
           "tests/test_faults.py::test_estimators_stay_finite_and_do_not_restart_on_spikes[mpf]@g"]
    metrics = LONG_TESTS["test_metrics.py::test_streamed_metrics_equal_run_metrics"]
    faults = LONG_TESTS["test_faults.py::test_estimators_stay_finite_and_do_not_restart_on_spikes"]
    assert faults > metrics  # the order below: test_faults' module, then test_metrics', then the rest
    assert long_test_seconds(ids[4]) == metrics
    assert long_test_seconds(ids[6]) == faults and long_test_seconds(ids[0]) == 0.0  # the group suffix is ignored
    assert [ids[i] for i in long_modules_first(ids)] == [ids[5], ids[6], ids[2], ids[4], ids[0], ids[1], ids[3]]
