"""Dashboard update rate: paper-sim with the MPF at N = 500, live in the viser dashboard.

    .venv/bin/python benchmarks/bench_dashboard.py [--particles 500] [--seconds 10]
        [--speeds max 1x] [--no-browser]

For each speed (max: step as fast as possible; 1x: real time) the dashboard runs the
scenario with a headless chromium (Debian's /usr/bin/chromium through Playwright) showing
the page, and prints over a window of --seconds after one second of warm-up:
- updates/s:  view updates the server published (charts, particle cloud, vehicle pose,
              status), each one websocket frame to the page;
- frames/s:   websocket frames the page received (the browser's side of the same);
- samples/s:  estimator samples stepped, and the real-time factor;
- step:       median wall time of Estimator.step.
The issue asks for at least 20 updates per second at N = 500.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from tirefilter.cli import import_viewer

CHROMIUM = Path("/usr/bin/chromium")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def measure(speed: str, particles: int, seconds: float, browser_context) -> dict:
    viewer = import_viewer()
    d = viewer.Dashboard(port=0, speed=speed, settings=viewer.Settings(particles=particles, seed=0))
    frames: list[float] = []
    page = None
    try:
        if browser_context is not None:
            page = browser_context.new_page()
            page.on("websocket", lambda ws: ws.on("framereceived", lambda _: frames.append(time.perf_counter())))
            page.goto(d.url)
            page.get_by_role("button", name="Start", exact=True).wait_for(timeout=30000)
            page.get_by_role("button", name="Start", exact=True).click()
        else:
            d.command("start")
        # sleep through Playwright when a page is open: its events (the frames) arrive only then
        sleep = (lambda s: page.wait_for_timeout(s * 1e3)) if page is not None else time.sleep
        while d.status()["rows"] < 2:
            sleep(0.01)
        sleep(1.0)  # warm-up
        s0, t0 = d.status(), time.perf_counter()
        sleep(seconds)
        s1, t1 = d.status(), time.perf_counter()
        if s1["state"] != "running":
            raise SystemExit(f"the run ended ({s1['state']}) inside the window: use fewer --seconds")
        wall = t1 - t0
        n_frames = sum(1 for f in frames if t0 <= f < t1)
        return {"speed": speed, "updates_per_s": (s1["updates"] - s0["updates"]) / wall,
                "frames_per_s": n_frames / wall if page is not None else float("nan"),
                "samples_per_s": (s1["rows"] - s0["rows"]) / wall, "rtf": (s1["t"] - s0["t"]) / wall,
                "step_us": d._run.median_step_us()}
    finally:
        if page is not None:
            page.close()
        d.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--seconds", type=float, default=10.0, help="measurement window per speed (s)")
    ap.add_argument("--speeds", nargs="+", default=["max", "1x"])
    ap.add_argument("--no-browser", action="store_true", help="no page connected (server side only)")
    args = ap.parse_args()

    rows = []
    if args.no_browser or not CHROMIUM.is_file():
        if not args.no_browser:
            print(f"{CHROMIUM} is absent: measuring without a browser")
        rows = [measure(s, args.particles, args.seconds, None) for s in args.speeds]
    else:
        from playwright.sync_api import sync_playwright

        with sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
            context = pw.chromium.launch_persistent_context(profile, executable_path=str(CHROMIUM), headless=True,
                                                            args=FLAGS, viewport={"width": 1400, "height": 1000})
            try:
                rows = [measure(s, args.particles, args.seconds, context) for s in args.speeds]
            finally:
                context.close()
    print(f"dashboard, paper-sim, MPF N = {args.particles}, {args.seconds:g} s windows"
          + ("" if args.no_browser or not CHROMIUM.is_file() else ", headless chromium connected"))
    print(f"{'speed':>6s} {'updates/s':>10s} {'frames/s':>9s} {'samples/s':>10s} {'x real time':>12s} {'step us':>8s}")
    for r in rows:
        print(f"{r['speed']:>6s} {r['updates_per_s']:10.1f} {r['frames_per_s']:9.1f} {r['samples_per_s']:10.0f} "
              f"{r['rtf']:12.2f} {r['step_us']:8.0f}")
    worst = min(r["updates_per_s"] for r in rows)
    print(f"lowest update rate {worst:.1f}/s: {'meets' if worst >= 20 else 'MISSES'} the target of 20 updates/s")


if __name__ == "__main__":
    main()
