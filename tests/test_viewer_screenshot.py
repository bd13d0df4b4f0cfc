"""scripts/viewer_screenshot.py's own parts, without a browser or a viewer build: the server gives
index.html with the layout in place of Lichtblick's placeholder and the recording in byte ranges
(the viewer's remote-file reader asks for ranges), and refuses what is not a viewer build."""

from __future__ import annotations

import importlib.util
import io
import json
import socket
import sys
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def vs():
    spec = importlib.util.spec_from_file_location("viewer_screenshot", ROOT / "scripts" / "viewer_screenshot.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["viewer_screenshot"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture
def site(tmp_path, vs):
    viewer = tmp_path / "web"
    viewer.mkdir()
    (viewer / "index.html").write_text(f"<script>L = [{vs.PLACEHOLDER}][0];</script>")
    (viewer / "main.js").write_text("console.log(1)")
    mcap = tmp_path / "trial.mcap"
    mcap.write_bytes(bytes(range(256)) * 4)
    layout = tmp_path / "layout.json"
    layout.write_text(json.dumps({"layout": "3D!a", "configById": {"3D!a": {}}}))
    return viewer, mcap, layout


def get(url: str, headers: dict | None = None, method: str = "GET"):
    with urllib.request.urlopen(urllib.request.Request(url, headers=headers or {}, method=method)) as r:
        return r.status, dict(r.headers), r.read()


def test_index_carries_the_layout_and_the_recording_is_served_in_ranges(vs, site):
    viewer, mcap, layout = site
    server = vs.serve(viewer, mcap, layout, 0)
    base = f"http://127.0.0.1:{server.server_address[1]}"
    try:
        _, _, index = get(base + "/?ds=remote-file")
        assert index.decode() == f"<script>L = [{json.dumps(json.loads(layout.read_text()))}][0];</script>"
        assert get(base + "/main.js")[2] == b"console.log(1)"
        data = mcap.read_bytes()
        status, headers, body = get(base + vs.MCAP_URL_PATH, {"Range": "bytes=10-19"})
        assert (status, body, headers["Content-Range"]) == (206, data[10:20], f"bytes 10-19/{len(data)}")
        status, headers, body = get(base + vs.MCAP_URL_PATH, {"Range": "bytes=1000-"})
        assert (status, body, headers["Content-Range"]) == (206, data[1000:], f"bytes 1000-1023/{len(data)}")
        assert get(base + vs.MCAP_URL_PATH)[2] == data
        status, headers, body = get(base + vs.MCAP_URL_PATH, method="HEAD")
        assert (status, headers["Content-Length"], headers["Accept-Ranges"], body) == (200, str(len(data)), "bytes", b"")
    finally:
        server.shutdown()
        server.server_close()


def test_what_is_not_a_viewer_build_or_a_free_port_is_refused(vs, site, tmp_path):
    viewer, mcap, layout = site
    with pytest.raises(vs.ScreenshotError, match="--viewer .*no index.html"):
        vs.serve(tmp_path / "nowhere", mcap, layout, 0)
    with pytest.raises(vs.ScreenshotError, match="--mcap .*no such file"):
        vs.serve(viewer, tmp_path / "none.mcap", layout, 0)
    (viewer / "index.html").write_text("<html></html>")
    with pytest.raises(vs.ScreenshotError, match="not a Lichtblick web build"):
        vs.serve(viewer, mcap, layout, 0)
    (viewer / "index.html").write_text(vs.PLACEHOLDER)
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(vs.ScreenshotError, match="--layout"):
        vs.serve(viewer, mcap, tmp_path / "bad.json", 0)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        with pytest.raises(vs.ScreenshotError, match=f"--port {taken.getsockname()[1]}"):
            vs.serve(viewer, mcap, layout, taken.getsockname()[1])


def test_a_screenshot_over_the_size_limit_is_stored_with_a_palette(vs):
    from PIL import Image

    rng = __import__("numpy").random.default_rng(0)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 256, (64, 64, 3), dtype="uint8")).save(buf, "PNG")
    full, how = vs.png_bytes(buf.getvalue(), max_kb=1000)
    assert how == "full colour" and Image.open(io.BytesIO(full)).mode == "RGB"
    small, how = vs.png_bytes(buf.getvalue(), max_kb=1)
    assert how == "256-colour palette" and Image.open(io.BytesIO(small)).mode == "P" and len(small) < len(full)
