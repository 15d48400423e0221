"""`gx3 view` (the live fleet in Rerun) and `gx3 rrd` (an archive rendered to .rrd)."""

from __future__ import annotations

import math
import os
import shlex
import signal
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from bridge._text import counted
from bridge.cli.bridge import ConnectOpt, ListenOpt, ModeOpt, PrefixOpt, ZenohConfigOpt
from bridge.cli.common import (
    FAILED,
    EndOpt,
    ForceOpt,
    LogFormat,
    LogFormatOpt,
    LogLevel,
    LogLevelOpt,
    StartOpt,
    app,
    err,
    fail,
    log_to,
    refused,
    written,
)
from bridge.viz.review import FULL_RATE_SAMPLES, OVERVIEW_RATES_HZ

if TYPE_CHECKING:
    from bridge.analysis.magcal import UnitIron
    from bridge.viz.review import Review

MagCalOpt = Annotated[list[Path] | None, typer.Option(
    "--mag-cal", metavar="FILE",
    help="Iron calibration (JSON) of one unit from gx3 calibrate-mag (repeatable, one per "
         "unit): that unit's mag and stab_mag are shown corrected, soft_iron @ (raw - "
         "hard_iron).")]


def _irons(files: list[Path] | None) -> list[UnitIron]:
    """The calibrations given, or a one-line error."""
    from bridge.analysis.magcal import read_document

    try:
        return [read_document(path) for path in files or ()]
    except ValueError as exc:
        raise fail(f"--mag-cal: {exc}") from None


