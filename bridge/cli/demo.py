"""`gx3 demo`: the whole product working on one machine, in one command."""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import sys
import time
import urllib.parse
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.live import Live
from rich.table import Table

from bridge._text import counted, number
from bridge.cli.common import INTERRUPTED, app, fail, failing, parse_code
from bridge.cli.record import unit_table

if TYPE_CHECKING:
    from bridge.fleet.demo import Demo, UnitOutcome
    from bridge.recorder.units import UnitRow

#: Off a terminal (a CI log, a pipe), a line of progress this often, seconds.
LOG_EVERY_S = 5.0
#: Where `rerun --serve-web` serves the web viewer and the recording, where there is no
#: display: Rerun's own defaults, on loopback.
WEB, WEB_GRPC = 9090, 9876


def web_viewer_url() -> str:
    """The address that opens the served recording in a browser (Rerun 0.41)."""
    source = urllib.parse.quote(f"rerun+http://127.0.0.1:{WEB_GRPC}/proxy", safe="")
    return f"http://127.0.0.1:{WEB}/?url={source}"


def _summary(rows: list[UnitOutcome]) -> Table:
    table = Table(title="summary (drift: found by the bridge, true in brackets)",
                  title_justify="left", box=None, pad_edge=False)
    for name in ("unit", "samples", "drops", "checksum", "resyncs", "reconn.", "drift ppm",
                 "what happened"):
        table.add_column(name, justify="left" if name in ("unit", "what happened") else "right",
                         no_wrap=name != "what happened")
    for r in rows:
        found = "not yet known" if r.drift_ppm is None else f"{r.drift_ppm:+.1f}"
        table.add_row(r.unit, *map(number, (r.samples, r.dropped, r.checksum_failures,
                                            r.resyncs, r.reconnects)),
                      f"{found} ({r.true_ppm:+.0f})", r.notes)
    return table


def _runnable(name: str) -> str:
    """``name`` (gx3, rerun) as a shell runs this installation's: bare where the PATH
    finds it, else its path (relative where that is shorter), so a suggestion printed
    with it runs as printed in the user's shell."""
    here = Path(sys.executable).parent / name  # a venv's scripts sit beside its python
    if not here.exists():
        return name
    found = shutil.which(name)
    if found is not None and Path(found).resolve() == here.resolve():
        return name
    relative = os.path.relpath(here)
    return shlex.quote(relative if len(relative) < len(str(here)) else str(here))


def _progress_line(rows: list[UnitRow], elapsed: float, duration: float,
                   units: int) -> str:
    """The demo's progress as one line, for a log."""
    streaming = sum(1 for r in rows if r.samples)
    if not elapsed:
        return f"demo: starting the bridges, {streaming} of {counted(units, 'unit')} streaming"
    samples = sum(r.samples for r in rows)
    return (f"demo: {elapsed:,.0f} of {duration:g} s, {counted(samples, 'sample')} from "
            f"{streaming} of {counted(units, 'unit')}")


def _align_hints(gx3: str, run: Demo, folder: str, body: bool) -> list[tuple[str, str]]:
    """With --body, the commands that find the units' mountings and draw them so."""
    if not body or len(run.units) < 2:
        return []
    archive = shlex.quote(str(run.archive))
    names = " ".join(f"-u {u.name}" for u in run.units)
    return [(f"{gx3} align {archive} {names} -o {folder}/mounts.yaml",
             f"each unit's mounting and time shift against {run.units[0].name}"),
            (f"{gx3} rrd {archive} --mounts {folder}/mounts.yaml -o {folder}/mounted.rrd",
             f"every unit drawn in {run.units[0].name}'s axes and time")]


