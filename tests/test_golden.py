"""The estimators' outputs equal their committed golden masters (tests/golden.py says how the
masters are made and when to rewrite them): paper-sim and snow-sine with the MPF, friction-snow
with the GP-SSM, and the default replay over a log with dropped rows, blank cells and a gap."""

from __future__ import annotations

import numpy as np
import pytest

import golden


@pytest.mark.parametrize("case", golden.CASES)
def test_outputs_equal_golden_master(case, tmp_path):
    problems = golden.compare(case, golden.run_case(case, tmp_path))
    assert not problems, "\n".join(problems) + "\n(an intended change: rewrite with `python tests/golden.py --write`)"


def test_comparison_notices_a_relative_change_of_1e_8():
    master, total = golden.read_master("paper-sim", "results")
    run = np.zeros((total, master.shape[1]))
    run[golden.thin_index(total)] = master
    assert golden.compare("paper-sim", {"results": run}) == []
    run[golden.thin_index(total)[7], golden.ESTIMATE_COLUMNS.index("Cr_y")] *= 1 + 1e-8
    problems = golden.compare("paper-sim", {"results": run})
    assert len(problems) == 1 and "1 values differ" in problems[0] and "Cr_y" in problems[0]
    assert golden.compare("paper-sim", {"results": run[:-1]})[0].endswith(f"the master's run had {total}")
