"""A real screenshot of a trial's recording (``trial.mcap``) opened in Lichtblick, taken headless.

Lichtblick is the open-source continuation of Foxglove Studio 1.x (MPL-2.0,
github.com/lichtblick-suite/lichtblick); it reads MCAP files with Foxglove's schemas as Foxglove
does. This script does not build it (see the end of this text); given its built web app it
serves the app and the recording on 127.0.0.1 (HTTP with Range requests, as the app's remote file
reader asks for), injects a layout (``scripts/viewer_layout.json``: a 3D panel in the pile frame
with the scan's point cloud, the reconstructed logs and the twin-tried grasps; the scan's left
image; the trial's, the crane's and the CAN frames' states over time; the progress log) the way
Lichtblick's own Docker image does (its ``LICHTBLICK_SUITE_DEFAULT_LAYOUT_PLACEHOLDER`` in
index.html), opens ``?ds=remote-file&ds.url=...`` in headless Chromium (WebGL through
SwiftShader), closes the left sidebar, plays the recording to its end at the layout's speed (5x;
the Log panel lists what it played through) and saves the page with the DevTools protocol's
``Page.captureScreenshot``. ``--play-s 0`` instead opens the file at its last message time.

    .venv/bin/python scripts/viewer_screenshot.py --viewer /work/viewer-build/lichtblick/web/.webpack \\
        --mcap out/demo/trial/trial.mcap --out docs/img/trial_foxglove.png

The viewer: Lichtblick v1.28.1 (commit 66adecb99ca4363b1028c750919c9046609f5c85), its web app
built from source by ``scripts/build_lichtblick.sh GIT_DIR DEST`` outside this repository (that
script lists what its build changes from upstream's and why); Chromium is Debian's (156 when the
README's screenshot was taken).
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import datetime as dt
import http.server
import json
import os
import re
import shutil
import subprocess
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

PLACEHOLDER = "/*LICHTBLICK_SUITE_DEFAULT_LAYOUT_PLACEHOLDER*/"
MCAP_URL_PATH = "/trial.mcap"
DEVTOOLS_WAIT_S = 20.0  # how long Chromium may take to open its DevTools port [s]
MAX_PNG_KB = 600  # a larger screenshot is stored with a 256-colour palette [kB]


class ScreenshotError(Exception):
    """A one-line reason the screenshot cannot be taken (the CLI exits 2 with it)."""


class QuietServer(http.server.ThreadingHTTPServer):
    """The app cancels range requests it no longer needs; a closed connection is no error here."""

    def handle_error(self, request, client_address) -> None:
        import sys

        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


def png_bytes(png: bytes, max_kb: float = MAX_PNG_KB) -> tuple[bytes, str]:
    """The screenshot as an optimised PNG, palette-quantised only if it would exceed ``max_kb``."""
    import io

    from PIL import Image

    im = Image.open(io.BytesIO(png)).convert("RGB")
    out = io.BytesIO()
    im.save(out, "PNG", optimize=True)
    if out.tell() <= max_kb * 1000:
        return out.getvalue(), "full colour"
    out = io.BytesIO()
    im.quantize(256, method=Image.Quantize.MEDIANCUT).save(out, "PNG", optimize=True)
    return out.getvalue(), "256-colour palette"


def recording_end(mcap: Path) -> dt.datetime:
    """The last log time in the recording (UTC), so every one-shot topic is on screen."""
    from mcap.reader import make_reader

    with mcap.open("rb") as f:
        stats = make_reader(f).get_summary().statistics
    return dt.datetime.fromtimestamp(stats.message_end_time / 1e9, tz=dt.timezone.utc)


def make_handler(viewer: Path, mcap: Path, index_html: bytes):
    """A request handler serving the viewer's files, index.html with the layout, and the MCAP with Range."""

    class Handler(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a, **kw):
            super().__init__(*a, directory=str(viewer), **kw)

        def log_message(self, *args) -> None:  # quiet
            pass

        def end_headers(self) -> None:
            self.send_header("Access-Control-Allow-Origin", "*")
            self.send_header("Accept-Ranges", "bytes")
            super().end_headers()

        def do_GET(self) -> None:
            path = self.path.split("?", 1)[0]
            if path in ("/", "/index.html"):
                self._send(index_html, "text/html")
            elif path == MCAP_URL_PATH:
                self._send_mcap()
            else:
                super().do_GET()

        def do_HEAD(self) -> None:
            if self.path.split("?", 1)[0] == MCAP_URL_PATH:
                self.send_response(200)
                self.send_header("Content-Length", str(mcap.stat().st_size))
                self.send_header("Content-Type", "application/octet-stream")
                self.end_headers()
            else:
                super().do_HEAD()

        def _send(self, body: bytes, ctype: str, status: int = 200, extra: dict | None = None) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            for k, v in (extra or {}).items():
                self.send_header(k, v)
            self.end_headers()
            self.wfile.write(body)

        def _send_mcap(self) -> None:
            data, size = mcap.read_bytes(), mcap.stat().st_size
            m = re.fullmatch(r"bytes=(\d+)-(\d*)", self.headers.get("Range", ""))
            if not m:
                self._send(data, "application/octet-stream")
                return
            start, end = int(m[1]), min(int(m[2]) if m[2] else size - 1, size - 1)
            self._send(data[start:end + 1], "application/octet-stream", 206,
                       {"Content-Range": f"bytes {start}-{end}/{size}"})

    return Handler


