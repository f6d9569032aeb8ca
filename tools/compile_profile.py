"""Where one warm-up task's compile goes (docs/development.md, "How long `make test` takes"): run a task of tests/conftest.py's WARM_UP in this (fresh) interpreter and print, as
JSON, its CPU and wall time, the time under numba's LLVM lock (LLVM's optimisation and code
generation), and the time per kernel (`numba:compile` events) and per compiler pass and kernel
(`numba:run_pass`), each exclusive of the nested compiles or passes:

    NUMBA_CACHE_DIR=$(mktemp -d) .venv/bin/python tools/compile_profile.py gpssm-tensor-exact

Use an empty cache: with it filled nothing compiles."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from numba.core import event as ev

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

_STACK = []  # [kind, name, start, time of nested events of the same kind]
PER_KERNEL, PER_PASS, LLVM = {}, {}, [0.0]


class _Timer(ev.Listener):
    def __init__(self, kind: str):
        self.kind = kind

    def on_start(self, event):
        if self.kind == "compile":
            name = event.data["dispatcher"].py_func.__qualname__
        elif self.kind == "pass":
            name = event.data["name"]
        else:
            name = "llvm"
        _STACK.append([self.kind, name, time.perf_counter(), 0.0])

    def on_end(self, event):
        kind, name, t0, nested = _STACK.pop()
        dt = time.perf_counter() - t0
        if kind == "llvm":
            LLVM[0] += dt
            return
        for frame in reversed(_STACK):
            if frame[0] == kind:
                frame[3] += dt
                break
        per = PER_KERNEL if kind == "compile" else PER_PASS
        per[name] = per.get(name, 0.0) + dt - nested


def main() -> int:
    ev.register("numba:compile", _Timer("compile"))
    ev.register("numba:run_pass", _Timer("pass"))
    ev.register("numba:llvm_lock", _Timer("llvm"))
    from conftest import WARM_UP

    task = sys.argv[1] if len(sys.argv) > 1 else ""
    if task not in WARM_UP:
        raise SystemExit(f"usage: compile_profile.py TASK, TASK one of {', '.join(WARM_UP)}")
    c0, w0 = time.process_time(), time.perf_counter()
    WARM_UP[task]()
    top = lambda d: dict(sorted(((k, round(v, 2)) for k, v in d.items()), key=lambda kv: -kv[1])[:15])  # noqa: E731
    print(json.dumps({"task": task, "cpu_s": round(time.process_time() - c0, 1),
                      "wall_s": round(time.perf_counter() - w0, 1), "llvm_s": round(LLVM[0], 1),
                      "kernels_s": top(PER_KERNEL), "passes_s": top(PER_PASS)}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
