"""Rerun's web viewer in a real browser: serve a recording on loopback with rerun-sdk's
viewer, open it in Debian's chromium through Playwright (software GL), and read the
rendered pixels. Used by tests/test_rerun_web.py and, from the command line, to make the
screenshots of docs/img/ from a recording of `tirefilter run`:

    .venv/bin/python tests/rerun_web.py RECORDING.rrd OUT.png [--tab MIDDLE RIGHT]
    .venv/bin/python tests/rerun_web.py RECORDING.rrd OUTDIR --all-tabs

The viewer draws everything into one canvas (egui), so the checks work on pixels: the
views are the cells of the blueprint's grid (`view_cells`), a view shows data when its
inside holds enough coloured pixels (the layout draws every series, bar and outline in
colour on a grey UI; a text view: dark text pixels), and an error badge is the viewer's
error red in a view. Other tabs are opened by sending the final blueprint again with them
active, rebuilt from the layout the recording keeps as its property (`recorded_layout`).
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import tempfile
import time
import weakref
from pathlib import Path

import numpy as np

CHROMIUM = Path("/usr/bin/chromium")
# headless chromium with WebGL on SwiftShader (no GPU); nothing from the network
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--disable-quic", "--use-gl=angle",
                  "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
VIEWPORT = {"width": 1600, "height": 1000}
TOP_BAR, TIME_BAR, TAB_BAR = 38, 40, 28  # px of the viewer's top panel, collapsed time panel, a tab strip
LOAD_TIMEOUT = 150.0  # s: the viewer needs 30-60 s to start under software GL on a loaded machine


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rerun_exe() -> str:
    import rerun_cli

    return str(Path(rerun_cli.__file__).with_name("rerun"))


class Gate:
    """Holds back the served file after its first `first` bytes until `release()` (a viewer
    that has only the start of a recording, as one that opens a file still being written or
    watches a live stream)."""

    def __init__(self, first: int, timeout: float = 300.0):
        import threading

        self.first, self.timeout = int(first), timeout
        self._open = threading.Event()

    def release(self) -> None:
        self._open.set()

    def wait(self) -> None:
        self._open.wait(self.timeout)


@contextlib.contextmanager
def _serve_file(path: Path, gate: Gate | None = None):
    """`path` over HTTP on 127.0.0.1 (a free port), to pages of any origin (the viewer's page
    is on another port); yields its URL. Nothing else is served. With a `gate`, the body
    stops after its first bytes until the gate is released."""
    import http.server
    import threading
    from urllib.parse import quote, unquote

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 (http.server's name)
            if unquote(self.path.split("?", 1)[0]) != "/" + path.name:  # a name with spaces comes quoted
                self.send_error(404)
                return
            data = path.read_bytes()
            self.send_response(200)
            self.send_header("Content-Type", "application/octet-stream")
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Access-Control-Allow-Origin", "*")
            self.end_headers()
            if gate is not None:
                self.wfile.write(data[:gate.first])
                self.wfile.flush()
                gate.wait()
                data = data[gate.first:]
            self.wfile.write(data)

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/{quote(path.name)}"
    finally:
        if gate is not None:
            gate.release()
        server.shutdown()
        server.server_close()
        thread.join(10)


@contextlib.contextmanager
def serve_web_viewer(rrd: Path, log: Path | None = None, gate: Gate | None = None):
    """rerun-sdk's web viewer (HTTP) and gRPC proxy on 127.0.0.1 (free ports), and `rrd` over
    HTTP; yields (page URL, gRPC proxy URL). The page opens both: the viewer fetches the file
    (as it opens any .rrd URL) and stays connected to the proxy, through which the tests send
    blueprints and probes into the same recording. The file is not given to the `rerun`
    process: rerun 0.41's server, once a file it loaded has been read to its end, polls its
    finished source in a loop (`re_grpc_server::spawn_from_rx_set`: 0.4 CPU s per second for as
    long as it runs, about a third of the web test's CPU; with nothing loaded it idles at 0;
    docs/development.md, "How long `make test` takes"). `--serve-web`, not
    `--web-viewer`, which also tries to open a browser of its own. `gate`: the file stops after
    its first bytes until released (`Gate`). Everything stops on leaving."""
    grpc, http = free_port(), free_port()
    env = dict(os.environ, RERUN_ANALYTICS="0")  # the welcome text only; nothing leaves the machine
    out = open(log, "w") if log else subprocess.DEVNULL
    proc = subprocess.Popen([rerun_exe(), "--serve-web", "--bind", "127.0.0.1", "--port", str(grpc),
                             "--web-viewer-port", str(http), "--renderer", "webgl"],
                            stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT, env=env,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        for port in (grpc, http):
            while True:
                with contextlib.suppress(OSError):
                    socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                    break
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"the Rerun web viewer did not listen on 127.0.0.1:{port}"
                                       + (f" (see {log})" if log else ""))
                time.sleep(0.2)
        proxy = f"rerun+http://127.0.0.1:{grpc}/proxy"
        from urllib.parse import quote

        with _serve_file(Path(rrd), gate) as file_url:
            yield (f"http://127.0.0.1:{http}/?url={quote(file_url, safe='')}&url={quote(proxy, safe='')}"
                   "&renderer=webgl"), proxy
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        if log:
            out.close()


# Rerun's wasm viewer logs at debug level to the browser's console: naga (the shader translator)
# alone wrote 18 652 console.debug lines in one run of the web test, each formatted by the
# renderer, passed to the browser process and sent to Playwright's driver (about 18 of its CPU s;
# docs/development.md, "How long `make test` takes"). Nothing reads them;
# warnings and errors still reach the console.
QUIET_CONSOLE_DEBUG = "console.debug = () => {};"


@contextlib.contextmanager
def browser_page(viewport=None):
    """A Playwright page in Debian's chromium (never Playwright's own browser download), its
    console.debug silenced (`QUIET_CONSOLE_DEBUG`)."""
    from playwright import sync_api

    with sync_api.sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
        ctx = pw.chromium.launch_persistent_context(profile, executable_path=str(CHROMIUM), headless=True,
                                                    args=CHROMIUM_FLAGS, viewport=viewport or VIEWPORT)
        try:
            page = ctx.new_page()
            page.add_init_script(QUIET_CONSOLE_DEBUG)
            yield page
        finally:
            ctx.close()


_CDP = weakref.WeakKeyDictionary()  # page -> its DevTools session


def screenshot_png(page) -> bytes:
    """The page as PNG, from the DevTools protocol's Page.captureScreenshot (a session per
    page), not Playwright's `page.screenshot`: the viewer's page under software GL took 3-5 s
    and as many CPU s of the GPU process for each of Playwright's screenshots (whose steps
    around the capture make the viewer draw again), about 0.4 s and a tenth of that for this
    (docs/development.md, "How long `make test` takes"); the pixels are the
    compositor's frame either way."""
    import base64

    if page not in _CDP:
        _CDP[page] = page.context.new_cdp_session(page)
    return base64.b64decode(_CDP[page].send("Page.captureScreenshot", {"format": "png"})["data"])


