"""Mutation testing of the core maths: small, deliberate errors put into the source one at a
time, and whether a mapped, fast subset of the tests notices (docs/mutation.md).

    .venv/bin/python benchmarks/mutation.py [--module PATH] [--max N] [--seed S] [--list] [--rescore FILE]
                                            [--match TEXT] [--json FILE] [--jobs 1]

Mutants come from the source's syntax tree (`ast`), one per change:
- arithmetic operators swapped: + <-> -, * <-> /, // -> /, ** -> *, and in augmented
  assignments (+= <-> -=, *= <-> /=);
- comparisons flipped: < <-> <=, > <-> >=, == <-> !=;
- numeric constants changed: 0 -> 1, 1 -> 0, another int c -> c + 1, a float c -> 1.01 c;
  True <-> False;
- a term dropped: a + b -> a, a + b -> b, a - b -> a, a * b -> a, a * b -> b, a / b -> a;
- a negation removed: -a -> a, not a -> a;
- max <-> min (the builtins and numpy's maximum / minimum);
- a return value replaced: return x -> return None.
Not mutated: strings, f-strings, docstrings, annotations, decorators, and the defaults of
dataclass fields in class bodies (configuration values, not maths).

Each mutant is written into the source file in place; the mapped tests run in a child of this
process (forked after numpy, scipy, numba and pytest are imported, so each run costs the tests
and the package's own import, not the interpreter's start), with a timeout of 3 times the clean
run (at least 10 s more than it). Killed: a test fails, errors or times out. The original file
is put back after every mutant (try/finally, and a copy kept in a journal outside the worktree
that the next run restores if this one was killed), and the run ends with a check that every
file is byte-identical to what it was.

Targets whose numpy reference has a compiled twin (the MPF's numpy step, the NiW and MNIW
statistics) run the twin-equality tests (tests/test_kernels.py) only for the mutants the other
tests miss: such a mutant is "killed by the twin" (the compiled kernel, an independent
implementation, disagrees), which would not catch the same error made in both. The report
gives the score with and without those kills. The compiled twins themselves are not mutated:
they are guarded by the numba-against-numpy equality tests.

Mutants with no observable effect may be listed, with a reason each, in
benchmarks/mutation_equivalent.toml (by key: `--list` prints it); they are left out of the
score.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import math
import os
import random
import signal
import sys
import tempfile
import time
import tomllib
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EQUIVALENT_FILE = ROOT / "benchmarks" / "mutation_equivalent.toml"
JOURNAL = Path(tempfile.gettempdir()) / f"tirefilter-mutation-{hashlib.sha1(str(ROOT).encode()).hexdigest()[:12]}"

# ---- what is mutated and which tests run for it ------------------------------------------------

_LOG_TESTS = ("tests/test_replay.py", "tests/test_exact_log.py", "-k",
              "not reproduces_the_cosimulation and not missing_samples and not real_recording")
_MPF_TWIN = ("tests/test_kernels.py", "-k", "stiffness_mpf")


@dataclass(frozen=True)
class Target:
    """One source file: the tests that run for its mutants (pytest arguments), the twin
    tests run for the mutants those miss, and optionally the functions mutated (qualnames;
    "Qual@start..end": the lines of Qual from the first containing `start` up to the first
    after it containing `end`)."""

    path: str
    tests: tuple[str, ...]
    twin_tests: tuple[str, ...] = ()
    functions: tuple[str, ...] | None = None
    skip: tuple[str, ...] = ()  # qualnames not mutated (presentation)
    env: tuple[tuple[str, str], ...] = ()


TARGETS = (
    Target("src/tirefilter/stats/linalg.py", ("tests/test_stats.py", "tests/test_exact_stats.py")),
    Target("src/tirefilter/stats/student_t.py", ("tests/test_stats.py", "tests/test_exact_stats.py")),
    Target("src/tirefilter/stats/particles.py", ("tests/test_stats.py", "tests/test_exact_stats.py")),
    Target("src/tirefilter/stats/niw.py", ("tests/test_stats.py", "tests/test_exact_stats.py"), _MPF_TWIN),
    Target("src/tirefilter/stats/noise.py", ("tests/test_sensors.py", "tests/test_exact_stats.py", "-k",
                                                      "noise_estimate or noise_level or held")),
    Target("src/tirefilter/stats/sandwich.py", ("tests/test_stats.py", "tests/test_exact_stats.py", "-k",
                                                         "sandwich or batch_means")),
    Target("src/tirefilter/stats/gp.py", ("tests/test_gp_stats.py", "tests/test_exact_gp.py"),
           ("tests/test_kernels.py", "-k", "basis_features")),
    Target("src/tirefilter/stats/mniw.py", ("tests/test_gp_stats.py", "tests/test_exact_mniw.py"),
           ("tests/test_kernels.py", "-k", "mniw_kernels_equal")),
    Target("src/tirefilter/vehicle/tires.py", ("tests/test_vehicle_model.py", "tests/test_exact_vehicle.py")),
    Target("src/tirefilter/vehicle/single_track.py", ("tests/test_vehicle_model.py", "tests/test_exact_vehicle.py",
                                                    "tests/test_exact_model.py", "tests/test_imu_roll.py")),
    Target("src/tirefilter/vehicle/params.py", ("tests/test_vehicle_model.py", "tests/test_scenarios.py",
                                                "tests/test_exact_vehicle.py")),
    Target("src/tirefilter/metrics.py", ("tests/test_metrics.py", "tests/test_exact_metrics.py"),
           skip=("_cov_warning", "_pct", "_signed_pct", "format_metrics", "metrics_line")),
    Target("src/tirefilter/io/log.py", _LOG_TESTS),
    Target("src/tirefilter/estimators/mpf/filter.py",
           ("tests/test_stiffness_mpf.py", "tests/test_exact_mpf.py", "-k", "numpy or exact_mpf"), _MPF_TWIN,
           functions=("StiffnessMPF._step@# 2. weights..plausible = self._plausible",
                      "StiffnessMPF._step@# 4. bias..self.w_prev = w",
                      "StiffnessMPF._bias_update")),
)

# ---- the mutants ------------------------------------------------------------------------------

_BINOP_SWAP = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult, ast.FloorDiv: ast.Div,
               ast.Pow: ast.Mult}
_AUG_SWAP = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult}
_CMP_SWAP = {ast.Lt: ast.LtE, ast.LtE: ast.Lt, ast.Gt: ast.GtE, ast.GtE: ast.Gt, ast.Eq: ast.NotEq, ast.NotEq: ast.Eq}
_CALL_SWAP = {"max": "min", "min": "max", "maximum": "minimum", "minimum": "maximum"}
_OPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.FloorDiv: "//", ast.Pow: "**",
        ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==", ast.NotEq: "!="}


@dataclass
class Mutant:
    path: str  # relative to the repository root
    qualname: str
    line: int
    kind: str
    original: str  # the node's source, as ast.unparse writes it
    mutated: str
    start: int = field(repr=False)  # byte offsets of the replaced text in the original file
    end: int = field(repr=False)
    text: bytes = field(repr=False)  # what replaces it
    key: str = ""
    status: str = ""
    seconds: float = 0.0

    def short(self, width: int = 110) -> str:
        def cut(s):
            s = " ".join(s.split())
            return s if len(s) <= width // 2 else s[: width // 2 - 3] + "..."

        return f"{cut(self.original)}  ->  {cut(self.mutated)}"


def _offsets(source: bytes) -> list[int]:
    starts, pos = [0], 0
    for line in source.splitlines(keepends=True):
        pos += len(line)
        starts.append(pos)
    return starts


class _Collector(ast.NodeVisitor):
    def __init__(self, target: Target, source: bytes):
        self.target, self.source = target, source
        self.lines = _offsets(source)
        self.stack: list[str] = []
        self.mutants: list[Mutant] = []
        self.text_lines = source.decode("utf-8").splitlines()
        self.ranges = self._ranges()

    # which lines are in scope
    def _ranges(self) -> dict[str, tuple[int, int] | None] | None:
        if self.target.functions is None:
            return None
        out: dict[str, list] = {}
        for spec in self.target.functions:
            qual, _, anchors = spec.partition("@")
            out.setdefault(qual, []).append(anchors or None)
        return out

    def _in_scope(self, line: int) -> bool:
        qual = ".".join(self.stack)
        if any(qual == s or qual.startswith(s + ".") for s in self.target.skip):
            return False
        if self.ranges is None:
            return True
        for scope, specs in self.ranges.items():
            if not (qual == scope or qual.startswith(scope + ".")):
                continue
            for anchors in specs:
                if anchors is None:
                    return True
                lo, hi = self._anchor_lines(scope, anchors)
                if lo <= line < hi:
                    return True
        return False

    def _anchor_lines(self, scope: str, anchors: str) -> tuple[int, int]:
        start, end = anchors.split("..")
        lo0, hi0 = self.func_lines[scope]
        lo = next((i for i in range(lo0, hi0 + 1) if start in self.text_lines[i - 1]), None)
        if lo is None:
            raise SystemExit(f"{self.target.path}: anchor {start!r} not found in {scope}")
        hi = next((i for i in range(lo + 1, hi0 + 1) if end in self.text_lines[i - 1]), None)
        if hi is None:
            raise SystemExit(f"{self.target.path}: anchor {end!r} not found in {scope} after {start!r}")
        return lo, hi

    def collect(self, tree: ast.Module) -> list[Mutant]:
        self.func_lines = {}
        stack: list[tuple[str, ast.AST]] = [("", tree)]
        while stack:  # the line span of every function and class, by qualname
            prefix, node = stack.pop()
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    q = f"{prefix}.{child.name}" if prefix else child.name
                    self.func_lines[q] = (child.lineno, child.end_lineno)
                    stack.append((q, child))
        self.visit(tree)
        return self.mutants

    # scopes
    def visit_FunctionDef(self, node):
        self.stack.append(node.name)
        for d in node.args.defaults + [d for d in node.args.kw_defaults if d is not None]:
            self.visit(d)
        for stmt in node.body:
            if stmt is node.body[0] and _is_docstring(stmt):
                continue
            self.visit(stmt)
        self.stack.pop()

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_ClassDef(self, node):
        self.stack.append(node.name)
        for stmt in node.body:
            if stmt is node.body[0] and _is_docstring(stmt):
                continue
            if isinstance(stmt, ast.AnnAssign):  # dataclass fields and their defaults: configuration
                continue
            self.visit(stmt)
        self.stack.pop()

    def visit_Module(self, node):
        for stmt in node.body:
            if stmt is node.body[0] and _is_docstring(stmt):
                continue
            if isinstance(stmt, (ast.Import, ast.ImportFrom)):
                continue
            self.visit(stmt)

    def visit_JoinedStr(self, node):  # f-strings: messages
        return

    def visit_AnnAssign(self, node):
        if node.value is not None:
            self.visit(node.value)

    def visit_arg(self, node):
        return

    # mutants
    def _add(self, node, kind: str, new_node, *, paren: bool = True):
        if not self._in_scope(node.lineno):
            return
        start = self.lines[node.lineno - 1] + node.col_offset
        end = self.lines[node.end_lineno - 1] + node.end_col_offset
        text = ast.unparse(new_node)
        self.mutants.append(Mutant(self.target.path, ".".join(self.stack) or "<module>", node.lineno, kind,
                                   ast.unparse(node), text, start, end,
                                   (f"({text})" if paren else text).encode("utf-8")))

    def visit_BinOp(self, node):
        op = type(node.op)
        if op in _BINOP_SWAP:
            self._add(node, f"op {_OPS[op]} -> {_OPS[_BINOP_SWAP[op]]}",
                      ast.BinOp(node.left, _BINOP_SWAP[op](), node.right))
        if op in (ast.Add, ast.Sub, ast.Mult, ast.Div):
            self._add(node, "drop right operand", node.left)
        if op in (ast.Add, ast.Mult):
            self._add(node, "drop left operand", node.right)
        self.generic_visit(node)

    def visit_AugAssign(self, node):
        op = type(node.op)
        if op in _AUG_SWAP:
            self._add(node, f"op {_OPS[op]}= -> {_OPS[_AUG_SWAP[op]]}=",
                      ast.AugAssign(node.target, _AUG_SWAP[op](), node.value), paren=False)
        self.visit(node.value)
        if not isinstance(node.target, ast.Name):
            self.visit(node.target)

    def visit_Compare(self, node):
        for i, op in enumerate(node.ops):
            if type(op) in _CMP_SWAP:
                ops = list(node.ops)
                ops[i] = _CMP_SWAP[type(op)]()
                self._add(node, f"cmp {_OPS[type(op)]} -> {_OPS[type(ops[i])]}",
                          ast.Compare(node.left, ops, node.comparators))
        self.generic_visit(node)

    def visit_UnaryOp(self, node):
        if isinstance(node.op, (ast.USub, ast.Not)):
            self._add(node, "drop negation" if isinstance(node.op, ast.USub) else "drop not", node.operand)
        self.generic_visit(node)

    def visit_Constant(self, node):
        v = node.value
        if isinstance(v, bool):
            self._add(node, "constant", ast.Constant(not v), paren=False)
        elif isinstance(v, int):
            new = 1 if v == 0 else 0 if v == 1 else v + 1
            self._add(node, "constant", ast.Constant(new), paren=False)
        elif isinstance(v, float):
            new = 1.0 if v == 0 else 0.0 if v == 1 else v * 1.01
            self._add(node, "constant", ast.Constant(new), paren=False)

    def visit_Call(self, node):
        f = node.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
        numpy_attr = isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id in ("np", "numpy")
        if name in _CALL_SWAP and (isinstance(f, ast.Name) or numpy_attr):
            new_f = ast.Name(_CALL_SWAP[name]) if isinstance(f, ast.Name) else ast.Attribute(f.value, _CALL_SWAP[name])
            self._add(node, f"call {name} -> {_CALL_SWAP[name]}", ast.Call(new_f, node.args, node.keywords))
        self.generic_visit(node)

    def visit_Return(self, node):
        v = node.value
        if v is not None and not (isinstance(v, ast.Constant) and v.value is None):
            self._add(v, "return None", ast.Constant(None), paren=False)
        self.generic_visit(node)


def _is_docstring(stmt) -> bool:
    return isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) and isinstance(stmt.value.value, str)


def mutants_of(target: Target) -> list[Mutant]:
    source = (ROOT / target.path).read_bytes()
    found = _Collector(target, source).collect(ast.parse(source))
    seen: dict[str, int] = {}
    for m in found:  # the key: stable across edits elsewhere in the file and reformatting
        base = f"{m.path}|{m.qualname}|{m.kind}|{m.original}|{m.mutated}"
        seen[base] = seen.get(base, 0) + 1
        m.key = base if seen[base] == 1 else f"{base}|#{seen[base]}"
    for m in found:  # each mutant must parse and differ from the original
        new = source[: m.start] + m.text + source[m.end:]
        ast.parse(new)
    return found


def load_equivalent() -> dict[str, str]:
    if not EQUIVALENT_FILE.is_file():
        return {}
    data = tomllib.loads(EQUIVALENT_FILE.read_text())
    out = {}
    for e in data.get("equivalent", []):
        if not e.get("reason"):
            raise SystemExit(f"{EQUIVALENT_FILE.name}: every entry needs a reason ({e.get('key')})")
        out[e["key"]] = e["reason"]
    return out


# ---- running the tests ------------------------------------------------------------------------

def _preload(numba: bool) -> None:
    """Import what every test run imports, once, before the children are forked (never the
    package itself: the children import the mutated source)."""
    import importlib
    from importlib.metadata import entry_points

    for name in ("numpy", "scipy", "scipy.special", "scipy.stats", "scipy.linalg", "pytest", "fmpy", "tomli_w",
                 "hypothesis"):
        try:
            importlib.import_module(name)
        except ImportError:
            pass
    if numba:
        try:
            importlib.import_module("numba")
        except ImportError:
            pass
    for ep in entry_points(group="pytest11"):  # the pytest plugins
        try:
            ep.load()
        except Exception:  # a plugin that cannot load here is pytest's business in the child
            pass
    assert not any(m == "tirefilter" or m.startswith("tirefilter.") for m in sys.modules), "package preloaded"


def run_tests(args: tuple[str, ...], env: dict, timeout: float, log: Path) -> tuple[str, float]:
    """pytest `args` in a forked child: ("passed" | "failed" | "timeout", seconds)."""
    sys.stdout.flush()
    sys.stderr.flush()
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:  # the child
        code = 70
        try:
            os.setpgid(0, 0)
            fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            os.environ.update(env)
            sys.dont_write_bytecode = True
            os.chdir(ROOT)
            import pytest

            code = int(pytest.main(["-q", "-x", "-p", "no:cacheprovider", *args]))
        except BaseException:
            traceback.print_exc()
        finally:
            os._exit(code)
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            rc = os.waitstatus_to_exitcode(status)
            return ("passed" if rc == 0 else "failed"), time.monotonic() - t0
        if time.monotonic() - t0 > timeout:
            try:
                os.killpg(pid, signal.SIGKILL)  # the child's own process group
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)
            return "timeout", time.monotonic() - t0
        time.sleep(0.02)


class InPlace:
    """Writes mutants into one file and always puts the original back (bytes and mtime); a
    journal outside the worktree holds the original while a mutant is in place."""

    def __init__(self, path: Path):
        self.path = path
        self.original = path.read_bytes()
        self.stat = path.stat()
        self.digest = hashlib.sha256(self.original).hexdigest()

    def write(self, data: bytes) -> None:
        JOURNAL.mkdir(exist_ok=True)
        (JOURNAL / "original").write_bytes(self.original)
        (JOURNAL / "path").write_text(str(self.path))
        self.path.write_bytes(data)
        _drop_pyc(self.path)

    def restore(self) -> None:
        self.path.write_bytes(self.original)
        os.utime(self.path, ns=(self.stat.st_atime_ns, self.stat.st_mtime_ns))
        _drop_pyc(self.path)
        for name in ("original", "path"):
            (JOURNAL / name).unlink(missing_ok=True)

    def check(self) -> None:
        now = hashlib.sha256(self.path.read_bytes()).hexdigest()
        if now != self.digest:
            raise SystemExit(f"{self.path} is not byte-identical to the original after the run")


def _drop_pyc(path: Path) -> None:
    import importlib.util

    Path(importlib.util.cache_from_source(str(path))).unlink(missing_ok=True)


def lock_journal():
    """One run at a time per worktree: an exclusive lock on the journal, held until this
    process ends (the file stays open); a second run stops here."""
    import fcntl

    JOURNAL.mkdir(exist_ok=True)
    f = open(JOURNAL / "lock", "w")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise SystemExit(f"another mutation run of {ROOT} is in progress (lock: {JOURNAL / 'lock'})") from None
    return f


def recover_journal() -> None:
    """A run that was killed with a mutant in place: put the original back (only while
    holding the lock: no run is in progress)."""
    if (JOURNAL / "path").is_file() and (JOURNAL / "original").is_file():
        path = Path((JOURNAL / "path").read_text())
        path.write_bytes((JOURNAL / "original").read_bytes())
        print(f"restored {path} from the journal of an interrupted run")
        for name in ("original", "path"):
            (JOURNAL / name).unlink(missing_ok=True)


def _raise_exit(signum, frame):
    raise SystemExit(128 + signum)


def run_target(target: Target, mutants: list[Mutant], equivalent: dict[str, str], logs: Path) -> dict:
    env = {"PYTHONPATH": f"{ROOT / 'src'}{os.pathsep}{ROOT / 'viewer'}", "OPENBLAS_NUM_THREADS": "1",
           **dict(target.env)}
    path = ROOT / target.path
    name = Path(target.path).name
    base, clean = run_tests(target.tests, env, 600.0, logs / f"{name}.clean.log")
    if base != "passed":
        raise SystemExit(f"{target.path}: the mapped tests fail without a mutant (log: {logs / f'{name}.clean.log'})")
    twin_clean = 0.0
    if target.twin_tests:
        base, twin_clean = run_tests(target.twin_tests, env, 600.0, logs / f"{name}.twin-clean.log")
        if base != "passed":
            raise SystemExit(f"{target.path}: the twin tests fail without a mutant")
    timeout, twin_timeout = max(3 * clean, clean + 10.0), max(3 * twin_clean, twin_clean + 10.0)
    print(f"{target.path}: {len(mutants)} mutants, clean run {clean:.1f} s"
          + (f" (+ twin {twin_clean:.1f} s)" if target.twin_tests else "") + f", timeout {timeout:.0f} s", flush=True)
    place = InPlace(path)
    try:
        for i, m in enumerate(mutants, 1):
            try:
                place.write(place.original[: m.start] + m.text + place.original[m.end:])
                status, sec = run_tests(target.tests, env, timeout, logs / f"{name}.mutant.log")
                if status == "passed" and target.twin_tests:
                    status, s2 = run_tests(target.twin_tests, env, twin_timeout, logs / f"{name}.mutant.log")
                    sec += s2
                    status = {"passed": "passed", "failed": "failed-twin", "timeout": "timeout-twin"}[status]
            finally:
                place.restore()
            m.status = {"passed": "equivalent" if m.key in equivalent else "survived", "failed": "killed",
                        "timeout": "killed (timeout)", "failed-twin": "killed by the twin",
                        "timeout-twin": "killed by the twin (timeout)"}[status]
            m.seconds = round(sec, 2)
            mark = "  " if m.status.startswith("killed") else "!!" if m.status == "survived" else "=="
            print(f"{mark} [{i}/{len(mutants)}] {m.status:<18s} {sec:5.1f} s  {name}:{m.line} {m.qualname}  "
                  f"{m.short()}", flush=True)
    finally:
        place.restore()
        place.check()
    return summarize(target.path, mutants, equivalent)


def summarize(path: str, mutants: list[Mutant], equivalent: dict[str, str], population: int | None = None) -> dict:
    """One module's counts; `population` is the number of mutants it has when `mutants` is a
    random draw of them (--max)."""
    n = len(mutants)
    killed = sum(m.status.startswith("killed") for m in mutants)
    twin = sum(m.status.startswith("killed by the twin") for m in mutants)
    eq = sum(m.status == "equivalent" for m in mutants)
    stale = [m.key for m in mutants if m.key in equivalent and m.status.startswith("killed")]
    scored = n - eq
    return {"module": path, "mutants": n, "killed": killed, "killed_by_twin_only": twin, "equivalent": eq,
            "survived": n - killed - eq, "score": killed / scored if scored else None,
            "score_without_twin": (killed - twin) / scored if scored else None,
            "allow_listed_but_killed": stale, "population": population or n}


# ---- the command ------------------------------------------------------------------------------

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--module", action="append", help="only this source file (repeatable), e.g. "
                    "src/tirefilter/stats/niw.py")
    ap.add_argument("--max", type=int, help="at most N mutants per module, drawn at random (--seed)")
    ap.add_argument("--seed", type=int, default=0, help="the draw of --max (default 0)")
    ap.add_argument("--match", action="append", help="only mutants whose key contains this text (repeatable: any)")
    ap.add_argument("--list", action="store_true", help="list the mutants (index, place, change, key) and stop")
    ap.add_argument("--json", type=Path, help="write the report (summary and every mutant) to this file")
    ap.add_argument("--jobs", type=int, default=1, help="mutants run at a time; only 1: each is written into the "
                    "worktree's own source file in place")
    ap.add_argument("--logs", type=Path, help="folder for the test logs (default: a temporary one)")
    ap.add_argument("--rescore", type=Path, metavar="JSON", help="print the report of an earlier --json file with "
                    "the allow-list as it is now (runs nothing)")
    a = ap.parse_args(argv)
    if a.jobs != 1:
        ap.error("--jobs: only 1 (the mutants are written into the source files in place, one at a time)")
    if a.rescore:
        return rescore(a.rescore)
    targets = list(TARGETS)
    if a.module:
        wanted = {str((ROOT / p).resolve().relative_to(ROOT)) if (ROOT / p).exists() else p for p in a.module}
        targets = [t for t in TARGETS if t.path in wanted]
        unknown = wanted - {t.path for t in targets}
        if unknown:
            ap.error(f"not a mutation target: {', '.join(sorted(unknown))} (targets: "
                     f"{', '.join(t.path for t in TARGETS)})")
    equivalent = load_equivalent()
    plan = []
    for t in targets:
        ms = mutants_of(t)
        if a.match:
            ms = [m for m in ms if any(s in m.key for s in a.match)]
        population = len(ms)
        if a.max is not None and len(ms) > a.max:
            keep = set(random.Random(a.seed).sample(range(len(ms)), a.max))
            ms = [m for i, m in enumerate(ms) if i in keep]
        plan.append((t, ms, population))
    if a.list:
        for t, ms, _ in plan:
            print(f"# {t.path}: {len(ms)} mutants")
            for i, m in enumerate(ms, 1):
                eq = "  [equivalent]" if m.key in equivalent else ""
                print(f"{i:4d} {Path(m.path).name}:{m.line} {m.qualname}  {m.short()}{eq}\n     key: {m.key}")
        return 0
    lock = lock_journal()  # noqa: F841 (held open for the whole run)
    recover_journal()
    os.environ["PYTHONPATH"] = f"{ROOT / 'src'}{os.pathsep}{ROOT / 'viewer'}"
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    for p in (ROOT / "viewer", ROOT / "src"):
        sys.path.insert(0, str(p))
    _preload(numba=not any(dict(t.env).get("NUMBA_DISABLE_JIT") for t, _, _ in plan))
    signal.signal(signal.SIGTERM, _raise_exit)
    logs = a.logs or Path(tempfile.mkdtemp(prefix="mutation-logs-"))
    logs.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    summaries, all_mutants = [], []
    for t, ms, population in plan:
        if not ms:
            continue
        summaries.append(run_target(t, ms, equivalent, logs) | {"population": population})
        all_mutants += ms
    print_report(summaries, all_mutants, equivalent, time.monotonic() - t0)
    if not (a.match or a.max is not None):  # every mutant of these modules ran: entries that match none are stale
        ran = {t.path for t, _, _ in plan}
        keys = {m.key for m in all_mutants}
        for key in equivalent:
            if key.split("|", 1)[0] in ran and key not in keys:
                print(f"note: {EQUIVALENT_FILE.name} entry matches no mutant (the code changed?): {key}")
    if a.json:
        a.json.write_text(json.dumps({"summary": summaries, "total": total(summaries),
                                      "mutants": [{k: v for k, v in asdict(m).items()
                                                   if k not in ("start", "end", "text")} for m in all_mutants]},
                                     indent=1) + "\n")
    return 0


def rescore(path: Path) -> int:
    """The report of a --json file, its survivors and equivalents sorted again by the
    allow-list as it is now."""
    equivalent = load_equivalent()
    data = json.loads(path.read_text())
    by_module: dict[str, list[Mutant]] = {}
    for d in data["mutants"]:
        m = Mutant(start=0, end=0, text=b"", **d)
        if m.status in ("survived", "equivalent"):
            m.status = "equivalent" if m.key in equivalent else "survived"
        by_module.setdefault(m.path, []).append(m)
    population = {s["module"]: s.get("population") for s in data["summary"]}
    summaries = [summarize(p, ms, equivalent, population.get(p)) for p, ms in by_module.items()]
    print_report(summaries, [m for ms in by_module.values() for m in ms], equivalent, None)
    return 0


def total(summaries: list[dict]) -> dict:
    n = sum(s["mutants"] for s in summaries)
    k = sum(s["killed"] for s in summaries)
    tw = sum(s["killed_by_twin_only"] for s in summaries)
    eq = sum(s["equivalent"] for s in summaries)
    out = {"mutants": n, "killed": k, "killed_by_twin_only": tw, "equivalent": eq, "survived": n - k - eq,
           "score": k / (n - eq) if n - eq else None, "score_without_twin": (k - tw) / (n - eq) if n - eq else None}
    if any(s["population"] > s["mutants"] for s in summaries):
        out |= stratified(summaries)
    return out


def stratified(summaries: list[dict]) -> dict:
    """The score of all the modules' mutants estimated from a random draw of each (--max):
    each module's share of caught non-equivalent mutants, weighted by its number of mutants,
    with a 95 % interval from the normal approximation whose variance takes the Agresti-Coull
    share (k + 2) / (n + 4) of each module (so that a draw with no survivor still has a width)
    and the finite-population correction."""
    pop = sum(s["population"] for s in summaries)
    est = var = 0.0
    for s in summaries:
        scored = s["mutants"] - s["equivalent"]
        if not scored:
            continue
        w, p = s["population"] / pop, s["killed"] / scored
        p_ac = (s["killed"] + 2) / (scored + 4)
        fpc = (s["population"] - s["mutants"]) / max(s["population"] - 1, 1)
        est += w * p
        var += w * w * p_ac * (1 - p_ac) / (scored + 4) * fpc
    half = 1.96 * math.sqrt(var)
    return {"population": pop, "estimated_score": est, "estimated_score_ci95": [max(est - half, 0.0), min(est + half, 1.0)]}


def print_report(summaries, mutants, equivalent, seconds) -> None:
    print(f"\n{'module':44s}{'mutants':>8s}{'killed':>8s}{'(twin)':>8s}{'equiv':>7s}{'survived':>9s}{'score':>8s}"
          f"{'w/o twin':>9s}")

    def row(name, s):
        def pct(x):
            return "n/a" if x is None else f"{100 * x:.1f} %"

        print(f"{name:44s}{s['mutants']:8d}{s['killed']:8d}{s['killed_by_twin_only']:8d}{s['equivalent']:7d}"
              f"{s['survived']:9d}{pct(s['score']):>8s}{pct(s['score_without_twin']):>9s}")

    for s in summaries:
        row(s["module"].removeprefix("src/tirefilter/"), s)
    if len(summaries) > 1:
        tot = total(summaries)
        row("total", tot)
        if "estimated_score" in tot:
            lo, hi = tot["estimated_score_ci95"]
            print(f"score of all {tot['population']} mutants, estimated from this draw (weighted by each module's "
                  f"count): {100 * tot['estimated_score']:.1f} % (95 % interval {100 * lo:.1f}-{100 * hi:.1f} %)")
    if seconds is not None:
        print(f"({seconds / 60:.1f} min)")
    surv = [m for m in mutants if m.status == "survived"]
    if surv:
        print("\nsurviving mutants:")
        for m in surv:
            print(f"  {m.path}:{m.line} {m.qualname}  {m.short(160)}\n      key: {m.key}")
    for s in summaries:
        for key in s["allow_listed_but_killed"]:
            print(f"note: allow-listed as equivalent but killed (remove it from {EQUIVALENT_FILE.name}): {key}")


if __name__ == "__main__":
    sys.exit(main())