@app.command("rrd")
def rrd(
    archive: Annotated[Path, typer.Argument(metavar="ARCHIVE.mcap",
                                            help="Archive from gx3 record or gx3 replay.")],
    output: Annotated[Path, typer.Option("--output", "-o", metavar="OUT.rrd",
                                         help="Rerun recording to write; it appears when "
                                              "complete.")],
    start: StartOpt = None,
    end: EndOpt = None,
    unit: Annotated[list[str] | None, typer.Option(
        "--unit", "-u", metavar="NAME",
        help="Only this unit (repeatable). Default: every unit.")] = None,
    max_rate: Annotated[float | None, typer.Option(
        "--max-rate", metavar="HZ",
        help="An overview: each plotted line as the least and the greatest value of each "
             "1/HZ s bin, at the instants they happened (so every spike and extreme "
             "shows), attitude and arrows at HZ; status and events whole. Default: full "
             f"rate for up to {FULL_RATE_SAMPLES:,} samples, else the highest of "
             f"{_RATES} Hz that keeps each line within as many rows.")] = None,
    mag_cal: MagCalOpt = None,
    mounts: Annotated[Path | None, typer.Option(
        "--mounts", metavar="MOUNTS.yaml",
        help="How units on one body are mounted (gx3 align writes it): each unit it names "
             "is drawn in the reference's axes (its vectors and attitude turned, as gx3 "
             "export --mounts does) and on the reference's time (its samples moved by "
             "time_shift_s); the file, its SHA-256 and what it holds are the recording's "
             "gx3_mounts property.")] = None,
    force: ForceOpt = False,
) -> None:
    """Render an archive, or a window of it, into a Rerun recording with the live view's
    layout.

    Every unit's attitude in a north-east-down scene, its signals by quantity, status
    and events, on the timelines `time` and `device_time`. Always a recording the viewer
    can hold: a window small enough at full rate, a longer one as an overview (see
    --max-rate), said so with the command for full rate on a window. Only the chunks of
    the window are read. An archive cut short (a killed recorder) is rendered up to its
    last complete chunk; a corrupt chunk or a message that is not what its topic says is
    left out with a warning.
    """
    from bridge.analysis.mounts import read_mounts
    from bridge.archive.outputs import named_format
    from bridge.archive.times import TimeSpan
    from bridge.archive.walk import sample_span
    from bridge.exceptions import ArchiveReadError
    from bridge.viz.review import plan
    from bridge.viz.thin import bin_width_ns

    named_format(output, ".rrd")  # refused before the archive is read
    window = TimeSpan(start, end)  # and a span that is none, where it can be
    irons = _irons(mag_cal)
    mounted = None if mounts is None else read_mounts(mounts)  # a refusal is exit 2
    if not archive.is_file():
        raise fail(f"{archive}: no such file; give an archive (gx3 record -o FILE.mcap)")
    if max_rate is not None:
        try:
            bin_width_ns(max_rate)
        except ValueError as exc:
            raise fail(f"--max-rate: {exc}") from None
    try:
        span = sample_span(archive)
    except ArchiveReadError as exc:
        raise fail(str(exc)) from None
    try:
        review = plan(span, unit, window, max_rate)
    except ValueError as exc:
        raise fail(f"{archive}: {exc}") from None
    if missing := [i.unit for i in irons if i.unit not in review.units]:
        raise fail(f"--mag-cal: the calibration of unit {missing[0]} has no samples in "
                   f"{archive} (units shown: {', '.join(review.units)})")
    if mounted is not None:
        mounted.check_units(sorted(span.counts))
    from bridge.viz.mounted import MountedLogger  # Rerun loads once there is work for it
    from bridge.viz.sources import log_archive

    with written(output, [archive], force, suffixes=(".rrd",)) as temp:
        progress = Progress(TextColumn("rendering"), BarColumn(), MofNCompleteColumn(),
                            console=err, transient=True, disable=not err.is_terminal)
        try:
            # nobody waits for a row of an archive: sends of max_rows, the fewest chunks
            logger = MountedLogger(mounted, irons, temp, review.units,
                                   recording_id=archive.stem, max_rate_hz=review.max_rate_hz,
                                   latency_s=math.inf)
        except (OSError, RuntimeError) as exc:  # Rerun says RuntimeError
            raise fail(f"{output}: cannot write ({exc})", FAILED) from None
        with progress:
            task = progress.add_task("rrd", total=review.samples)
            logged = log_archive(
                archive, logger, units=review.units, start_ns=review.start_ns,
                end_ns=review.end_ns, progress=lambda n: progress.advance(task, n),
                on_problem=lambda text: err.print(f"[yellow]{escape(text)}[/]"))
            logger.close()
    units = counted(len(review.units), "unit")
    if review.max_rate_hz is None:
        err.print(f"wrote {output}: {counted(logged, 'sample')} of {units}; "
                  f"open it with: rerun {output}")
        return
    why = f"--max-rate {review.max_rate_hz:g}" if review.asked else \
        f"more than {FULL_RATE_SAMPLES:,} samples"
    err.print(f"wrote {output}: an overview of {counted(logged, 'sample')} of {units} "
              f"({why}): each line's least and greatest value of each "
              f"{_width(review.max_rate_hz)}, attitude once a bin, status and events whole; "
              f"open it with: rerun {output}\nfull rate on a window: "
              f"{_window_command(archive, output, review, unit)}", highlight=False)


_RATES = ", ".join(f"{r:g}" if r >= 0.1 else f"1/{round(1 / r)}" for r in OVERVIEW_RATES_HZ)


def _width(rate_hz: float) -> str:
    """A bin's width in words: 100 ms, 1 s, 1 min."""
    seconds = 1 / rate_hz
    if seconds < 1:
        return f"{seconds * 1000:g} ms"
    return f"{seconds:g} s" if seconds < 60 else f"{seconds / 60:g} min"


def _window_command(archive: Path, output: Path, review: Review, units: list[str] | None
                    ) -> str:
    """``gx3 rrd`` of as much of the window, from its start, as full rate fits in."""
    start = review.offset_s
    length = min(review.full_rate_seconds(), review.seconds)
    chosen = "".join(f" -u {shlex.quote(u)}" for u in review.units) if units else ""
    window = output.with_name(f"{output.stem}-window{output.suffix}")
    return (f"gx3 rrd {shlex.quote(str(archive))} -o {shlex.quote(str(window))} "
            f"--start {start:g} --end {start + length:g}{chosen}")


