"""Per-statement timer of the MPF step's Python (issue 14, stop 24).

    .venv/bin/python benchmarks/profile_mpf_lines.py SRC_DIR N [DURATION] [FUNCTIONS]

Loads SRC_DIR's MPF (the modules of `tirefilter/estimators/mpf/`, or an older checkout's single
`tirefilter/estimators/stiffness_mpf.py`; and `stats/sandwich.py`) as modules of their own
with a timing mark (`_lp`) inserted by `ast` before every statement of the step's methods (FUNCTIONS, comma
separated; default: `step`, `_step_compiled` and what they call per sample), builds the filter with this
checkout's defaults as `tirefilter run` does, and steps it three times through the first DURATION s
(default 5) of recorded paper-sim samples (seed 0) at N particles. Printed per statement: the median over
the steps of the wall time from its mark to the next one (exclusive: a statement that calls an instrumented
method gets the time until the callee's first mark; a compiled pass's statement includes numba's dispatch),
times the share of steps that ran it, less the cost of one mark (measured first; on a loaded machine the
subtraction is rough: compare statements within one run, and the step's median with the uninstrumented
bench_mpf_ab.py). The kernels are this checkout's (imported, not copied).
"""
import ast, os, sys, time, types, dataclasses
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
from pathlib import Path  # noqa: E402
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cost import record, WARMUP
from tirefilter.estimators import build_estimator

src_dir, N = Path(sys.argv[1]), int(sys.argv[2])
dur = float(sys.argv[3]) if len(sys.argv) > 3 else 5.0
FUNCS = set(sys.argv[4].split(",")) if len(sys.argv) > 4 else {
    "step", "_step", "_step_compiled", "_calibrate", "_estimate_fused", "_gate_or_restart", "_work",
    "_predict_ay", "_excite_cx", "_smooth_surprise", "_draw_factors", "_draw_inflation", "_cap_forgetting",
    "_set_undriven_share", "_pinned_too_long", "_outlier_bound", "_state_noise_scale", "_swap_work", "update", "_close",
    "_calibrate_moments", "_ay_residual", "update_pair"}
SANDWICH = ("update", "update_pair", "_close")  # (the functions of stats/sandwich.py)
acc, state = {}, {"last": None, "t": 0}
pc = time.perf_counter_ns
def _lp(key):
    t = pc()
    lk = state["last"]
    if lk is not None:
        acc[lk] = acc.get(lk, 0) + (t - state["t"])
    state["last"] = key
    state["t"] = pc()

class Ins(ast.NodeTransformer):
    def __init__(self, tag): self.tag = tag
    def _stmts(self, body, fname):
        out = []
        for s in body:
            self.generic_visit_stmt(s, fname)
            seg = f"{fname}:{s.lineno}"
            call = ast.Expr(ast.Call(ast.Name("_lp", ast.Load()), [ast.Constant(seg)], []))
            out += [call, s]
        return out
    def generic_visit_stmt(self, s, fname):
        for field in ("body", "orelse", "finalbody"):
            b = getattr(s, field, None)
            nested_def = isinstance(s, (ast.FunctionDef, ast.ClassDef))
            if isinstance(b, list) and b and isinstance(b[0], ast.stmt) and not nested_def:
                setattr(s, field, self._stmts(b, fname))
    def visit_FunctionDef(self, node):
        if node.name in FUNCS:
            node.body = self._stmts(node.body, node.name)
        return node

def load(path, modname, extra=None):
    text = path.read_text()
    if extra:
        for a, b in extra:
            text = text.replace(a, b)
    tree = ast.parse(text)
    tree = Ins(modname).visit(tree)
    ast.fix_missing_locations(tree)
    mod = types.ModuleType(modname)
    mod.__file__ = str(path)
    mod._lp = _lp
    sys.modules[modname] = mod
    exec(compile(tree, str(path), "exec"), mod.__dict__)
    return mod

est_dir = src_dir / "tirefilter" / "estimators"
sw = load(src_dir / "tirefilter" / "stats" / "sandwich.py", "prof_sandwich")
swaps = [("from tirefilter.stats.sandwich import", "from prof_sandwich import")]
if (est_dir / "mpf").is_dir():  # the package: its modules in the order they import each other
    parts = ("config", "supervision", "adaptation", "compiled", "filter")
    swaps += [(f"from tirefilter.estimators.mpf.{p} import", f"from prof_mpf_{p} import") for p in parts]
    files = [est_dir / "mpf" / f"{p}.py" for p in parts]
    for p, f in zip(parts, files):
        load(f, f"prof_mpf_{p}", swaps)
    mpf = types.SimpleNamespace(MPFConfig=sys.modules["prof_mpf_config"].MPFConfig,
                                StiffnessMPF=sys.modules["prof_mpf_filter"].StiffnessMPF)
else:
    files = [est_dir / "stiffness_mpf.py"]
    mpf = load(files[0], "prof_mpf", swaps)
# the file of each instrumented function, for its lines
file_of = {node.name: f for f in files for node in ast.walk(ast.parse(f.read_text()))
           if isinstance(node, ast.FunctionDef)}
sim, samples = record("paper-sim", dur)
new = build_estimator("mpf", sim, model="auto", particles=N, config={})
fields = {f.name for f in dataclasses.fields(mpf.MPFConfig)}
cfg = mpf.MPFConfig(**{k: v for k, v in dataclasses.asdict(new.cfg).items() if k in fields})
est = mpf.StiffnessMPF(new.vehicle, cfg)
# empty-mark cost
t0 = pc()
for _ in range(10000):
    _lp("x")
mark = (pc() - t0) / 10000
acc.clear(); state["last"] = None
rounds = 3
totals = []
steps = []
print(f"load {os.getloadavg()[0]:.2f}")
for r in range(rounds):
    est.reset(np.random.default_rng(1))
    for k, s in enumerate(samples):
        if k == WARMUP and r == 0:
            acc.clear()
        state["last"] = None
        t0 = pc()
        est.step(*s)
        _lp("END")
        if k >= WARMUP:
            totals.append((pc() - t0) / 1e3)
            steps.append(dict(acc))
        acc.clear()
nsteps = rounds * (len(samples) - WARMUP)
lines = {f: f.read_text().splitlines() for f in files}
swl = (src_dir / "tirefilter" / "stats" / "sandwich.py").read_text().splitlines()
print(f"N = {N}: {nsteps} steps, step median {np.median(totals):.1f} us mean {np.mean(totals):.1f}; "
      f"mark {mark:.0f} ns (subtracted)")
rows = []
keys = {k for d in steps for k in d}
for key in keys:
    vals = [d[key] for d in steps if key in d]
    v = float(np.median(vals)) * len(vals)
    if ":" not in key: continue
    f, ln = key.split(":")
    ln = int(ln)
    src = (swl if f in SANDWICH else lines[file_of[f]])[ln - 1].strip()[:90]
    rows.append((v / nsteps / 1e3 - mark / 1e3, f, ln, src))
rows.sort(reverse=True)
tot = sum(r[0] for r in rows)
print(f"sum of statements (median per statement x share of steps) {tot:.1f} us/step")
for us, f, ln, src in rows[:60]:
    print(f"{us:7.2f}  {f}:{ln}  {src}")
