"""The package's parts import only their own layer and the layers below (tools/imports.py)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

import imports  # noqa: E402


def test_no_upward_import_and_no_cycle():
    graph = imports.edges()
    assert ("cli", "cosim") in graph  # the graph is read (the command line runs co-simulations)
    assert imports.upward(graph) == []
    assert imports.cycles(graph) == []


def test_every_part_is_in_a_layer():
    folder = imports.PACKAGES["tirefilter"]
    parts = {p.stem if p.is_file() else p.name for p in folder.iterdir()
             if (p.suffix == ".py" or (p / "__init__.py").is_file())}
    assert parts - set(imports.LAYER) == set()


def test_the_checks_find_what_they_look_for():
    graph = {("io", "runs"): ["a.py:1"], ("runs", "io"): ["b.py:2"], ("cosim", "estimators"): ["c.py:3"]}
    assert imports.upward(graph) == ["io (layer 4) imports runs (layer 5): a.py:1"]
    assert imports.cycles(graph) == [["io", "runs"]]


def test_relative_and_package_imports_are_resolved(tmp_path):
    package = tmp_path / "tirefilter"
    (package / "cosim").mkdir(parents=True)
    source = package / "cosim" / "run.py"
    source.write_text("from ..io import results\nfrom . import fmu\nfrom tirefilter import runs\n"
                      "def f():\n    import tirefilter.viz.options\n")
    found = imports.imports_of(source, "tirefilter.cosim.run")
    assert [m for m, _ in found] == ["tirefilter.io", "tirefilter.cosim", "tirefilter.runs", "tirefilter.viz.options"]