async def capture(devtools_port: int, url: str, width: int, height: int, load_s: float, play_s: float,
                  dump_text: bool = False) -> bytes:
    """Open ``url`` in the browser's first page, close the left sidebar, play the recording for
    ``play_s`` (0: stay at the URL's time) and return a PNG of the page."""
    import websockets

    with urllib.request.urlopen(f"http://127.0.0.1:{devtools_port}/json") as r:
        page = next(t for t in json.load(r) if t["type"] == "page")
    async with websockets.connect(page["webSocketDebuggerUrl"], max_size=None) as ws:
        ids = iter(range(1, 1_000_000))

        async def call(method: str, **params) -> dict:
            i = next(ids)
            await ws.send(json.dumps({"id": i, "method": method, "params": params}))
            while True:
                msg = json.loads(await ws.recv())
                if msg.get("id") == i:
                    if "error" in msg:
                        raise RuntimeError(f"{method}: {msg['error']}")
                    return msg["result"]

        async def js(expr: str):
            return (await call("Runtime.evaluate", expression=expr, returnByValue=True))["result"].get("value")

        await call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1,
                   mobile=False)
        await call("Page.enable")
        await call("Page.navigate", url=url)
        deadline = time.monotonic() + load_s
        while not await js("!!document.querySelector('[data-testid=play-button]')"):
            if time.monotonic() > deadline:
                raise ScreenshotError(f"the viewer showed no playback controls in {load_s:.0f} s: {url}")
            await asyncio.sleep(0.5)
        await asyncio.sleep(load_s / 3)  # let the panels subscribe and the file's index load
        for kind in ("keyDown", "keyUp"):  # Lichtblick's "[" shortcut: close the left sidebar
            await call("Input.dispatchKeyEvent", type=kind, key="[", code="BracketLeft", text="[",
                       windowsVirtualKeyCode=219)
        if play_s > 0:
            await js("document.querySelector('[data-testid=play-button]').click()")
            await asyncio.sleep(play_s)
        else:
            await asyncio.sleep(load_s / 3)
        # the Log panel stops following when lines arrive faster than it scrolls: show its last ones
        await js("document.querySelector('[data-testid=scroll-to-bottom-button]')?.click()")
        await asyncio.sleep(1.0)
        if dump_text:
            print(await js("document.body.innerText"))
        shot = await call("Page.captureScreenshot", format="png")
    return base64.b64decode(shot["data"])


