"""Screenshot the demo recording in Rerun's web viewer, in headless Chromium: what a remote
reviewer sees after `gx3 view --serve` or `rerun --serve-web`.

Needs Debian's Chromium and Playwright's Python package, without Playwright's own browser
download (the page is opened in /usr/bin/chromium, WebGL on SwiftShader):

    apt-get install -y chromium && .venv/bin/pip install -e '.[docs]'
    .venv/bin/python docs/web_viewer_shot.py docs/images/web-viewer.png

The recording is a gx3 demo run, as docs/images/viewer.png shows (bridge.fleet.snapshot).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
from pathlib import Path

from playwright.sync_api import sync_playwright

from bridge.fleet.snapshot import demo_picture, free_port, rerun_executable

CHROMIUM = "/usr/bin/chromium"
SIZE = (1600, 1000)
#: After the page's canvas appears: the wasm app starts, fetches the recording from the
#: server and draws it, in software, on a loaded 2-core machine.
SETTLE_S = 25.0


def _wait_for_port(port: int, server: subprocess.Popen[bytes], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1.0):
                return
        except OSError:
            if server.poll() is not None:
                raise RuntimeError("rerun --serve-web exited before it listened") from None
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)


def shoot(rrd: Path, png: Path) -> None:
    """Serve ``rrd`` with its web viewer, open it in headless Chromium, save what it shows."""
    grpc, web = free_port(), free_port()
    server = subprocess.Popen(
        [rerun_executable(), "--serve-web", "--bind", "127.0.0.1", "--port", str(grpc),
         "--web-viewer-port", str(web), str(rrd)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        _wait_for_port(web, server, 60.0)
        _wait_for_port(grpc, server, 60.0)
        source = urllib.parse.quote(f"rerun+http://127.0.0.1:{grpc}/proxy", safe="")
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=[
                "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"])
            page = browser.new_page(viewport={"width": SIZE[0], "height": SIZE[1]})
            page.goto(f"http://127.0.0.1:{web}/?url={source}")
            page.wait_for_selector("canvas", timeout=60_000)
            time.sleep(SETTLE_S)
            page.screenshot(path=str(png))
            browser.close()
    finally:
        os.killpg(server.pid, signal.SIGTERM)  # the wrapper and the server it started
        server.wait(timeout=10)


def main(argv: list[str]) -> int:
    return demo_picture(argv, "python docs/web_viewer_shot.py", shoot)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
