"""The dashboard reads only inside its data root (`--data-dir`): '..', absolute paths
outside and symlinks out of it are refused, in the resolver and in the page."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from tirefilter.cli import build_parser, import_viewer
from tirefilter.errors import ConfigError

viewer = import_viewer()
from tirefilter_viewer.dataroot import DataRoot  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
VEHICLE = REPO / "src/tirefilter/scenarios/data/vehicles/midsize-suv.toml"


@pytest.fixture
def tree(tmp_path):
    """root/ with a log, a subfolder, a symlink inside and symlinks out; secret/ beside it."""
    root, secret = tmp_path / "root", tmp_path / "secret"
    (root / "sub").mkdir(parents=True)
    secret.mkdir()
    (secret / "results.csv").write_text("t\n0\n")
    (root / "sub" / "drive.csv").write_text("t\n0\n")
    (root / "vehicle.toml").write_text(VEHICLE.read_text())
    os.symlink(root / "sub" / "drive.csv", root / "inside-link.csv")
    os.symlink(secret / "results.csv", root / "out-link.csv")
    os.symlink(secret, root / "out-dir")
    return root, secret


def test_paths_inside_resolve(tree):
    root, _ = tree
    r = DataRoot(root)
    assert r.resolve("sub/drive.csv", "Log CSV") == (root / "sub" / "drive.csv").resolve()
    assert r.resolve(f"  {root / 'sub' / 'drive.csv'}  ", "Log CSV") == (root / "sub" / "drive.csv").resolve()
    assert r.resolve("inside-link.csv", "Log CSV") == (root / "sub" / "drive.csv").resolve()
    assert r.resolve("./sub/./drive.csv", "Log CSV").name == "drive.csv"


@pytest.mark.parametrize("typed, expected", [
    ("../secret/results.csv", "'..' is not allowed"),
    ("sub/../../secret/results.csv", "'..' is not allowed"),
    ("/etc/passwd", "outside the data directory"),
    ("out-link.csv", "through a symlink"),
    ("out-dir/results.csv", "through a symlink"),
    ("", "no path given"),
    ("a\x00b", "NUL"),
])
def test_paths_out_are_refused(tree, typed, expected):
    root, secret = tree
    with pytest.raises(ConfigError, match=expected) as exc:
        DataRoot(root).resolve(typed, "Result CSV")
    assert "Result CSV" in str(exc.value)


def test_absolute_path_to_the_secret_is_refused(tree):
    root, secret = tree
    with pytest.raises(ConfigError, match="outside the data directory"):
        DataRoot(root).resolve(str(secret / "results.csv"), "Result CSV")


def test_settings_resolve_log_vehicle_and_scenario_files(tree):
    root, _ = tree
    r = DataRoot(root)
    s = r.settings(viewer.Settings(source="log", log="sub/drive.csv", vehicle="vehicle.toml"))
    assert Path(s.log) == (root / "sub" / "drive.csv").resolve() and Path(s.vehicle).parent == root.resolve()
    with pytest.raises(ConfigError, match="vehicle TOML"):
        r.settings(viewer.Settings(source="log", log="sub/drive.csv", vehicle=str(VEHICLE)))
    assert r.settings(viewer.Settings(scenario="paper-sim")).scenario == "paper-sim"  # a built-in name
    with pytest.raises(ConfigError, match="scenario"):
        r.settings(viewer.Settings(scenario="/etc/x.toml"))


def test_data_dir_option_and_a_missing_folder(tmp_path):
    assert build_parser().parse_args(["dashboard", "--data-dir", str(tmp_path)]).data_dir == str(tmp_path)
    assert build_parser().parse_args(["dashboard"]).data_dir is None
    with pytest.raises(ConfigError, match="not a directory"):
        DataRoot(tmp_path / "none")
    assert DataRoot().root == Path.cwd().resolve()


def _wait(predicate, timeout=30.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError("timed out")


def test_the_page_refuses_paths_out_of_the_data_root(fmu_paths, tree):
    root, secret = tree
    d = viewer.Dashboard(port=0, data_dir=root)
    try:
        for typed in (str(secret / "results.csv"), "../secret/results.csv", "out-link.csv"):
            d.command("open_result", typed)
            error = _wait(lambda: d.status()["error"])
            assert "Result CSV" in error and ("outside the data directory" in error or "'..'" in error)
            assert d.status()["state"] != "result"
            d._clear_error()
        d._source.value, d._log.value, d._vehicle.value = "log", "../secret/results.csv", "vehicle.toml"
        d.command("start")
        error = _wait(lambda: d.status()["error"])
        assert "Log CSV" in error and "'..' is not allowed" in error and d._run is None
    finally:
        d.stop()
