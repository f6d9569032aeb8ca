"""The recording's layout rendered by Rerun's own web viewer in a real browser (Debian's
chromium, headless, software GL, driven by Playwright). The page first gets only the first
30 % of the file (`rerun_web.Gate`), as a viewer has that opens a file while the run writes
it or watches the stream: it must already show the recording's layout (the tab strips and
view titles of the whole file's), not Rerun's automatic grid. Then every tab of the final
blueprint is shown in turn (blueprints rebuilt from the recording's layout property and sent
to the served recording) and screenshotted into runs/rerun-web/; a tab fails when one of its
views is empty (a text view: without text) or shows the viewer's error red, or when its
frame is still the previous tab's. The check itself is shown to catch a real error badge (a
2-D entity in the 3-D top view, a defect the layout once had). One short recording, one
browser session, a 1200 x 750 page (the viewer draws continuously under software GL, at a
cost that goes with the pixels: at 1600 x 1000 the test took 1.5 times the CPU,
docs/development.md, "How long `make test` takes"): the viewer needs 20-50 s to start."""

from __future__ import annotations

import re
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from PIL import Image
from rerun_web import (CHROMIUM, Gate, _serve_file, blueprint_sender, browser_page, check_views, error_red, pixels,
                       recorded_layout, screenshot_tabs, serve_web_viewer, title_strips_match, wait_stable)
from tirefilter.cli import main
from tirefilter.scenarios import DATA_DIR
from tirefilter.viz.blueprint import Layout, tab_counts

REPO = Path(__file__).resolve().parents[1]
ARTIFACTS = REPO / "runs" / "rerun-web"  # the screenshots of the last run, kept for people to look at
PAGE = {"width": 1200, "height": 750}  # the README's screenshots (rerun_web.py's command) keep VIEWPORT
SIZE = (PAGE["width"], PAGE["height"])


def _short_scenario(tmp_path: Path, duration: float = 4.0) -> Path:
    text = (DATA_DIR / "paper-sim.toml").read_text()
    text = re.sub(r"(?m)^duration = 60\.0", f"duration = {duration}", text)
    text = re.sub(r'(?m)^name = "paper-sim"', 'name = "paper-sim-short"', text)
    text = re.sub(r"(?m)^excitation = .*$", f"excitation = [[0.0, {duration}]]", text)
    path = tmp_path / "short.toml"
    path.write_text(text)
    return path


def mpf_layout() -> Layout:
    """The layout of the short paper-sim recording: MPF, full model, bias estimation off."""
    return Layout("mpf", params=("Cx", "Cf_y", "Cr_y"), clouds=True, densities=("Cx", "Cf_y", "Cr_y"),
                  references=("vx", "vy", "yaw_rate", "beta"), bias_estimated=False, ess_lines=True)


def test_the_recording_is_served_under_its_own_name_and_nothing_else(tmp_path):
    """The page loads the recording from the test's own HTTP server (rerun_web._serve_file): the
    file under its name, quoted where a URL needs it; any other path is a 404."""
    import urllib.error
    import urllib.request

    for name in ("short.rrd", "my run.rrd", "a#b.rrd"):
        path = tmp_path / name
        path.write_bytes(name.encode())
        with _serve_file(path) as url:
            assert url.startswith("http://127.0.0.1:")
            assert urllib.request.urlopen(url, timeout=10).read() == name.encode()
            for other in ("other.rrd", "", "..%2Fshort.toml"):
                with pytest.raises(urllib.error.HTTPError, match="404"):
                    urllib.request.urlopen(url.rsplit("/", 1)[0] + "/" + other, timeout=10)


@pytest.mark.xdist_group("browser")  # one browser at a time (make test runs two workers)
def test_every_tab_of_the_layout_renders_without_errors_or_empty_views(fmu_paths, tmp_path, chromium):
    import rerun as rr

    rrd = tmp_path / "short.rrd"
    assert main(["run", "--scenario", str(_short_scenario(tmp_path)), "--particles", "100", "--seed", "1", "--out",
                 str(tmp_path / "run"), "--rrd", str(rrd), "--quiet"]) == 0
    layout, _ = recorded_layout(rrd)
    assert layout == replace(mpf_layout(), path_bounds=layout.path_bounds, cx_excited=True)  # what the grid assumes
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    ARTIFACTS.mkdir(parents=True)
    problems, early = {}, None
    # the page gets the first 30 % of the file, then the rest: a viewer that opens a file while it
    # is written, or watches a live stream, has only the start of the recording
    gate = Gate(first=int(0.3 * rrd.stat().st_size))
    with serve_web_viewer(rrd, ARTIFACTS / "viewer.log", gate) as (url, proxy), browser_page(PAGE) as page:
        page.goto(url)
        early = wait_stable(page)
        Image.fromarray(early).save(ARTIFACTS / "early.png")
        gate.release()
        middle, right = tab_counts(layout)
        assert (middle, right) == (3, 4)  # states, bias, ESS; particles, densities, quantiles, top view
        tabs = [(min(k, middle - 1), min(k, right - 1)) for k in range(max(middle, right))]
        for active, img, boxes, text in screenshot_tabs(page, rrd, proxy, SIZE, tabs, ARTIFACTS, timeout=150):
            name = f"tab-{active[0]}-{active[1]}"
            problems[name] = check_views(img, boxes, text=text)
            if active == (0, 0):
                # the start of the file already holds the recording's layout: the same tab strips and
                # view titles as the whole file's (not Rerun's automatic grid of every entity)
                problems["early"] = [] if (m := title_strips_match(early, img, boxes)) > 0.9 else [
                    f"the start of the file shows another layout ({m:.0%} of the title bars alike); see early.png"]

        # the check sees a real error badge: a 2-D line strip in the 3-D close-up (what /vehicle/path once was)
        before = int(error_red(img).sum())
        sender = blueprint_sender(rrd, proxy)
        sender.log("/vehicle/body/probe_2d", rr.LineStrips2D([[[0, 0], [10, 0]]]), static=True)
        sender.flush()
        deadline = time.monotonic() + 60
        while True:
            time.sleep(1)
            bad = pixels(page, ARTIFACTS / "error-probe.png")
            if [p for p in check_views(bad, boxes, text=text) if p.startswith("error")] or time.monotonic() > deadline:
                break
        sender.disconnect()
    assert [p for p in check_views(bad, boxes, text=text) if p.startswith("error")], \
        f"the 2-D probe in the 3-D view gave no error red (before: {before} px); see {ARTIFACTS / 'error-probe.png'}"
    assert problems == {name: [] for name in problems}, f"see the screenshots in {ARTIFACTS}"
    for shot in ARTIFACTS.glob("tab-*.png"):
        assert np.asarray(Image.open(shot).convert("L"), float).std() > 5.0, f"{shot} looks blank"
