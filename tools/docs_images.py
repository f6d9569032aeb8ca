"""The README's example output and the pictures in docs/img/, made from the current code
(`make docs-images`), so that they cannot go stale:

1. `tirefilter run --scenario paper-sim --seed 0 --out runs/paper-sim --rrd
   runs/paper-sim/paper-sim.rrd` (what `make run` runs): its printed summary becomes the
   README's `text` block (the truth table, the compile line and the output paths left out
   as "...": tests/test_golden.py checks the block against what `tirefilter run` prints);
2. that recording in Rerun's web viewer (tests/rerun_web.py, Debian's chromium, headless,
   1600 x 1000): docs/img/recording.png and three more tabs;
3. the dashboard (`tirefilter dashboard`) running paper-sim (N = 500, seed 0) at full speed
   in the same browser: docs/img/dashboard*.png, one per tab shown. It stops, writing
   nothing, when that run diverged or restarted (the README must not show one).

    .venv/bin/python tools/docs_images.py [--only readme|rerun|dashboard ...]

Under software GL the Rerun viewer needs 30-60 s to load and the dashboard's run about a
minute: the whole takes 3-6 minutes on a 2-core machine.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMG = ROOT / "docs" / "img"
README = ROOT / "README.md"
RUN_DIR = ROOT / "runs" / "paper-sim"
RRD = RUN_DIR / "paper-sim.rrd"
# Rerun's tabs (middle column, right column) -> picture; the order of `rerun_web.py --all-tabs`
RERUN_SHOTS = {(0, 0): "recording.png", (1, 1): "recording-bias-densities.png",
               (2, 2): "recording-ess-quantiles.png", (2, 3): "recording-topview.png"}
# the dashboard's tabs -> picture (docs/dashboard.md shows them; the README the first)
DASHBOARD_SHOTS = {"stiffness": "dashboard.png", "state": "dashboard-state.png",
                   "densities": "dashboard-densities.png", "path": "dashboard-path.png"}
# lines of the printed summary the README leaves out (as "..."): the truth table, the one-time
# compile (a fresh clone's first run only) and the output paths
TRUTH_TABLE = re.compile(r"^(truth  |speed vx|lateral acc|yaw rate \[|slip angle|wheel slip|C[fr]_y surface)")
LEFT_OUT = re.compile(r"^(compile |results: |summary: |recording: )")


def readme_block(printed: str) -> list[str]:
    """The README's example output: the printed lines, each run of lines left out as one
    "..." (the truth table, the compile line, the output paths)."""
    out: list[str] = []
    for line in printed.splitlines():
        if TRUTH_TABLE.match(line) or LEFT_OUT.match(line):
            if not out or out[-1] != "...":
                out.append("...")
        else:
            out.append(line)
    while out and out[-1] == "...":
        out.pop()
    return out


def replace_text_block(text: str, lines: list[str]) -> str:
    """`text` with the content of its first ```text block replaced by `lines`."""
    start = text.index("```text\n") + len("```text\n")
    end = text.index("```", start)
    return text[:start] + "\n".join(lines) + "\n" + text[end:]


def make_readme_output() -> None:
    """Run what `make run` runs and write its summary into the README."""
    from tirefilter.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["run", "--scenario", "paper-sim", "--seed", "0", "--out", str(RUN_DIR), "--rrd", str(RRD),
                     "--quiet"])
    if code != 0:
        raise SystemExit(f"tirefilter run failed ({code}):\n{out.getvalue()}")
    block = readme_block(out.getvalue())
    README.write_text(replace_text_block(README.read_text(), block))
    print(f"{README.relative_to(ROOT)}: example output of {len(block)} lines ({README.stat().st_size} bytes)")


