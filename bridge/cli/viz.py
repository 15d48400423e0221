"""`gx3 view` (the live fleet in Rerun) and `gx3 rrd` (an archive rendered to .rrd)."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from bridge._text import counted
from bridge.cli.bridge import ConnectOpt, ListenOpt, ModeOpt, PrefixOpt, ZenohConfigOpt
from bridge.cli.common import (
    FAILED,
    ForceOpt,
    LogFormat,
    LogFormatOpt,
    LogLevel,
    LogLevelOpt,
    app,
    err,
    fail,
    log_to,
    refused,
    written,
)

if TYPE_CHECKING:
    from bridge.analysis.magcal import UnitIron

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
    """Render an archive into a Rerun recording with the live view's layout.

    Every unit's attitude in a north-east-down scene, its signals by quantity, status
    and events, on the timelines `time` and `device_time`. An archive cut short (a
    killed recorder) is rendered up to its last complete chunk; a corrupt chunk or a
    message that is not what its topic says is left out with a warning.
    """
    from bridge.analysis.mounts import read_mounts
    from bridge.archive.explain import describe_problem
    from bridge.archive.walk import read_archive
    from bridge.viz.mounted import MountedLogger
    from bridge.viz.sources import log_archive

    irons = _irons(mag_cal)
    mounted = None if mounts is None else read_mounts(mounts)  # a refusal is exit 2

    if not archive.is_file():
        raise fail(f"{archive}: no such file; give an archive (gx3 record -o FILE.mcap)")
    with written(output, [archive], force, suffixes=(".rrd",)) as temp:
        found = read_archive(archive)
        if not found.complete:
            err.print(f"[yellow]{describe_problem(found)}[/]")
        counts = found.counts()
        total = sum(counts[t][0] for t in found.topics("imu") if t in counts)
        if total == 0:
            raise fail(f"{archive}: no samples in it; give an archive gx3 recorded units "
                       "into")
        if missing := [i.unit for i in irons if i.unit not in found.units()]:
            raise fail(f"--mag-cal: the calibration of unit {missing[0]} has no samples in "
                       f"{archive} (units: {', '.join(found.units())})")
        if mounted is not None:
            mounted.check_units(found.units())
        progress = Progress(TextColumn("rendering"), BarColumn(), MofNCompleteColumn(),
                            console=err, transient=True, disable=not err.is_terminal)
        try:
            logger = MountedLogger(mounted, irons, temp, found.units(),
                                   recording_id=archive.stem)
        except (OSError, RuntimeError) as exc:  # Rerun says RuntimeError
            raise fail(f"{output}: cannot write ({exc})", FAILED) from None
        with progress:
            task = progress.add_task("rrd", total=total)
            logged = log_archive(found, logger, lambda n: progress.advance(task, n))
            logger.close()
    err.print(f"wrote {output}: {counted(logged, 'sample')} of "
              f"{counted(len(found.units()), 'unit')}; "
              f"open it with: rerun {output}")


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
