"""Render a recording to PNG with Rerun's headless viewer, to look at it without a display.

Needs a Vulkan driver (on Debian: mesa-vulkan-drivers and libvulkan1, Mesa's software
rasteriser). The viewer is driven through its control API rather than
``--screenshot-to``: that one shoots after a fixed delay, before a recording of a few MB
has loaded, and with the time cursor wherever playback happens to be.

    python -m bridge.fleet.snapshot docs/images/viewer.png    # a gx3 demo run, as in the README
    python -m bridge.fleet.snapshot shot.png --recording gx3-demo/demo.rrd   # one you have
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
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from rerun.experimental import ViewerClient, ViewerState

from bridge.archive.walk import read_archive
from bridge.bus.gx3_pb2 import Event
from bridge.fleet.loopback import free_port
from bridge.viz.layout import TIME


def rerun_executable() -> str:
    """The ``rerun`` command beside this interpreter, or else on the PATH.

    Raises:
        RuntimeError: It is not installed.
    """
    beside = Path(sys.executable).with_name("rerun")
    found = str(beside) if beside.exists() else shutil.which("rerun")
    if found is None:
        raise RuntimeError("the rerun command is not installed: pip install rerun-sdk")
    return found


@contextmanager
def headless_viewer(size: tuple[int, int] = (1600, 1000), timeout_s: float = 60.0,
                    memory_limit: str | None = None
                    ) -> Iterator[tuple[ViewerClient, subprocess.Popen[bytes]]]:
    """A headless Rerun viewer on a free loopback port, and a client connected to it.

    Stopped on leaving, with the viewer its ``rerun`` wrapper started.

    Args:
        size: The window's size, points.
        timeout_s: How long it may take to answer.
        memory_limit: Its ``--memory-limit`` (``1GB``); None: Rerun's default.

    Yields:
        The client, and the process (the wrapper, leading its process group).
    """
    port = free_port()
    limit = [] if memory_limit is None else ["--memory-limit", memory_limit]
    viewer = subprocess.Popen(
        [rerun_executable(), "--headless", "--bind", "127.0.0.1", "--port", str(port),
         "--window-size", f"{size[0]}x{size[1]}", "--hide-welcome-screen", *limit],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        yield _connect(f"rerun+http://127.0.0.1:{port}/proxy", viewer,
                       time.monotonic() + timeout_s), viewer
    finally:
        os.killpg(viewer.pid, signal.SIGTERM)  # the wrapper and the viewer it started
        viewer.wait(timeout=10)


def open_recording(client: ViewerClient, rrd: str | os.PathLike[str],
                   timeout_s: float = 60.0) -> ViewerState:
    """Open ``rrd`` in a viewer and wait until it has loaded.

    Returns:
        The viewer's state once loaded.

    Raises:
        TimeoutError: It has not loaded within ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    client.open(os.fspath(Path(rrd).resolve()))
    while True:
        state = client.get_state()
        if not state.loading and state.active_recording:
            return state
        if time.monotonic() > deadline:
            raise TimeoutError(f"the viewer did not load {rrd} within {timeout_s:g} s")
        time.sleep(0.2)


def render(rrd: str | os.PathLike[str], png: str | os.PathLike[str], *, at_ns: int | None = None,
           before_end_s: float | None = None, size: tuple[int, int] = (1600, 1000),
           timeout_s: float = 60.0, tab: str | None = None) -> ViewerState:
    """Open ``rrd`` in a headless viewer and save what it shows to ``png``.

    The time cursor is paused at ``at_ns`` on the ``time`` timeline, else
    ``before_end_s`` seconds before its end, else where the viewer puts it; ``tab``
    names the tab shown (``accel [g]``), else the first is. Returns the viewer's own
    account of what it showed: recordings, timelines, views and what each view failed
    to show.
    """
    with headless_viewer(size, timeout_s) as (client, _):
        state = open_recording(client, rrd, timeout_s)
        if tab is not None:
            _show_tab(client, tab)
        if at_ns is None and before_end_s is not None:
            (end,) = [t.end for r in state.recordings for t in r.timelines if t.name == TIME]
            at_ns = None if end is None else end - round(before_end_s * 1e9)
        if at_ns is not None:
            client.set_time(TIME, timestamp=np.datetime64(at_ns, "ns"), play_state="paused")
        time.sleep(1.0)  # let the views catch up with the cursor before the shot
        client.save_screenshot(os.fspath(png))
        return client.get_state()