def serve(viewer: Path, mcap: Path, layout_path: Path, port: int) -> QuietServer:
    """The viewer and the recording on http://127.0.0.1:PORT, index.html carrying the layout."""
    if not (viewer / "index.html").is_file():
        raise ScreenshotError(f"--viewer {viewer}: no index.html (give Lichtblick's built web/.webpack folder)")
    if not mcap.is_file():
        raise ScreenshotError(f"--mcap {mcap}: no such file (loggrasp demo --out out/demo writes one)")
    index = (viewer / "index.html").read_text()
    if PLACEHOLDER not in index:
        raise ScreenshotError(f"{viewer}/index.html has no {PLACEHOLDER}: not a Lichtblick web build")
    try:
        layout = json.dumps(json.loads(layout_path.read_text()))
    except (OSError, ValueError) as e:
        raise ScreenshotError(f"--layout {layout_path}: {e}") from e
    try:
        handler = make_handler(viewer, mcap, index.replace(PLACEHOLDER, layout).encode())
        server = QuietServer(("127.0.0.1", port), handler)
    except OSError as e:
        raise ScreenshotError(f"--port {port}: {e.strerror}") from e
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def start_browser(chromium: str, profile: str, devtools_port: int, width: int, height: int) -> subprocess.Popen:
    """Headless Chromium with WebGL through SwiftShader, its DevTools on 127.0.0.1:``devtools_port``."""
    browser = subprocess.Popen(
        [chromium, "--headless", "--no-sandbox", "--no-first-run", "--hide-scrollbars", f"--user-data-dir={profile}",
         f"--remote-debugging-port={devtools_port}", "--remote-debugging-address=127.0.0.1",
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
         f"--window-size={width},{height}", "about:blank"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + DEVTOOLS_WAIT_S
    while True:
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{devtools_port}/json/version").close()
            return browser
        except OSError:
            if time.monotonic() > deadline:
                browser.kill()
                browser.wait()
                raise ScreenshotError(f"--chromium {chromium} opened no DevTools port in {DEVTOOLS_WAIT_S:.0f} s")
            time.sleep(0.3)


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--viewer", type=Path, required=True, help="Lichtblick's built web app (web/.webpack)")
    ap.add_argument("--mcap", type=Path, default=Path("out/demo/trial/trial.mcap"))
    ap.add_argument("--layout", type=Path, default=Path(__file__).with_name("viewer_layout.json"))
    ap.add_argument("--out", type=Path, default=Path("docs/img/trial_foxglove.png"))
    ap.add_argument("--chromium", default=shutil.which("chromium") or "chromium")
    ap.add_argument("--size", default="1600x900", help="the page's size in pixels, WxH")
    ap.add_argument("--load-s", type=float, default=30.0, help="time the app gets to load the file [s]")
    ap.add_argument("--play-s", type=float, default=20.0,
                    help="play the recording from its start this long (the layout's speed), 0: show its end [s]")
    ap.add_argument("--dump-text", action="store_true", help="print the page's text (to see the app's alerts)")
    ap.add_argument("--port", type=int, default=8765, help="HTTP port on 127.0.0.1")
    ap.add_argument("--devtools-port", type=int, default=9333)
    return ap.parse_args()


def main() -> None:
    args = parse_args()
    m = re.fullmatch(r"(\d+)x(\d+)", args.size)
    if not m:
        raise ScreenshotError(f"--size {args.size}: give WxH in pixels, e.g. 1600x900")
    width, height = int(m[1]), int(m[2])
    server = serve(args.viewer, args.mcap, args.layout, args.port)
    base = f"http://127.0.0.1:{args.port}"
    url = f"{base}/?ds=remote-file&ds.url={base}{MCAP_URL_PATH}"
    if args.play_s <= 0:
        url += "&time=" + recording_end(args.mcap).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    try:
        with tempfile.TemporaryDirectory() as profile:
            browser = start_browser(args.chromium, profile, args.devtools_port, width, height)
            try:
                png = asyncio.run(capture(args.devtools_port, url, width, height, args.load_s, args.play_s,
                                          args.dump_text))
            finally:
                browser.terminate()
                browser.wait(timeout=10)
    finally:
        server.shutdown()
    data, how = png_bytes(png)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp.png")
    tmp.write_bytes(data)
    os.replace(tmp, args.out)
    print(f"{args.out}: {width}x{height}, {len(data) / 1000:.0f} kB ({how}), {url}")


if __name__ == "__main__":
    import sys

    try:
        main()
    except ScreenshotError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
