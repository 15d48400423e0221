"""`gx3 record`: every unit on Zenoh into one MCAP archive, with a live view."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.live import Live
from rich.progress import Progress, TextColumn
from rich.table import Table

from bridge.cli.bridge import ConnectOpt, ListenOpt, ModeOpt, PrefixOpt, ZenohConfigOpt
from bridge.cli.common import (
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


def _table(rows: list[dict[str, Any]], elapsed: float, written: int, path: Path) -> Table:
    table = Table(title=f"recording {path} · {elapsed:,.0f} s · {written:,} messages",
                  title_justify="left", box=None, pad_edge=False)
    for name, justify in (("unit", "left"), ("state", "left"), ("samples/s", "right"),
                          ("samples", "right"), ("drops", "right"), ("checksum", "right"),
                          ("offset ms", "right"), ("drift ppm", "right"),
                          ("recorded", "right"), ("MB", "right")):
        table.add_column(name, justify=justify)  # type: ignore[arg-type]
    for r in rows:
        table.add_row(
            r["unit"], "[green]live[/]" if r["alive"] else "[red]gone[/]", f"{r['rate']:,.0f}",
            f"{r['samples']:,}", str(r["dropped"]), str(r["checksum_failures"]),
            "–" if r["offset_ms"] is None else f"{r['offset_ms']:,.1f}",
            "–" if r["drift_ppm"] is None else f"{r['drift_ppm']:+.1f}",
            f"{r['recorded_s']:,.0f} s", f"{r['bytes'] / 1e6:,.1f}")
    if not rows:
        table.add_row("[dim]waiting for units…[/]", *[""] * 9)
    return table


@app.command("record")
def record(
    output: Annotated[Path | None, typer.Option(
        "--output", "-o", metavar="FILE.mcap",
        help="Archive to write (default: gx3-DATE-TIME.mcap here). An existing file is "
             "refused unless --force; one another recorder is writing, always.")] = None,
    units: Annotated[str, typer.Option(
        metavar="KEYEXPR", help="Units to record: a name, or a key expression chunk "
                                "such as '*' (every unit) or 'lab-*'.")] = "*",
    prefix: PrefixOpt = "gx3",
    raw: Annotated[bool, typer.Option(
        "--raw", help="Also record each unit's raw reads where its bridge publishes them "
                 "(gx3 bridge --publish-raw); gx3 replay takes the archive.")] = False,
    history: Annotated[int, typer.Option(
        min=0, help="Ask each bridge's cache for this many past samples on joining.")] = 0,
    rrd: Annotated[Path | None, typer.Option(
        metavar="FILE.rrd", help="Also write a Rerun recording as the archive is recorded (an "
                                 "existing one only with --force).")]
    = None,
    split_mb: Annotated[float | None, typer.Option(
        min=1.0, help="Start a new numbered file (FILE_0001.mcap, FILE_0002.mcap, ...) when "
                      "one reaches this size, MB. Numbers go on after the parts already "
                      "there: a restarted recorder adds parts, never replaces one.")] = None,
    split_minutes: Annotated[float | None, typer.Option(
        min=0.1, help="Start a new numbered file after this many minutes (numbered as "
                      "--split-mb).")] = None,
    duration: Annotated[float | None, typer.Option(
        min=0.0, help="Stop after this many seconds (default: until Ctrl-C).")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q",
                                        help="No live view; errors and warnings only.")]
    = False,
    force: ForceOpt = False,
    zenoh_config: ZenohConfigOpt = None,
    connect: ConnectOpt = None,
    listen: ListenOpt = None,
    mode: ModeOpt = None,
    log_level: LogLevelOpt = LogLevel.info,
    log_format: LogFormatOpt = LogFormat.text,
) -> None:
    """Record every unit's samples, status, events and info into one MCAP archive.

    Units are found by their bridges' liveliness tokens and may join late, leave and
    come back. Samples keep the very protobuf bytes from Zenoh, with the schemas
    embedded. Each unit also gets a foxglove.FrameTransform channel (REP-103 frames:
    gx3_world east-north-up, gx3_world_ned, gx3_<unit>_frd) with a point cloud of its
    body axes, and every event is also a foxglove.Log on <prefix>/log: Foxglove's 3D
    and Log panels show them with no plugin, and `rerun FILE.mcap` opens a 3-D view of
    each unit's axes beside a text log of the events (it plots no samples: `gx3 rrd`
    renders those). Messages are written in log-time order: each
    waits half a second for any logged before it, and the file is flushed every
    second, so a crash loses at most the last 1.5 s (`gx3 repair` finishes such a
    file). Ctrl-C or SIGTERM finish the archive properly. Each file is locked while it
    is written: a second recorder given the same file is refused at once, naming the
    first one's process.

    Every message is checked before it is archived (the CRC-32 in its attachment, its
    unit against its key). What does not reach the archive (samples lost in transit,
    messages rejected, samples shed while the disk could not keep up) and a unit
    published by two bridges at once are archived as events of the unit, with count
    and span, and printed as warnings.
    """
    log_to(log_level, log_format)
    from bridge.bus.keys import BadName, check_prefix
    from bridge.bus.session import SessionError, open_session
    from bridge.recorder.archive import ArchiveError, ArchiveWriter
    from bridge.recorder.live import Recorder

    try:
        check_prefix(prefix)
    except BadName as exc:
        raise fail(str(exc)) from None
    path = output or Path(time.strftime("gx3-%Y%m%d-%H%M%S.mcap"))
    if rrd is not None:
        if rrd.absolute() == path.absolute():
            raise fail(f"--rrd {rrd} is the archive's own file; give the recording "
                       "another name")
        refused(rrd, force=force)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:  # first: a file refused (exists, being written) is said at once
        writer = ArchiveWriter(path, prefix=prefix,
                               split_bytes=None if split_mb is None else int(split_mb * 1e6),
                               split_seconds=None if split_minutes is None
                               else split_minutes * 60, force=force)
    except ArchiveError as exc:
        raise fail(str(exc)) from None

    def discard() -> None:
        """Nothing recorded yet: leave no empty archive behind."""
        writer.close()
        for part in writer.paths:
            part.unlink(missing_ok=True)

    try:
        session = open_session(zenoh_config, connect=connect or [], listen=listen or [],
                               mode=mode)
    except SessionError as exc:
        discard()
        raise fail(str(exc)) from None
    console = err
    table = not quiet and log_format is LogFormat.text  # the live table is for people

    def announce(unit: str, joined: bool) -> None:
        if quiet:
            return
        console.print(f"[dim]{time.strftime('%H:%M:%S')}[/] {unit} "
                      + ("[green]joined[/]" if joined else "[red]left[/]"))

    logger = None
    if rrd is not None:
        from bridge.viz.logger import RerunLogger
        from bridge.viz.sources import log_messages

        try:
            # long recordings: bigger chunks, and no in-memory index of every chunk
            logger = RerunLogger(rrd, recording_id=path.stem, latency_s=2.0, write_footer=False)
        except (OSError, RuntimeError) as exc:  # Rerun says RuntimeError
            discard()
            session.close()
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise fail(f"--rrd {rrd}: cannot write ({why})") from None
        sink = logger

        def to_rerun(messages: list[Any]) -> None:
            log_messages(sink, messages, prefix)
    started = time.monotonic()
    recorder = Recorder(session, writer, prefix, units, raw, history, on_unit=announce,
                        on_written=None if logger is None else to_rerun,
                        on_event=lambda unit, event: console.print(
                            f"[yellow]warning:[/] {event.detail}", highlight=False,
                            soft_wrap=True))
    try:
        with Live(console=console, refresh_per_second=2, transient=True,
                  auto_refresh=False) as live:
            while not stop.is_set() and recorder.error is None:
                if duration is not None and time.monotonic() - started >= duration:
                    break
                recorder.run_once(0.25)
                if table:
                    live.update(_table(recorder.snapshot(), time.monotonic() - started,
                                       recorder.written, path), refresh=True)
    finally:
        recorder.close()
        if logger is not None:
            logger.close()
        try:
            writer.close()
        except ArchiveError as exc:
            recorder.error = recorder.error or exc
        session.close()
    if recorder.error is not None:
        raise fail(str(recorder.error), 1)
    if table:
        console.print(_table(recorder.snapshot(), time.monotonic() - started,
                             recorder.written, path))
    if not quiet:
        files = ", ".join(str(p) for p in writer.paths)
        console.print(f"wrote {files}; {recorder.misses} samples reported lost in transit")
    err.file.flush()


@app.command("replay")
def replay_command(
    captures: Annotated[list[Path], typer.Argument(
        metavar="CAPTURE.mcap...", help="Raw captures (gx3 bridge --capture, or archives "
                                        "recorded with --raw).")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", metavar="ARCHIVE.mcap",
        help="Archive to write; it appears when complete (nothing is left there if the "
             "replay fails or is interrupted).")],
    prefix: PrefixOpt = "gx3",
    jobs: Annotated[int, typer.Option(
        "--jobs", "-j", min=0, help="Processes replaying at once, a capture file each (a unit "
                                    "each when there are fewer files); 0: one per core.")] = 0,
    force: ForceOpt = False,
    transport: Annotated[str | None, typer.Option(
        metavar="uart|usb|usb-serial",
        help="Time every unit as linked this way (a UART; the unit's own USB port; a "
             "USB-serial adapter), whatever a capture's metadata says or its receive "
             "times show.")] = None,
) -> None:
    """Run raw captures through the bridge's framer and timing into an archive, no Zenoh.

    Gives the samples and live time_ns the bridge published when the capture was
    made. A capture from another program is understood from its bytes: record type,
    rate and float byte order; and its link from its receive times (reads crowding
    just after the host's 1 ms USB frames, reads ending mid-record, their spacing
    against the serial line's byte time: UART, the unit's own USB port, or a
    USB-serial adapter with a 1 or 16 ms latency timer). What was inferred is said on
    the unit's line. Units are replayed side by side on the machine's cores; each
    unit's samples are the same as replayed alone.
    """
    from bridge.recorder.archive import ArchiveError
    from bridge.recorder.read import ArchiveReadError
    from bridge.recorder.replay import Replayed, ReplayError, UnusableCapture, replay
    from bridge.timing.stream import TRANSPORTS

    if transport is not None and transport not in TRANSPORTS:
        raise fail(f"--transport {transport!r}: use " + ", ".join(TRANSPORTS))

    for path in captures:
        if not path.is_file():
            raise fail(f"{path}: no such file; give a raw capture (gx3 bridge --capture)")

    # refreshed here, not by Rich's thread: replay forks its workers after this starts
    progress = Progress(TextColumn("replaying"), TextColumn("{task.completed:,.0f} samples"),
                        TextColumn("{task.fields[units]} unit(s) done"), console=err,
                        transient=True, auto_refresh=False, disable=not err.is_terminal)
    task = progress.add_task("replay", total=None, units=0)
    shown = [0.0]

    def report(result: Replayed) -> None:
        events = ", ".join(f"{n} {kind}" for kind, n in sorted(result.events.items()))
        guessed = f" (inferred: {', '.join(result.inferred)})" if result.inferred else ""
        progress.console.print(f"{result.unit}: {result.samples:,} samples"
                               + (f", {events}" if events else "") + guessed)
        progress.update(task, units=progress.tasks[0].fields["units"] + 1, refresh=True)

    def advance(samples: int) -> None:
        progress.advance(task, samples)
        if time.monotonic() - shown[0] >= 0.2:
            shown[0] = time.monotonic()
            progress.refresh()

    with written(output, captures, force) as temp:
        try:
            with progress:
                results = replay(captures, temp, prefix, on_unit=report, jobs=jobs or None,
                                 on_samples=advance, transport=transport)
        except (ArchiveReadError, UnusableCapture) as exc:
            raise fail(str(exc)) from None
        except (ReplayError, ArchiveError) as exc:
            raise fail(str(exc).replace(str(temp), str(output)), 1) from None
    err.print(f"wrote {output}: {sum(r.samples for r in results):,} samples of "
              f"{len(results)} unit(s)")
