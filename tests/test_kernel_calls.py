"""The kernels' helpers compiled without a Python wrapper (`_JIT_IN`: `no_cpython_wrapper=True`;
docs/development.md, "How long make test takes") are called only from other compiled kernels:
a call from Python would not raise but crash the interpreter (a segmentation fault), taking a
test worker down with no traceback. This test finds every such helper and every reference to one
in src/, tests/, benchmarks/ and fmu/ outside a function compiled with `@njit`."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

from numba.core.registry import CPUDispatcher

REPO = Path(__file__).resolve().parents[1]
KERNEL_MODULES = ("tirefilter.estimators.mpf.kernels_weigh", "tirefilter.estimators.mpf.kernels_update",
                  "tirefilter.estimators.gpssm.kernels_particles", "tirefilter.estimators.gpssm.kernels_stats",
                  "tirefilter.estimators.gpssm.kernels_resample",
                  "tirefilter.stats.mniw_numba", "tirefilter.stats.particles_numba",
                  "tirefilter.vehicle.single_track_numba")


def internal_helpers() -> dict[str, set[str]]:
    """{module: names of its dispatchers compiled without a Python wrapper}."""
    found = {}
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        found[name] = {attr for attr, obj in vars(module).items()
                       if isinstance(obj, CPUDispatcher) and obj.targetoptions.get("no_cpython_wrapper")}
    return found


def _jitted(node) -> bool:
    for dec in getattr(node, "decorator_list", ()):
        func = dec.func if isinstance(dec, ast.Call) else dec
        if (func.id if isinstance(func, ast.Name) else getattr(func, "attr", "")) in {"njit", "jit"}:
            return True
    return False


def python_references(source: str, own_module: str | None, helpers: dict[str, set[str]]) -> list[tuple[int, str]]:
    """(line, name) of each reference to a helper outside `@njit` functions in `source`: bare names
    in the helper's own module (`own_module`) or imported from it, and `alias.name` for a kernel
    module imported as `alias`."""
    tree = ast.parse(source)
    bare = set(helpers.get(own_module, ()))
    aliases = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            for a in node.names:
                full = f"{node.module}.{a.name}"
                if full in helpers:
                    aliases[a.asname or a.name] = full
                elif node.module in helpers and a.name in helpers[node.module]:
                    bare.add(a.asname or a.name)
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name in helpers and a.asname:
                    aliases[a.asname] = a.name
    found = []

    def visit(node, compiled):
        for child in ast.iter_child_nodes(node):
            inner = compiled or _jitted(child)
            if not inner:
                if isinstance(child, ast.Name) and child.id in bare:
                    found.append((child.lineno, child.id))
                elif (isinstance(child, ast.Attribute) and isinstance(child.value, ast.Name)
                      and child.attr in helpers.get(aliases.get(child.value.id, ""), ())):
                    found.append((child.lineno, f"{child.value.id}.{child.attr}"))
            visit(child, inner)

    visit(tree, False)
    return found


def test_every_helper_without_a_python_wrapper_is_called_only_from_compiled_code():
    helpers = internal_helpers()
    assert helpers["tirefilter.vehicle.single_track_numba"] >= {"_model_t", "_xdot_t"}  # the finder finds them
    module_of = {str(REPO / "src" / (m.replace(".", "/") + ".py")): m for m in KERNEL_MODULES}
    calls = {}
    for folder in ("src", "tests", "benchmarks", "tools", "fmu"):
        for path in sorted((REPO / folder).rglob("*.py")):
            if ".venv" in path.parts or "build" in path.parts:
                continue
            refs = python_references(path.read_text(), module_of.get(str(path)), helpers)
            if refs:
                calls[str(path.relative_to(REPO))] = refs
    assert not calls, f"called from Python (a segmentation fault at run time): {calls}"


def test_the_check_finds_a_call_from_python():
    helpers = {"tirefilter.vehicle.single_track_numba": {"_model_t"}}
    source = '''
from numba import njit
from tirefilter.vehicle import single_track_numba as nb
from tirefilter.vehicle.single_track_numba import _model_t

@njit
def fine(x):
    return nb._model_t(x) + _model_t(x)

def wrong(x):
    return nb._model_t(x)

y = _model_t(1.0)
'''
    assert python_references(source, None, helpers) == [(11, "nb._model_t"), (13, "_model_t")]
    own = "@njit\ndef _model_t(x):\n    return x\n\ndef py(x):\n    return _model_t(x)\n"
    assert python_references(own, "tirefilter.vehicle.single_track_numba", helpers) == [(6, "_model_t")]