def pixels(page, path: Path | None = None) -> np.ndarray:
    """A screenshot as an (h, w, 3) uint8 array (also saved to `path`)."""
    import io

    from PIL import Image

    png = screenshot_png(page)
    if path:
        Path(path).write_bytes(png)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def view_cells(rows: tuple[int, ...], tabs: tuple[bool, ...], size=(VIEWPORT["width"], VIEWPORT["height"])):
    """The pixel boxes (x0, y0, x1, y1) of the views of a horizontal row of equal columns,
    column j holding rows[j] equal views below a tab strip when tabs[j]; each box is the
    inside of the view (below its title bar, off its axes' edges)."""
    w, h = size
    top, bottom = TOP_BAR, h - TIME_BAR
    col_w = w / len(rows)
    boxes = []
    for j, (n, tabbed) in enumerate(zip(rows, tabs)):
        y0 = top + (TAB_BAR if tabbed else 0)
        cell_h = (bottom - y0) / n
        for i in range(n):
            x_a, x_b = j * col_w, (j + 1) * col_w
            y_a, y_b = y0 + i * cell_h, y0 + (i + 1) * cell_h
            boxes.append((int(x_a + 0.12 * col_w), int(y_a + 30), int(x_b - 0.04 * col_w), int(y_b - 0.12 * cell_h)))
    return boxes


def coloured(img: np.ndarray) -> np.ndarray:
    """Pixels with colour (chroma > 60): data; the viewer's own UI is grey, text black."""
    img = img.astype(int)
    return (img.max(axis=2) - img.min(axis=2)) > 60


def error_red(img: np.ndarray) -> np.ndarray:
    """Pixels of the viewer's error colour (a saturated red, as its error badges and texts
    are drawn; the layout draws no red)."""
    img = img.astype(int)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 170) & (g < 90) & (b < 90)


def dark(img: np.ndarray) -> np.ndarray:
    """Pixels of text (dark grey to black) on the viewer's light UI."""
    return img.astype(int).max(axis=2) < 110