def _display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def live_recording(recording_id: str, spawn: bool, serve: bool, save: Path | None,
                   bind: str = "127.0.0.1", grpc_port: int = 9876,
                   web_port: int = 9090) -> Any:
    """A Rerun recording streaming to a spawned viewer, a served one, and/or a file;
    the URLs to open a served one are printed."""
    import rerun as rr

    recording = rr.RecordingStream("gx3", recording_id=recording_id)
    sinks: list[Any] = []
    if spawn:
        rr.spawn(port=grpc_port, connect=False)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{grpc_port}/proxy"))
    if serve:
        server = rr.GrpcServerSink(bind, grpc_port)
        sinks.append(server)
    if save is not None:
        sinks.append(rr.FileSink(save))
    recording.set_sinks(*sinks)
    if serve:
        rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=server.uri)
        err.print(f"web viewer: http://{bind}:{web_port}/?url={server.uri}\n"
                  f"native viewer: rerun --connect {server.uri}")
    return recording


@app.command("view")
def view(
    spawn: Annotated[bool | None, typer.Option(
        "--spawn/--no-spawn", help="Start a Rerun viewer on this machine (default: when "
                                   "there is a display and no --serve or --save).")] = None,
    serve: Annotated[bool, typer.Option(
        "--serve", help="Serve the recording for remote or web viewers and print the URLs "
                        "to open.")] = False,
    bind: Annotated[str, typer.Option(help="Address --serve listens on.")] = "127.0.0.1",
    grpc_port: Annotated[int, typer.Option(help="gRPC port of --serve (rerun --connect).")]
    = 9876,
    web_port: Annotated[int, typer.Option(help="Web viewer port of --serve.")] = 9090,
    save: Annotated[Path | None, typer.Option(
        metavar="FILE.rrd", help="Also write the recording to this file (an existing one "
                                 "only with --force).")] = None,
    force: ForceOpt = False,
    window: Annotated[float, typer.Option(
        min=1.0, metavar="SECONDS", help="Plots show the last so many seconds.")] = 30.0,
    units: Annotated[str, typer.Option(
        metavar="KEYEXPR", help="Units to show: a name or a key expression chunk.")] = "*",
    prefix: PrefixOpt = "gx3",
    duration: Annotated[float | None, typer.Option(
        min=0.0, help="Stop after this many seconds (default: until Ctrl-C).")] = None,
    zenoh_config: ZenohConfigOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    mode: ModeOpt = None,
    mag_cal: MagCalOpt = None,
    log_level: LogLevelOpt = LogLevel.info,
    log_format: LogFormatOpt = LogFormat.text,
) -> None:
    """Show the live fleet in Rerun: attitude in 3-D and every signal, as it arrives.

    Spawn a local viewer where there is a display, --serve for a remote or web
    viewer, --save FILE.rrd; any combination.
    """
    log_to(log_level, log_format)
    from bridge.bus.session import open_session
    from bridge.viz.magcal import IronedLogger
    from bridge.viz.sources import LiveFeed

    irons = _irons(mag_cal)

    if spawn is None:
        spawn = _display() and not serve and save is None
    if not (spawn or serve or save):
        raise fail("no display here to spawn a viewer: use --serve (remote or web viewer) "
                   "and/or --save FILE.rrd")
    if save is not None:
        refused(save, force=force, suffixes=(".rrd",))
    # before anything is made: a stop while it starts (systemd's SIGTERM) ends it cleanly
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    # first: a session that cannot open leaves no empty FILE.rrd
    session = open_session(zenoh_config, connect=connect or [], listen=listen or [], mode=mode)
    try:
        recording = live_recording(time.strftime("live-%Y%m%d-%H%M%S"), spawn, serve, save,
                                   bind, grpc_port, web_port)
    except (OSError, RuntimeError) as exc:  # Rerun says RuntimeError
        session.close()
        raise fail(f"cannot start the Rerun recording ({exc})") from None
    logger = IronedLogger(irons, recording, window_s=window)
    feed = LiveFeed(session, logger, prefix, units)
    try:
        stop.wait(duration)
    finally:
        feed.close()
        logger.close()
        recording.flush()
        session.close()
    err.print(f"{counted(feed.samples, 'sample')} shown" + (f"; saved {save}" if save else ""))
