"""The README's screenshot of the dashboard: a paper-sim run at full speed in Debian's
chromium (headless, 1600 x 1000), the stiffness tab after the run, written at half size:

    .venv/bin/python tests/dashboard_screenshot.py docs/img/dashboard.png
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> int:
    import argparse
    import io

    from PIL import Image

    from rerun_web import browser_page
    from tirefilter.cli import import_viewer

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path)
    p.add_argument("--particles", type=int, default=500)
    p.add_argument("--tab", default="stiffness", help="the charts tab to show (default stiffness)")
    p.add_argument("--scale", type=float, default=0.5)
    args = p.parse_args(argv)
    import_viewer()
    from tirefilter_viewer.app import Dashboard
    from tirefilter_viewer.session import Settings

    d = Dashboard(port=0, speed="max", settings=Settings(particles=args.particles, seed=0))
    try:
        with browser_page({"width": 1600, "height": 1000}) as page:
            page.goto(d.url)
            page.get_by_role("button", name="Start", exact=True).click()
            end = time.monotonic() + 600
            while d.status()["state"] != "finished" and time.monotonic() < end:
                time.sleep(1)
            page.get_by_role("tab", name=args.tab, exact=True).click()
            close = page.locator(".mantine-Notification-closeButton")  # "software WebGL" notice of headless chromium
            for k in range(close.count()):
                close.nth(k).click()
            time.sleep(3)
            png = page.screenshot()
    finally:
        d.stop()
    img = Image.open(io.BytesIO(png)).convert("RGB")
    img = img.resize((int(img.width * args.scale), int(img.height * args.scale)), Image.LANCZOS)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    img.save(args.out, optimize=True)
    print(f"{args.out}: {args.out.stat().st_size / 1024:.0f} KB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