def check_views(img: np.ndarray, boxes, min_pixels: int = 40, text: frozenset = frozenset()) -> list[str]:
    """Problems of a screenshot: views (boxes) without coloured pixels (the boxes of `text`,
    indices of text views, without dark text pixels), error red anywhere in the views' area."""
    problems = []
    for k, (x0, y0, x1, y1) in enumerate(boxes):
        n = int((dark if k in text else coloured)(img[y0:y1, x0:x1]).sum())
        if n < min_pixels:
            problems.append(f"view {k} at ({x0}, {y0})-({x1}, {y1}) is empty ({n} {'text' if k in text else 'coloured'}"
                            " pixels)")
    red = error_red(img[TOP_BAR:img.shape[0] - TIME_BAR])
    if red.sum() > 30:
        ys, xs = np.nonzero(red)
        problems.append(f"error red at {int(red.sum())} pixels around ({int(np.median(xs))}, "
                        f"{int(np.median(ys)) + TOP_BAR})")
    return problems


def changed(img: np.ndarray, before: np.ndarray, fraction: float = 0.02) -> bool:
    """Whether more than `fraction` of the pixels differ between two screenshots."""
    return img.shape != before.shape or float(np.any(img != before, axis=2).mean()) > fraction


def wait_loaded(page, boxes, timeout: float = LOAD_TIMEOUT, shot: Path | None = None, poll: float = 1.0,
                changed_from: np.ndarray | None = None, text: frozenset = frozenset()) -> np.ndarray:
    """Screenshots, `poll` s apart, until every view shows data (the viewer has loaded and
    ingested the recording) or `timeout`; returns the last screenshot (saved to `shot`).
    Under load the viewer sometimes draws a frame with its time series empty; the next frames
    have them. `changed_from`: only a frame that differs from this one counts (the previous
    tab's: until a new blueprint is applied the old tab's frame would pass the new views'
    checks). `text`: the indices of the boxes that are text views."""
    from PIL import Image

    end = time.monotonic() + timeout
    while True:
        img = pixels(page)
        fresh = changed_from is None or changed(img, changed_from)
        if (fresh and not [p for p in check_views(img, boxes, text=text) if "empty" in p]) or time.monotonic() > end:
            if shot:
                Image.fromarray(img).save(shot)  # the very frame that was checked
            return img
        time.sleep(poll)


def wait_stable(page, timeout: float = LOAD_TIMEOUT, still: float = 4.0, poll: float = 1.0,
                min_coloured: int = 200) -> np.ndarray:
    """Screenshots until one has not changed for `still` s and shows at least `min_coloured`
    coloured pixels (the viewer has taken all it was sent and its time cursor, which follows
    the data, has stopped), or `timeout`; returns the last one."""
    end = time.monotonic() + timeout
    last, since = None, time.monotonic()
    while True:
        img = pixels(page)
        if last is None or changed(img, last, fraction=0.0005):
            last, since = img, time.monotonic()
        elif time.monotonic() - since >= still and int(coloured(img[TOP_BAR:-TIME_BAR]).sum()) >= min_coloured:
            return img
        if time.monotonic() > end:
            return img
        time.sleep(poll)


def title_strips_match(img: np.ndarray, reference: np.ndarray, boxes, tabs_y: int = TOP_BAR) -> float:
    """The share of the pixels of the tab strips and the views' title bars (the 24 px above
    each box's inside, and the tab strip row) that are alike (within 40 of each other in
    every channel) in two screenshots: 1 when both show the same layout."""
    rows = [slice(tabs_y, tabs_y + TAB_BAR)] + [slice(max(y0 - 30, 0), y0 - 6) for _, y0, _, _ in boxes]
    cols = [slice(0, img.shape[1])] + [slice(x0, x1) for x0, _, x1, _ in boxes]
    alike = total = 0
    for r, c in zip(rows, cols):
        a, b = img[r, c].astype(int), reference[r, c].astype(int)
        alike += int((np.abs(a - b).max(axis=2) <= 40).sum())
        total += a.shape[0] * a.shape[1]
    return alike / max(total, 1)


def screenshot_tabs(page, rrd: Path, proxy: str, size, tabs, shots: Path | None = None, timeout: float = LOAD_TIMEOUT):
    """The recording in the viewer's page with each tab pair of `tabs` open in turn: the first
    as the recording's own (final) blueprint shows it, once the viewer has loaded the whole
    file; the others through blueprints built from the recording's layout (`recorded_layout`,
    its y ranges included). Yields (active, screenshot, boxes, text) per tab; screenshots go to
    `shots`/tab-M-R.png."""
    from PIL import Image

    from tirefilter.viz.blueprint import build_blueprint

    layout, ranges = recorded_layout(rrd)
    sender, previous = None, None
    try:
        for active in tabs:
            rows, tabbed, text = layout_grid(layout, active)
            boxes = view_cells(rows, tabbed, size)
            if previous is None:
                img = wait_stable(page, timeout)
                img = wait_loaded(page, boxes, 30, text=text)
            else:
                sender = sender or blueprint_sender(rrd, proxy)
                sender.send_blueprint(build_blueprint(layout, y_ranges=ranges, active=active), make_active=True)
                sender.flush()
                img = wait_loaded(page, boxes, timeout, changed_from=previous, text=text)
                img = wait_stable(page, 30)
            if shots:
                Image.fromarray(img).save(shots / f"tab-{active[0]}-{active[1]}.png")
            previous = img
            yield active, img, boxes, text
    finally:
        if sender is not None:
            sender.disconnect()


