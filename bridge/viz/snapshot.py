"""Render a recording to PNG with Rerun's headless viewer, to look at it without a display.

Needs a Vulkan driver (on Debian: mesa-vulkan-drivers and libvulkan1, Mesa's software
rasteriser). The viewer is driven through its control API rather than
``--screenshot-to``: that one shoots after a fixed delay, before a recording of a few MB
has loaded, and with the time cursor wherever playback happens to be.

    python -m bridge.viz.snapshot docs/images/viewer.png    # the demo fleet, as in the README
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from rerun.experimental import ViewerClient, ViewerState

from bridge.loopback import free_port
from bridge.viz.demo import DEMO_EPOCH_NS, write_demo
from bridge.viz.layout import TIME


def rerun_executable() -> str:
    beside = Path(sys.executable).with_name("rerun")
    found = str(beside) if beside.exists() else shutil.which("rerun")
    if found is None:
        raise RuntimeError("the rerun command is not installed: pip install rerun-sdk")
    return found


def render(rrd: str | os.PathLike[str], png: str | os.PathLike[str], *, at_ns: int | None = None,
           size: tuple[int, int] = (1600, 1000), timeout_s: float = 60.0) -> ViewerState:
    """Open ``rrd`` in a headless viewer, pause the time cursor at ``at_ns`` on the ``time``
    timeline (default: where the viewer puts it), save what it shows to ``png`` and return
    the viewer's own account of it: recordings, timelines, views and what each view
    failed to show."""
    port = free_port()
    viewer = subprocess.Popen(
        [rerun_executable(), "--headless", "--bind", "127.0.0.1", "--port", str(port),
         "--window-size", f"{size[0]}x{size[1]}", "--hide-welcome-screen"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + timeout_s
        client = _connect(f"rerun+http://127.0.0.1:{port}/proxy", viewer, deadline)
        client.open(os.fspath(Path(rrd).resolve()))
        while True:
            state = client.get_state()
            if not state.loading and state.active_recording:
                break
            if time.monotonic() > deadline:
                raise TimeoutError(f"the viewer did not load {rrd} within {timeout_s:g} s")
            time.sleep(0.2)
        if at_ns is not None:
            client.set_time(TIME, timestamp=np.datetime64(at_ns, "ns"), play_state="paused")
        time.sleep(1.0)  # let the views catch up with the cursor before the shot
        client.save_screenshot(os.fspath(png))
        return client.get_state()
    finally:
        os.killpg(viewer.pid, signal.SIGTERM)  # the wrapper and the viewer it started
        viewer.wait(timeout=10)


def _connect(url: str, viewer: subprocess.Popen[bytes], deadline: float) -> ViewerClient:
    while True:
        try:
            client = ViewerClient.connect(url)
            client.get_state()
            return client
        except Exception:
            if viewer.poll() is not None:
                raise RuntimeError("the headless viewer exited: does this machine have a "
                                   "Vulkan driver (apt-get install mesa-vulkan-drivers)?") from None
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)


def demo_picture(argv: list[str], prog: str, take: Callable[[Path, Path], object]) -> int:
    """The screenshot scripts' main: ``take(recording, png)`` of the demo recording."""
    parser = argparse.ArgumentParser(prog=prog, description="Picture the demo recording.")
    parser.add_argument("png", type=Path, metavar="OUT.png", help="the picture to write")
    png: Path = parser.parse_args(argv).png
    with tempfile.TemporaryDirectory() as tmp:
        rrd = Path(tmp) / "demo.rrd"
        write_demo(rrd)
        take(rrd, png)
    return 0


def main(argv: list[str]) -> int:
    return demo_picture(argv, "python -m bridge.viz.snapshot",
                        lambda rrd, png: render(rrd, png, at_ns=DEMO_EPOCH_NS + 20 * 10**9))


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