@app.command("demo")
def demo(
    output: Annotated[Path | None, typer.Option(
        "--output", "-o", metavar="DIR", show_default=False,
        help="Folder for the archive, the Rerun recording, the configs and the logs "
             "(default: gx3-demo here, or gx3-demo-2, -3, ... when an earlier run's results "
             "are there). A folder that is not empty is refused unless --force.")] = None,
    duration: Annotated[float, typer.Option(
        min=1.0, help="Seconds of streaming (after every bridge is up); Ctrl-C stops "
                      "earlier.")] = 20.0,
    units: Annotated[int, typer.Option(min=1, max=16, help="Emulated units.")] = 4,
    rate: Annotated[float, typer.Option(min=1.0, max=1000.0, help="Output rate, Hz.")] = 100.0,
    record_type: Annotated[str, typer.Option(
        help="Record every unit streams, e.g. 0xCC (accel, ang_rate, mag, M).")] = "0xCC",
    router: Annotated[bool, typer.Option(
        "--router", help="Route through a gx3 router instead of peer to peer.")] = False,
    body: Annotated[bool, typer.Option(
        "--body", help="Fix the units to one body turned by hand, each mounted its own way "
                       "(upside down and turned 90°, turned 177°, 0.3 m apart, one behind "
                       "a 3.2 ms link); the summary says how to find it all with gx3 "
                       "align.")] = False,
    viewer: Annotated[str | None, typer.Option(
        metavar="spawn|serve", help="Also show it live in Rerun: spawn a viewer here, or "
                                    "serve one for a browser.")] = None,
    force: Annotated[bool, typer.Option(
        "--force", help="Write into a --output folder that is not empty, replacing an "
                        "earlier run's results (never those of a demo still running).")]
    = False,
) -> None:
    """Run an emulated fleet through the whole product: bridges, Zenoh, recorder, Rerun.

    Units with different clock errors stream over real pseudo-terminals, one `gx3
    bridge` process each; one unit crosses the timer rollover, one suffers bit flips
    and an unplug. The recorder writes DIR/demo.mcap and DIR/demo.rrd while a
    dashboard shows each unit; at the end a summary compares what the bridges found
    with the truth, and says how to open the results.
    """
    from bridge.archive.outputs import free_folder, named_folder
    from bridge.cli.viz import _display, live_recording
    from bridge.exceptions import DemoError
    from bridge.fleet.demo import Demo, fleet

    if viewer not in (None, "spawn", "serve"):
        raise fail(f"--viewer {viewer!r}: use spawn or serve")
    if viewer == "spawn" and not _display():
        raise fail("--viewer spawn: no display here (DISPLAY and WAYLAND_DISPLAY are unset); "
                   "use --viewer serve for a remote or web viewer, or leave --viewer out")
    members = fleet(units, parse_code(record_type), rate, duration, body)
    output = free_folder(named_folder(output) if output else Path("gx3-demo"), force,
                         next_free=output is None)
    console = Console(stderr=True)
    live = Live(console=console, refresh_per_second=2, transient=True, auto_refresh=False)
    logged = [-LOG_EVERY_S]  # when the last progress line went out, off a terminal

    def show(rows: list[UnitRow], elapsed: float) -> None:
        if not console.is_terminal:
            now = time.monotonic()
            if now - logged[0] >= LOG_EVERY_S:
                logged[0] = now
                console.print(_progress_line(rows, elapsed, duration, units), highlight=False)
            return
        title = f"demo: {elapsed:,.0f} of {duration:g} s" if elapsed else "demo: starting"
        live.update(unit_table(rows, title), refresh=True)

    recording = None
    if viewer is not None:
        recording = live_recording("demo-live", viewer == "spawn", viewer == "serve", None)
    run = Demo(output, members, duration, router, recording, show, force=force)
    interrupted = []

    def stop(*_: Any) -> None:
        interrupted.append(True)
        run.stop.set()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    started = time.monotonic()
    # an ArchiveError is a refusal (another demo writes there): exit 2, as any Gx3Error
    with failing(DemoError), live:
        run.run()
    console.print(_summary(run.summary()))
    ended = "interrupted after" if interrupted else "done in"
    console.print(f"{ended} {time.monotonic() - started:,.0f} s; results in {output}/ (the "
                  "archive, the Rerun recording, each bridge's log and the Zenoh configs "
                  "they used). Open them with:", highlight=False)
    gx3, rerun = _runnable("gx3"), _runnable("rerun")
    if not _display():  # Rerun's native viewer needs one: its web viewer, in a browser
        rerun += f" --serve-web --bind 127.0.0.1 --port {WEB_GRPC} --web-viewer-port {WEB}"
    folder = shlex.quote(str(output))
    for command, what in ((f"{rerun} {shlex.quote(str(run.rrd))}",
                           "the recording: attitude and signals"),
                          (f"{rerun} {shlex.quote(str(run.archive))}",
                           "the archive: each unit's axes in 3-D, and the events"),
                          (f"{gx3} export {shlex.quote(str(run.archive))} -o "
                           f"{folder}/demo.parquet", "one row per sample"),
                          (f"{gx3} export {shlex.quote(str(run.archive))} --align 100 -o "
                           f"{folder}/aligned.csv", "every unit on one 100 Hz grid"),
                          *_align_hints(gx3, run, folder, body)):
        # never wrapped: a command is copied as one line
        console.print(f"  {command}", highlight=False, soft_wrap=True, markup=False)
        console.print(f"      [dim]{what}[/]", highlight=False)
    if not _display():
        console.print("No display here: each rerun line serves Rerun's web viewer until "
                      f"Ctrl-C; open {web_viewer_url()} in a browser (from another "
                      f"machine: ssh -L {WEB}:127.0.0.1:{WEB} -L {WEB_GRPC}:127.0.0.1:"
                      f"{WEB_GRPC} THIS-HOST first)", highlight=False, soft_wrap=True,
                      markup=False)
    if interrupted:
        raise typer.Exit(INTERRUPTED)