def layout_grid(layout, active: tuple[int, int]):
    """(rows, tabs, text) of `view_cells` for `viz.blueprint.build_blueprint(layout, active=...)`;
    `text` holds the indices (in `view_cells` order) of the text views."""
    e = layout.estimator
    bias = len(layout.sensors) if layout.bias_estimated else 1 + len(layout.true_bias)
    middle = [4, bias, 2] if e else [4, 2]
    right = ([2] if e and layout.clouds else []) + ([len(layout.densities)] * 2 if e and layout.densities else [])
    right += [2] if e and layout.friction else []
    right += [2]
    m = min(active[0], len(middle) - 1)
    rows = ((len(layout.params),) if e and layout.params else ()) + (middle[m], right[min(active[1], len(right) - 1)])
    text = frozenset([rows[0] if len(rows) == 3 else 0]) if e and m == 1 and not layout.bias_estimated else frozenset()
    return rows, (False,) * (len(rows) - 2) + (True, True), text


def recorded_layout(rrd: Path):
    """(Layout, y ranges) of a recording's final blueprint, from its property `tirefilter`
    (`viz.blueprint.layout_json`)."""
    import warnings

    from rerun.chunk import RrdReader

    from tirefilter.viz.blueprint import layout_from_json

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = RrdReader(rrd)
    for chunk in reader.stream():
        if chunk.entity_path == "/__properties/tirefilter":
            batch = chunk.to_record_batch()
            name = next(n for n in batch.schema.names if n.endswith("layout"))
            return layout_from_json(batch.column(name).to_pylist()[0][0])
    raise ValueError(f"{rrd} has no property 'tirefilter' (not written by tirefilter's recorder?)")


def recording_id(rrd: Path) -> str:
    """The recording id of the (one) recording in `rrd`."""
    import warnings

    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return RrdReader(rrd).recordings()[0].recording_id


def blueprint_sender(rrd: Path, proxy: str):
    """A stream into the served recording (same application and recording id: a stream
    of its own would open an empty recording in the viewer) for sending blueprints."""
    import rerun as rr

    rec = rr.RecordingStream("tirefilter", recording_id=recording_id(rrd))
    rec.connect_grpc(proxy)
    return rec


def main(argv=None) -> int:
    import argparse

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from tirefilter.viz.blueprint import tab_counts

    p = argparse.ArgumentParser(description="screenshot a recording in Rerun's web viewer (chromium, headless)")
    p.add_argument("rrd", type=Path)
    p.add_argument("out", type=Path, help="PNG to write; with --all-tabs, a folder for tab-M-R.png")
    p.add_argument("--tab", type=int, nargs=2, default=(0, 0), metavar=("MIDDLE", "RIGHT"),
                   help="the open tab of the middle and the right column (default 0 0)")
    p.add_argument("--all-tabs", action="store_true", help="every tab in turn, one browser session")
    p.add_argument("--wait", type=float, default=LOAD_TIMEOUT, help="s to wait for the views to fill")
    p.add_argument("--scale", type=float, default=1.0, help="scale of the PNG written (default 1)")
    args = p.parse_args(argv)
    from PIL import Image

    layout, _ = recorded_layout(args.rrd)
    middle, right = tab_counts(layout)
    tabs = [(min(k, middle - 1), min(k, right - 1)) for k in range(max(middle, right))] if args.all_tabs \
        else [(0, 0)] + ([tuple(args.tab)] if tuple(args.tab) != (0, 0) else [])
    size = (VIEWPORT["width"], VIEWPORT["height"])
    with serve_web_viewer(args.rrd) as (url, proxy), browser_page() as page:
        page.goto(url)
        shots = {}
        for active, img, boxes, text in screenshot_tabs(page, args.rrd, proxy, size, tabs, timeout=args.wait):
            for problem in check_views(img, boxes, text=text):
                print(f"warning: tab {active}: {problem}", file=sys.stderr)
            shots[active] = img
    for active, img in shots.items():
        if not args.all_tabs and active != tuple(args.tab):
            continue
        out = args.out / f"tab-{active[0]}-{active[1]}.png" if args.all_tabs else args.out
        pic = Image.fromarray(img)
        if args.scale != 1:
            pic = pic.resize((int(pic.width * args.scale), int(pic.height * args.scale)), Image.LANCZOS)
        out.parent.mkdir(parents=True, exist_ok=True)
        pic.save(out, optimize=True)
        print(f"{out}: {out.stat().st_size / 1024:.0f} KB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
