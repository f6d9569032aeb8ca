"""The import graph of the package's parts, checked against its layers.

    python tools/imports.py          # the graph, part by part, and any violation (exit 1 if any)
    python tools/imports.py --dot    # the graph in Graphviz dot

A part is a subpackage or top-level module of `tirefilter` (`estimators`, `io`, `cosim`,
`runs`, ...), or the dashboard `tirefilter_viewer`. Every import counts, at module level or
inside a function (a deferred import is still a dependency). A part may import its own
layer's parts and those of the layers below it, never one above, and the graph of the parts
has no cycle.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"tirefilter": ROOT / "src" / "tirefilter", "tirefilter_viewer": ROOT / "viewer" / "tirefilter_viewer"}

# Lowest first. A part may import parts of its own layer and of the layers before it.
LAYERS = (
    ("__init__", "errors", "config", "compiling"),  # the version, the errors, the TOML reader, the compile watch
    ("vehicle", "stats", "vehicle_fmu"),  # the models, the probability machinery, the vehicle FMU's sources
    ("scenarios",),  # what a co-simulation plays (vehicle, tires, inputs, sensors)
    ("estimators",),  # the filters, and the registry that builds one by name
    ("io", "metrics", "model_check", "viz"),  # what a run writes: file formats, scores, model check, recording
    ("runs",),  # the run loop: samples -> an estimator -> sinks
    ("cosim", "replay", "peer"),  # the sample sources: the vehicle FMU, a recorded log, a peer drive
    ("study", "fmu_export"),  # Monte-Carlo studies, the estimator and driver FMUs
    ("cli", "tirefilter_viewer"),  # the command line, the dashboard
)
LAYER = {part: i for i, names in enumerate(LAYERS) for part in names}


def part_of(module: str) -> str | None:
    """`tirefilter.io.results` -> `io`; `tirefilter_viewer.session` -> `tirefilter_viewer`;
    None outside the package."""
    head, _, rest = module.partition(".")
    if head == "tirefilter_viewer":
        return head
    if head != "tirefilter":
        return None
    return rest.split(".")[0] if rest else "__init__"


def module_name(package: str, path: Path) -> str:
    rel = path.relative_to(PACKAGES[package]).with_suffix("")
    parts = [package, *rel.parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path, module: str) -> list[tuple[str, int]]:
    """(imported module, line) of every import in the file, relative ones resolved."""
    tree = ast.parse(path.read_text(), str(path))
    is_package = path.name == "__init__.py"
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            # `from tirefilter import io` imports the subpackage tirefilter.io
            names = [f"{target}.{alias.name}" for alias in node.names] if part_of(target) == "__init__" else [target]
            found += [(name, node.lineno) for name in names]
    return found


def edges() -> dict[tuple[str, str], list[str]]:
    """(importing part, imported part) -> where ("file:line"), for imports across parts."""
    out: dict[tuple[str, str], list[str]] = {}
    for package, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            module = module_name(package, path)
            source = part_of(module)
            for target, line in imports_of(path, module):
                dest = part_of(target)
                if dest is None or dest == source:
                    continue
                if target.startswith("tirefilter.") and not _is_part(dest):
                    dest = "__init__"  # a name of the package's __init__: `from tirefilter import __version__`
                out.setdefault((source, dest), []).append(f"{path.relative_to(ROOT)}:{line}")
    return out


def _is_part(name: str) -> bool:
    folder = PACKAGES["tirefilter"]
    return (folder / f"{name}.py").is_file() or (folder / name / "__init__.py").is_file() or name == "__init__"


def upward(graph) -> list[str]:
    """Imports of a part in a higher layer (or of a part no layer names)."""
    problems = []
    for (a, b), where in sorted(graph.items()):
        for part in (a, b):
            if part not in LAYER:
                problems.append(f"{part}: in no layer of tools/imports.py LAYERS ({where[0]})")
        if a in LAYER and b in LAYER and LAYER[b] > LAYER[a]:
            problems.append(f"{a} (layer {LAYER[a]}) imports {b} (layer {LAYER[b]}): {', '.join(where)}")
    return problems


def cycles(graph) -> list[list[str]]:
    """The strongly connected components of more than one part (Tarjan)."""
    succ: dict[str, list[str]] = {}
    for a, b in graph:
        succ.setdefault(a, []).append(b)
        succ.setdefault(b, [])
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in succ[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(succ):
        if v not in index:
            visit(v)
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    graph = edges()
    if "--dot" in argv:
        print("digraph imports {\n  rankdir=BT;")
        for a, b in sorted(graph):
            print(f'  "{a}" -> "{b}";')
        print("}")
        return 0
    for i, names in enumerate(LAYERS):
        for part in names:
            deps = sorted({b for a, b in graph if a == part}, key=lambda p: (LAYER.get(p, -1), p))
            print(f"{i:2d} {part:18s} -> {', '.join(deps) or '-'}")
    problems = upward(graph) + [f"cycle: {' <-> '.join(c)}" for c in cycles(graph)]
    for p in problems:
        print(f"error: {p}")
    print("no upward import, no cycle" if not problems else f"{len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