def _show_tab(client: ViewerClient, name: str) -> None:
    """Make the tab of that name the one shown, in the recording's blueprint."""
    blueprint = client.get_blueprint(of="recording").blueprint
    tabs = {parts["ContainerBlueprint"]["display_name"]: path.lstrip("/")
            for path, parts in blueprint.items()
            if "display_name" in parts.get("ContainerBlueprint", {})}
    if name not in tabs:
        raise ValueError(f"no tab {name!r} in the recording (tabs: {', '.join(tabs)})")
    for parts in blueprint.values():
        if parts.get("ContainerBlueprint", {}).get("container_kind") == "Tabs":
            parts["ContainerBlueprint"]["active_tab"] = tabs[name]
    client.set_blueprint(blueprint, of="recording")


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


#: The README's fleet: enough units to show the colours and the grid, and the unplugged
#: unit's gap and reconnect (gx3 demo unplugs its last unit part-way).
DEMO_UNITS = 4
DEMO_DURATION_S = 20.0
#: Where the picture's time cursor sits: this long after the unplugged unit came back (gx3
#: demo pulls its last unit part-way), so the events show the disconnect, the reconnect
#: and the records lost meanwhile, with their count and span.
AFTER_RECONNECT_S = 1.5


def record_demo(out: Path, units: int = DEMO_UNITS, duration_s: float = DEMO_DURATION_S) -> Path:
    """Run ``gx3 demo`` (real bridges, Zenoh, recorder) into the new folder ``out``.

    Returns its Rerun recording.
    """
    gx3 = Path(sys.executable).with_name("gx3")
    command = [str(gx3)] if gx3.exists() else [sys.executable, "-c",
                                               "from bridge.cli import app; app()"]
    run = subprocess.run([*command, "demo", "--units", str(units), "--duration",
                          f"{duration_s:g}", "-o", str(out)], capture_output=True, text=True)
    if run.returncode != 0:
        raise RuntimeError(f"gx3 demo failed ({run.returncode}): {run.stderr.strip()}")
    return out / "demo.rrd"


def demo_picture(argv: list[str], prog: str, take: Callable[[Path, Path], object]) -> int:
    """The screenshot scripts' main: ``take(recording, png)`` of a gx3 demo recording.

    Of a new run's, unless one is given.
    """
    parser = argparse.ArgumentParser(prog=prog, description="Picture a gx3 demo recording.")
    parser.add_argument("png", type=Path, metavar="OUT.png", help="the picture to write")
    parser.add_argument("--recording", type=Path, metavar="DEMO.rrd",
                        help="a recording gx3 demo made (default: run gx3 demo --units "
                        f"{DEMO_UNITS} --duration {DEMO_DURATION_S:g} for it, about 40 s)")
    args = parser.parse_args(argv)
    if args.recording is not None:
        if not args.recording.is_file():
            parser.error(f"{args.recording}: no such file; give the demo.rrd gx3 demo wrote")
        take(args.recording, args.png)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        take(record_demo(Path(tmp) / "demo"), args.png)
    return 0


def _after_reconnect_ns(rrd: Path) -> int | None:
    """A moment AFTER_RECONNECT_S after the first reconnect in the demo's archive.

    The archive gx3 demo wrote beside ``rrd`` (demo.mcap); None when there is none.
    """
    archive = rrd.with_suffix(".mcap")
    if not archive.is_file():
        return None
    found = [e.time_ns for _, e in read_archive(archive).events() if e.kind == Event.RECONNECT]
    return min(found) + round(AFTER_RECONNECT_S * 1e9) if found else None


def main(argv: list[str]) -> int:
    """``python -m bridge.fleet.snapshot``: picture a gx3 demo run, as the README shows."""
    return demo_picture(argv, "python -m bridge.fleet.snapshot",
                        lambda rrd, png: render(rrd, png, at_ns=_after_reconnect_ns(rrd),
                                                before_end_s=1.0))


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
