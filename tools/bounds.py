"""Print every accuracy figure of the tests beside its bound.

    .venv/bin/python tools/bounds.py [--workers 2] [--json FILE] [TEST_FILE ...]

Runs the test files that check figures through `tests/figures.within` (default: every such
file under tests/), with the environment variable that makes `within` record each figure, and
prints one row per figure: the test, what was measured, today's value, the bound, and the bound
over the value (how much room the bound leaves; the rule is at most about 3x, or a stated reason
in `wide`). Rows whose bound leaves more than 3.5x and give no reason are listed at the end. Exits
with pytest's status: a figure beyond its bound is a failed test.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from figures import ENV  # noqa: E402

ROOM = 3.5  # the rule: a bound at most about 3x the figure it guards; flagged beyond 3.5x


def figure_files() -> list[Path]:
    return sorted(p for p in (ROOT / "tests").glob("test_*.py") if "from figures import within" in p.read_text())


def room(rec: dict) -> float:
    """The bound over the value (math.inf for a zero value); for a two-sided bound the narrower side's ratio."""
    value, bound, lower = rec["value"], rec["bound"], rec["lower"]
    if value is None:
        return math.nan
    if lower is not None:  # two-sided: how far each edge is from the value, against the value
        return 1.0 + min(bound - value, value - lower) / abs(value) if value else math.inf
    return bound / value if value > 0 else math.inf


def table(records: list[dict]) -> str:
    lines = ["| test | figure | value | bound | bound / value | stated reason for a wider bound |",
             "|---|---|---|---|---|---|"]
    for rec in sorted(records, key=lambda r: (r["test"], r["figure"])):
        span = f"{rec['lower']:.4g} .. {rec['bound']:.4g}" if rec["lower"] is not None else f"{rec['bound']:.4g}"
        value = "NaN" if rec["value"] is None else f"{rec['value']:.4g}"
        mark = "" if rec["ok"] else " (FAILED)"
        lines.append(f"| {rec['test']} | {rec['figure']} | {value}{mark} | {span} | {room(rec):.2f} | {rec['wide']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="*", type=Path, help="test files (default: every file that uses figures.within)")
    ap.add_argument("--workers", type=int, default=2, help="pytest-xdist workers (default 2)")
    ap.add_argument("--json", type=Path, help="also write the records here")
    args = ap.parse_args(argv)
    files = args.files or figure_files()
    with tempfile.TemporaryDirectory() as tmp:
        record_file = Path(tmp) / "figures.jsonl"
        env = dict(os.environ, **{ENV: str(record_file)})
        cmd = [sys.executable, "-m", "pytest", *map(str, files), "-q", "-p", "no:cacheprovider"]
        if args.workers > 1:
            cmd += ["-n", str(args.workers), "--dist", "loadgroup"]
        status = subprocess.call(cmd, cwd=ROOT, env=env)
        records = [json.loads(line) for line in record_file.read_text().splitlines()] if record_file.exists() else []
    if args.json:
        args.json.write_text(json.dumps(records, indent=1))
    print(f"\n{len(records)} figures from {len(files)} test files\n")
    print(table(records))
    loose = [r for r in records if room(r) > ROOM and not r["wide"]]
    failed = [r for r in records if not r["ok"]]
    print(f"\nbounds leaving more than {ROOM:g}x today's figure with no stated reason: {len(loose)}")
    for rec in loose:
        print(f"  {rec['test']}: {rec['figure']} {rec['value']:.4g}, bound {rec['bound']:.4g} ({room(rec):.1f}x)")
    print(f"figures beyond their bounds: {len(failed)}")
    return status


if __name__ == "__main__":
    sys.exit(main())
