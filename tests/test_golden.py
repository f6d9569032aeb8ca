"""The estimators' outputs equal their committed golden masters (tests/golden.py says how the
masters are made and when to rewrite them): paper-sim and snow-sine with the MPF, friction-snow
with the GP-SSM, and the default replay over a log with dropped rows, blank cells and a gap."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import golden


@pytest.mark.parametrize("case", golden.CASES)
def test_outputs_equal_golden_master(case, tmp_path):
    problems = golden.compare(case, golden.run_case(case, tmp_path))
    assert not problems, "\n".join(problems) + "\n(an intended change: rewrite with `python tests/golden.py --write`)"


@pytest.mark.parametrize("case", [c for c in golden.CASES if c != "friction-snow"])
def test_numba_backend_outputs_equal_golden_master(case, tmp_path):
    """The MPF's cases on its numba backend ([mpf] backend = "numba"): the masters of the default backend,
    the C core, which computes the numba kernels' numbers (`golden.py --hash --backend numba` prints the
    same hashes)."""
    problems = golden.compare(case, golden.run_case(case, tmp_path, backend="numba"))
    assert not problems, "\n".join(problems)


def test_comparison_notices_a_relative_change_of_1e_8():
    master, total = golden.read_master("paper-sim", "results")
    run = np.zeros((total, master.shape[1]))
    run[golden.thin_index(total)] = master
    assert golden.compare("paper-sim", {"results": run}) == []
    run[golden.thin_index(total)[7], golden.ESTIMATE_COLUMNS.index("Cr_y")] *= 1 + 1e-8
    problems = golden.compare("paper-sim", {"results": run})
    assert len(problems) == 1 and "1 values differ" in problems[0] and "Cr_y" in problems[0]
    assert golden.compare("paper-sim", {"results": run[:-1]})[0].endswith(f"the master's run had {total}")


README = Path(__file__).resolve().parents[1] / "README.md"
TIMING = re.compile(r"wall time \d+\.\d\d s \(\d+x real time\), median step \d+\.\d us")


def readme_output_block() -> list[str]:
    """The lines of the README's first `text` block: the example output of `make run`."""
    text = README.read_text()
    start = text.index("```text\n") + len("```text\n")
    return text[start:text.index("```", start)].splitlines()


def test_readme_example_output_is_what_make_run_prints(tmp_path):
    """The README's example output is `tirefilter run --scenario paper-sim --seed 0` (what
    `make run` runs): every line it shows is printed, in that order, character for character;
    the timing line in the printed format with this machine's figures; "..." stands for lines
    left out."""
    printed: list[str] = []
    golden.run_case("paper-sim", tmp_path, printed)
    lines = printed[0].splitlines()
    at = 0
    for shown in readme_output_block():
        if shown == "...":
            continue
        if shown.startswith("wall time"):
            assert TIMING.fullmatch(shown), f"README's timing line is not in the printed format: {shown!r}"
            match = lambda line: TIMING.fullmatch(line) is not None  # noqa: E731
        else:
            match = shown.__eq__
        found = next((k for k in range(at, len(lines)) if match(lines[k])), None)
        assert found is not None, f"README shows a line `tirefilter run` does not print (after line {at}):\n{shown}\n" \
                                  f"printed:\n{printed[0]}\n(regenerate the README's block from this run)"
        at = found + 1