def make_rerun_shots(wait: float = 600.0) -> None:
    """The recording's four tabs in Rerun's web viewer (make_readme_output made it); none
    written unless every view of every tab shows data and no error (`rerun_web.check_views`)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from PIL import Image

    import rerun_web

    if not RRD.is_file():
        make_readme_output()
    layout, _ = rerun_web.recorded_layout(RRD)
    size = (rerun_web.VIEWPORT["width"], rerun_web.VIEWPORT["height"])
    tabs = list(RERUN_SHOTS)
    shots = {}
    with rerun_web.serve_web_viewer(RRD) as (url, proxy), rerun_web.browser_page() as page:
        page.goto(url)
        rows, tabbed, text = rerun_web.layout_grid(layout, tabs[0])
        # the whole file ingested (under load the first frames show part of it)
        rerun_web.wait_loaded(page, rerun_web.view_cells(rows, tabbed, size), wait, text=text)
        for active, img, boxes, text in rerun_web.screenshot_tabs(page, RRD, proxy, size, tabs, timeout=wait):
            problems = rerun_web.check_views(img, boxes, text=text)
            if problems:
                raise SystemExit(f"Rerun's viewer, tab {active}: {'; '.join(problems)}; no pictures written")
            shots[active] = img
    missing = set(RERUN_SHOTS) - set(shots)
    if missing:
        raise SystemExit(f"Rerun's viewer gave no tab {sorted(missing)}: the recording's layout has other tabs; "
                         "update RERUN_SHOTS")
    for active, img in shots.items():
        Image.fromarray(img).save(IMG / RERUN_SHOTS[active], optimize=True)
        print(f"docs/img/{RERUN_SHOTS[active]}: {(IMG / RERUN_SHOTS[active]).stat().st_size / 1024:.0f} KB")


def make_dashboard_shots(particles: int = 500, seed: int = 0) -> None:
    """The dashboard after a whole paper-sim run (N = `particles`), one picture per tab of
    DASHBOARD_SHOTS, at 1600 x 1000; none when the run diverged or restarted."""
    sys.path.insert(0, str(ROOT / "tests"))
    from rerun_web import browser_page, screenshot_png
    from tirefilter.cli import import_viewer

    import_viewer()
    from tirefilter_viewer.app import Dashboard
    from tirefilter_viewer.session import Settings

    d = Dashboard(port=0, speed="max", settings=Settings(particles=particles, seed=seed))
    shots = {}
    try:
        with browser_page({"width": 1600, "height": 1000}) as page:
            page.goto(d.url)
            close = page.locator(".mantine-Notification-closeButton")  # the 'software WebGL' notice
            with contextlib.suppress(Exception):
                close.first.wait_for(timeout=10000)
            for k in range(close.count()):
                close.nth(k).click()
            page.get_by_role("button", name="Start", exact=True).click()
            end = time.monotonic() + 900
            while d.status()["state"] not in ("finished", "failed") and time.monotonic() < end:
                time.sleep(1)
            status = d._status.content
            if d.status()["state"] != "finished":
                raise SystemExit(f"the dashboard's run did not finish: {status}")
            if "DIVERGED" in status or "restart" in status:
                raise SystemExit(f"the dashboard's run diverged or restarted; no pictures written: {status}")
            # the page has drawn the end (a loaded machine's browser can lag the run by a minute)
            page.get_by_text(re.compile(r"^finished · ")).wait_for(timeout=300000)
            for tab, name in DASHBOARD_SHOTS.items():
                page.get_by_role("tab", name=tab, exact=True).click(timeout=120000)
                time.sleep(3)  # the tab's charts drawn
                shots[name] = screenshot_png(page)
    finally:
        d.stop()
    for name, png in shots.items():
        (IMG / name).write_bytes(_optimized(png))
        print(f"docs/img/{name}: {(IMG / name).stat().st_size / 1024:.0f} KB")


def _optimized(png: bytes) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.open(io.BytesIO(png)).convert("RGB").save(out, format="PNG", optimize=True)
    return out.getvalue()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="+", choices=("readme", "rerun", "dashboard"),
                   help="make only these (default: all three, in this order)")
    args = p.parse_args(argv)
    parts = args.only or ("readme", "rerun", "dashboard")
    IMG.mkdir(parents=True, exist_ok=True)
    if "readme" in parts:
        make_readme_output()
    if "rerun" in parts:
        make_rerun_shots()
    if "dashboard" in parts:
        make_dashboard_shots()
    return 0


if __name__ == "__main__":
    sys.exit(main())
